//! System test of the ASI parts (issue #6): the real `asi` binary in process mode on
//! `configs/smoke.toml`, once with frontier-reaching episodes and self-imitation switched on
//! early, once with both off (HESS), asserting from `metrics.jsonl` that FR episodes and SI
//! steps happened (or did not). Each run has its own folder and run id and a watchdog.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use serde_json::Value;

static ONE_RUN_AT_A_TIME: Mutex<()> = Mutex::new(());
/// Upper bound for one smoke run on a loaded 2-core machine; past it the run is killed.
const WATCHDOG: Duration = Duration::from_secs(300);

struct Run {
    dir: PathBuf,
    child: Child,
}

impl Run {
    fn start(test: &str, extra: &[&str]) -> Run {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos();
        let dir = std::env::temp_dir().join(format!(
            "asi-asisystem-{test}-{}-{nanos}",
            std::process::id()
        ));
        let dir_arg = dir.to_string_lossy().into_owned();
        let name_arg = format!("run.name=a{}", nanos % 1_000_000_000);
        let mut args = vec!["train", "--config", "configs/smoke.toml", "--actors", "2"];
        args.extend(["--run-dir", &dir_arg, "--set", &name_arg]);
        args.extend(extra);
        let child = Command::new(env!("CARGO_BIN_EXE_asi"))
            .args(&args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("asi starts");
        Run { dir, child }
    }

    /// Waits for the launcher; kills it (which stops its children) at the watchdog.
    fn wait_success(&mut self) {
        let deadline = Instant::now() + WATCHDOG;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                assert!(status.success(), "launcher exit: {status}");
                return;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                panic!("watchdog: run in {} did not finish", self.dir.display());
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Per metric key, the last value written to `metrics.jsonl`.
    fn last_metrics(&self) -> BTreeMap<String, f64> {
        let text = std::fs::read_to_string(self.dir.join("metrics.jsonl")).unwrap();
        let mut last = BTreeMap::new();
        for line in text.lines() {
            let record: Value = serde_json::from_str(line).unwrap();
            for (key, value) in record.as_object().unwrap() {
                if let Some(v) = value.as_f64() {
                    last.insert(key.clone(), v);
                }
            }
        }
        last
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            let _ = self.child.kill();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
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
    let _lock = ONE_RUN_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let mut on = Run::start(
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
        ],
    );
    on.wait_success();
    let m = on.last_metrics();
    assert!(sum(&m, "fr/episodes") > 0.0, "FR episodes: {m:?}");
    assert!(sum(&m, "fr/waypoint_decisions") > 0.0, "waypoints: {m:?}");
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

    let mut off = Run::start(
        "off",
        &[
            "--set",
            "asi.frontier_reaching=false",
            "--set",
            "asi.self_imitation=false",
        ],
    );
    off.wait_success();
    let m = off.last_metrics();
    assert_eq!(sum(&m, "fr/episodes"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "fr/waypoint_decisions"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "si/steps"), 0.0, "{m:?}");
    assert_eq!(sum(&m, "si/buffer_len"), 0.0, "{m:?}");
}
