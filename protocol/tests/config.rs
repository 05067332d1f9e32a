//! Config loading: precedence, all-at-once error reporting, resolved round trip, shipped files.

use std::path::{Path, PathBuf};

use protocol::config::{FrProbStep, FutureCountAveraging, LowAlgo, NodePosition};
use protocol::{Config, ConfigError, ConfigErrors};

/// A TOML file in a fresh folder of the system temp dir, removed with the folder on drop
/// (also when the test fails).
struct TempToml {
    dir: PathBuf,
    path: PathBuf,
}

impl TempToml {
    fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for TempToml {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Writes `text` to `name` in a folder of its own (tests run in parallel).
fn temp_toml(name: &str, text: &str) -> TempToml {
    let dir =
        std::env::temp_dir().join(format!("asi-protocol-tests-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("create temp dir");
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write temp toml");
    TempToml { dir, path }
}

fn invalid(result: Result<Config, ConfigError>) -> ConfigErrors {
    match result {
        Err(ConfigError::Invalid(errors)) => errors,
        other => panic!("expected ConfigError::Invalid, got {other:?}"),
    }
}

fn sets(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| (*s).to_owned()).collect()
}

#[test]
fn defaults_validate() {
    Config::default()
        .validate()
        .expect("defaults must validate");
    let loaded = Config::load(None, &[]).expect("no file, no overrides");
    assert_eq!(loaded, Config::default());
}

#[test]
fn unknown_key_wrong_type_and_out_of_range_are_reported_together() {
    let toml = temp_toml(
        "bad.toml",
        r#"
[run]
nmae = "typo"

[learner.high]
gamma = 1.5
batch_size = "big"

[learner.low]
algo = "ppo"

[bogus]
x = 1
"#,
    );
    let errors = invalid(Config::load(
        Some(toml.path()),
        &sets(&["graph.cell_size=-2"]),
    ));
    for path in [
        "run.nmae",
        "learner.high.batch_size",
        "learner.high.gamma",
        "learner.low.algo",
        "bogus",
        "graph.cell_size",
    ] {
        assert!(errors.has_path(path), "missing issue for {path}:\n{errors}");
    }
    assert_eq!(errors.issues.len(), 6, "{errors}");
    let text = errors.to_string();
    assert!(
        text.contains("learner.high.gamma = 1.5: must be in (0, 1)"),
        "{text}"
    );
    assert!(text.contains("unknown key"), "{text}");
    assert!(text.contains("invalid type"), "{text}");
}

#[test]
fn validate_lists_every_problem_with_its_value() {
    let mut config = Config::default();
    config.learner.high.gamma = 1.5;
    config.learner.low.tau = 0.0;
    config.asi.fr_k_range = [5, 3];
    config.asi.fr_waypoint_straightness = 1.2;
    config.asi.fr_prob_schedule = vec![FrProbStep {
        from_episode: 10,
        p: 1.5,
    }];
    config.run.n_actors = 100;
    let errors = config.validate().expect_err("invalid on purpose");
    for path in [
        "learner.high.gamma",
        "learner.low.tau",
        "asi.fr_k_range",
        "asi.fr_waypoint_straightness",
        "asi.fr_prob_schedule",
        "asi.fr_prob_schedule[0].p",
        "transport.max_actors",
    ] {
        assert!(errors.has_path(path), "missing issue for {path}:\n{errors}");
    }
}

#[test]
fn set_overrides_beat_the_file_which_beats_defaults() {
    let toml = temp_toml(
        "precedence.toml",
        "[learner.high]\ngamma = 0.95\nlr = 1e-3\n[hierarchy]\nc = 10\n",
    );
    let config = Config::load(
        Some(toml.path()),
        &sets(&["learner.high.gamma=0.9", "env.task=antmaze-s"]),
    )
    .expect("valid");
    assert_eq!(config.learner.high.gamma, 0.9, "--set wins over the file");
    assert_eq!(config.learner.high.lr, 1e-3, "the file wins over defaults");
    assert_eq!(config.hierarchy.c, 10);
    assert_eq!(
        config.learner.high.tau, 0.005,
        "untouched fields keep defaults"
    );
    assert_eq!(
        config.env.task, "antmaze-s",
        "bare strings are accepted in --set"
    );
}

#[test]
fn later_overrides_win_and_accept_toml_values() {
    let config = Config::load(
        None,
        &sets(&[
            "learner.high.hidden=[64, 64, 64]",
            "asi.fr_prob_schedule=[{from_episode = 0, p = 0.1}]",
            "graph.node_position=\"centre\"",
            "learner.low.algo=deterministic",
            "env.episode_length=200",
            "asi.si_alpha=0.5",
            "asi.si_alpha=0.1",
        ]),
    )
    .expect("valid");
    assert_eq!(config.learner.high.hidden, vec![64, 64, 64]);
    assert_eq!(
        config.asi.fr_prob_schedule,
        vec![FrProbStep {
            from_episode: 0,
            p: 0.1
        }]
    );
    assert_eq!(config.graph.node_position, NodePosition::Centre);
    assert_eq!(config.learner.low.algo, LowAlgo::Deterministic);
    assert_eq!(config.env.episode_length, Some(200));
    assert_eq!(config.asi.si_alpha, 0.1);
}

#[test]
fn malformed_overrides_are_refused_with_the_argument() {
    for arg in ["no-equals-sign", "=1", "run..name=x", "run name=x"] {
        match Config::load(None, &sets(&[arg])) {
            Err(ConfigError::Override { arg: got, .. }) => assert_eq!(got, arg),
            other => panic!("{arg}: expected Override error, got {other:?}"),
        }
    }
    match Config::load(None, &sets(&["run.name=x", "run.name.deeper=1"])) {
        Err(ConfigError::Override { arg, reason }) => {
            assert_eq!(arg, "run.name.deeper=1");
            assert!(reason.contains("`run.name` is a value"), "{reason}");
        }
        other => panic!("expected Override error, got {other:?}"),
    }
    // A section that does not exist yet is created, so a nested key under a scalar field that
    // was never set is reported as a type error at that field instead.
    let errors = invalid(Config::load(None, &sets(&["run.name.deeper=1"])));
    assert!(errors.has_path("run.name"), "{errors}");
}

#[test]
fn wrong_type_in_override_names_the_path() {
    let errors = invalid(Config::load(
        None,
        &sets(&["learner.high.gamma=0.9x", "eval.n_episodes=-1"]),
    ));
    assert!(errors.has_path("learner.high.gamma"), "{errors}");
    assert!(errors.has_path("eval.n_episodes"), "{errors}");
    let errors = invalid(Config::load(None, &sets(&["learner.high=3"])));
    assert!(errors.has_path("learner.high"), "{errors}");
}

#[test]
fn toml_syntax_errors_name_the_file() {
    let toml = temp_toml("syntax.toml", "[run\nname = 1\n");
    match Config::load(Some(toml.path()), &[]) {
        Err(ConfigError::Syntax { origin, .. }) => assert!(origin.contains("syntax.toml")),
        other => panic!("expected Syntax error, got {other:?}"),
    }
    match Config::load(Some(Path::new("/nonexistent/asi.toml")), &[]) {
        Err(ConfigError::Read { .. }) => {}
        other => panic!("expected Read error, got {other:?}"),
    }
}

#[test]
fn resolved_toml_round_trips_to_an_equal_config() {
    let mut config = Config::default();
    config.run.max_env_steps = Some(1_000_000);
    config.env.episode_length = Some(300);
    config.learner.low.updates_per_env_step = Some(0.25);
    config.encoder.negative_offset = Some(15);
    config.exploration.future_count_averaging = FutureCountAveraging::CodeCompatible;
    config.exploration.far_goal_fraction = 2.0 / 3.0;
    let text = config.to_resolved_toml().expect("serializable");
    let back = Config::from_toml_str(&text, "resolved").expect("resolved config loads");
    assert_eq!(back, config);

    let defaults = Config::default();
    let text = defaults.to_resolved_toml().expect("serializable");
    assert!(
        !text.contains("episode_length"),
        "absent options are omitted:\n{text}"
    );
    assert_eq!(
        Config::from_toml_str(&text, "resolved").expect("loads"),
        defaults
    );
}

#[test]
fn derived_values_follow_the_spec() {
    let config = Config::default();
    assert_eq!(config.learner.low.updates_per_env_step_for(500), 0.4);
    assert_eq!(config.learner.low.updates_per_env_step_for(1000), 0.2);
    assert_eq!(config.encoder.negative_offset_or(config.hierarchy.c), 20);
    let fr = &config.asi;
    assert_eq!(
        [
            fr.fr_prob(0),
            fr.fr_prob(499),
            fr.fr_prob(500),
            fr.fr_prob(700),
            fr.fr_prob(10_000)
        ],
        [0.2, 0.2, 0.3, 0.4, 0.4]
    );
    assert_eq!(config.run.run_dir(), PathBuf::from("runs/antmaze-u"));
}

#[test]
fn every_shipped_config_loads_and_validates() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).expect("configs/ exists") {
        let path = entry.expect("dir entry").path();
        if path.extension().is_some_and(|ext| ext == "toml") {
            let config = Config::load(Some(&path), &[])
                .unwrap_or_else(|err| panic!("{}: {err}", path.display()));
            let stem = path
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default()
                .to_owned();
            assert_eq!(
                config.run.name,
                stem,
                "{}: run.name should match the file name",
                path.display()
            );
            assert!(
                config.notes().is_empty(),
                "{}: {:?}",
                path.display(),
                config.notes()
            );
            names.push(stem);
        }
    }
    names.sort();
    let expected = [
        "ant-fourrooms",
        "antmaze-s",
        "antmaze-u",
        "antmaze-w",
        "halfcheetah-hurdle",
        "pointmaze-s",
        "pointmaze-u",
        "smoke",
    ];
    for name in expected {
        assert!(
            names.iter().any(|n| n == name),
            "configs/{name}.toml missing; found {names:?}"
        );
    }
}

#[test]
fn the_default_config_file_is_the_defaults() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/antmaze-u.toml");
    let config = Config::load(Some(&path), &[]).expect("loads");
    assert_eq!(config, Config::default());
}

/// `configs/antmaze-u-1000.toml` doubles the episode and halves every count in episodes, so
/// its episode e is the default config's episode 2e in env steps and schedules: the defaults
/// with exactly those changes (a default counted in episodes and left out of the file fails
/// here).
#[test]
fn the_1000_step_config_is_the_defaults_with_every_episode_count_halved() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/antmaze-u-1000.toml");
    let config = Config::load(Some(&path), &[]).expect("loads");
    let mut expected = Config::default();
    expected.run.name = "antmaze-u-1000".into();
    expected.env.episode_length = Some(1000);
    // Updates per env step stay those of 500-step episodes (200 per episode / 500).
    let low_default = expected.learner.low.updates_per_env_step_for(500);
    expected.learner.low.updates_per_env_step = Some(low_default);
    let half = |n: u64| {
        assert_eq!(n % 2, 0, "{n} episodes cannot be halved");
        n / 2
    };
    expected.run.max_episodes = half(expected.run.max_episodes);
    expected.eval.interval_episodes = half(expected.eval.interval_episodes);
    expected.learner.high.random_episodes = half(expected.learner.high.random_episodes);
    let det = &mut expected.learner.low.deterministic;
    det.lr_decay_episodes = half(det.lr_decay_episodes);
    let enc = &mut expected.encoder;
    enc.interval_episodes = half(enc.interval_episodes);
    enc.first_round_episode = half(enc.first_round_episode);
    enc.stable_coeff_switch_episode = half(enc.stable_coeff_switch_episode);
    let ex = &mut expected.exploration;
    ex.potential_start_episode = half(ex.potential_start_episode);
    ex.explore_start_episode = half(ex.explore_start_episode);
    ex.future_count_interval_episodes = half(ex.future_count_interval_episodes);
    ex.count_prob_interval_episodes = half(ex.count_prob_interval_episodes);
    ex.count_prob_success_unit /= 2.0;
    let asi = &mut expected.asi;
    asi.fr_start_episode = half(asi.fr_start_episode);
    asi.si_start_episode = half(asi.si_start_episode);
    for step in &mut asi.fr_prob_schedule {
        step.from_episode = half(step.from_episode);
    }
    assert_eq!(config, expected);
}

#[test]
fn fr_before_the_first_phi_round_is_noted_not_refused() {
    assert!(Config::default().notes().is_empty());
    let early = Config::load(None, &sets(&["asi.fr_start_episode=60"])).expect("valid");
    let notes = early.notes();
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(
        notes[0].contains("asi.fr_start_episode = 60")
            && notes[0].contains("encoder.first_round_episode = 100"),
        "{notes:?}"
    );
    // At the first round, or with FR off, there is nothing to note.
    for ok in [
        &["asi.fr_start_episode=100"][..],
        &["asi.fr_start_episode=60", "asi.frontier_reaching=false"][..],
    ] {
        let config = Config::load(None, &sets(ok)).expect("valid");
        assert!(config.notes().is_empty(), "{ok:?}: {:?}", config.notes());
    }
}

#[test]
fn a_route_table_cap_beyond_16_bit_node_ids_is_refused() {
    let errors = invalid(Config::load(
        None,
        &sets(&["graph.route_table_max_nodes=65536"]),
    ));
    assert!(errors.has_path("graph.route_table_max_nodes"), "{errors}");
    for ok in ["0", "65535"] {
        Config::load(None, &sets(&[&format!("graph.route_table_max_nodes={ok}")]))
            .expect("in range");
    }
}

#[test]
fn the_high_target_clamp_is_off_by_default_written_only_when_on_and_round_trips() {
    let defaults = Config::default();
    assert!(!defaults.learner.high.clip_target);
    let text = defaults.to_resolved_toml().expect("serializable");
    assert!(
        !text.contains("clip_target"),
        "off is not written, so older fingerprints hold:\n{text}"
    );
    let on = Config::load(None, &sets(&["learner.high.clip_target=true"])).expect("loads");
    assert!(on.learner.high.clip_target);
    let text = on.to_resolved_toml().expect("serializable");
    assert!(text.contains("clip_target = true"), "{text}");
    assert_eq!(Config::from_toml_str(&text, "resolved").expect("loads"), on);
    let errors = invalid(Config::load(
        None,
        &sets(&["learner.high.clip_target=\"yes\""]),
    ));
    assert!(errors.has_path("learner.high.clip_target"), "{errors}");
}
