//! Bit-exact serial resume (issue #7): a serial-mode run stopped after M episodes and resumed in
//! the same folder ends with exactly the same `metrics.jsonl` and `eval.jsonl` as an
//! uninterrupted run of N episodes with the same seed — also when it was SIGKILLed between
//! checkpoints, after φ re-maps (the lines written past the checkpoint are moved to a side
//! file, the graph-service comes back from the checkpoint's own base).
//!
//! The stops are deterministic: a launch with `run.max_episodes = M`, then, in the same folder,
//! launches with larger values (the run-length knobs may change on resume). The smoke config's
//! 2 actors run 100-step episodes in 50-step chunks, so both end an episode every second round
//! and an even M falls between two episodes of each actor. The stops are spread over φ rounds,
//! explore, frontier-reaching and self-imitation episodes and evaluations, so all of their
//! state must come back. Each launch runs the real binary in a temporary folder under a
//! watchdog. The smoke graph is small (4 to 7 nodes), so a resume that rebuilt the graph from
//! the whole store instead of replaying the graph-service's inputs would give the same metrics
//! there; a separate test uses 0.1-wide cells and one φ re-map in 12 episodes, where the graph
//! grows from 84 to 210 nodes and such a resume diverges (checked by hand: the metrics differ
//! from episode 12 on).
//!
//! Forked ablation arms: the experiments run one shared prefix with frontier-reaching (FR) and
//! self-imitation (SI) off (HESS) and fork the other arms from copies of its folder (`cp -a`),
//! resumed with the switches changed at the episode where FR or SI starts. A test checks that
//! the HESS prefix copied at FR's start (8 in the smoke config) and resumed with FR on, then
//! copied at SI's start (10) and resumed with SI on, ends with the `metrics.jsonl` and
//! `eval.jsonl` of a run with both on from the start, as does a copy that switches both on
//! early (at 4); that FR episodes and SI steps happen only after the forks; that the prefix
//! names no path of its own folder and is left untouched by its copy's resume; and, so that
//! the equality is not vacuous, that the prefixes continued with FR (SI) off part from the
//! reference on the first metrics line after FR's (SI's) start. Checked by hand to fail when
//! the SI buffer is not filled with SI off (the fork starts SI with an empty buffer) and when
//! an FR-on actor draws its FR number while `fr_prob` is 0. A fork at FR's start before the
//! first φ round (FR set to start early, the first round moved to 8) equals its uninterrupted
//! run too: the graph-service's checkpoint keeps the learner's initial φ (version 0), whose
//! graph is empty (it failed with the φ dropped on restore: the fork's first broadcast
//! re-mapped the stored states into a 4-node graph of the untrained φ).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Upper bound for one launch on a loaded 2-core machine; past it the launch is killed.
const WATCHDOG: Duration = Duration::from_secs(300);
/// Episodes of the uninterrupted run.
const N_EPISODES: u64 = 24;
/// Where the interrupted runs stop, one launch each, before a last launch to [`N_EPISODES`].
/// The first launch of each chain starts fresh, the others resume. Stops at 4 and 16 fall
/// right after a φ re-map (the next metrics line still shows that round's φ statistics), 6,
/// 10, 14 and 18 between re-maps (the graph-service must replay its inputs since the last
/// one), 8 where frontier-reaching and the potential start, 10 where self-imitation starts,
/// 18 right after an evaluation.
const STOP_CHAINS: [&[u64]; 2] = [&[4, 10, 16], &[6, 8, 14, 18]];

/// A unique folder under the temp dir, removed at the end of the test.
struct TempDir(PathBuf);

impl TempDir {
    fn new(test: &str) -> TempDir {
        let dir = common::fresh_dir(&format!("serial-resume-{test}"));
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `asi train --serial` on the smoke config in `run_dir` for `max_episodes`, killed at the
/// watchdog; panics unless it exits 0.
fn serial_train(run_dir: &Path, max_episodes: u64, extra: &[String]) -> Output {
    let (child, args) = spawn_serial(run_dir, max_episodes, extra);
    wait_success(child, &args)
}

/// Starts `asi train --serial` (see [`serial_train`]); returns the child and its arguments.
fn spawn_serial(run_dir: &Path, max_episodes: u64, extra: &[String]) -> (Child, Vec<String>) {
    let mut args = common::serial_smoke_args(run_dir);
    args.extend([
        "--set".to_owned(),
        format!("run.max_episodes={max_episodes}"),
    ]);
    args.extend(extra.iter().cloned());
    let child = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    (child, args)
}

/// Waits for `child` under the watchdog; panics unless it exits 0.
fn wait_success(mut child: Child, args: &[String]) -> Output {
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > WATCHDOG {
            let _ = child.kill();
            panic!("watchdog: `asi {}` ran past {WATCHDOG:?}", args.join(" "));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "`asi {}` failed: {}\n{}",
        args.join(" "),
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

/// The run folder's launch history (`launches.jsonl`), a JSON value per line.
fn history(dir: &Path) -> Vec<serde_json::Value> {
    lines(&dir.join("launches.jsonl"))
        .iter()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// The records of launch `launch` in `history`, as (event, record).
fn launch_records(history: &[serde_json::Value], launch: u64) -> Vec<(&str, &serde_json::Value)> {
    history
        .iter()
        .filter(|r| r["launch"].as_u64() == Some(launch))
        .map(|r| (r["event"].as_str().unwrap(), r))
        .collect()
}

/// Checks launch `launch` of `history`: started (resumed from a checkpoint of `resumed_from`
/// episodes, or fresh), resumed exactly if it resumed, and ended with `outcome` and a newest
/// checkpoint of `ended_at` episodes (no end line when `outcome` is `None`: killed).
fn assert_launch(
    history: &[serde_json::Value],
    launch: u64,
    resumed_from: Option<u64>,
    outcome: Option<(&str, u64)>,
) {
    let records = launch_records(history, launch);
    let events: Vec<&str> = records.iter().map(|(e, _)| *e).collect();
    let mut expected = vec!["start"];
    if resumed_from.is_some() {
        expected.push("resume");
    }
    if outcome.is_some() {
        expected.push("end");
    }
    assert_eq!(events, expected, "launch {launch}: {history:#?}");
    let start = records[0].1;
    assert_eq!(start["mode"], "serial", "{start}");
    assert_eq!(start["seed"], history[0]["seed"], "{start}");
    assert_eq!(
        start["binary"], history[0]["binary"],
        "one build for every launch: {start}"
    );
    assert!(
        start["command"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a == "--serial"),
        "{start}"
    );
    assert_eq!(
        start["resumed_from"]["episodes"].as_u64(),
        resumed_from,
        "{start}"
    );
    if resumed_from.is_some() {
        assert_eq!(records[1].1["exact"], true, "{}", records[1].1);
    }
    if let Some((outcome, episodes)) = outcome {
        let end = records.last().unwrap().1;
        assert_eq!(end["outcome"], outcome, "{end}");
        assert_eq!(end["checkpoint"]["episodes"], episodes, "{end}");
        assert!(end["error"].is_null(), "{end}");
    }
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .map(str::to_owned)
        .collect()
}

fn episodes_of(line: &str) -> u64 {
    let value: serde_json::Value = serde_json::from_str(line).unwrap();
    value["learner/ingest/episodes_completed"].as_f64().unwrap() as u64
}

/// The keys whose values differ between two metrics lines, with both values.
fn differing_keys(a: &str, b: &str) -> Vec<String> {
    let a: serde_json::Map<String, serde_json::Value> = serde_json::from_str(a).unwrap();
    let b: serde_json::Map<String, serde_json::Value> = serde_json::from_str(b).unwrap();
    let mut keys: Vec<&String> = a.keys().chain(b.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .filter(|k| a.get(*k) != b.get(*k))
        .map(|k| format!("{k}: {:?} vs {:?}", a.get(k), b.get(k)))
        .collect()
}

/// Asserts that the two files' lines are equal, naming the first line that differs and, for
/// metrics lines, the keys that differ in it.
fn assert_same_lines(what: &str, uninterrupted: &[String], resumed: &[String]) {
    for (i, (a, b)) in uninterrupted.iter().zip(resumed).enumerate() {
        assert!(
            a == b,
            "{what}: line {} differs (uninterrupted vs resumed): {:#?}",
            i + 1,
            differing_keys(a, b)
        );
    }
    assert_eq!(
        uninterrupted.len(),
        resumed.len(),
        "{what}: the runs wrote different numbers of lines"
    );
}

/// Launches `asi train --serial` in `dir` to `episodes` (see [`serial_train`]); checks that it
/// resumed exactly when `resumes` (restoring the serial state and replaying the
/// graph-service's inputs), started fresh otherwise, and stopped at `episodes`. `what` names
/// the launch in messages. Returns its stderr.
fn launch(dir: &Path, episodes: u64, extra: &[String], resumes: bool, what: &str) -> String {
    let output = serial_train(dir, episodes, extra);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(
        stdout.contains("resuming from checkpoint"),
        resumes,
        "{what}: resumes {resumes}: {stdout}"
    );
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert_eq!(
        stderr.contains("bit-exact resume")
            && stderr.contains("graph-service inputs since its checkpoint replayed"),
        resumes,
        "{what}: a resume restores the serial state exactly and replays the graph-service's \
         inputs: {stderr}"
    );
    let written = lines(&dir.join("metrics.jsonl"));
    assert_eq!(
        written.last().map(|l| episodes_of(l)),
        Some(episodes),
        "{what} should stop at {episodes} episodes"
    );
    stderr
}

/// Launches `asi train --serial` in `dir` once per stop of `stops`, then once to
/// [`N_EPISODES`]; checks that each launch ended where it should and that every launch after
/// the first resumed.
fn run_chain(dir: &Path, stops: &[u64], extra: &[String]) {
    let mut total = 0;
    let launches = stops.len() + 1;
    for (i, &episodes) in stops.iter().chain([&N_EPISODES]).enumerate() {
        let what = format!("launch {i} of {stops:?}");
        let stderr = launch(dir, episodes, extra, i > 0, &what);
        let n_written = stderr.matches("serial checkpoint written").count();
        // At least the final one, or a timed one at the last round boundary, which holds the
        // same state (the final one is then skipped).
        assert!(
            n_written >= 1,
            "{what}: {n_written} serial checkpoints written"
        );
        total += n_written;
    }
    if !extra.is_empty() {
        assert!(
            total > launches,
            "timed checkpoints between the final ones: {total} in {launches} launches"
        );
    }
    // The history holds every launch: where it resumed from, that it resumed exactly, where
    // it ended; and each launch's own resolved config (run.max_episodes differs).
    let history = history(dir);
    let ends: Vec<u64> = stops.iter().copied().chain([N_EPISODES]).collect();
    for (k, &episodes) in ends.iter().enumerate() {
        let resumed_from = k.checked_sub(1).map(|previous| ends[previous]);
        assert_launch(
            &history,
            k as u64,
            resumed_from,
            Some(("budget_reached", episodes)),
        );
    }
    assert_eq!(history.len(), 3 * ends.len() - 1, "{history:#?}");
    let configs: std::collections::HashSet<&str> = history
        .iter()
        .filter_map(|r| r["config"].as_str())
        .collect();
    assert_eq!(configs.len(), ends.len(), "{history:#?}");
}

#[test]
fn a_serial_run_stopped_and_resumed_ends_with_the_metrics_of_an_uninterrupted_one() {
    let tmp = TempDir::new("exact");
    let start = Instant::now();
    let whole = tmp.0.join("whole");
    run_chain(&whole, &[], &[]);
    let expected = lines(&whole.join("metrics.jsonl"));
    let expected_eval = lines(&whole.join("eval.jsonl"));
    assert_eq!(
        expected.len() as u64,
        N_EPISODES / 2,
        "one metrics line per round in which both actors end an episode, none repeated"
    );
    assert_eq!(
        expected_eval.len(),
        4,
        "evaluations at 6, 12, 18 and 24 episodes"
    );
    let picture = std::fs::read(whole.join("plots/eval_latest.png")).unwrap_or_default();
    assert!(
        picture.starts_with(b"\x89PNG"),
        "serial mode draws the last evaluation as the evaluator process does"
    );
    for (k, stops) in STOP_CHAINS.into_iter().enumerate() {
        let split = tmp.0.join(format!("split-{stops:?}"));
        // The second chain also writes timed checkpoints at every round boundary where no
        // episode is open: they must not change the run.
        let extra = match k {
            0 => vec![],
            _ => vec![
                "--set".to_owned(),
                "run.checkpoint_interval_mins=1e-6".to_owned(),
            ],
        };
        run_chain(&split, stops, &extra);
        let what = format!("stopped at {stops:?}");
        assert_same_lines(
            &format!("metrics.jsonl, {what}"),
            &expected,
            &lines(&split.join("metrics.jsonl")),
        );
        assert_same_lines(
            &format!("eval.jsonl, {what}"),
            &expected_eval,
            &lines(&split.join("eval.jsonl")),
        );
    }
    let signalled = stop_by_signal_and_resume(&tmp.0.join("signal"));
    assert_same_lines(
        &format!("metrics.jsonl, stopped by SIGINT at {signalled} episodes"),
        &expected,
        &lines(&tmp.0.join("signal").join("metrics.jsonl")),
    );
    assert_same_lines(
        "eval.jsonl, stopped by SIGINT",
        &expected_eval,
        &lines(&tmp.0.join("signal").join("eval.jsonl")),
    );
    let killed_dir = tmp.0.join("killed");
    let killed = kill_past_a_checkpoint_and_resume(&killed_dir);
    assert_same_lines(
        &format!("metrics.jsonl, SIGKILLed at {killed} episodes, 8 after its checkpoint"),
        &expected,
        &lines(&killed_dir.join("metrics.jsonl")),
    );
    assert_same_lines(
        "eval.jsonl, SIGKILLed",
        &expected_eval,
        &lines(&killed_dir.join("eval.jsonl")),
    );
    eprintln!(
        "compared {} metrics lines and {} evaluations ({N_EPISODES} episodes) against runs \
         stopped at {STOP_CHAINS:?}, at {signalled} (SIGINT) and at {killed} (SIGKILL) and \
         resumed, in {:.1} s",
        expected.len(),
        expected_eval.len(),
        start.elapsed().as_secs_f64()
    );
}

/// A run checkpointed at 8 episodes, launched on to [`N_EPISODES`] with no timed checkpoint
/// and SIGKILLed once it has written metrics lines to 16 episodes or more (past the evaluation
/// at 12), then resumed to the end. The resume must move the lines written after the
/// checkpoint aside (they are written again) and keep them in side files. Returns the
/// episodes of the last line before the kill.
fn kill_past_a_checkpoint_and_resume(dir: &Path) -> u64 {
    const CHECKPOINTED: u64 = 8;
    const KILL_FROM: u64 = 16;
    serial_train(dir, CHECKPOINTED, &[]);
    let metrics = dir.join("metrics.jsonl");
    let at_checkpoint = lines(&metrics).len();
    let no_timer = [
        "--set".to_owned(),
        "run.checkpoint_interval_mins=1e6".to_owned(),
    ];
    let (mut child, _) = spawn_serial(dir, N_EPISODES, &no_timer);
    let start = Instant::now();
    let killed = loop {
        // Whole lines only: the last one may be half-written.
        let text = std::fs::read_to_string(&metrics).unwrap_or_default();
        let last = text
            .strip_suffix('\n')
            .and_then(|whole| whole.lines().next_back())
            .map(episodes_of);
        if last.is_some_and(|e| e >= KILL_FROM) {
            child.kill().unwrap();
            child.wait().unwrap();
            break last.unwrap();
        }
        assert!(
            child.try_wait().unwrap().is_none(),
            "the launch to {N_EPISODES} ended before it could be killed"
        );
        assert!(
            start.elapsed() < WATCHDOG,
            "watchdog: no line at {KILL_FROM} episodes"
        );
        std::thread::sleep(Duration::from_millis(5));
    };
    assert!(killed < N_EPISODES, "killed at {killed}");
    // What the killed launch wrote past the checkpoint (a last line may be half-written).
    let text = std::fs::read_to_string(&metrics).unwrap();
    let tail_at = text
        .match_indices('\n')
        .nth(at_checkpoint - 1)
        .map_or(0, |(i, _)| i + 1);
    let tail = &text[tail_at..];
    let past = tail.matches('\n').count();
    let evals_past = lines(&dir.join("eval.jsonl"))
        .iter()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["train_episodes"].as_u64()
                > Some(CHECKPOINTED)
        })
        .count();
    assert!(evals_past >= 1, "the evaluation at 12 episodes was written");
    // The killed launch re-mapped φ twice after the checkpoint (every 4 episodes), writing
    // two newer graph-service bases; the checkpoint's own base was kept beside them.
    let serial_manifest = dir.join("checkpoints/serial/ckpt-000001/manifest.json");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(serial_manifest).unwrap()).unwrap();
    let base = manifest["graph_base"].as_str().unwrap().to_owned();
    let graph_ckpts: Vec<String> = std::fs::read_dir(dir.join("checkpoints/graph-service"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("ckpt-"))
        .collect();
    assert!(graph_ckpts.contains(&base), "{base} in {graph_ckpts:?}");
    assert!(
        graph_ckpts.iter().filter(|n| **n > base).count() >= 2,
        "{base} in {graph_ckpts:?}"
    );
    let resumed = serial_train(dir, N_EPISODES, &[]);
    let stdout = String::from_utf8_lossy(&resumed.stdout);
    assert!(
        stdout.contains(&format!(
            "metrics.jsonl: {past} lines written after checkpoint 1"
        )) && stdout.contains(&format!(
            "eval.jsonl: {evals_past} lines written after checkpoint 1"
        )),
        "{stdout}"
    );
    // Nothing lost: the side file holds what the killed launch wrote past the checkpoint.
    let side: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.to_string_lossy().contains("metrics.jsonl.past-ckpt-1-"))
        .collect();
    assert_eq!(side.len(), 1, "{side:?}");
    assert!(std::fs::read_to_string(&side[0]).unwrap() == tail);
    // The killed launch has no end line; the next one resumed exactly from checkpoint 1.
    let history = history(dir);
    assert_launch(&history, 0, None, Some(("budget_reached", CHECKPOINTED)));
    assert_launch(&history, 1, Some(CHECKPOINTED), None);
    assert_launch(
        &history,
        2,
        Some(CHECKPOINTED),
        Some(("budget_reached", N_EPISODES)),
    );
    killed
}

/// A launch to [`N_EPISODES`] stopped by SIGINT once its first metrics lines are on disk
/// (wherever that falls: the stop waits for the open episodes), then resumed to the end;
/// returns the episodes at which it stopped.
fn stop_by_signal_and_resume(dir: &Path) -> u64 {
    let (child, args) = spawn_serial(dir, N_EPISODES, &[]);
    let metrics = dir.join("metrics.jsonl");
    let start = Instant::now();
    while std::fs::metadata(&metrics).map_or(true, |m| m.len() == 0) {
        assert!(start.elapsed() < WATCHDOG, "watchdog: no metrics line");
        std::thread::sleep(Duration::from_millis(10));
    }
    // SAFETY: kill(2) on the pid of a child we spawned and have not waited for.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) };
    let output = wait_success(child, &args);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains("stopped by signal"),
        "the launch should stop on SIGINT: {stderr}"
    );
    let stopped = lines(&metrics).last().map_or(0, |l| episodes_of(l));
    assert!(
        stopped < N_EPISODES && stopped.is_multiple_of(2),
        "the signal should stop the run between episodes before its end: {stopped}"
    );
    let resumed = serial_train(dir, N_EPISODES, &[]);
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    assert!(
        stderr.contains("bit-exact resume"),
        "the launch after the signal resumes exactly: {stderr}"
    );
    let history = history(dir);
    assert_launch(&history, 0, None, Some(("stopped", stopped)));
    assert_launch(
        &history,
        1,
        Some(stopped),
        Some(("budget_reached", N_EPISODES)),
    );
    stopped
}

/// Launches `asi train --serial` expecting a failure; returns its stderr.
fn serial_train_fails(run_dir: &Path, extra: &[&str]) -> String {
    let mut args = common::serial_smoke_args(run_dir);
    args.extend(extra.iter().map(|a| a.to_string()));
    let output = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(&args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(
        !output.status.success(),
        "`asi {}` should fail",
        args.join(" ")
    );
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn a_serial_checkpoint_of_other_actors_or_a_corrupt_one_is_refused_with_a_clear_error() {
    let tmp = TempDir::new("refused");
    let dir = tmp.0.join("run");
    serial_train(&dir, 2, &[]);
    let metrics_before = lines(&dir.join("metrics.jsonl"));
    let err = serial_train_fails(&dir, &["--actors", "1", "--set", "run.max_episodes=4"]);
    assert!(
        err.contains("serial checkpoint") && err.contains("(actors, seed, task)"),
        "{err}"
    );
    let state = dir.join("checkpoints/serial/ckpt-000001/state.json");
    let mut bytes = std::fs::read(&state).unwrap();
    bytes[10] ^= 0x20;
    std::fs::write(&state, &bytes).unwrap();
    let err = serial_train_fails(&dir, &["--set", "run.max_episodes=4"]);
    assert!(
        err.contains("state.json") && err.contains("checksum"),
        "{err}"
    );
    assert_eq!(
        lines(&dir.join("metrics.jsonl")),
        metrics_before,
        "a refused resume writes nothing"
    );
    // Nothing but its record in the history: both refused launches failed, with the reason.
    let history = history(&dir);
    for (launch, reason) in [(1, "(actors, seed, task)"), (2, "checksum")] {
        let records = launch_records(&history, launch);
        let events: Vec<&str> = records.iter().map(|(e, _)| *e).collect();
        assert_eq!(events, ["start", "end"], "{history:#?}");
        let end = records[1].1;
        assert_eq!(end["outcome"], "failed", "{end}");
        assert!(end["error"].as_str().unwrap().contains(reason), "{end}");
        assert_eq!(end["checkpoint"]["checkpoint"], 1, "{end}");
    }
}

/// Rewrites every manifest under `dir` as a format-1 build wrote it: `format_version` 1 and
/// each file's word-wise FNV-1a ([`ckpt::fingerprint`]) as its checksum. Returns how many.
fn as_format_1(dir: &Path) -> usize {
    let mut rewritten = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rewritten += as_format_1(&path);
            continue;
        }
        if path.file_name().unwrap() != "manifest.json" {
            continue;
        }
        let mut manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        // Format 2 (serial, graph-service) or 3 (learner: replay next observations elided).
        let format = manifest["format_version"].as_u64();
        assert!(matches!(format, Some(2 | 3)), "{}", path.display());
        manifest["format_version"] = 1.into();
        for file in manifest["files"].as_array_mut().unwrap() {
            let bytes = std::fs::read(dir.join(file["name"].as_str().unwrap())).unwrap();
            file["checksum"] = format!("{:016x}", ckpt::fingerprint(&bytes)).into();
        }
        std::fs::write(&path, serde_json::to_vec_pretty(&manifest).unwrap()).unwrap();
        rewritten += 1;
    }
    rewritten
}

#[test]
fn a_run_whose_checkpoints_are_of_format_1_resumes_bit_exactly() {
    let tmp = TempDir::new("format-1");
    let dir = tmp.0.join("run");
    launch(&dir, 2, &[], false, "the first launch");
    // The serial, learner and graph-service manifests, each as the build before format 2 wrote
    // it (the files are today's: a format-1 reader of the learner's replay files is the
    // unit test `whole_columns_of_formats_1_and_2_still_restore`).
    let rewritten = as_format_1(&dir.join("checkpoints"));
    assert!(rewritten >= 3, "{rewritten} manifests");
    launch(&dir, 4, &[], true, "the resume from format 1");
    let history = history(&dir);
    assert_launch(&history, 1, Some(2), Some(("budget_reached", 4)));
}

#[test]
fn a_run_ended_mid_episode_by_its_step_budget_resumes_and_says_it_is_not_exact() {
    let tmp = TempDir::new("mid-episode");
    let dir = tmp.0.join("run");
    // 2 actors × 50-step chunks: the budget is met after the third round, mid-episode.
    let budget = ["--set".to_owned(), "run.max_env_steps=250".to_owned()];
    let first = serial_train(&dir, 100, &budget);
    let stderr = String::from_utf8_lossy(&first.stderr);
    assert!(stderr.contains("2 open episodes are lost"), "{stderr}");
    let second = serial_train(&dir, 4, &[]);
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(
        stderr.contains("resume not bit-exact") && stderr.contains("open episodes are lost"),
        "{stderr}"
    );
    let written = lines(&dir.join("metrics.jsonl"));
    assert_eq!(written.last().map(|l| episodes_of(l)), Some(4));
    // The history says so too.
    let history = history(&dir);
    let resume = launch_records(&history, 1)
        .into_iter()
        .find(|(event, _)| *event == "resume")
        .expect("a resume line")
        .1;
    assert_eq!(resume["exact"], false, "{resume}");
    assert!(
        resume["detail"]
            .as_str()
            .unwrap()
            .contains("2 open episodes are lost"),
        "{resume}"
    );
}

#[test]
fn a_resume_between_phi_re_maps_keeps_the_graph_of_the_last_re_map() {
    let tmp = TempDir::new("graph");
    let fine = [
        "--set",
        "graph.cell_size=0.1",
        "--set",
        "encoder.interval_episodes=12",
    ]
    .map(str::to_owned);
    let (whole, split) = (tmp.0.join("whole"), tmp.0.join("split"));
    serial_train(&whole, 18, &fine);
    serial_train(&split, 10, &fine);
    let resumed = serial_train(&split, 18, &fine);
    let stderr = String::from_utf8_lossy(&resumed.stderr);
    assert!(stderr.contains("bit-exact resume"), "{stderr}");
    let expected = lines(&whole.join("metrics.jsonl"));
    let nodes = |line: &str| {
        let value: serde_json::Value = serde_json::from_str(line).unwrap();
        value["graph-service/graph/nodes"].as_u64().unwrap()
    };
    assert!(
        nodes(&expected[7]) > nodes(&expected[4]),
        "the graph grows at the re-map after the stop, so a graph rebuilt at the stop would \
         differ from the uninterrupted one"
    );
    assert_same_lines(
        "metrics.jsonl, fine graph stopped at 10",
        &expected,
        &lines(&split.join("metrics.jsonl")),
    );
}

/// Where [`a_fork_before_the_first_phi_round_keeps_the_graph_of_the_initial_phi`] forks, at
/// FR's start, and where its first φ round falls.
const PRE_ROUND_FORK: u64 = 2;
const LATE_FIRST_ROUND: u64 = 8;

#[test]
fn a_fork_before_the_first_phi_round_keeps_the_graph_of_the_initial_phi() {
    // Until the first φ round the learner broadcasts its initial φ (version 0), which reached
    // the graph-service while its store was empty: its graph has no node, and an FR draw finds
    // no route. A fork resumed from a checkpoint of that time must keep this φ. (The
    // graph-service's checkpoint once dropped φ 0 as "no φ", so the fork's first broadcast
    // re-mapped every stored state and built a graph of the untrained φ, whose frontiers the
    // FR episodes then walked to.)
    let tmp = TempDir::new("pre-round-fork");
    let flags = |fr_on: bool| {
        let mut flags = arm_flags(fr_on, true);
        for set in [
            format!("asi.fr_start_episode={PRE_ROUND_FORK}"),
            "asi.fr_prob_schedule=[{ from_episode = 0, p = 1.0 }]".to_owned(),
            format!("encoder.first_round_episode={LATE_FIRST_ROUND}"),
        ] {
            flags.extend(["--set".to_owned(), set]);
        }
        flags
    };
    let (reference, prefix, forked) = (
        tmp.0.join("reference"),
        tmp.0.join("prefix"),
        tmp.0.join("forked"),
    );
    launch(
        &reference,
        LATE_FIRST_ROUND,
        &flags(true),
        false,
        "reference",
    );
    launch(
        &prefix,
        PRE_ROUND_FORK,
        &flags(false),
        false,
        "FR-off prefix",
    );
    fork(&prefix, &forked);
    launch(&forked, LATE_FIRST_ROUND, &flags(true), true, "FR fork");
    let expected = lines(&reference.join("metrics.jsonl"));
    assert_same_lines(
        &format!("metrics.jsonl, FR forked in at {PRE_ROUND_FORK}"),
        &expected,
        &lines(&forked.join("metrics.jsonl")),
    );
    // Not vacuous: the two episodes that started after 4 had ended (each actor's third) drew
    // FR (p = 1) before the φ round and found no route in the empty graph.
    let line_at = |episodes: u64| &expected[first_line_after(&expected, episodes) - 1];
    let six = line_at(6);
    assert_eq!(episodes_of(six), 6, "{six}");
    assert_eq!(metric_sum(six, "/actor/fr/no_route"), 2.0, "{six}");
    assert_eq!(metric_sum(six, "graph-service/graph/nodes"), 0.0, "{six}");
    assert_eq!(metric_sum(six, "learner/phi/version"), 0.0, "{six}");
}

/// Episodes of the forked runs: past self-imitation's start in the smoke config, with an
/// evaluation (at 12) after both forks.
const N_FORKED: u64 = 16;
/// Where a copy of the shared prefix switches frontier-reaching and self-imitation on early,
/// before either starts.
const EARLY_SWITCH: u64 = 4;

/// `--set` flags for an ablation arm: frontier-reaching and self-imitation on or off.
fn arm_flags(frontier_reaching: bool, self_imitation: bool) -> Vec<String> {
    [
        format!("asi.frontier_reaching={frontier_reaching}"),
        format!("asi.self_imitation={self_imitation}"),
    ]
    .into_iter()
    .flat_map(|set| ["--set".to_owned(), set])
    .collect()
}

/// Every file under `dir` with its contents, by path, sorted; panics on anything but plain
/// files and folders (a link could lead a copy back to the original).
fn files_of(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let kind = std::fs::symlink_metadata(&path).unwrap().file_type();
        if kind.is_dir() {
            files.extend(files_of(&path));
        } else {
            assert!(kind.is_file(), "{}: not a plain file", path.display());
            let bytes = std::fs::read(&path).unwrap();
            files.push((path, bytes));
        }
    }
    files.sort();
    files
}

/// Forks the run in `from` as the experiments do, with `cp -a` of the whole folder to `to`,
/// after checking that no file of it names its folder (the copy must be self-contained). The
/// launch history is the exception: it records the commands that made the prefix, which name
/// the folder they ran in, and nothing reads a path from it.
fn fork(from: &Path, to: &Path) {
    let name = from.to_str().unwrap().as_bytes();
    for (path, bytes) in files_of(from) {
        if path.file_name().is_some_and(|n| n == "launches.jsonl") {
            continue;
        }
        assert!(
            !bytes.windows(name.len()).any(|w| w == name),
            "{} names its run folder: a copy would lead back to the original",
            path.display()
        );
    }
    let status = Command::new("cp")
        .arg("-a")
        .arg(from)
        .arg(to)
        .status()
        .unwrap();
    assert!(
        status.success(),
        "cp -a {} {}",
        from.display(),
        to.display()
    );
}

/// The sum over actors (or the one learner value) of the metric whose key ends with `suffix`.
fn metric_sum(line: &str, suffix: &str) -> f64 {
    let value: serde_json::Map<String, serde_json::Value> = serde_json::from_str(line).unwrap();
    let found: Vec<f64> = value
        .iter()
        .filter(|(k, _)| k.ends_with(suffix))
        .map(|(_, v)| v.as_f64().unwrap())
        .collect();
    assert!(!found.is_empty(), "no metric *{suffix} in {line}");
    found.iter().sum()
}

/// The index of the first metrics line written after `episodes` episodes.
fn first_line_after(metrics: &[String], episodes: u64) -> usize {
    metrics
        .iter()
        .position(|l| episodes_of(l) > episodes)
        .unwrap()
}

/// The index of the first line where `a` and `b` differ, if any.
fn first_difference(a: &[String], b: &[String]) -> Option<usize> {
    (0..a.len().max(b.len())).find(|&i| a.get(i) != b.get(i))
}

#[test]
fn ablation_arms_forked_from_a_shared_serial_prefix_equal_runs_started_with_their_flags() {
    let tmp = TempDir::new("fork");
    let start = Instant::now();
    let smoke = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/smoke.toml");
    let asi = protocol::Config::load(Some(&smoke), &[]).unwrap().asi;
    let (fr_start, si_start) = (asi.fr_start_episode, asi.si_start_episode);
    let stops = [EARLY_SWITCH, fr_start, si_start, N_FORKED];
    assert!(
        stops.windows(2).all(|w| w[0] < w[1]) && stops.iter().all(|s| s.is_multiple_of(2)),
        "the forks ({stops:?}) must be in order and fall between two episodes of each actor"
    );
    let reference_dir = tmp.0.join("reference");
    launch(&reference_dir, N_FORKED, &[], false, "reference");
    let reference = lines(&reference_dir.join("metrics.jsonl"));
    let reference_eval = lines(&reference_dir.join("eval.jsonl"));

    // The shared prefix runs as HESS (both off); one copy switches both on early, one turns
    // frontier-reaching on at its start, and a copy of that one turns self-imitation on at
    // its start.
    let (hess, early) = (tmp.0.join("hess"), tmp.0.join("early"));
    let (fr, both) = (tmp.0.join("fr"), tmp.0.join("fr-si"));
    launch(&hess, EARLY_SWITCH, &arm_flags(false, false), false, "HESS");
    fork(&hess, &early);
    launch(&hess, fr_start, &arm_flags(false, false), true, "HESS");
    fork(&hess, &fr);
    let prefix = files_of(&hess);
    launch(&fr, si_start, &arm_flags(true, false), true, "FR fork");
    assert!(
        files_of(&hess) == prefix,
        "resuming the copy must leave the original folder untouched"
    );
    fork(&fr, &both);
    launch(&both, N_FORKED, &[], true, "FR+SI fork");
    launch(&early, N_FORKED, &[], true, "early switch");
    // The fork's history is its prefix's launches (two of HESS, one of the FR fork), then
    // its own, each resumed exactly from where the one before it ended.
    let forked = history(&both);
    for (k, resumed_from) in [None, Some(EARLY_SWITCH), Some(fr_start), Some(si_start)]
        .into_iter()
        .enumerate()
    {
        let ended_at = [EARLY_SWITCH, fr_start, si_start, N_FORKED][k];
        assert_launch(
            &forked,
            k as u64,
            resumed_from,
            Some(("budget_reached", ended_at)),
        );
    }
    let run_dir_of = |k: usize| {
        let start = launch_records(&forked, k as u64)[0].1;
        let command: Vec<&str> = start["command"]
            .as_array()
            .unwrap()
            .iter()
            .map(|a| a.as_str().unwrap())
            .collect();
        let at = command.iter().position(|a| *a == "--run-dir").unwrap();
        PathBuf::from(command[at + 1])
    };
    assert_eq!(
        [run_dir_of(0), run_dir_of(2), run_dir_of(3)],
        [hess.clone(), fr.clone(), both.clone()]
    );
    for (what, dir) in [
        (format!("forked at {fr_start} and {si_start}"), &both),
        (format!("switched on at {EARLY_SWITCH}"), &early),
    ] {
        assert_same_lines(
            &format!("metrics.jsonl, {what}"),
            &reference,
            &lines(&dir.join("metrics.jsonl")),
        );
        assert_same_lines(
            &format!("eval.jsonl, {what}"),
            &reference_eval,
            &lines(&dir.join("eval.jsonl")),
        );
    }

    // Not vacuous: FR episodes and SI steps happen after the forks, not before.
    let at = |episodes| &reference[first_line_after(&reference, episodes) - 1];
    let last = reference.last().unwrap();
    assert_eq!(metric_sum(at(fr_start), "/actor/fr/episodes"), 0.0);
    assert!(metric_sum(last, "/actor/fr/episodes") > 0.0, "{last}");
    assert_eq!(metric_sum(at(si_start), "learner/si/steps"), 0.0);
    assert!(metric_sum(last, "learner/si/steps") > 0.0, "{last}");
    // The graph-service's counters are in every line, so the comparisons above held them too.
    for key in [
        "graph-service/graph/requests",
        "graph-service/graph/explore_answers",
        "graph-service/graph/hess_visited_cells",
        "graph-service/graph/future_count_recomputes",
        "graph-service/graph/reach_samples",
    ] {
        assert!(metric_sum(last, key) > 0.0, "{key}: {last}");
    }
    // The flags matter: the prefixes continued with FR (SI) off part from the reference on
    // the first metrics line after FR's (SI's) start.
    launch(
        &hess,
        N_FORKED,
        &arm_flags(false, false),
        true,
        "HESS to the end",
    );
    launch(
        &fr,
        N_FORKED,
        &arm_flags(true, false),
        true,
        "FR to the end",
    );
    for (what, dir, start) in [("HESS", &hess, fr_start), ("FR only", &fr, si_start)] {
        assert_eq!(
            first_difference(&reference, &lines(&dir.join("metrics.jsonl"))),
            Some(first_line_after(&reference, start)),
            "{what} should equal the reference exactly until {start} episodes, and no further"
        );
    }
    eprintln!(
        "forked arms equal the reference ({} metrics lines, {} evaluations, {N_FORKED} \
         episodes), in {:.1} s",
        reference.len(),
        reference_eval.len(),
        start.elapsed().as_secs_f64()
    );
}
