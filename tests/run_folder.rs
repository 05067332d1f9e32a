//! One launch per run folder, and a folder whose run stopped before its first checkpoint is
//! not started over in place: the real `asi` binary on `configs/smoke.toml` in serial mode
//! (one process, so SIGKILL stops the whole run), with the shared watchdog.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

use common::{one_run_at_a_time, serial_smoke_args, signal, spawn_asi, Run, WATCHDOG};

/// Every file under `folder` but the lock file (which a refused launch rewrites with its pid)
/// and `status/` (the killed run's), with its bytes.
fn files_of(folder: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            let name = path
                .strip_prefix(root)
                .unwrap()
                .to_string_lossy()
                .into_owned();
            if name == "run.lock" || name == "status" {
                continue;
            }
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(folder, folder, &mut out);
    out
}

/// Runs `asi train --serial` on the smoke config in `dir` to its exit (killed at the
/// watchdog); returns whether it succeeded and its output.
fn launch(dir: &Path, extra: &[&str]) -> (bool, String) {
    let log = dir.with_extension("second.log");
    let mut args = serial_smoke_args(dir);
    args.extend(extra.iter().map(|a| a.to_string()));
    let mut child = spawn_asi(&args, &log);
    let started = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if started.elapsed() > WATCHDOG {
            let _ = child.kill();
            panic!("watchdog: launch in {} did not exit", dir.display());
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let output = std::fs::read_to_string(&log).unwrap_or_default();
    let _ = std::fs::remove_file(&log);
    (status.success(), output)
}

#[test]
fn a_running_folder_refuses_a_second_launch_and_a_run_killed_before_its_first_checkpoint_is_kept() {
    let _slot = one_run_at_a_time();
    // No checkpoint for the first 1,000 minutes: the run is killed long before.
    let mut run = Run::start(
        "run-folder",
        "configs/smoke.toml",
        &[
            "--serial",
            "--set",
            "run.max_episodes=100000",
            "--set",
            "run.checkpoint_interval_mins=1000",
        ],
    );
    run.wait_until("three metrics lines", |dir| {
        std::fs::read_to_string(dir.join("metrics.jsonl")).is_ok_and(|t| t.lines().count() >= 3)
    });

    let (ok, output) = launch(&run.dir, &[]);
    assert!(
        !ok,
        "a second launch on a running folder must fail:\n{output}"
    );
    assert!(
        output.contains("in use by another `asi train`")
            && output.contains(&format!("pid {}", run.child.id())),
        "{output}"
    );
    assert!(
        run.child.try_wait().unwrap().is_none(),
        "the first run goes on"
    );

    // A crash before the first learner checkpoint: metrics and the graph-service's start
    // checkpoint are on disk, no `checkpoints/ckpt-*`.
    signal(run.child.id(), libc::SIGKILL);
    let _ = run.child.wait();
    let left = files_of(&run.dir);
    assert!(!left["metrics.jsonl"].is_empty(), "{:?}", left.keys());
    assert!(
        left.keys()
            .any(|k| k.starts_with("checkpoints/graph-service/")),
        "{:?}",
        left.keys()
    );
    assert!(
        !left.keys().any(|k| k.starts_with("checkpoints/ckpt-")),
        "{:?}",
        left.keys()
    );

    let (ok, output) = launch(&run.dir, &["--set", "run.max_episodes=2"]);
    assert!(!ok, "starting over in place must be refused:\n{output}");
    assert!(
        output.contains("no learner checkpoint")
            && output.contains("metrics.jsonl")
            && output.contains("--restart"),
        "{output}"
    );
    assert!(
        files_of(&run.dir) == left,
        "the refused launch changed the folder"
    );

    let (ok, output) = launch(&run.dir, &["--restart", "--set", "run.max_episodes=2"]);
    assert!(ok, "{output}");
    let moved = output
        .lines()
        .find_map(|l| l.strip_prefix("restarting: the previous run folder was moved to "))
        .unwrap_or_else(|| panic!("{output}"));
    let old = Path::new(moved).to_owned();
    let kept = files_of(&old);
    let _ = std::fs::remove_dir_all(&old);
    assert!(kept == left, "the old run is kept as it was");
    let new = std::fs::read_to_string(run.dir.join("metrics.jsonl")).unwrap();
    assert!(new.lines().count() >= 1 && new.as_bytes() != left["metrics.jsonl"].as_slice());
}
