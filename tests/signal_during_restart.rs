//! Issue #7: a SIGTERM that reaches `asi train` while a crashed learner waits for its restart
//! (the launcher's back-off) still stops the run cleanly — the launcher keeps ticking during
//! the back-off (no blocking sleep), so it sees the signal, stops the actors, sends the
//! graph-service its Stop, and exits 0 with nothing of the run left running or registered.
//!
//! The learner's back-off is 500 ms and the signal follows the crash notice at once, so the
//! signal normally lands inside it; if the machine is so slow that the restart happens first,
//! the test checks the same properties of that case (the restarted learner is stopped too).
//!
//! A SIGTERM just after the restart finds the new learner still restoring its checkpoint, with
//! no control port yet: the launcher hands it the Stop when its port appears (the channel keeps
//! the last message), instead of SIGTERMing it after the 120 s service stop wait.
//!
//! A SIGTERM while the launcher still waits for learner and graph-service to be ready (before
//! any actor runs) stops them the same way: Stop message, exit 0, nothing left behind.

mod common;

use common::*;

fn learner_starts(dir: &std::path::Path) -> usize {
    std::fs::read_to_string(dir.join("status").join("learner.starts.jsonl"))
        .unwrap_or_default()
        .lines()
        .count()
}

#[test]
fn sigterm_while_a_crashed_learner_waits_for_its_restart_stops_the_run_cleanly() {
    let _lock = one_run_at_a_time();
    let mut run = Run::start(
        "signal-in-backoff",
        "configs/smoke.toml",
        &["--actors", "2", "--set", "run.max_episodes=1000000"],
    );
    run.wait_until("both actors published data", |dir| {
        every_actor_published(dir, 2)
    });
    let run_id = run.run_id();
    let learner = pid_of(&run.dir, "learner").expect("learner pid file");
    signal(learner, libc::SIGKILL);
    run.wait_until("the launcher noticed the crash", |dir| {
        launcher_log_has(dir, "restarting in")
    });
    signal(run.child.id(), libc::SIGTERM);
    let status = run.wait();
    let output = run.launcher_output();
    assert!(status.success(), "launcher exit {status}:\n{output}");
    assert!(output.contains("stopped by signal"), "{output}");
    let restarted = learner_starts(&run.dir) > 1;
    eprintln!("signal landed in the back-off: {}", !restarted);
    assert_eq!(
        run.status("graph-service")["stop_reason"],
        "stop requested",
        "the graph-service got its Stop and wrote its final state"
    );
    for actor in ["actor-0-0", "actor-1-0"] {
        assert!(
            as_u64(&run.status(actor), "published_steps") > 0,
            "{actor} stopped and wrote its status"
        );
    }
    if restarted {
        assert!(
            run.status("learner")["stop_reason"].is_string(),
            "a restarted learner was stopped too"
        );
    }
    for pid in pids(&run.dir) {
        // SAFETY: signal 0 only checks whether the pid exists.
        let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0;
        assert!(!alive, "process {pid} of the run still runs");
    }
    assert_eq!(services_of(&run_id), Vec::<String>::new());
}

/// Whether the launcher's output (`<dir>.launcher.log`, beside the run folder) has `text`.
fn launcher_log_has(dir: &std::path::Path, text: &str) -> bool {
    let mut log = dir.as_os_str().to_owned();
    log.push(".launcher.log");
    std::fs::read_to_string(log).is_ok_and(|t| t.contains(text))
}

#[test]
fn sigterm_just_after_a_crashed_learner_was_restarted_still_reaches_it_as_a_stop_message() {
    let _lock = one_run_at_a_time();
    let mut run = Run::start(
        "signal-after-restart",
        "configs/smoke.toml",
        &["--actors", "2", "--set", "run.max_episodes=1000000"],
    );
    run.wait_until("the learner ingested data", |dir| {
        learner_steps_now(dir) > 0
    });
    let run_id = run.run_id();
    let first = pid_of(&run.dir, "learner").expect("learner pid file");
    signal(first, libc::SIGKILL);
    run.wait_until("the learner restarted", |dir| {
        pid_of(dir, "learner").is_some_and(|pid| pid != first)
    });
    // The new learner is most likely still restoring its checkpoint and has no control port
    // yet when the launcher sends Stop.
    signal(run.child.id(), libc::SIGTERM);
    let status = run.wait();
    let output = run.launcher_output();
    assert!(status.success(), "launcher exit {status}:\n{output}");
    assert!(
        !output.contains("did not stop on the Stop message"),
        "every service got the Stop:\n{output}"
    );
    for process in ["learner", "graph-service"] {
        assert_eq!(
            run.status(process)["stop_reason"],
            "stop requested",
            "{process} stopped by the launcher's Stop message"
        );
    }
    for pid in pids(&run.dir) {
        // SAFETY: signal 0 only checks whether the pid exists.
        let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0;
        assert!(!alive, "process {pid} of the run still runs");
    }
    assert_eq!(services_of(&run_id), Vec::<String>::new());
}

/// Whether `process` has written its ready file.
fn is_ready(dir: &std::path::Path, process: &str) -> bool {
    dir.join("status").join(format!("{process}.ready")).exists()
}

#[test]
fn sigterm_while_the_launcher_waits_for_the_services_to_be_ready_stops_them_in_order() {
    let _lock = one_run_at_a_time();
    let mut run = Run::start(
        "signal-while-starting",
        "configs/smoke.toml",
        &["--actors", "2", "--set", "run.max_episodes=1000000"],
    );
    // Both services spawned (pid files are written at spawn), the learner not ready yet: poll
    // tightly, the window is its start-up (building networks, opening channels).
    loop {
        let spawned =
            pid_of(&run.dir, "learner").is_some() && pid_of(&run.dir, "graph-service").is_some();
        if spawned || run.child.try_wait().unwrap().is_some() {
            break;
        }
        run.check_watchdog("the services spawned");
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    let before_ready = !is_ready(&run.dir, "learner") || !is_ready(&run.dir, "graph-service");
    signal(run.child.id(), libc::SIGTERM);
    let run_id = run.run_id();
    let status = run.wait();
    let output = run.launcher_output();
    eprintln!("signal landed before both services were ready: {before_ready}");
    assert!(status.success(), "launcher exit {status}:\n{output}");
    assert!(output.contains("stopped by signal"), "{output}");
    if before_ready {
        assert!(output.contains("while starting"), "{output}");
        assert!(
            pid_of(&run.dir, "actor-0").is_none(),
            "no actor was started:\n{output}"
        );
    }
    assert!(
        !output.contains("did not stop on the Stop message"),
        "the services stopped on the Stop:\n{output}"
    );
    for process in ["learner", "graph-service"] {
        assert_eq!(
            run.status(process)["stop_reason"],
            "stop requested",
            "{process} stopped by the launcher's Stop message, not left to notice it was gone"
        );
    }
    for pid in pids(&run.dir) {
        // SAFETY: signal 0 only checks whether the pid exists.
        let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0;
        assert!(!alive, "process {pid} of the run still runs");
    }
    assert_eq!(services_of(&run_id), Vec::<String>::new());
}
