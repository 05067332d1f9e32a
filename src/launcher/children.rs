//! The launcher's child processes: spawn, watch, restart crashed ones with back-off, stop in
//! order (SIGTERM, then SIGKILL after a grace period).
//!
//! Every kind of process comes back after a crash: actors and the evaluator hold nothing worth
//! keeping; the learner restarts from its newest checkpoint; the graph-service restores what it
//! saved or starts empty, and its clients fall back to their defaults meanwhile. A crash loop —
//! more than `run.max_restarts` crashes of one kind within `run.restart_window_mins` — ends the
//! run with an error naming the process and its log.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;

use super::starts::StartBook;
use crate::run::RunContext;

/// First restart delay of a crashed process; doubles with each of its crashes, up to
/// [`MAX_BACKOFF`].
const FIRST_BACKOFF: Duration = Duration::from_millis(500);
const MAX_BACKOFF: Duration = Duration::from_secs(30);
/// How long a child may take to exit after SIGTERM before it is killed.
const STOP_GRACE: Duration = Duration::from_secs(20);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChildKind {
    GraphService,
    Learner,
    Actor(u32),
    Evaluator,
}

impl ChildKind {
    pub fn name(self) -> String {
        match self {
            ChildKind::GraphService => "graph-service".to_owned(),
            ChildKind::Learner => "learner".to_owned(),
            ChildKind::Actor(id) => format!("actor-{id}"),
            ChildKind::Evaluator => "evaluator".to_owned(),
        }
    }

    /// Actors and the evaluator: they produce data and are stopped before the services, which
    /// drain what they sent.
    pub fn stops_first(self) -> bool {
        matches!(self, ChildKind::Actor(_) | ChildKind::Evaluator)
    }

    /// The kind without an actor's id: what the crash-loop guard and the per-kind restart
    /// counts (`launcher/restarts_<family>`) go by.
    pub fn family(self) -> &'static str {
        match self {
            ChildKind::GraphService => "graph_service",
            ChildKind::Learner => "learner",
            ChildKind::Actor(_) => "actor",
            ChildKind::Evaluator => "evaluator",
        }
    }
}

/// What one [`Children::restart_crashed`] call saw and did.
#[derive(Debug, Default)]
pub struct Restarts {
    /// Children found exited.
    pub crashed: usize,
    /// Children started again.
    pub restarted: Vec<ChildKind>,
}

struct Supervised {
    kind: ChildKind,
    process: Option<Child>,
    /// Earlier starts of this process in the run folder, all launches ([`StartBook`]).
    incarnation: u32,
    /// Crashes of this process in this launch (its restart back-off doubles with each).
    crashes: u32,
    /// When a crashed process is due to come back.
    restart_at: Option<Instant>,
}

pub struct Children {
    ctx: RunContext,
    exe: std::path::PathBuf,
    children: Vec<Supervised>,
    starts: StartBook,
    /// The most training episodes the run is known to have completed (the resumed checkpoint's,
    /// then the learner's reports): an actor started now takes its share of what is left of
    /// the random warm-up (`actor::warm_up_share`).
    run_episodes: u64,
    restarts: u64,
    /// Restarts so far per [`ChildKind::family`].
    restarts_per_family: BTreeMap<&'static str, u64>,
    /// Crash times within the window per family (the crash-loop guard).
    recent_crashes: BTreeMap<&'static str, VecDeque<Instant>>,
}

impl Children {
    pub fn new(ctx: &RunContext) -> anyhow::Result<Self> {
        std::fs::create_dir_all(ctx.run_dir.join("logs"))?;
        let exe = std::env::current_exe().context("finding the asi executable")?;
        Ok(Self {
            ctx: ctx.clone(),
            exe,
            children: Vec::new(),
            starts: StartBook::open(&ctx.run_dir, ctx.resume)?,
            run_episodes: 0,
            restarts: 0,
            restarts_per_family: BTreeMap::new(),
            recent_crashes: BTreeMap::new(),
        })
    }

    /// Notes that the run has completed at least `episodes` training episodes.
    pub fn note_run_episodes(&mut self, episodes: u64) {
        self.run_episodes = self.run_episodes.max(episodes);
    }

    pub fn total_restarts(&self) -> u64 {
        self.restarts
    }

    /// Restarts so far per [`ChildKind::family`] (families without a restart are absent).
    pub fn restarts_per_family(&self) -> &BTreeMap<&'static str, u64> {
        &self.restarts_per_family
    }

    /// Where a child's stdout and stderr go: `run_dir/logs/<name>.log`.
    pub fn log_path(&self, kind: ChildKind) -> std::path::PathBuf {
        self.ctx
            .run_dir
            .join("logs")
            .join(format!("{}.log", kind.name()))
    }

    pub fn spawn(&mut self, kind: ChildKind) -> anyhow::Result<()> {
        let (process, incarnation) = self.start(kind)?;
        self.children.push(Supervised {
            kind,
            process: Some(process),
            incarnation,
            crashes: 0,
            restart_at: None,
        });
        Ok(())
    }

    /// Starts one process as its next incarnation (counted in the run folder's [`StartBook`]
    /// first); its stdout/stderr go to `run_dir/logs/<name>.log` (appended across restarts and
    /// launches). Its own process group keeps a terminal Ctrl-C away from it: the launcher
    /// decides the shutdown order.
    fn start(&mut self, kind: ChildKind) -> anyhow::Result<(Child, u32)> {
        let incarnation = self.starts.next(&kind.name())?;
        if matches!(kind, ChildKind::Actor(_))
            && incarnation >= crate::proc::actor::MAX_INCARNATIONS
        {
            anyhow::bail!(
                "{} has been started {incarnation} times in this run folder; the episode ids \
                 of a further start would not fit (at most {} starts per actor)",
                kind.name(),
                crate::proc::actor::MAX_INCARNATIONS
            );
        }
        let log_path = self.log_path(kind);
        let log = File::options().create(true).append(true).open(&log_path)?;
        let mut command = Command::new(&self.exe);
        command
            .args(subcommand(kind, incarnation, self.run_episodes))
            .arg("--run-dir")
            .arg(&self.ctx.run_dir)
            .args(["--run-id", self.ctx.run_id.as_str()])
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .process_group(0);
        let child = command
            .spawn()
            .with_context(|| format!("spawning {}", kind.name()))?;
        // For operators and fault-injection tests: which pid is which process right now.
        let pid_file = self
            .ctx
            .run_dir
            .join(crate::run::STATUS_DIR)
            .join(format!("{}.pid", kind.name()));
        crate::run::write_atomically(&pid_file, &child.id().to_string())?;
        Ok((child, incarnation))
    }

    /// While starting: `Some(message)` if the learner or graph-service has exited before it
    /// was ready (a broken setup; restarting it would only repeat the failure). The message
    /// names the process, its exit status, the error it printed last and its log.
    pub fn check_services(&mut self) -> anyhow::Result<Option<String>> {
        for i in 0..self.children.len() {
            let kind = self.children[i].kind;
            if kind.stops_first() {
                continue;
            }
            if let Some(process) = &mut self.children[i].process {
                if let Some(status) = process.try_wait()? {
                    // Reaped: stopping the rest must not signal a pid that may be reused.
                    self.children[i].process = None;
                    let log = self.log_path(kind);
                    let reason = last_error(&log).map_or(String::new(), |e| format!(": {e}"));
                    return Ok(Some(format!(
                        "{} exited while starting ({status}){reason}; see {}",
                        kind.name(),
                        log.display()
                    )));
                }
            }
        }
        Ok(None)
    }

    /// Notices every child that has exited and schedules its restart after a back-off that
    /// doubles per crash of that process; starts those whose back-off is over. A crash beyond
    /// the crash-loop guard's limit is an error that names the process and its log.
    pub fn restart_crashed(&mut self) -> anyhow::Result<Restarts> {
        let now = Instant::now();
        let mut tick = Restarts::default();
        for i in 0..self.children.len() {
            let kind = self.children[i].kind;
            if let Some(process) = &mut self.children[i].process {
                if let Some(status) = process.try_wait()? {
                    self.children[i].process = None;
                    tick.crashed += 1;
                    self.note_crash(kind, &status.to_string(), now)?;
                    let child = &mut self.children[i];
                    let delay = backoff(child.crashes);
                    child.crashes = child.crashes.saturating_add(1);
                    tracing::warn!(
                        process = %kind.name(), %status, incarnation = child.incarnation,
                        "{} exited ({status}); restarting in {delay:?}", kind.name()
                    );
                    child.restart_at = Some(now + delay);
                }
            }
            if self.children[i].restart_at.is_some_and(|at| at <= now) {
                self.restart(i)?;
                tick.restarted.push(kind);
            }
        }
        Ok(tick)
    }

    /// Whether the learner and graph-service processes are running (none waits for a restart).
    pub fn services_running(&self) -> bool {
        self.children
            .iter()
            .filter(|c| !c.kind.stops_first())
            .all(|c| c.process.is_some())
    }

    /// Counts a crash of `kind` in its family's window; past the limit, the crash loop error.
    fn note_crash(&mut self, kind: ChildKind, status: &str, now: Instant) -> anyhow::Result<()> {
        let run = &self.ctx.config.run;
        // Validated finite and > 0; a window too long for a Duration is as good as forever.
        let window =
            Duration::try_from_secs_f64(run.restart_window_mins * 60.0).unwrap_or(Duration::MAX);
        let crashes = self.recent_crashes.entry(kind.family()).or_default();
        crashes.push_back(now);
        while crashes
            .front()
            .is_some_and(|&t| now.duration_since(t) > window)
        {
            crashes.pop_front();
        }
        if crashes.len() > run.max_restarts as usize {
            anyhow::bail!(
                "crash loop: {} processes crashed {} times within {} min (run.max_restarts = {}); \
                 the last was {} ({status}); see {}",
                kind.family(),
                crashes.len(),
                run.restart_window_mins,
                run.max_restarts,
                kind.name(),
                self.log_path(kind).display()
            );
        }
        Ok(())
    }

    /// Starts the next incarnation of child `i`.
    fn restart(&mut self, i: usize) -> anyhow::Result<()> {
        let kind = self.children[i].kind;
        let (process, incarnation) = self.start(kind)?;
        let child = &mut self.children[i];
        child.process = Some(process);
        child.incarnation = incarnation;
        child.restart_at = None;
        self.restarts += 1;
        *self.restarts_per_family.entry(kind.family()).or_default() += 1;
        tracing::info!(process = %kind.name(), incarnation, "{} restarted (incarnation {incarnation})", kind.name());
        Ok(())
    }

    /// Waits up to `timeout` for every running child selected by `which` to exit on its own
    /// (after a Stop message); returns whether all did.
    pub fn wait_for_exit(&mut self, which: impl Fn(ChildKind) -> bool, timeout: Duration) -> bool {
        let deadline = Instant::now() + timeout;
        loop {
            let mut running = false;
            for child in self.children.iter_mut().filter(|c| which(c.kind)) {
                if let Some(process) = &mut child.process {
                    match process.try_wait() {
                        Ok(Some(status)) => {
                            if !status.success() {
                                tracing::warn!("{} exited with {status}", child.kind.name());
                            }
                            child.process = None;
                        }
                        _ => running = true,
                    }
                }
            }
            if !running {
                return true;
            }
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Sends SIGTERM to every running child selected by `which`, waits for them, and kills any
    /// that outlive the grace period.
    pub fn stop_kind(&mut self, which: impl Fn(ChildKind) -> bool) {
        let selected: Vec<usize> = (0..self.children.len())
            .filter(|&i| which(self.children[i].kind))
            .collect();
        for &i in &selected {
            self.children[i].restart_at = None;
            if let Some(process) = &self.children[i].process {
                terminate(process.id());
            }
        }
        let deadline = Instant::now() + STOP_GRACE;
        for &i in &selected {
            let name = self.children[i].kind.name();
            if let Some(mut process) = self.children[i].process.take() {
                wait_or_kill(&mut process, deadline, &name);
            }
        }
    }
}

/// The last `error: …` line a process printed to its log (what `main` prints before a
/// non-zero exit), read from the log's tail; `None` when there is none.
fn last_error(log: &std::path::Path) -> Option<String> {
    use std::io::{Read, Seek, SeekFrom};
    /// Enough for the error chain, which is printed last.
    const TAIL_BYTES: u64 = 16 * 1024;
    let mut file = File::open(log).ok()?;
    let len = file.metadata().ok()?.len();
    file.seek(SeekFrom::Start(len.saturating_sub(TAIL_BYTES)))
        .ok()?;
    let mut tail = Vec::new();
    file.read_to_end(&mut tail).ok()?;
    String::from_utf8_lossy(&tail)
        .lines()
        .rev()
        .find_map(|line| line.strip_prefix("error: "))
        .map(str::to_owned)
}

/// The `asi` subcommand and its own arguments that start `kind` as its `incarnation`, the run
/// having completed `run_episodes` training episodes.
fn subcommand(kind: ChildKind, incarnation: u32, run_episodes: u64) -> Vec<String> {
    match kind {
        ChildKind::GraphService => vec!["graph-service".to_owned()],
        ChildKind::Learner => vec!["learner".to_owned()],
        ChildKind::Actor(id) => vec![
            "actor".to_owned(),
            "--actor-id".to_owned(),
            id.to_string(),
            "--incarnation".to_owned(),
            incarnation.to_string(),
            "--run-episodes".to_owned(),
            run_episodes.to_string(),
        ],
        ChildKind::Evaluator => vec!["evaluator".to_owned()],
    }
}

/// The delay before restarting a process after its `earlier_crashes + 1`-th crash of this launch.
fn backoff(earlier_crashes: u32) -> Duration {
    FIRST_BACKOFF
        .saturating_mul(1 << earlier_crashes.min(16))
        .min(MAX_BACKOFF)
}

fn terminate(pid: u32) {
    // SAFETY: plain syscall on a pid we spawned and have not yet reaped.
    let rc = unsafe { libc::kill(pid as libc::pid_t, libc::SIGTERM) };
    if rc != 0 {
        tracing::debug!(pid, "SIGTERM failed (already gone?)");
    }
}

fn wait_or_kill(process: &mut Child, deadline: Instant, name: &str) {
    loop {
        match process.try_wait() {
            Ok(Some(status)) => {
                if !status.success() {
                    tracing::warn!("{name} exited with {status}");
                }
                return;
            }
            Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            _ => {
                tracing::warn!("{name} did not stop within {STOP_GRACE:?}; killing it");
                let _ = process.kill();
                let _ = process.wait();
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn children(max_restarts: u32) -> (Children, std::path::PathBuf) {
        let dir = std::env::temp_dir().join(format!(
            "asi-children-{}-{max_restarts}",
            std::process::id()
        ));
        let mut config = protocol::Config::default();
        config.run.max_restarts = max_restarts;
        config.run.restart_window_mins = 10.0;
        let ctx = RunContext {
            config,
            run_dir: dir.clone(),
            run_id: protocol::RunId::new("t-1").unwrap(),
            resume: false,
            resumed_from: None,
            launch: None,
            _lock: None,
        };
        (Children::new(&ctx).unwrap(), dir)
    }

    #[test]
    fn the_crash_loop_guard_allows_max_restarts_per_kind_and_names_the_process_and_log_beyond() {
        let (mut children, dir) = children(2);
        let now = Instant::now();
        for _ in 0..2 {
            children
                .note_crash(ChildKind::Learner, "signal: 9", now)
                .unwrap();
        }
        // Other kinds have budgets of their own; actors share one.
        children
            .note_crash(ChildKind::Actor(0), "signal: 9", now)
            .unwrap();
        children
            .note_crash(ChildKind::Actor(1), "signal: 9", now)
            .unwrap();
        let err = children
            .note_crash(ChildKind::Actor(0), "exit status: 3", now)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("actor processes crashed 3 times") && err.contains("actor-0.log"),
            "{err}"
        );
        let err = children
            .note_crash(ChildKind::Learner, "signal: 9", now)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("learner (signal: 9)") && err.contains("logs/learner.log"),
            "{err}"
        );
        assert!(err.contains("run.max_restarts = 2"), "{err}");
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn an_actor_is_told_its_incarnation_and_the_episodes_the_run_has_completed() {
        let (mut children, dir) = children(1);
        children.note_run_episodes(120);
        children.note_run_episodes(80); // a restarted learner's lower count: the warm-up stays done
        assert_eq!(
            subcommand(ChildKind::Actor(3), 2, children.run_episodes),
            [
                "actor",
                "--actor-id",
                "3",
                "--incarnation",
                "2",
                "--run-episodes",
                "120"
            ]
        );
        assert_eq!(subcommand(ChildKind::Learner, 5, 120), ["learner"]);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn crashes_older_than_the_window_are_forgotten() {
        let (mut children, dir) = children(1);
        let window = Duration::from_secs(600);
        let start = Instant::now();
        children
            .note_crash(ChildKind::GraphService, "signal: 9", start)
            .unwrap();
        let later = start + window + Duration::from_secs(1);
        children
            .note_crash(ChildKind::GraphService, "signal: 9", later)
            .unwrap();
        assert!(children
            .note_crash(ChildKind::GraphService, "signal: 9", later)
            .is_err());
        let _ = std::fs::remove_dir_all(dir);
    }
}
