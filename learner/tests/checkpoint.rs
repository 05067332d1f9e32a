//! Learner checkpoints: a restored learner is the saved one (every file it writes again is
//! byte-identical, and it trains on exactly like the uninterrupted learner); incompatible,
//! corrupt or truncated checkpoints are refused with an error naming the file and problem.

mod common;

use std::fs;
use std::path::{Path, PathBuf};

use common::*;
use learner::learner::checkpoint::{
    checksum, latest_checkpoint, CheckpointError, Checksum, Manifest, MANIFEST,
};
use learner::Learner;

/// φ rounds every 4 episodes (60 steps each), so the encoder's Adam and the φ store are live;
/// replay capacity 256 low / 128 high transitions, so both rings wrap after 30 episodes.
fn config() -> protocol::Config {
    let mut c = common::config();
    c.replay.capacity_steps = 256;
    c.encoder.first_round_episode = 4;
    c.encoder.interval_episodes = 4;
    c.encoder.steps_per_round = 60;
    c.encoder.batch_size = 8;
    c.validate().unwrap();
    c
}

/// A fresh folder under the temp dir for one test, removed when dropped.
struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

fn scratch(name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("asi-ckpt-{}-{name}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

/// Trains until nothing is due (φ rounds run to completion).
fn train_all(l: &mut Learner) {
    while l.train(1_000).unwrap() > 0 {}
}

/// Ingests episodes `eps` (actor 0 and 1 alternating) and trains after each.
fn play(l: &mut Learner, eps: std::ops::Range<u64>) {
    for ep in eps {
        ingest_episode(l, ep as u32 % 2, ep, 10, 2, 4);
        train_all(l);
    }
}

/// A learner with wrapped buffers, finished φ rounds and SAC updates behind it.
fn trained() -> Learner {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    play(&mut l, 0..30);
    assert!(l.low_replay().ring().total() > 256, "the low ring wrapped");
    assert!(
        l.high_replay().ring().total() > 128,
        "the high ring wrapped"
    );
    assert!(l.phi_stats().rounds >= 2, "φ rounds ran");
    l
}

fn read_manifest(ckpt: &Path) -> Manifest {
    serde_json::from_slice(&fs::read(ckpt.join(MANIFEST)).unwrap()).unwrap()
}

fn losses(l: &Learner) -> Vec<(&'static str, f64)> {
    l.metrics()
        .into_iter()
        .filter(|(n, _)| n.starts_with("losses/") || n.starts_with("phi/triplet"))
        .collect()
}

/// The values of the U8 or I64 tensor `name` of a safetensors file.
fn i64_or_u8_values(file: &Path, name: &str) -> Vec<i64> {
    let bytes = fs::read(file).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let view = st.tensor(name).unwrap();
    match view.dtype() {
        safetensors::Dtype::U8 => view.data().iter().map(|&b| i64::from(b)).collect(),
        safetensors::Dtype::I64 => view
            .data()
            .chunks_exact(8)
            .map(|b| i64::from_le_bytes(b.try_into().unwrap()))
            .collect(),
        other => panic!("{name} is {other:?}"),
    }
}

#[test]
fn a_restored_learner_writes_the_same_files_and_trains_on_exactly_like_the_original() {
    let dir = scratch("round-trip");
    let mut original = trained();
    let saved = original.save_checkpoint(&config(), &dir).unwrap();
    assert_eq!(saved.manifest.sequence, 1);
    assert_eq!(saved.manifest.env_steps, 300);

    let (mut restored, info) = Learner::restore_checkpoint(&config(), DIMS, &saved.path).unwrap();
    assert_eq!(info.manifest, saved.manifest);
    assert_eq!(restored.progress(), original.progress());
    assert_eq!(restored.ingest_stats(), original.ingest_stats());
    assert_eq!(restored.run_schedule(), original.run_schedule());
    assert_eq!(restored.phi_stats().rounds, original.phi_stats().rounds);
    // The metrics show the latest SAC, φ and SI statistics until the next update of each
    // kind; they come back too (timings aside).
    let untimed = |l: &Learner| -> Vec<(&'static str, f64)> {
        l.metrics()
            .into_iter()
            .filter(|(n, _)| !n.contains("per_sec"))
            .collect()
    };
    assert!(losses(&original).iter().any(|(_, v)| *v != 0.0));
    assert_eq!(untimed(&restored), untimed(&original));
    for i in 0..original.low_replay().ring().len() {
        let (a, b) = (original.low_replay().get(i), restored.low_replay().get(i));
        assert_eq!(
            (a.obs, a.phi, a.action),
            (b.obs, b.phi, b.action),
            "low row {i}"
        );
        assert_eq!(
            (a.subgoal, a.next_obs),
            (b.subgoal, b.next_obs),
            "low row {i}"
        );
    }
    let si_len = original.self_imitation().buffer().len();
    assert!(si_len > 0, "the SI buffer holds entries");
    assert_eq!(restored.self_imitation().buffer().len(), si_len);
    let (a, b) = (
        original.self_imitation().buffer().parts(),
        restored.self_imitation().buffer().parts(),
    );
    assert_eq!((a.obs, a.goal, a.episode), (b.obs, b.goal, b.episode));
    // Format 3 wrote most next observations and SI observations as references, and some not:
    // the episodes' last steps; the SI entries of runs the φ store (256 states) evicted.
    let flags = i64_or_u8_values(&saved.path.join("replay_low.safetensors"), "follows");
    assert!(flags.contains(&1) && flags.contains(&0), "{flags:?}");
    let sources = i64_or_u8_values(&saved.path.join("si.safetensors"), "obs_source");
    assert_eq!(sources.len(), si_len);
    assert!(
        sources.contains(&-1) && sources.iter().any(|&s| s >= 0),
        "{sources:?}"
    );
    assert_eq!(restored.si_pending(), original.si_pending());
    assert_eq!(restored.low_replay().ring(), original.low_replay().ring());
    assert_eq!(restored.high_replay().ring(), original.high_replay().ring());

    // Every file — weights, Adam moments, buffers, φ store, SI buffer, counters and
    // generators — is written again byte for byte by the restored learner.
    let again = restored
        .save_checkpoint(&config(), &scratch("round-trip-again"))
        .unwrap();
    assert_eq!(again.manifest.files, saved.manifest.files);

    // Training on continues identically: same batches, same noise, same Adam steps.
    play(&mut original, 30..36);
    play(&mut restored, 30..36);
    assert_eq!(restored.progress(), original.progress());
    assert_eq!(losses(&restored), losses(&original));
    assert_eq!(
        nets::to_safetensors_bytes(restored.policy_varmap()).unwrap(),
        nets::to_safetensors_bytes(original.policy_varmap()).unwrap()
    );
}

#[test]
fn a_restored_deterministic_low_level_has_its_targets_and_adam_states_and_trains_on_identically() {
    let mut config = config();
    config.learner.low.algo = protocol::config::LowAlgo::Deterministic;
    config.learner.low.deterministic.actor_hidden = vec![16, 16];
    config.learner.low.deterministic.critic_hidden = vec![16, 16];
    let dir = scratch("deterministic");
    let mut original = Learner::new(&config, DIMS, 7).unwrap();
    play(&mut original, 0..10);
    assert!(original.progress().updates_low > 3, "targets moved");
    let saved = original.save_checkpoint(&config, &dir).unwrap();
    let optim = fs::read(saved.path.join("optim.safetensors")).unwrap();
    let target = fs::read(saved.path.join("target.safetensors")).unwrap();
    let target = safetensors::SafeTensors::deserialize(&target).unwrap();
    assert!(
        target.names().iter().any(|n| n.starts_with("low_policy.")),
        "the target actor is saved"
    );
    let optim = safetensors::SafeTensors::deserialize(&optim).unwrap();
    for key in ["low.actor.m.0", "low.critic.v.0"] {
        assert!(optim.names().contains(&key), "{key} saved");
    }

    let (mut restored, _) = Learner::restore_checkpoint(&config, DIMS, &saved.path).unwrap();
    let dir2 = scratch("deterministic-again");
    let again = restored.save_checkpoint(&config, &dir2).unwrap();
    assert_eq!(again.manifest.files, saved.manifest.files);
    play(&mut original, 10..14);
    play(&mut restored, 10..14);
    assert_eq!(restored.progress(), original.progress());
    assert_eq!(losses(&restored), losses(&original));
    assert_eq!(
        nets::to_safetensors_bytes(restored.policy_varmap()).unwrap(),
        nets::to_safetensors_bytes(original.policy_varmap()).unwrap()
    );
}

#[test]
fn only_the_newest_two_checkpoints_are_kept_and_unfinished_ones_are_ignored() {
    let dir = scratch("keep");
    let l = trained();
    for _ in 0..3 {
        l.save_checkpoint(&config(), &dir).unwrap();
    }
    fs::create_dir(dir.join(".tmp-ckpt-000009")).unwrap();
    let mut names: Vec<String> = fs::read_dir(&dir.0)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.starts_with("ckpt-"))
        .collect();
    names.sort();
    assert_eq!(names, ["ckpt-000002", "ckpt-000003"]);
    assert_eq!(
        latest_checkpoint(&dir).unwrap(),
        Some(dir.join("ckpt-000003"))
    );
    assert_eq!(latest_checkpoint(&dir.join("missing")).unwrap(), None);
}

#[test]
fn no_checkpoint_is_taken_while_a_phi_round_runs() {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    for ep in 0..4 {
        ingest_episode(&mut l, 0, ep, 10, 2, 4);
    }
    l.train(1).unwrap();
    assert!(l.phi_round_active());
    let err = l.save_checkpoint(&config(), &scratch("round")).unwrap_err();
    assert!(matches!(err, CheckpointError::RoundActive), "{err}");
}

/// A saved checkpoint to damage (its folder lives as long as the guard).
fn saved(name: &str) -> (Scratch, PathBuf) {
    let dir = scratch(name);
    let path = trained().save_checkpoint(&config(), &dir).unwrap().path;
    (dir, path)
}

fn refused(ckpt: &Path, config: &protocol::Config) -> String {
    match Learner::restore_checkpoint(config, DIMS, ckpt) {
        Ok(_) => panic!("a damaged checkpoint was accepted"),
        Err(err) => err.to_string(),
    }
}

#[test]
fn a_flipped_byte_is_refused_by_its_checksum_naming_the_file() {
    let (_dir, ckpt) = saved("flip");
    let file = ckpt.join("replay_low.safetensors");
    let mut bytes = fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x10;
    fs::write(&file, bytes).unwrap();
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("replay_low.safetensors") && err.contains("checksum"),
        "{err}"
    );
}

#[test]
fn a_truncated_file_is_refused_naming_the_file() {
    let (_dir, ckpt) = saved("truncated");
    let file = ckpt.join("critic.safetensors");
    let bytes = fs::read(&file).unwrap();
    fs::write(&file, &bytes[..bytes.len() - 100]).unwrap();
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("critic.safetensors") && err.contains("truncated"),
        "{err}"
    );
}

#[test]
fn a_missing_file_or_unreadable_manifest_is_refused() {
    let (_dir, ckpt) = saved("missing");
    fs::remove_file(ckpt.join("state.json")).unwrap();
    let err = refused(&ckpt, &config());
    assert!(err.contains("state.json"), "{err}");

    fs::write(ckpt.join(MANIFEST), b"{\"format_version\": 1,").unwrap();
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("manifest.json") && err.contains("unreadable"),
        "{err}"
    );
}

#[test]
fn contents_that_pass_the_checksum_but_do_not_fit_are_refused() {
    // A state file rewritten, with a matching manifest, to hold a field this build lacks.
    let (_dir, ckpt) = saved("inconsistent");
    let file = ckpt.join("state.json");
    let text = fs::read_to_string(&file).unwrap();
    eprintln!("{text}");
    let broken = text.replacen("\"updates_low\"", "\"updates_lo\"", 1);
    fs::write(&file, &broken).unwrap();
    let mut manifest = read_manifest(&ckpt);
    let entry = manifest
        .files
        .iter_mut()
        .find(|f| f.name == "state.json")
        .unwrap();
    entry.bytes = broken.len() as u64;
    entry.checksum = format!(
        "{:016x}",
        learner::learner::checkpoint::checksum(broken.as_bytes())
    );
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&manifest).unwrap()).unwrap();
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("state.json") && err.contains("updates_lo"),
        "{err}"
    );
}

#[test]
fn another_format_or_protocol_version_is_refused() {
    let (_dir, ckpt) = saved("versions");
    let original = read_manifest(&ckpt);
    for (what, edit) in [
        (
            "format version",
            (|m: &mut Manifest| m.format_version += 1) as fn(&mut Manifest),
        ),
        ("protocol version", |m: &mut Manifest| {
            m.protocol_version += 1
        }),
    ] {
        let mut m = original.clone();
        edit(&mut m);
        fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&m).unwrap()).unwrap();
        let err = refused(&ckpt, &config());
        assert!(
            err.contains("incompatible") && err.contains(what),
            "{what}: {err}"
        );
    }
}

#[test]
fn another_network_layout_or_config_is_refused() {
    let (_dir, ckpt) = saved("config");
    let mut wider = config();
    wider.encoder.hidden = vec![12];
    let err = refused(&ckpt, &wider);
    assert!(err.contains("network layout hash"), "{err}");

    let mut bigger = config();
    bigger.replay.capacity_steps = 512;
    let err = refused(&ckpt, &bigger);
    assert!(err.contains("config fingerprint"), "{err}");

    // Sections outside the fingerprint may change on resume, and so may where φ rounds run.
    let mut longer = config();
    longer.run.seed += 1;
    longer.encoder.background_rounds = true;
    Learner::restore_checkpoint(&longer, DIMS, &ckpt).unwrap();
}

/// Replaces the checkpoint's `state.json` by `older` and re-seals the manifest (size and
/// checksum), as an older build would have written it.
fn rewrite_state(ckpt: &Path, older: &[u8]) {
    fs::write(ckpt.join("state.json"), older).unwrap();
    let mut manifest = read_manifest(ckpt);
    let entry = manifest
        .files
        .iter_mut()
        .find(|f| f.name == "state.json")
        .unwrap();
    entry.checksum = format!("{:016x}", checksum(older));
    entry.bytes = older.len() as u64;
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&manifest).unwrap()).unwrap();
}

#[test]
fn the_count_window_survives_a_checkpoint_and_an_older_checkpoint_derives_it() {
    let dir = scratch("count-window");
    let mut c = config();
    c.asi.fr_in_count_window = false;
    c.exploration.count_prob_interval_episodes = 4;
    let mut l = Learner::new(&c, DIMS, 7).unwrap();
    // Episodes 0-4, FR (every chunk flagged FRONTIER, as the actor sends them) at 1 and 3: the
    // window holds 0, 2 and 4.
    for ep in 0..5u64 {
        let fr = if ep % 2 == 1 {
            protocol::TrajectoryFlags::FRONTIER
        } else {
            0
        };
        let records = steps(0..10, ep, 2, 9);
        let start = protocol::TrajectoryFlags::EPISODE_START | fr;
        ingest(&mut l, 0, ep, 0, &records[..5], start).unwrap();
        let end =
            protocol::TrajectoryFlags::EPISODE_END | protocol::TrajectoryFlags::TRUNCATED | fr;
        ingest(&mut l, 0, ep, 1, &records[5..], end).unwrap();
    }
    assert_eq!(metric(&l, "schedule/window_episodes"), 3.0);
    let saved = l.save_checkpoint(&c, &dir).unwrap();
    let (restored, _) = Learner::restore_checkpoint(&c, DIMS, &saved.path).unwrap();
    assert_eq!(metric(&restored, "schedule/window_episodes"), 3.0);
    assert_eq!(restored.run_schedule(), l.run_schedule());

    // A build before the switch wrote no window length and counted every episode: 5 mod 4.
    let text = fs::read_to_string(saved.path.join("state.json")).unwrap();
    let older: Vec<&str> = text
        .lines()
        .filter(|line| !line.trim_start().starts_with("\"count_window_episodes\":"))
        .collect();
    assert_eq!(
        older.len(),
        text.lines().count() - 1,
        "the field is written"
    );
    rewrite_state(&saved.path, older.join("\n").as_bytes());
    let (older, _) = Learner::restore_checkpoint(&c, DIMS, &saved.path).unwrap();
    assert_eq!(metric(&older, "schedule/window_episodes"), 1.0);
}

#[test]
fn a_checkpoint_written_before_the_gradient_norms_existed_loads_with_them_at_zero() {
    let dir = scratch("before-grad-norms");
    let original = trained();
    let saved = original.save_checkpoint(&config(), &dir).unwrap();
    // An older build wrote no gradient norms in `state.json`: take their lines out of the
    // pretty-printed file (text, as a `serde_json::Value` cannot hold the generator's u128),
    // drop the comma a removed last field leaves, and re-seal the manifest. SAC's norm is the
    // line after `alpha_loss` (the deterministic level's `actor_grad_norm` is older and stays).
    let file = saved.path.join("state.json");
    let text = fs::read_to_string(&file).unwrap();
    let all: Vec<&str> = text.lines().map(str::trim_start).collect();
    let is_new = |i: usize| {
        let line = all[i];
        line.starts_with("\"si_high_grad_norm\":")
            || line.starts_with("\"si_low_grad_norm\":")
            || (line.starts_with("\"actor_grad_norm\":")
                && all[i - 1].starts_with("\"alpha_loss\":"))
    };
    let mut lines: Vec<String> = text
        .lines()
        .enumerate()
        .filter(|&(i, _)| !is_new(i))
        .map(|(_, l)| l.to_owned())
        .collect();
    assert_eq!(lines.len(), all.len() - 4, "four norms are written");
    for i in 1..lines.len() {
        if lines[i].trim_start().starts_with('}') {
            if let Some(kept) = lines[i - 1].strip_suffix(',') {
                lines[i - 1] = kept.to_owned();
            }
        }
    }
    rewrite_state(&saved.path, lines.join("\n").as_bytes());

    let (restored, _) = Learner::restore_checkpoint(&config(), DIMS, &saved.path).unwrap();
    let norms = [
        "charts/low_actor_grad_norm",
        "charts/high_actor_grad_norm",
        "si/high_grad_norm",
        "si/low_grad_norm",
    ];
    type Metrics = Vec<(&'static str, f64)>;
    let split = |l: &Learner| -> (Metrics, Metrics) {
        l.metrics()
            .into_iter()
            .filter(|(n, _)| !n.contains("per_sec"))
            .partition(|(n, _)| norms.contains(n))
    };
    let (restored_norms, restored_rest) = split(&restored);
    let (original_norms, original_rest) = split(&original);
    assert_eq!(restored_norms.len(), 4);
    assert!(
        restored_norms.iter().all(|(_, v)| *v == 0.0),
        "{restored_norms:?}"
    );
    assert!(
        original_norms.iter().any(|(_, v)| *v > 0.0),
        "{original_norms:?}"
    );
    assert_eq!(
        restored_rest, original_rest,
        "the other statistics come back"
    );
}

/// Flips the top bit of the last two whole 8-byte words of `file`: a two-bit error that the
/// word-wise FNV-1a of format 1 cannot see (both flips reach only the top bit of its state and
/// cancel), returned as the bytes before and after.
fn flip_top_bits_of_two_words(file: &Path) -> (Vec<u8>, Vec<u8>) {
    let before = fs::read(file).unwrap();
    let mut after = before.clone();
    let end = before.len() / 8 * 8;
    after[end - 9] ^= 0x80;
    after[end - 1] ^= 0x80;
    fs::write(file, &after).unwrap();
    (before, after)
}

#[test]
fn a_two_bit_error_that_the_format_1_checksum_misses_is_refused() {
    let (_dir, ckpt) = saved("two-bits");
    let file = ckpt.join("replay_low.safetensors");
    let (before, after) = flip_top_bits_of_two_words(&file);
    assert_ne!(before, after);
    // The old checksum would have let these contents through as the saved ones.
    assert_eq!(
        Checksum::Fnv1aWords.of(&before),
        Checksum::Fnv1aWords.of(&after)
    );
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("replay_low.safetensors") && err.contains("checksum"),
        "{err}"
    );
}

#[test]
fn a_format_1_checkpoint_still_restores_and_its_checksums_still_guard_it() {
    let (_dir, ckpt) = saved("format-1");
    let current = read_manifest(&ckpt);
    assert_eq!(current.format_version, 3);
    // A format-2 manifest lists its files with the same CRC-64 sums.
    let mut format_2 = current.clone();
    format_2.format_version = 2;
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&format_2).unwrap()).unwrap();
    assert!(Learner::restore_checkpoint(&config(), DIMS, &ckpt).is_ok());
    // The manifest as a format-1 build wrote it: the same files, word-wise FNV-1a sums.
    let mut old = current.clone();
    old.format_version = 1;
    for entry in &mut old.files {
        let bytes = fs::read(ckpt.join(&entry.name)).unwrap();
        entry.checksum = format!("{:016x}", Checksum::Fnv1aWords.of(&bytes));
        assert_ne!(entry.checksum, format!("{:016x}", checksum(&bytes)));
    }
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&old).unwrap()).unwrap();
    let (restored, info) = Learner::restore_checkpoint(&config(), DIMS, &ckpt).unwrap();
    assert_eq!(info.manifest, old);
    // It is the saved learner: written again (as format 3), every file is the same.
    let again = restored
        .save_checkpoint(&config(), &scratch("format-1-again"))
        .unwrap();
    assert_eq!(again.manifest.files, current.files);

    // A format-1 manifest is checked with its own function: CRC sums under format 1 do not
    // match, and a flipped byte is still caught.
    let mut mixed = current.clone();
    mixed.format_version = 1;
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&mixed).unwrap()).unwrap();
    assert!(refused(&ckpt, &config()).contains("checksum"));
    fs::write(ckpt.join(MANIFEST), serde_json::to_vec(&old).unwrap()).unwrap();
    let file = ckpt.join("replay_high.safetensors");
    let mut bytes = fs::read(&file).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x04;
    fs::write(&file, bytes).unwrap();
    let err = refused(&ckpt, &config());
    assert!(
        err.contains("replay_high.safetensors") && err.contains("checksum"),
        "{err}"
    );
}
