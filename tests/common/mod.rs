//! Helpers shared by the system tests that run the real `asi train`: a unique run folder and run
//! name per test, a watchdog that kills every process of the run (the launcher and each child
//! by its pid file: children run in process groups of their own) and fails the test, and
//! readers for the status files and iceoryx2 leftovers of a run.

#![allow(dead_code)] // each test binary uses its own subset

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

/// Upper bound for one smoke run on a loaded 2-core machine; past it the run is killed.
pub const WATCHDOG: Duration = Duration::from_secs(600);

/// The right to run one training run of several processes: held by every test that starts one,
/// while its run is alive, so these runs, whose checks wait on processes that share the two CI
/// cores, never run beside each other. (Serial runs are one process, bit-exact whatever the
/// load, and do not take it.) An exclusive lock on one file in cargo's test scratch folder: it
/// serialises the tests of one binary (each `open` is its own lock holder, even within one
/// process) and of every binary at once, so it also holds when a runner such as nextest starts
/// tests in parallel processes. The operating system drops the lock when the holder exits, even
/// by a panic or a kill, so a failed test never blocks the next.
pub struct RunSlot {
    _file: std::fs::File,
}

/// Waits for the [`RunSlot`] (a lock on one file in cargo's test scratch folder) and takes it.
pub fn one_run_at_a_time() -> RunSlot {
    RunSlot::take(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("asi-one-run-at-a-time.lock"))
}

impl RunSlot {
    /// Waits for the exclusive lock on `path` (created if missing) and takes it.
    pub fn take(path: &Path) -> RunSlot {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(path)
            .unwrap_or_else(|e| panic!("cannot open the run lock {}: {e}", path.display()));
        file.lock()
            .unwrap_or_else(|e| panic!("cannot lock {}: {e}", path.display()));
        RunSlot { _file: file }
    }
}

/// A running `asi train` in a fresh folder; dropping it kills what is left and removes the
/// folder.
pub struct Run {
    pub dir: PathBuf,
    pub child: Child,
    started: Instant,
}

impl Run {
    /// Starts `asi train --config <config> --run-dir <fresh> --set run.name=<unique>` plus
    /// `extra`; the launcher's stdout and stderr go to `<dir>.launcher.log` beside the folder.
    pub fn start(test: &str, config: &str, extra: &[&str]) -> Run {
        Run::start_in(fresh_dir(test), config, extra)
    }

    /// [`Run::start`] in `dir` (e.g. a [`fresh_dir`] holding an earlier run's checkpoints).
    pub fn start_in(dir: PathBuf, config: &str, extra: &[&str]) -> Run {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos();
        std::fs::create_dir_all(&dir).unwrap();
        let name = format!("run.name=f{}", nanos % 1_000_000_000);
        let dir_arg = dir.to_string_lossy().into_owned();
        let mut args = vec![
            "train",
            "--config",
            config,
            "--run-dir",
            &dir_arg,
            "--set",
            &name,
        ];
        args.extend(extra);
        let child = spawn_asi(&args, &launcher_log(&dir));
        Run {
            dir,
            child,
            started: Instant::now(),
        }
    }

    /// Waits for the launcher and asserts that it exited successfully.
    pub fn wait_success(&mut self) {
        let status = self.wait();
        assert!(
            status.success(),
            "launcher exit {status}:\n{}",
            self.launcher_output()
        );
    }

    /// Per metric key, the last value written to `metrics.jsonl`.
    pub fn last_metrics(&self) -> std::collections::BTreeMap<String, f64> {
        let text = std::fs::read_to_string(self.dir.join("metrics.jsonl")).unwrap();
        let mut last = std::collections::BTreeMap::new();
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

    /// Seconds since the launcher started.
    pub fn elapsed_secs(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// Waits for the launcher to exit; kills the whole run and fails at the watchdog.
    pub fn wait(&mut self) -> ExitStatus {
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            self.check_watchdog("the launcher's exit");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Polls `check` on the run folder until it returns `Some`, or fails the test when the
    /// launcher exits first or at the watchdog.
    pub fn wait_for<T>(&mut self, what: &str, check: impl Fn(&Path) -> Option<T>) -> T {
        loop {
            if let Some(value) = check(&self.dir) {
                return value;
            }
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!(
                    "launcher exited ({status}) before: {what}\n{}",
                    self.launcher_output()
                );
            }
            self.check_watchdog(what);
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Polls `check` on the run folder until it holds (as [`Run::wait_for`]).
    pub fn wait_until(&mut self, what: &str, check: impl Fn(&Path) -> bool) {
        self.wait_for(what, |dir| check(dir).then_some(()));
    }

    /// Kills the whole run and fails the test once the watchdog has expired.
    pub fn check_watchdog(&mut self, what: &str) {
        if self.started.elapsed() > WATCHDOG {
            self.kill_all();
            panic!(
                "watchdog: {what} not seen within {WATCHDOG:?} in {}",
                self.dir.display()
            );
        }
    }

    /// SIGKILLs every child that wrote a pid file, then the launcher.
    pub fn kill_all(&mut self) {
        for pid in pids(&self.dir) {
            signal(pid, libc::SIGKILL);
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    pub fn status(&self, process: &str) -> Value {
        read_json(&self.dir.join("status").join(format!("{process}.json")))
    }

    pub fn run_id(&self) -> String {
        std::fs::read_to_string(self.dir.join("run_id"))
            .unwrap()
            .trim()
            .to_owned()
    }

    /// The launcher's output so far.
    pub fn launcher_output(&self) -> String {
        std::fs::read_to_string(launcher_log(&self.dir)).unwrap_or_default()
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            self.kill_all();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
        let _ = std::fs::remove_file(launcher_log(&self.dir));
    }
}

/// Starts the `asi` binary with `args` in the package folder (where `configs/` lies), stdin
/// closed, stdout and stderr both written to a new file at `log`.
pub fn spawn_asi<S: AsRef<OsStr>>(args: impl IntoIterator<Item = S>, log: &Path) -> Child {
    let log = std::fs::File::create(log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
    Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .expect("asi starts")
}

/// The arguments of `asi train --serial` on the smoke config in `run_dir` (more may follow).
pub fn serial_smoke_args(run_dir: &Path) -> Vec<String> {
    let mut args: Vec<String> = ["train", "--serial", "--config", "configs/smoke.toml"]
        .map(str::to_owned)
        .into();
    args.extend([
        "--run-dir".to_owned(),
        run_dir.to_string_lossy().into_owned(),
    ]);
    args
}

/// A unique run folder path for `test` under the temp folder (not created).
pub fn fresh_dir(test: &str) -> PathBuf {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    std::env::temp_dir().join(format!("asi-{test}-{}-{nanos}", std::process::id()))
}

fn launcher_log(dir: &Path) -> PathBuf {
    let mut name = dir.as_os_str().to_owned();
    name.push(".launcher.log");
    PathBuf::from(name)
}

/// Sends `sig` to `pid` (a process of the run under test).
pub fn signal(pid: u32, sig: i32) {
    // SAFETY: plain syscall on a pid of this run.
    unsafe { libc::kill(pid as libc::pid_t, sig) };
}

/// Pids in the run's `status/*.pid` files.
pub fn pids(dir: &Path) -> Vec<u32> {
    let entries = std::fs::read_dir(dir.join("status"))
        .map(|d| d.flatten().collect::<Vec<_>>())
        .unwrap_or_default();
    entries
        .iter()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".pid"))
        .filter_map(|e| std::fs::read_to_string(e.path()).ok()?.trim().parse().ok())
        .collect()
}

/// The current pid of a child (`learner`, `actor-0`, …) from its pid file.
pub fn pid_of(dir: &Path, process: &str) -> Option<u32> {
    std::fs::read_to_string(dir.join("status").join(format!("{process}.pid")))
        .ok()?
        .trim()
        .parse()
        .ok()
}

pub fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}: {text}", path.display()))
}

pub fn as_u64(v: &Value, key: &str) -> u64 {
    v.get(key)
        .and_then(Value::as_u64)
        .unwrap_or_else(|| panic!("`{key}` missing in {v}"))
}

/// The newest `learner/ingest/env_steps` in `metrics.jsonl` (0 before the first line).
pub fn learner_steps_now(dir: &Path) -> u64 {
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap_or_default();
    text.lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .find_map(|v| v.get("learner/ingest/env_steps").and_then(Value::as_f64))
        .unwrap_or(0.0) as u64
}

/// Whether each of actors `0..n_actors` has published steps by `metrics.jsonl` (an actor
/// reports metrics only after sending a chunk). Tests that stop a run early and then check
/// every actor's data wait for this: on a loaded machine one actor can start seconds after
/// the other, long after the learner ingested the first one's data.
pub fn every_actor_published(dir: &Path, n_actors: usize) -> bool {
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap_or_default();
    let lines: Vec<Value> = text
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .collect();
    (0..n_actors).all(|k| {
        let key = format!("actor{k}/actor/env_steps");
        lines
            .iter()
            .any(|v| v.get(&key).and_then(Value::as_f64).is_some_and(|s| s > 0.0))
    })
}

/// iceoryx2 services whose names contain the run id (they must all be gone after a run).
pub fn services_of(run_id: &str) -> Vec<String> {
    use iceoryx2::prelude::*;
    let mut found = Vec::new();
    let config = iceoryx2::config::Config::global_config();
    let _ = ipc::Service::list(config, |service| {
        let name = service.static_details.name().to_string();
        if name.contains(run_id) {
            found.push(format!("service {name}"));
        }
        CallbackProgression::Continue
    });
    found
}

/// iceoryx2 nodes (alive or dead) whose names contain the run id.
pub fn nodes_of(run_id: &str) -> Vec<String> {
    use iceoryx2::node::NodeView;
    use iceoryx2::prelude::*;
    let mut found = Vec::new();
    let config = iceoryx2::config::Config::global_config();
    let _ = Node::<ipc::Service>::list(config, |state| {
        let (kind, details) = match &state {
            NodeState::Alive(view) => ("alive", view.details().clone()),
            NodeState::Dead(view) => ("dead", view.details().clone()),
            _ => return CallbackProgression::Continue,
        };
        if let Some(details) = details {
            let name = details.name().to_string();
            if name.contains(run_id) {
                found.push(format!("{kind} node {name}"));
            }
        }
        CallbackProgression::Continue
    });
    found
}

/// Where iceoryx2 0.10 keeps its files on Linux: static service and node records under its root
/// path, shared memory (data segments, dynamic configs, event management) in `/dev/shm`, all
/// named `iox2_…`.
pub const ICEORYX2_DIRS: [&str; 2] = ["/tmp/iceoryx2", "/dev/shm"];

/// The ids in iceoryx2 file names that belong to nodes of the run: each node's id (its folder
/// under `nodes/`, found by the run id in its `iox2_node.details`) and the port and service ids
/// of its `*.port_tag` and `*.service_tag` files. Called repeatedly during a run, so that nodes
/// of killed processes are caught too.
pub fn collect_iceoryx2_ids(run_id: &str, ids: &mut std::collections::BTreeSet<String>) {
    let nodes = Path::new(ICEORYX2_DIRS[0]).join("nodes");
    for node in std::fs::read_dir(&nodes)
        .map(|d| d.flatten().collect::<Vec<_>>())
        .unwrap_or_default()
    {
        let details =
            std::fs::read_to_string(node.path().join("iox2_node.details")).unwrap_or_default();
        if !details.contains(run_id) {
            continue;
        }
        ids.insert(node.file_name().to_string_lossy().into_owned());
        for tag in std::fs::read_dir(node.path())
            .map(|d| d.flatten().collect::<Vec<_>>())
            .unwrap_or_default()
        {
            let name = tag.file_name().to_string_lossy().into_owned();
            let id = name.strip_prefix("iox2_").and_then(|n| {
                n.strip_suffix(".port_tag")
                    .or_else(|| n.strip_suffix(".service_tag"))
            });
            if let Some(id) = id {
                ids.insert(id.to_owned());
            }
        }
    }
}

/// Files in the iceoryx2 folders whose names contain one of `ids`.
pub fn iceoryx2_files_with(ids: &std::collections::BTreeSet<String>) -> Vec<String> {
    let mut found = Vec::new();
    let mut stack: Vec<PathBuf> = ICEORYX2_DIRS.iter().map(PathBuf::from).collect();
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir)
            .map(|d| d.flatten().collect::<Vec<_>>())
            .unwrap_or_default()
        {
            let name = entry.file_name().to_string_lossy().into_owned();
            if ids.iter().any(|id| name.contains(id.as_str())) {
                found.push(entry.path().display().to_string());
            }
            if entry.file_type().is_ok_and(|t| t.is_dir()) {
                stack.push(entry.path());
            }
        }
    }
    found
}

/// Width and height of the PNG at `path`, after decoding every pixel; panics unless it decodes
/// and has a non-white pixel.
pub fn png_size(path: &Path) -> (u32, u32) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .expect("a PNG header");
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).expect("PNG pixels decode");
    assert!(pixels.iter().any(|&b| b != 255), "the picture is not blank");
    (info.width, info.height)
}
