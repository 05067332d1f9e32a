//! Start-up failures of `asi train` (process mode): a learner that exits before it reports
//! ready, or one that is not ready within `run.startup_timeout_secs`, stops the launch. The
//! launcher exits non-zero with an error naming the process, the reason and its log; no actor
//! is started; no process of the run is left running or registered in iceoryx2; and every
//! checkpoint file that was in the run folder before is still there, byte for byte (the
//! graph-service, which started fine, may add its usual final checkpoint when it is stopped).
//!
//! The failures are real and made from the run folder alone, without test hooks in the
//! binaries: a 2-episode serial run writes a genuine checkpoint, then
//! - one byte of its `policy.safetensors` is flipped: the launcher's up-front manifest check
//!   passes, the learner's checksum check refuses the file and the learner exits 1;
//! - its `policy.safetensors` is replaced by a FIFO that nobody writes: the learner's read of it
//!   never returns, as on a hung network file system, so it never becomes ready.

mod common;

use std::collections::BTreeMap;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::time::{Duration, Instant};

use common::*;

/// A failed start ends within seconds; past this the launcher hangs: the run is killed and the
/// test fails.
const STARTUP_WATCHDOG: Duration = Duration::from_secs(90);

const SMOKE: &str = "configs/smoke.toml";

/// The learner checkpoint the serial run writes.
const CHECKPOINT: &str = "checkpoints/ckpt-000001";

/// A fresh run folder holding the checkpoints of a 2-episode serial smoke run.
fn folder_with_checkpoints(test: &str) -> PathBuf {
    let dir = fresh_dir(test);
    std::fs::create_dir_all(&dir).unwrap();
    let args = [
        OsStr::new("train"),
        OsStr::new("--serial"),
        OsStr::new("--config"),
        OsStr::new(SMOKE),
        OsStr::new("--run-dir"),
        dir.as_os_str(),
        OsStr::new("--set"),
        OsStr::new("run.name=startup-setup"),
        OsStr::new("--set"),
        OsStr::new("run.max_episodes=2"),
        // Only the clean stop's checkpoint, however slow the machine: a second one from
        // smoke's 30 s timer would be the one the launch resumes from.
        OsStr::new("--set"),
        OsStr::new("run.checkpoint_interval_mins=600"),
    ];
    let mut child = spawn_asi(args, &dir.join("setup.log"));
    let deadline = Instant::now() + STARTUP_WATCHDOG;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("watchdog: the serial setup run in {} hangs", dir.display());
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let output = std::fs::read_to_string(dir.join("setup.log")).unwrap_or_default();
    assert!(status.success(), "serial setup run: {status}\n{output}");
    assert!(
        dir.join(CHECKPOINT).join("manifest.json").exists(),
        "{output}"
    );
    dir
}

/// Every regular file under `dir/checkpoints` with its bytes (a FIFO is not read).
fn checkpoint_files(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.join("checkpoints")];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).unwrap().flatten() {
            let kind = entry.file_type().unwrap();
            if kind.is_dir() {
                stack.push(entry.path());
            } else if kind.is_file() {
                files.insert(entry.path(), std::fs::read(entry.path()).unwrap());
            }
        }
    }
    files
}

/// Waits for the launcher's exit; kills the whole run and fails at [`STARTUP_WATCHDOG`].
fn wait_bounded(run: &mut Run) -> ExitStatus {
    loop {
        if let Some(status) = run.child.try_wait().unwrap() {
            eprintln!(
                "launcher exited ({status}) after {:.1} s",
                run.elapsed_secs()
            );
            return status;
        }
        if run.elapsed_secs() > STARTUP_WATCHDOG.as_secs_f64() {
            run.kill_all();
            panic!(
                "watchdog: the launcher still runs after {STARTUP_WATCHDOG:?} of a failed start\n{}",
                run.launcher_output()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// What every failed start leaves: exit code 1, no actor or evaluator started, no process of
/// the run alive, nothing of it in iceoryx2, and the checkpoint files of `before` unchanged.
fn check_stopped_cleanly(run: &Run, status: ExitStatus, before: &BTreeMap<PathBuf, Vec<u8>>) {
    let output = run.launcher_output();
    assert_eq!(status.code(), Some(1), "non-zero exit:\n{output}");
    for process in ["actor-0", "actor-1", "evaluator"] {
        assert!(
            pid_of(&run.dir, process).is_none(),
            "{process} was started although the services were not ready:\n{output}"
        );
    }
    let started = pids(&run.dir);
    assert!(
        started.len() >= 2,
        "learner and graph-service pid files: {started:?}"
    );
    for pid in started {
        // SAFETY: signal 0 only checks whether the pid exists.
        let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0;
        assert!(!alive, "process {pid} of the run still runs:\n{output}");
    }
    let run_id = run.run_id();
    assert_eq!(services_of(&run_id), Vec::<String>::new());
    assert_eq!(nodes_of(&run_id), Vec::<String>::new());
    let after = checkpoint_files(&run.dir);
    for (path, bytes) in before {
        assert!(
            after.get(path) == Some(bytes),
            "{} was changed or removed by the failed start",
            path.display()
        );
    }
}

#[test]
fn a_learner_that_refuses_its_checkpoint_stops_the_start_with_an_error_naming_it_its_reason_and_log(
) {
    let _lock = one_run_at_a_time();
    let dir = folder_with_checkpoints("startup-learner-exits");
    let policy = dir.join(CHECKPOINT).join("policy.safetensors");
    let mut bytes = std::fs::read(&policy).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0xff;
    std::fs::write(&policy, bytes).unwrap();
    let before = checkpoint_files(&dir);
    let mut run = Run::start_in(dir, SMOKE, &[]);
    let status = wait_bounded(&mut run);
    let output = run.launcher_output();
    assert!(
        output.contains("resuming from checkpoint 1"),
        "the launcher accepted the manifest:\n{output}"
    );
    assert!(
        output.contains("error: learner exited while starting (exit status: 1)"),
        "the error names the process:\n{output}"
    );
    assert!(
        output.contains("policy.safetensors is corrupt: checksum"),
        "the error gives the learner's reason:\n{output}"
    );
    assert!(
        output.contains("logs/learner.log"),
        "the error names the log:\n{output}"
    );
    check_stopped_cleanly(&run, status, &before);
}

#[test]
fn a_learner_that_never_becomes_ready_is_stopped_after_the_startup_timeout_with_an_error_naming_it()
{
    let _lock = one_run_at_a_time();
    let dir = folder_with_checkpoints("startup-learner-hangs");
    let policy = dir.join(CHECKPOINT).join("policy.safetensors");
    std::fs::remove_file(&policy).unwrap();
    let fifo = std::ffi::CString::new(policy.to_str().unwrap()).unwrap();
    // SAFETY: plain syscall with a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0, "mkfifo");
    let before = checkpoint_files(&dir);
    let mut run = Run::start_in(dir, SMOKE, &["--set", "run.startup_timeout_secs=4"]);
    let status = wait_bounded(&mut run);
    let output = run.launcher_output();
    assert!(
        output.contains("error: learner") && output.contains("not ready after 4s"),
        "the error names the learner and the timeout:\n{output}"
    );
    assert!(
        output.contains("run.startup_timeout_secs") && output.contains("logs/learner.log"),
        "the error names the config key and the log:\n{output}"
    );
    check_stopped_cleanly(&run, status, &before);
}
