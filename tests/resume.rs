//! Resume system tests: the real `asi` binary on `configs/smoke.toml`, each run in its own
//! folder with its own run id and a watchdog. A stopped run started again in the same folder
//! resumes from its checkpoint (counters continue, nothing restarts from 0), also after a
//! SIGKILL between checkpoints (what it wrote past the checkpoint is moved aside); a damaged
//! graph-service checkpoint is refused and kept while the run resumes; a checkpoint of another
//! config is refused before anything starts.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{as_u64, fresh_dir, one_run_at_a_time, pids, read_json, signal};
use serde_json::Value;

/// Upper bound for one smoke run on a loaded 2-core machine; past it the run is killed.
const WATCHDOG: Duration = Duration::from_secs(600);
/// Checkpoints only at clean stops (the interval is not part of the config fingerprint), so a
/// launch leaves exactly one checkpoint however slow the machine: smoke's 30 s timer would add
/// one to a launch that takes longer on a loaded machine. Every launch here sets it.
const NO_INTERVAL: &str = "run.checkpoint_interval_mins=600";

/// A unique run folder, removed at the end of the test.
struct RunDir(PathBuf);

impl RunDir {
    fn new(test: &str) -> RunDir {
        RunDir(fresh_dir(&format!("resume-{test}")))
    }

    fn status(&self, process: &str) -> Value {
        read_json(&self.0.join("status").join(format!("{process}.json")))
    }

    fn checkpoints(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(self.0.join("checkpoints"))
            .map(|d| {
                d.flatten()
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.retain(|n| n.starts_with("ckpt-"));
        names.sort();
        names
    }
}

impl Drop for RunDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Runs `asi train` on the smoke config in `dir` to its end (unique run name, [`NO_INTERVAL`]),
/// killing it at the watchdog; returns its output.
fn train(dir: &RunDir, extra: &[&str]) -> Output {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    let name = format!("run.name=r{}", nanos % 1_000_000_000);
    let dir_arg = dir.0.to_string_lossy().into_owned();
    let mut args = vec![
        "train",
        "--config",
        "configs/smoke.toml",
        "--actors",
        "2",
        "--run-dir",
        &dir_arg,
    ];
    args.extend(["--set", &name, "--set", NO_INTERVAL]);
    args.extend(extra);
    let child = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("asi starts");
    wait_with_watchdog(child, &dir.0)
}

/// [`train`], asserting that the launch succeeded (`what` names it in the message).
fn train_ok(dir: &RunDir, extra: &[&str], what: &str) -> Output {
    let output = train(dir, extra);
    assert!(
        output.status.success(),
        "{what}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

fn wait_with_watchdog(mut child: Child, dir: &Path) -> Output {
    let deadline = Instant::now() + WATCHDOG;
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            kill_children(dir);
            let _ = child.kill();
            panic!(
                "watchdog: run in {} did not finish within {WATCHDOG:?}",
                dir.display()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    child.wait_with_output().unwrap()
}

/// SIGKILLs every process of the run that wrote a pid file.
fn kill_children(dir: &Path) {
    for pid in pids(dir) {
        signal(pid, libc::SIGKILL);
    }
}

/// The names of the entries of `folder`, sorted.
fn names_in(folder: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(folder)
        .unwrap_or_else(|e| panic!("{}: {e}", folder.display()))
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// `learner/ingest/env_steps` of every metrics line, in file order.
fn env_steps_per_line(dir: &Path) -> Vec<u64> {
    env_steps_in(&dir.join("metrics.jsonl"))
}

/// `learner/ingest/env_steps` of every line of the metrics file at `path`.
fn env_steps_in(path: &Path) -> Vec<u64> {
    values_in(path, "learner/ingest/env_steps")
}

/// `learner/charts/coverage_free_cells_visited` of every metrics line that has it.
fn coverage_cells_per_line(dir: &Path) -> Vec<u64> {
    values_in(
        &dir.join("metrics.jsonl"),
        "learner/charts/coverage_free_cells_visited",
    )
}

/// `graph-service/graph/stored_steps` of every line of a serial run's `metrics.jsonl`.
fn stored_steps_per_line(dir: &Path) -> Vec<u64> {
    values_in(
        &dir.join("metrics.jsonl"),
        "graph-service/graph/stored_steps",
    )
}

/// The (whole-number) value of `key` in every line of the metrics file at `path` that has it.
fn values_in(path: &Path, key: &str) -> Vec<u64> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|v| v.get(key).and_then(Value::as_f64))
        .map(|x| x as u64)
        .collect()
}

/// Launches `dir`'s run again with 6 episodes more than the learner status `before` (taken at
/// the first launch's stop) and `extra` arguments; checks that it succeeded, resumed from
/// learner checkpoint 1 at `before`'s env steps, trained on (env steps and low updates
/// grew), and appended to the metrics file with no line starting again from 0. Returns the
/// learner status after it.
fn resume_six_more(dir: &RunDir, before: &Value, extra: &[&str]) -> Value {
    let (steps, updates) = (as_u64(before, "env_steps"), as_u64(before, "updates_low"));
    let lines_before = env_steps_per_line(&dir.0).len();
    let cells_before = coverage_cells_per_line(&dir.0);
    let covered = *cells_before
        .last()
        .expect("the first launch reported coverage");
    let budget = format!("run.max_episodes={}", as_u64(before, "episodes") + 6);
    let mut args = vec!["--set", budget.as_str()];
    args.extend_from_slice(extra);
    let second = train_ok(dir, &args, "second launch");
    let stdout = String::from_utf8_lossy(&second.stdout);
    assert!(
        stdout.contains(&format!("resuming from checkpoint 1 (env steps {steps})")),
        "{stdout}"
    );
    let after = dir.status("learner");
    assert!(
        as_u64(&after, "env_steps") > steps,
        "env steps continued: {before} → {after}"
    );
    assert!(
        as_u64(&after, "updates_low") > updates,
        "updates continued: {before} → {after}"
    );
    // The metrics file goes on, and no line of the second launch starts again from 0.
    let lines = env_steps_per_line(&dir.0);
    assert!(
        lines.len() > lines_before,
        "the second launch appended metrics"
    );
    assert!(
        lines[lines_before..].iter().all(|&s| s >= steps),
        "{lines:?}"
    );
    // Coverage goes on from the checkpoint's grid (saved beside it), not from 0.
    let cells = coverage_cells_per_line(&dir.0);
    assert!(
        covered > 0 && cells[cells_before.len()..].iter().all(|&c| c >= covered),
        "coverage cells before {cells_before:?}, after {cells:?}"
    );
    after
}

#[test]
fn a_stopped_run_resumes_from_its_checkpoint_and_its_counters_continue() {
    let _lock = one_run_at_a_time();
    let dir = RunDir::new("process");
    train_ok(&dir, &["--set", "run.max_episodes=6"], "first launch");
    assert_eq!(
        dir.checkpoints(),
        ["ckpt-000001"],
        "the clean stop wrote a checkpoint"
    );
    let graph_before = dir.status("graph-service");
    assert!(graph_before["restored_from"].is_null(), "{graph_before}");
    assert!(
        as_u64(&graph_before, "checkpoints_written") >= 1,
        "{graph_before}"
    );
    let graph_ckpt = dir.0.join("checkpoints/graph-service/ckpt-000001");
    assert!(graph_ckpt.join("manifest.json").exists(), "{graph_before}");
    let before = dir.status("learner");
    let (steps, updates) = (as_u64(&before, "env_steps"), as_u64(&before, "updates_low"));
    assert!(steps > 0 && updates > 0, "{before}");

    // The same command again: the checkpoint already reaches the budget, so nothing starts
    // (no process trains a few updates and writes another checkpoint before it stops).
    let metrics_before = std::fs::read(dir.0.join("metrics.jsonl")).unwrap();
    let again = train_ok(
        &dir,
        &["--set", "run.max_episodes=6"],
        "launch with nothing to do",
    );
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(
        stdout.contains(&format!(
            "already finished: checkpoint 1 holds {} episodes and {steps} env steps",
            as_u64(&before, "episodes")
        )),
        "{stdout}"
    );
    assert_eq!(dir.checkpoints(), ["ckpt-000001"]);
    assert_eq!(
        names_in(&dir.0.join("checkpoints/graph-service")),
        ["ckpt-000001"]
    );
    assert!(std::fs::read(dir.0.join("metrics.jsonl")).unwrap() == metrics_before);
    assert_eq!(dir.status("learner"), before, "no learner ran");

    // The random warm-up (smoke: 2 episodes over 2 actors, one each, 5 decisions an
    // episode). The first episode to start began before any had ended, so before count-based
    // exploration and FR could begin: its decisions were random. No actor made more than its
    // one episode's worth. (An actor that starts late may spend its warm-up episode in count
    // mode or FR, which come first as in the authors' code, so each actor's own count can be 0.)
    let random: Vec<u64> = (0..2)
        .map(|actor| as_u64(&dir.status(&format!("actor-{actor}-0")), "random_decisions"))
        .collect();
    assert!(random.iter().sum::<u64>() > 0, "{random:?}");
    assert!(random.iter().all(|&n| n <= 5), "{random:?}");

    // The first launch overshoots its budget while it stops; give the second 6 more episodes.
    let episodes = as_u64(&before, "episodes");
    let after = resume_six_more(&dir, &before, &[]);
    // The resumed launch's actors are their second starts in the folder: fresh episode ids
    // and env seeds, and no second random warm-up (before, both started again at episode 0).
    // The 6 episodes may all be one actor's when the other starts late on a loaded machine.
    let seconds: Vec<Value> = (0..2)
        .map(|actor| dir.status(&format!("actor-{actor}-1")))
        .collect();
    let published: u64 = seconds.iter().map(|s| as_u64(s, "published_steps")).sum();
    assert!(published > 0, "{seconds:?}");
    for second in &seconds {
        assert_eq!(as_u64(second, "random_decisions"), 0, "{second}");
    }
    let starts: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.0.join("process_starts.json")).unwrap())
            .unwrap();
    for process in ["actor-0", "actor-1", "learner", "graph-service"] {
        assert_eq!(as_u64(&starts, process), 2, "{process}: {starts}");
    }
    assert!(
        as_u64(&after, "episodes") >= episodes + 6,
        "the budget counts both launches: {after}"
    );
    assert_eq!(dir.checkpoints(), ["ckpt-000001", "ckpt-000002"]);
    // The history: two launches (the one with nothing to do started none), the second
    // resumed from checkpoint 1, not exactly (process mode), and both reached their budget.
    let history: Vec<Value> = std::fs::read_to_string(dir.0.join("launches.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let events: Vec<(&str, u64)> = history
        .iter()
        .map(|r| (r["event"].as_str().unwrap(), as_u64(r, "launch")))
        .collect();
    assert_eq!(
        events,
        [
            ("start", 0),
            ("end", 0),
            ("start", 1),
            ("resume", 1),
            ("end", 1)
        ],
        "{history:#?}"
    );
    assert_eq!(history[0]["mode"], "processes");
    assert!(history[0]["resumed_from"].is_null(), "{}", history[0]);
    assert_eq!(history[1]["outcome"], "budget_reached", "{}", history[1]);
    assert_eq!(history[1]["checkpoint"]["checkpoint"], 1, "{}", history[1]);
    assert_eq!(
        history[2]["resumed_from"]["checkpoint"], 1,
        "{}",
        history[2]
    );
    assert_eq!(as_u64(&history[2]["resumed_from"], "env_steps"), steps);
    assert_eq!(history[3]["exact"], false, "{}", history[3]);
    assert!(
        history[3]["detail"]
            .as_str()
            .unwrap()
            .contains("process mode"),
        "{}",
        history[3]
    );
    assert_eq!(history[4]["outcome"], "budget_reached", "{}", history[4]);
    assert_eq!(history[4]["checkpoint"]["checkpoint"], 2, "{}", history[4]);
    // The graph-service started from its checkpoint: the store and counters went on.
    let graph_after = dir.status("graph-service");
    assert_eq!(
        graph_after["restored_from"].as_str(),
        graph_ckpt.to_str(),
        "{graph_after}"
    );
    assert_eq!(
        as_u64(&graph_after, "restored_stored_steps"),
        as_u64(&graph_before, "stored_steps"),
        "{graph_after}"
    );
    assert!(
        as_u64(&graph_after, "chunks") > as_u64(&graph_before, "chunks"),
        "chunk counter continued: {graph_before} → {graph_after}"
    );
    assert!(graph_after["refused_checkpoints"]
        .as_array()
        .is_some_and(Vec::is_empty));
    // The resumed evaluator went on after the first launch's evaluations: no index twice.
    let indices: Vec<u64> = std::fs::read_to_string(dir.0.join("eval.jsonl"))
        .unwrap_or_default()
        .lines()
        .map(|l| as_u64(&serde_json::from_str(l).unwrap(), "index"))
        .collect();
    assert!(
        indices.windows(2).all(|w| w[0] < w[1]),
        "evaluation indices only grow: {indices:?}"
    );
    println!("evaluations over both launches: {indices:?}");
}

#[test]
fn a_run_killed_between_checkpoints_resumes_with_its_curves_cut_at_the_checkpoint() {
    let _lock = one_run_at_a_time();
    let dir = RunDir::new("killed");
    // Checkpoints only at clean stops ([`NO_INTERVAL`]), so the killed launch leaves none of
    // its own.
    train_ok(&dir, &["--set", "run.max_episodes=6"], "first launch");
    let before = dir.status("learner");
    let steps = as_u64(&before, "env_steps");
    let lines_at_checkpoint = env_steps_per_line(&dir.0).len();

    // A second launch with a large budget, SIGKILLed (launcher and every child) once it has
    // written a few metrics lines past the checkpoint.
    let dir_arg = dir.0.to_string_lossy().into_owned();
    let budget = format!("run.max_episodes={}", as_u64(&before, "episodes") + 10_000);
    let mut launcher = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(["train", "--config", "configs/smoke.toml", "--actors", "2"])
        .args([
            "--run-dir",
            &dir_arg,
            "--set",
            &budget,
            "--set",
            NO_INTERVAL,
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("asi starts");
    let start = Instant::now();
    while env_steps_per_line(&dir.0)
        .iter()
        .filter(|&&s| s > steps)
        .count()
        < 3
    {
        if start.elapsed() > WATCHDOG || launcher.try_wait().unwrap().is_some() {
            kill_children(&dir.0);
            let _ = launcher.kill();
            panic!("the second launch wrote no metrics past the checkpoint before it ended");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    launcher.kill().unwrap();
    launcher.wait().unwrap();
    kill_children(&dir.0);
    assert_eq!(
        dir.checkpoints(),
        ["ckpt-000001"],
        "the killed launch wrote none"
    );
    // The killed launch's lines past the checkpoint (its first ones may still show the
    // checkpoint's env steps: those stay).
    let all = env_steps_per_line(&dir.0);
    assert!(all[..lines_at_checkpoint].iter().all(|&s| s <= steps));
    let past = all.iter().filter(|&&s| s > steps).count();

    // The resume moves what the killed launch wrote aside and writes that stretch again.
    let budget = format!("run.max_episodes={}", as_u64(&before, "episodes") + 6);
    let resumed = train_ok(&dir, &["--set", &budget], "resume");
    let stdout = String::from_utf8_lossy(&resumed.stdout);
    assert!(
        stdout.contains(&format!("resuming from checkpoint 1 (env steps {steps})")),
        "{stdout}"
    );
    for moved in [
        format!("metrics.jsonl: {past} lines written after checkpoint 1"),
        "metrics.csv: ".to_owned(),
        "events written after checkpoint 1".to_owned(),
    ] {
        assert!(stdout.contains(&moved), "`{moved}` in {stdout}");
    }
    let lines = env_steps_per_line(&dir.0);
    assert!(*lines.last().unwrap() > steps, "trained on: {lines:?}");
    assert!(
        lines.windows(2).all(|w| w[0] <= w[1]),
        "env steps never go back along metrics.jsonl: {lines:?}"
    );
    let side_files: Vec<String> = names_in(&dir.0)
        .into_iter()
        .filter(|n| n.contains(".past-ckpt-1-"))
        .collect();
    assert!(
        side_files.iter().any(|n| n.starts_with("metrics.jsonl."))
            && side_files.iter().any(|n| n.starts_with("metrics.csv."))
            && side_files.iter().any(|n| n.starts_with("tensorboard.")),
        "{side_files:?}"
    );
    let jsonl_side = side_files
        .iter()
        .find(|n| n.starts_with("metrics.jsonl."))
        .unwrap();
    let moved = env_steps_in(&dir.0.join(jsonl_side));
    assert!(
        moved.len() == past && moved.iter().all(|&s| s > steps),
        "{moved:?}"
    );
}

/// Every file of a checkpoint folder, by name, with its bytes.
fn files_of(folder: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(folder)
        .unwrap_or_else(|e| panic!("{}: {e}", folder.display()))
        .flatten()
        .map(|e| {
            let bytes = std::fs::read(e.path()).unwrap();
            (e.file_name().to_string_lossy().into_owned(), bytes)
        })
        .collect()
}

#[test]
fn a_corrupt_graph_service_checkpoint_is_refused_kept_and_the_run_resumes_with_an_empty_store() {
    let _lock = one_run_at_a_time();
    let dir = RunDir::new("corrupt-graph");
    // Checkpoints only at the clean stops ([`NO_INTERVAL`]): the first launch leaves exactly
    // one graph-service checkpoint, and the second cannot prune the damaged one with interval
    // checkpoints.
    train_ok(&dir, &["--set", "run.max_episodes=6"], "first launch");
    assert_eq!(dir.checkpoints(), ["ckpt-000001"]);
    let graph_dir = dir.0.join("checkpoints/graph-service");
    let graph_ckpts = || names_in(&graph_dir);
    assert_eq!(
        graph_ckpts(),
        ["ckpt-000001"],
        "one graph-service checkpoint"
    );
    let graph_before = dir.status("graph-service");
    assert!(as_u64(&graph_before, "stored_steps") > 0, "{graph_before}");
    let before = dir.status("learner");
    let (steps, updates) = (as_u64(&before, "env_steps"), as_u64(&before, "updates_low"));
    assert!(steps > 0 && updates > 0, "{before}");

    // Flip one byte in the middle of the store (the manifest keeps its checksum).
    let damaged = graph_dir.join("ckpt-000001");
    let store = damaged.join("store.safetensors");
    let mut bytes = std::fs::read(&store).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0xff;
    std::fs::write(&store, &bytes).unwrap();
    let damaged_files = files_of(&damaged);

    // The learner resumed from its own checkpoint and trained on.
    resume_six_more(&dir, &before, &[]);
    // The graph-service refused its only checkpoint, naming the file, and started empty.
    let graph_after = dir.status("graph-service");
    assert!(graph_after["restored_from"].is_null(), "{graph_after}");
    assert_eq!(
        as_u64(&graph_after, "restored_stored_steps"),
        0,
        "{graph_after}"
    );
    let refused = graph_after["refused_checkpoints"]
        .as_array()
        .unwrap_or_else(|| panic!("{graph_after}"));
    assert_eq!(refused.len(), 1, "{graph_after}");
    let reason = refused[0].as_str().unwrap();
    assert!(
        reason.starts_with(&format!("{}: ", damaged.display()))
            && reason.contains(&store.display().to_string())
            && reason.contains("checksum"),
        "{reason}"
    );
    // It filled a new store from the new chunks and checkpointed it beside the damaged one,
    // which is left as it was.
    assert!(as_u64(&graph_after, "stored_steps") > 0, "{graph_after}");
    assert_eq!(graph_ckpts(), ["ckpt-000001", "ckpt-000002"]);
    assert!(
        files_of(&damaged) == damaged_files,
        "the refused checkpoint is kept unchanged"
    );
}

#[test]
fn a_serial_run_resumes_too_with_its_graph_store_and_another_config_is_refused_before_starting() {
    let _lock = one_run_at_a_time();
    let dir = RunDir::new("serial");
    train_ok(
        &dir,
        &["--serial", "--set", "run.max_episodes=4"],
        "first launch",
    );
    assert_eq!(dir.checkpoints(), ["ckpt-000001"]);
    let steps = *env_steps_per_line(&dir.0).last().unwrap();
    let stored = stored_steps_per_line(&dir.0);
    let first_lines = stored.len();
    let stored_at_stop = *stored.last().unwrap();
    let graph_ckpt = dir
        .0
        .join("checkpoints/graph-service/ckpt-000001/manifest.json");
    assert!(
        graph_ckpt.exists(),
        "serial mode checkpoints its graph-service"
    );
    let picture = std::fs::read(dir.0.join("plots/graph_latest.png")).unwrap_or_default();
    assert!(
        picture.starts_with(b"\x89PNG"),
        "serial mode draws the graph"
    );
    let curves = std::fs::read(dir.0.join("plots/curves.png")).unwrap_or_default();
    assert!(
        curves.starts_with(b"\x89PNG"),
        "serial mode draws the success and coverage curves"
    );

    // Launched again with nothing left to do: no checkpoint is rewritten (a re-save of the
    // same state would push an older, different one out of the two kept).
    let serial_ckpts = |dir: &RunDir| names_in(&dir.0.join("checkpoints/serial"));
    let serial_before = serial_ckpts(&dir);
    let again = train_ok(
        &dir,
        &["--serial", "--set", "run.max_episodes=4"],
        "launch with nothing to do",
    );
    let stdout = String::from_utf8_lossy(&again.stdout);
    assert!(
        stdout.contains("already finished: checkpoint 1 holds 4 episodes"),
        "{stdout}"
    );
    assert_eq!(dir.checkpoints(), ["ckpt-000001"]);
    assert_eq!(serial_ckpts(&dir), serial_before);
    assert_eq!(
        env_steps_per_line(&dir.0).len(),
        first_lines,
        "no metrics line added"
    );

    let second = train_ok(
        &dir,
        &["--serial", "--set", "run.max_episodes=8"],
        "second launch",
    );
    assert!(String::from_utf8_lossy(&second.stdout).contains("resuming from checkpoint 1"));
    let lines = env_steps_per_line(&dir.0);
    assert!(*lines.last().unwrap() > steps, "{lines:?}");
    // The graph store continued: the second launch's first line stores more states than the
    // first launch had at its stop (a fresh store would hold one episode's states only).
    let stored = stored_steps_per_line(&dir.0);
    assert!(
        stored[first_lines] > stored_at_stop,
        "{stored:?} (first launch: {first_lines} lines)"
    );

    let refused = train(&dir, &["--serial", "--set", "replay.capacity_steps=50000"]);
    assert!(!refused.status.success());
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(
        stderr.contains("another config") && stderr.contains("--restart"),
        "{stderr}"
    );

    let restarted = train_ok(
        &dir,
        &["--serial", "--restart", "--set", "run.max_episodes=2"],
        "restart",
    );
    let stdout = String::from_utf8_lossy(&restarted.stdout);
    let moved = stdout
        .lines()
        .find_map(|l| l.strip_prefix("restarting: the previous run folder was moved to "))
        .unwrap_or_else(|| panic!("{stdout}"));
    let old = RunDir(PathBuf::from(moved));
    assert_eq!(
        old.checkpoints(),
        ["ckpt-000001", "ckpt-000002"],
        "the old run is kept"
    );
    assert!(!stdout.contains("resuming"), "{stdout}");
    assert_eq!(dir.checkpoints(), ["ckpt-000001"], "a new run");
}
