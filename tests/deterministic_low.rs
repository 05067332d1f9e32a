//! System test of the reference code's deterministic low level (`learner.low.algo =
//! "deterministic"`, issue #5): the real `asi` binary on `configs/smoke.toml`, in serial mode
//! and in process mode, each run in its own folder with its own run id and a watchdog
//! ([`common::Run`]). Asserted from `metrics.jsonl`: the low level trained with finite losses
//! and its own metrics, the actors and the evaluator took the published deterministic weights
//! (none rejected), and the run ended cleanly.

mod common;

use std::collections::BTreeMap;

use common::{one_run_at_a_time, Run};

const DETERMINISTIC: &str = "learner.low.algo=\"deterministic\"";

fn get(metrics: &BTreeMap<String, f64>, key: &str) -> f64 {
    *metrics
        .get(key)
        .unwrap_or_else(|| panic!("{key} missing: {metrics:?}"))
}

/// The learner trained the deterministic low level: finite losses, its metrics (no SAC α),
/// updates and new weights versions, which the evaluator took.
fn assert_trained(metrics: &BTreeMap<String, f64>) {
    for key in [
        "learner/losses/low_critic",
        "learner/losses/low_actor",
        "learner/charts/low_q",
        "learner/charts/low_target_q",
        "learner/charts/low_actor_grad_norm",
        "learner/charts/low_critic_grad_norm",
        "learner/charts/low_kept_fraction",
    ] {
        let value = get(metrics, key);
        assert!(value.is_finite(), "{key} = {value}");
    }
    assert!(
        !metrics.contains_key("learner/charts/low_alpha"),
        "no SAC α"
    );
    assert!(get(metrics, "learner/charts/updates_low") > 0.0);
    assert!(get(metrics, "learner/losses/low_critic") > 0.0);
    assert!(get(metrics, "learner/charts/policy_version") > 0.0);
    assert!(get(metrics, "evaluator0/eval/policy_version") > 0.0);
    assert_eq!(get(metrics, "evaluator0/eval/weights_rejected"), 0.0);
}

#[test]
fn a_serial_smoke_run_trains_the_deterministic_low_level_with_finite_losses() {
    let _one = one_run_at_a_time();
    let mut run = Run::start(
        "deterministic-serial",
        "configs/smoke.toml",
        &["--serial", "--set", DETERMINISTIC],
    );
    run.wait_success();
    let metrics = run.last_metrics();
    assert_trained(&metrics);
    for actor in ["actor0", "actor1"] {
        let version = get(&metrics, &format!("{actor}/actor/policy_version"));
        assert!(version > 0.0, "{actor} acts with learned weights");
    }
    assert!(run.dir.join("weights/latest.safetensors").is_file());
    eprintln!(
        "serial deterministic smoke run: {:.1} s",
        run.elapsed_secs()
    );
}

#[test]
fn in_process_mode_the_actors_act_with_the_published_deterministic_weights() {
    let _one = one_run_at_a_time();
    let mut run = Run::start(
        "deterministic-process",
        "configs/smoke.toml",
        &["--actors", "2", "--set", DETERMINISTIC],
    );
    run.wait_success();
    assert_trained(&run.last_metrics());
    eprintln!(
        "process-mode deterministic smoke run: {:.1} s",
        run.elapsed_secs()
    );
}
