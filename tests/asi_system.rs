//! System test of the ASI parts (issue #6): the real `asi` binary in process mode on
//! `configs/smoke.toml`, once with frontier-reaching episodes and self-imitation switched on
//! early, once with both off (HESS), asserting from `metrics.jsonl` that FR episodes and SI
//! steps happened (or did not), and that the learner saw the FR episodes' chunks as such
//! (`asi.fr_in_low_replay = false` kept exactly their steps out of the low replay). Each run
//! has its own folder and run id and a watchdog.

mod common;

use std::collections::BTreeMap;

use common::{one_run_at_a_time, Run};

/// `asi train` on the smoke config with two actors (see [`common::Run`]).
fn start(test: &str, extra: &[&str]) -> Run {
    let args = [&["--actors", "2"][..], extra].concat();
    Run::start(&format!("asisystem-{test}"), "configs/smoke.toml", &args)
}

/// The values of every key ending in `suffix` (one per actor for actor metrics).
fn values(metrics: &BTreeMap<String, f64>, suffix: &str) -> Vec<f64> {
    let found: Vec<f64> = metrics
        .iter()
        .filter(|(k, _)| k.ends_with(suffix))
        .map(|(_, v)| *v)
        .collect();
    assert!(
        !found.is_empty(),
        "no metric ending in {suffix}: {metrics:?}"
    );
    found
}

fn sum(metrics: &BTreeMap<String, f64>, suffix: &str) -> f64 {
    values(metrics, suffix).iter().sum()
}

#[test]
fn fr_episodes_and_si_steps_run_when_on_and_stay_at_zero_when_off() {
    let _lock = one_run_at_a_time();
    let mut on = start(
        "on",
        &[
            "--set",
            "asi.fr_start_episode=12",
            "--set",
            "run.max_episodes=60",
            "--set",
            "asi.si_start_episode=6",
            "--set",
            "asi.fr_prob_schedule=[{from_episode=0,p=0.9}]",
            "--set",
            "asi.fr_in_low_replay=false",
            // The smoke run's φ spans a few units, well inside the default ε = 8, so with it an
            // FR episode may be "near its frontier" at its first decision and switch to count
            // mode before any waypoint (it happened in CI). A tiny ε leaves navigation to run.
            "--set",
            "asi.frontier_epsilon=1e-6",
        ],
    );
    on.wait_success();
    let m = on.last_metrics();
    assert!(sum(&m, "fr/episodes") > 0.0, "FR episodes: {m:?}");
    // The actors flag FR chunks and the learner sees the flag: with FR steps kept out of the
    // low replay (capacity far above the run's steps) it holds exactly the other steps.
    let (steps, fr_steps) = (
        sum(&m, "learner/ingest/env_steps"),
        sum(&m, "learner/ingest/frontier_steps"),
    );
    assert!(fr_steps > 0.0 && fr_steps < steps, "{fr_steps} of {steps}");
    assert_eq!(
        sum(&m, "learner/replay/low_size"),
        steps - fr_steps,
        "{m:?}"
    );
    assert!(
        sum(&m, "fr/waypoint_decisions") > 0.0,
        "waypoints ({} FR episodes, {} near-frontier switches): {m:?}",
        sum(&m, "fr/episodes"),
        sum(&m, "fr/near_frontier_switches"),
    );
    assert!(sum(&m, "si/steps") > 0.0, "SI steps: {m:?}");
    for loss in ["si/high_loss", "si/low_loss"] {
        assert!(
            values(&m, loss).iter().all(|v| v.is_finite()),
            "{loss}: {m:?}"
        );
    }
    let usable = values(&m, "si/usable_fraction")[0];
    assert!(usable > 0.0 && usable <= 1.0, "usable fraction {usable}");
    drop(on);

    let mut off = start(
        "off",
        &[
            "--set",
            "asi.frontier_reaching=false",
            "--set",
            "asi.self_imitation=false",
            // φ rounds on a thread of their own here (orthogonal to FR and SI): they must end
            // and be published as in line.
            "--set",
            "encoder.background_rounds=true",
        ],
    );
    off.wait_success();
    let m = off.last_metrics();
    assert!(sum(&m, "learner/phi/rounds") >= 2.0, "{m:?}");
    assert!(sum(&m, "learner/phi/version") >= 2.0, "{m:?}");
    assert_eq!(sum(&m, "fr/episodes"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "ingest/frontier_steps"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "fr/waypoint_decisions"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "si/steps"), 0.0, "{m:?}");
    assert!(
        sum(&m, "si/buffer_len") > 0.0,
        "filled with SI off too: {m:?}"
    );
}
