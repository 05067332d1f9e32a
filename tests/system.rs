//! System tests: the real `asi` binary, real processes, real iceoryx2 shared memory, on
//! `configs/smoke.toml`. Each test has its own run folder and run id, a watchdog that kills the
//! run if it hangs, and checks that no service of its run is left behind.
//!
//! The tests take a lock so that only one training run uses the two CI cores at a time.

mod common;

use std::path::Path;

use common::*;
use serde_json::Value;

/// `asi train` on the smoke config with two actors (see [`common::Run`]).
fn start(test: &str, extra: &[&str]) -> Run {
    let args = [&["--actors", "2"][..], extra].concat();
    Run::start(&format!("system-{test}"), "configs/smoke.toml", &args)
}

fn learner_steps_in_metrics(dir: &Path) -> u64 {
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap_or_default();
    text.lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter_map(|v| v.get("learner/ingest/env_steps").and_then(Value::as_f64))
        .fold(0.0, f64::max) as u64
}

/// Whether a metrics line shows actor 0's second incarnation with published steps (an actor
/// publishes its metrics only after sending a chunk).
fn restarted_actor0_published(dir: &Path) -> bool {
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap_or_default();
    text.lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .any(|v| {
            v["actor0/actor/incarnation"]
                .as_f64()
                .is_some_and(|i| i >= 1.0)
                && v["actor0/actor/env_steps"]
                    .as_f64()
                    .is_some_and(|s| s > 0.0)
        })
}

fn assert_nothing_lost(run: &Run, actor_statuses: &[Value]) {
    let learner = run.status("learner");
    let graph = run.status("graph-service");
    let published: u64 = actor_statuses
        .iter()
        .map(|s| as_u64(s, "published_steps"))
        .sum();
    assert!(published > 0, "actors published nothing");
    assert_eq!(
        as_u64(&learner, "env_steps"),
        published,
        "learner ingested every published step"
    );
    assert_eq!(
        as_u64(&graph, "env_steps"),
        published,
        "graph-service stored every published step"
    );
    assert_eq!(as_u64(&learner, "lost_chunks"), 0);
    assert_eq!(as_u64(&learner, "duplicate_chunks"), 0);
    assert_eq!(as_u64(&learner, "rejected_chunks"), 0);
    for id in ["0", "1"] {
        let steps = learner["per_actor_steps"][id].as_u64().unwrap_or(0);
        assert!(
            steps > 0,
            "actor {id}'s data reached the learner: {learner}"
        );
        assert_eq!(
            graph["per_actor_steps"][id].as_u64(),
            Some(steps),
            "graph agrees for actor {id}"
        );
    }
}

#[test]
fn a_smoke_run_moves_every_step_from_both_actors_to_learner_and_graph_service() {
    let _lock = one_run_at_a_time();
    // Evaluations every 4 training episodes, 2 episodes each, so the evaluator runs too.
    let mut run = start(
        "complete",
        &[
            "--set",
            "eval.interval_episodes=4",
            "--set",
            "eval.n_episodes=2",
        ],
    );
    let status = run.wait();
    assert!(status.success(), "launcher exit: {status}");
    let actors = [run.status("actor-0-0"), run.status("actor-1-0")];
    assert_nothing_lost(&run, &actors);
    for actor in &actors {
        assert!(
            as_u64(actor, "policy_version") > 0,
            "actor acted with published weights: {actor}"
        );
    }
    assert!(run.dir.join("config.resolved.toml").exists());
    assert!(
        learner_steps_in_metrics(&run.dir) > 0,
        "metrics.jsonl has learner progress"
    );
    // Coverage of the training data, a fraction of the maze's free cells.
    let last: Value = serde_json::from_str(
        std::fs::read_to_string(run.dir.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .last()
            .unwrap(),
    )
    .unwrap();
    let coverage = last["learner/charts/coverage"]
        .as_f64()
        .expect("coverage metric");
    assert!(coverage > 0.0 && coverage <= 1.0, "coverage {coverage}");
    // The evaluator evaluated published weights at least once and wrote its outputs.
    let evals = std::fs::read_to_string(run.dir.join("eval.jsonl")).unwrap_or_default();
    let first: Value =
        serde_json::from_str(evals.lines().next().expect("an evaluation ran")).unwrap();
    let rate = first["success_rate"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&rate), "{first}");
    assert!(
        first["train_episodes"].as_u64().unwrap() >= 4,
        "due only after 4 episodes: {first}"
    );
    assert!(as_u64(&run.status("evaluator"), "evaluations") >= 1);
    for picture in ["plots/eval_latest.png", "plots/curves.png"] {
        let bytes = std::fs::read(run.dir.join(picture)).unwrap_or_default();
        assert!(bytes.starts_with(b"\x89PNG"), "{picture} is a PNG");
    }
    // The graph-service drew the graph in the maze (the U-maze is square: 600 × 600 pixels,
    // walls dark grey, so not blank).
    assert_eq!(
        png_size(&run.dir.join("plots/graph_latest.png")),
        (600, 600)
    );
    let events: Vec<_> = std::fs::read_dir(run.dir.join("tensorboard"))
        .unwrap()
        .flatten()
        .collect();
    assert_eq!(events.len(), 1, "one TensorBoard event file");
    assert!(
        events[0].metadata().unwrap().len() > 100,
        "event file has records"
    );
    assert_eq!(services_of(&run.run_id()), Vec::<String>::new());
}

#[test]
fn sigterm_stops_every_process_cleanly_and_leaves_no_shared_memory() {
    let _lock = one_run_at_a_time();
    let mut run = start("sigterm", &["--set", "run.max_episodes=1000000"]);
    run.wait_until("both actors published data", |dir| {
        every_actor_published(dir, 2)
    });
    signal(run.child.id(), libc::SIGTERM);
    let status = run.wait();
    assert!(status.success(), "launcher exit after SIGTERM: {status}");
    let actors = [run.status("actor-0-0"), run.status("actor-1-0")];
    assert_nothing_lost(&run, &actors);
    for process in ["learner", "graph-service"] {
        assert_eq!(
            run.status(process)["stop_reason"],
            "stop requested",
            "{process} stopped by the launcher"
        );
    }
    assert_eq!(services_of(&run.run_id()), Vec::<String>::new());
}

#[test]
fn a_killed_actor_is_restarted_and_the_run_continues() {
    let _lock = one_run_at_a_time();
    let mut run = start("kill-actor", &["--set", "run.max_episodes=1000000"]);
    run.wait_until("the learner ingested data", |dir| {
        learner_steps_in_metrics(dir) > 0
    });
    let first_pid = pid_of(&run.dir, "actor-0").expect("actor-0 pid file");
    signal(first_pid, libc::SIGKILL);
    run.wait_until("actor-0 restarted", |dir| {
        pid_of(dir, "actor-0").is_some_and(|pid| pid != first_pid)
    });
    let steps_at_restart = learner_steps_in_metrics(&run.dir);
    run.wait_until(
        "the restarted actor published data",
        restarted_actor0_published,
    );
    run.wait_until("training continued after the restart", |dir| {
        learner_steps_in_metrics(dir) > steps_at_restart + 500
    });
    signal(run.child.id(), libc::SIGTERM);
    let status = run.wait();
    assert!(status.success(), "launcher exit: {status}");
    let restarted = run.status("actor-0-1");
    assert!(
        as_u64(&restarted, "published_steps") > 0,
        "the restarted actor produced data: {restarted}"
    );
    let learner = run.status("learner");
    assert_eq!(
        as_u64(&learner, "duplicate_chunks"),
        0,
        "restarted actor reused no episode id: {learner}"
    );
    assert_eq!(as_u64(&learner, "rejected_chunks"), 0, "{learner}");
    assert_eq!(services_of(&run.run_id()), Vec::<String>::new());
}

#[test]
fn two_serial_runs_with_the_same_seed_write_identical_metrics() {
    let _lock = one_run_at_a_time();
    let eval = [
        "--set",
        "eval.interval_episodes=2",
        "--set",
        "eval.n_episodes=1",
    ];
    let short = [
        &["--serial", "--set", "run.max_episodes=6", "--seed", "5"][..],
        &eval[..],
    ]
    .concat();
    let mut first = start("serial-a", &short);
    assert!(first.wait().success());
    let mut second = start("serial-b", &short);
    assert!(second.wait().success());
    let a = std::fs::read_to_string(first.dir.join("metrics.jsonl")).unwrap();
    let b = std::fs::read_to_string(second.dir.join("metrics.jsonl")).unwrap();
    assert!(
        a.lines().count() >= 3,
        "a line whenever episodes completed: {a}"
    );
    assert!(a.contains("losses/low_critic"), "training ran: {a}");
    assert_eq!(a, b, "same seed, same metrics");
    assert!(
        a.contains("evaluator0/eval/success_rate"),
        "evaluations ran inline: {a}"
    );
    assert!(
        a.contains("learner/charts/coverage"),
        "coverage in serial mode: {a}"
    );
    let evals = std::fs::read_to_string(first.dir.join("eval.jsonl")).unwrap();
    assert!(
        evals.lines().count() >= 2,
        "evaluations at 2, 4, 6 episodes: {evals}"
    );
    assert_eq!(
        evals,
        std::fs::read_to_string(second.dir.join("eval.jsonl")).unwrap()
    );
    let other_args = [
        &["--serial", "--set", "run.max_episodes=6", "--seed", "6"][..],
        &eval[..],
    ]
    .concat();
    let mut other = start("serial-c", &other_args);
    assert!(other.wait().success());
    let c = std::fs::read_to_string(other.dir.join("metrics.jsonl")).unwrap();
    assert_ne!(a, c, "another seed gives another run");
}

/// The run slot that keeps these runs off each other's cores holds against a second holder in
/// this process and in another process (Python's `fcntl.flock`, the same `flock(2)` lock), as
/// when nextest runs each test in a process of its own, and is free again once dropped. (On a
/// lock file of its own: the shared one may be taken by another test the moment it is free.)
#[test]
fn the_run_slot_is_exclusive_across_processes_until_its_holder_drops_it() {
    use std::fs::{OpenOptions, TryLockError};
    let path = fresh_dir("run-slot");
    let other_process_can_lock = || {
        let script = "import fcntl, sys\nf = open(sys.argv[1], 'a')\ntry:\n    \
                      fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)\nexcept BlockingIOError:\n    \
                      sys.exit(3)\n";
        let status = std::process::Command::new("python3")
            .args(["-c", script])
            .arg(&path)
            .status()
            .expect("python3 runs");
        match status.code() {
            Some(0) => true,
            Some(3) => false,
            other => panic!("the lock probe failed: {other:?}"),
        }
    };
    let slot = RunSlot::take(&path);
    let second = OpenOptions::new().write(true).open(&path).unwrap();
    assert!(matches!(second.try_lock(), Err(TryLockError::WouldBlock)));
    assert!(
        !other_process_can_lock(),
        "another process took the held slot"
    );
    drop(slot);
    assert!(other_process_can_lock(), "the dropped slot stays locked");
    second
        .try_lock()
        .expect("the dropped slot is free in this process");
    drop(second);
    std::fs::remove_file(&path).unwrap();
}
