//! `asi eval` and serial mode's signal handling, on the real binary and `configs/smoke.toml`:
//! a serial run stopped by SIGTERM ends cleanly with a checkpoint and saved weights, and
//! `asi eval` evaluates those weights (figures, PNG); bad run folders and damaged weights get
//! clear errors. Each run has its own folder and run name, and a watchdog.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Upper bound for each wait on a loaded 2-core machine; past it the test fails.
const WATCHDOG: Duration = Duration::from_secs(600);

struct Scratch(PathBuf);

impl Scratch {
    fn new(test: &str) -> Scratch {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .expect("clock after 1970")
            .as_nanos();
        Scratch(
            std::env::temp_dir().join(format!("asi-eval-{test}-{}-{nanos}", std::process::id())),
        )
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn asi(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .output()
        .expect("asi runs")
}

fn metric_lines(dir: &Path) -> usize {
    std::fs::read_to_string(dir.join("metrics.jsonl"))
        .map(|t| t.lines().count())
        .unwrap_or(0)
}

fn field<'a>(stdout: &'a str, key: &str) -> &'a str {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{key}: ")))
        .unwrap_or_else(|| panic!("`{key}` missing in:\n{stdout}"))
}

#[test]
fn a_serial_run_stops_on_sigterm_with_a_checkpoint_and_asi_eval_evaluates_its_weights() {
    let scratch = Scratch::new("serial");
    let dir = scratch.0.join("run");
    let dir_arg = dir.to_string_lossy().into_owned();
    let name = format!("run.name=ev{}", std::process::id());
    let mut child = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(common::serial_smoke_args(&dir))
        .args(["--set", &name, "--set", "run.max_episodes=1000000"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("asi starts");
    let deadline = Instant::now() + WATCHDOG;
    // Past the first evaluation (episode 6), so weights were saved, with episodes to spare.
    while metric_lines(&dir) < 8 || !dir.join("weights/latest.json").exists() {
        if let Some(status) = child.try_wait().expect("wait") {
            panic!("the run ended early: {status}");
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("watchdog: no metrics lines after {WATCHDOG:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let lines_at_signal = metric_lines(&dir);
    // SAFETY: plain syscall on the pid of our own child.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    while child.try_wait().expect("wait").is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("watchdog: the serial run ignored SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = child.wait_with_output().expect("output");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "exit after SIGTERM: {}\n{stderr}",
        out.status
    );
    assert!(stderr.contains("stopped by signal"), "{stderr}");
    let checkpoints: Vec<_> = std::fs::read_dir(dir.join("checkpoints"))
        .expect("checkpoint folder")
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("ckpt-"))
        .collect();
    assert!(
        !checkpoints.is_empty(),
        "a checkpoint is written at the stop"
    );
    assert!(
        metric_lines(&dir) >= lines_at_signal,
        "the last line is written"
    );

    let png = scratch.0.join("eval.png");
    let png_arg = png.to_string_lossy().into_owned();
    let eval = asi(&[
        "eval",
        "--run-dir",
        &dir_arg,
        "--episodes",
        "3",
        "--png",
        &png_arg,
    ]);
    let stdout = String::from_utf8_lossy(&eval.stdout);
    assert!(
        eval.status.success(),
        "asi eval: {}",
        String::from_utf8_lossy(&eval.stderr)
    );
    assert_eq!(field(&stdout, "task"), "pointmaze-u-test");
    assert_eq!(field(&stdout, "episodes"), "3");
    let success: f64 = field(&stdout, "success_rate").parse().expect("a number");
    assert!((0.0..=1.0).contains(&success), "{success}");
    let distance: f64 = field(&stdout, "mean_final_distance")
        .parse()
        .expect("a number");
    assert!(distance.is_finite() && distance >= 0.0, "{distance}");
    // Along the maze: whole 4 m cells, at most the 6 cells from the start to the goal.
    let along: f64 = field(&stdout, "mean_final_path_distance")
        .parse()
        .expect("a number");
    assert!((0.0..=24.0).contains(&along), "{along}");
    assert!(
        (along * 3.0 / 4.0 - (along * 3.0 / 4.0).round()).abs() < 1e-3,
        "{along}"
    );
    assert!(
        field(&stdout, "train_episodes")
            .parse::<u64>()
            .expect("a count")
            >= 6
    );
    let bytes = std::fs::read(&png).expect("the PNG is written");
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    // Deterministic policy and the same seed: the same figures again.
    let again = asi(&["eval", "--run-dir", &dir_arg, "--episodes", "3"]);
    assert_eq!(
        field(
            &String::from_utf8_lossy(&again.stdout),
            "mean_final_distance"
        ),
        field(&stdout, "mean_final_distance")
    );

    let weights = dir.join("weights/latest.safetensors");
    let mut damaged = std::fs::read(&weights).expect("weights file");
    let middle = damaged.len() / 2;
    damaged[middle] ^= 0xFF;
    std::fs::write(&weights, damaged).expect("write");
    let refused = asi(&["eval", "--run-dir", &dir_arg]);
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(stderr.contains("does not match"), "{stderr}");
}

#[test]
fn asi_eval_on_a_folder_that_is_no_run_says_so() {
    let scratch = Scratch::new("empty");
    std::fs::create_dir_all(&scratch.0).expect("mkdir");
    let out = asi(&["eval", "--run-dir", &scratch.0.to_string_lossy()]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("a run folder?"), "{stderr}");
}
