//! The learner end to end on hand-built episodes: construction rules, training produces finite
//! losses and the documented metrics, and the policy lag is measured.

mod common;

use common::*;
use learner::setup::LowLevel;
use learner::Learner;
use protocol::config::LowAlgo;

#[test]
fn training_on_ingested_episodes_gives_finite_losses_and_metrics() {
    let mut l = learner();
    for ep in 0..4 {
        ingest_episode(&mut l, ep as u32 % 2, ep, 10, 2, 4);
    }
    let ran = l.train(usize::MAX).unwrap();
    let p = l.progress();
    assert_eq!(ran as u64, p.updates_low + p.updates_high);
    assert_eq!(p.updates_low, 16, "40 steps × 0.4");
    assert_eq!(p.updates_high, 20 - 4 + 1, "20 segments, min 4");
    let metrics = l.metrics();
    for name in [
        "losses/low_critic",
        "losses/low_actor",
        "losses/high_critic",
        "losses/high_actor",
        "charts/updates_per_sec",
        "replay/low_size",
        "replay/high_size",
    ] {
        let value = metrics
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("{name} missing"))
            .1;
        assert!(value.is_finite(), "{name} = {value}");
    }
    assert!(metrics.iter().all(|(_, v)| v.is_finite()));
    let get = |name| metrics.iter().find(|(n, _)| *n == name).unwrap().1;
    assert_eq!(
        (get("replay/low_size"), get("replay/high_size")),
        (40.0, 20.0)
    );
    assert!(get("losses/low_critic") > 0.0 && get("losses/high_critic") > 0.0);
    assert!(
        get("charts/low_actor_grad_norm") > 0.0 && get("charts/high_actor_grad_norm") > 0.0,
        "both SAC actor steps had a gradient"
    );
}

#[test]
fn the_same_seed_gives_the_same_training() {
    let run = || {
        let mut l = learner();
        ingest_episode(&mut l, 0, 0, 10, 2, 5);
        ingest_episode(&mut l, 0, 1, 10, 2, 5);
        l.train(usize::MAX).unwrap();
        l.metrics()
            .into_iter()
            .filter(|(n, _)| n.starts_with("losses/"))
            .collect::<Vec<_>>()
    };
    assert_eq!(run(), run());
}

#[test]
fn the_deterministic_low_variant_trains_and_publishes_the_weights_actors_load() {
    let mut config = config();
    config.learner.low.algo = LowAlgo::Deterministic;
    config.learner.low.deterministic.actor_hidden = vec![16, 16];
    config.learner.low.deterministic.critic_hidden = vec![16, 16];
    let mut l = Learner::new(&config, DIMS, 7).unwrap();
    assert!(matches!(l.low_level(), LowLevel::Deterministic(_)));
    for ep in 0..4 {
        ingest_episode(&mut l, ep as u32 % 2, ep, 10, 2, 4);
    }
    l.train(usize::MAX).unwrap();
    assert_eq!(l.progress().updates_low, 16, "40 steps × 0.4");
    let metrics = l.metrics();
    assert!(metrics.iter().all(|(_, v)| v.is_finite()), "{metrics:?}");
    let get = |name| metrics.iter().find(|(n, _)| *n == name).unwrap().1;
    assert!(get("losses/low_critic") > 0.0, "the critic is fitted");
    assert!(get("charts/low_kept_fraction") > 0.0);
    assert_eq!(get("charts/low_lr"), 2e-4);
    assert!(
        metrics.iter().all(|(n, _)| *n != "charts/low_alpha"),
        "no SAC α"
    );
    // What an actor builds from the same config and task has the published layout.
    let spec = nets::spec_from_config(&config, DIMS).unwrap();
    let vm = candle_nn::VarMap::new();
    let vb = nets::seeded_var_builder(&vm, 1, &candle_core::Device::Cpu);
    nets::PolicySet::new(&spec, &vb).unwrap();
    let (header, bytes) = l.publish_due().unwrap().expect("first weights");
    assert_eq!(header.layout_hash, nets::layout_hash(&vm));
    nets::load_safetensors_bytes(&vm, &bytes).unwrap();
}

#[test]
fn without_an_episode_length_the_caller_must_pass_the_task_length() {
    let mut config = config();
    config.env.episode_length = None;
    config.learner.low.updates_per_env_step = None;
    let err = Learner::new(&config, DIMS, 0).err().expect("refused");
    assert!(err.to_string().contains("env.episode_length"), "{err}");
    let l = Learner::with_episode_length(&config, DIMS, 500, 0).unwrap();
    assert!(
        (l.replay_ratio().low_per_env_step - 0.4).abs() < 1e-12,
        "200 / 500"
    );
}

#[test]
fn an_invalid_config_is_refused_with_every_problem() {
    let mut config = config();
    config.learner.low.gamma = 1.5;
    config.learner.high.lr = -1.0;
    let err = Learner::new(&config, DIMS, 0)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("learner.low.gamma") && err.contains("learner.high.lr"),
        "{err}"
    );
}

#[test]
fn policy_lag_is_the_learner_version_minus_the_acting_version() {
    let mut l = learner();
    l.publish_due().unwrap();
    ingest_episode(&mut l, 0, 0, 10, 2, 5);
    l.train(usize::MAX).unwrap();
    l.publish_due().unwrap().unwrap(); // version 1; chunks below were acted with version 0
    ingest_episode(&mut l, 0, 1, 4, 2, 4);
    let lag = l
        .metrics()
        .into_iter()
        .find(|(n, _)| *n == "charts/policy_lag")
        .unwrap()
        .1;
    assert_eq!(lag, 1.0);
}

#[test]
fn updates_with_non_finite_losses_are_skipped_counted_and_leave_the_weights_unchanged() {
    // Finite values the protocol accepts, large enough that rewards and losses overflow.
    let mut l = learner();
    for ep in 0..4u64 {
        let mut records = steps(0..10, ep, 2, 9);
        for r in &mut records {
            r.reward = -3.0e38;
            r.phi = vec![3.0e38, 0.0];
            r.next_phi = vec![-3.0e38, 0.0];
        }
        let flags = protocol::TrajectoryFlags::EPISODE_START
            | protocol::TrajectoryFlags::EPISODE_END
            | protocol::TrajectoryFlags::TRUNCATED;
        ingest(&mut l, 0, ep, 0, &records, flags).unwrap();
    }
    let ran = l
        .train(usize::MAX)
        .expect("non-finite losses are not an error");
    let p = l.progress();
    assert!(p.updates_low > 0 && p.updates_high > 0, "{p:?}");
    assert_eq!(ran as u64, p.updates_low + p.updates_high);
    let metrics = l.metrics();
    let get = |name: &str| metrics.iter().find(|(n, _)| *n == name).unwrap().1;
    assert_eq!(get("charts/skipped_nonfinite_low"), p.updates_low as f64);
    assert_eq!(get("charts/skipped_nonfinite_high"), p.updates_high as f64);
    // Nothing was stepped: the published weights are those of an untrained learner.
    let (_, trained) = l.publish_due().unwrap().expect("first publication");
    let (_, fresh) = learner().publish_due().unwrap().expect("first publication");
    assert!(trained == fresh, "weights changed by skipped updates");

    // A learner on ordinary data skips nothing.
    let mut ok = learner();
    for ep in 0..4 {
        ingest_episode(&mut ok, 0, ep, 10, 2, 5);
    }
    ok.train(usize::MAX).unwrap();
    let metrics = ok.metrics();
    let skipped = metrics
        .iter()
        .filter(|(n, _)| n.starts_with("charts/skipped_nonfinite"))
        .map(|(_, v)| *v)
        .sum::<f64>();
    assert_eq!(skipped, 0.0);
}
