//! The launcher's child processes: spawn, watch, restart crashed actors with back-off, stop in
//! order (SIGTERM, then SIGKILL after a grace period).

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;

use crate::run::RunContext;

/// First restart delay of a crashed actor; doubles with each crash, up to [`MAX_BACKOFF`].
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

    /// Actors and the evaluator hold no state worth keeping: a crashed one is restarted.
    pub fn restartable(self) -> bool {
        matches!(self, ChildKind::Actor(_) | ChildKind::Evaluator)
    }
}

struct Supervised {
    kind: ChildKind,
    process: Option<Child>,
    incarnation: u32,
    /// When a crashed actor is due to come back.
    restart_at: Option<Instant>,
}

pub struct Children {
    ctx: RunContext,
    exe: std::path::PathBuf,
    children: Vec<Supervised>,
    restarts: u64,
}

impl Children {
    pub fn new(ctx: &RunContext) -> anyhow::Result<Self> {
        std::fs::create_dir_all(ctx.run_dir.join("logs"))?;
        let exe = std::env::current_exe().context("finding the asi executable")?;
        Ok(Self {
            ctx: ctx.clone(),
            exe,
            children: Vec::new(),
            restarts: 0,
        })
    }

    pub fn total_restarts(&self) -> u64 {
        self.restarts
    }

    pub fn spawn(&mut self, kind: ChildKind) -> anyhow::Result<()> {
        let process = self.start(kind, 0)?;
        self.children.push(Supervised {
            kind,
            process: Some(process),
            incarnation: 0,
            restart_at: None,
        });
        Ok(())
    }

    /// Starts one process; its stdout/stderr go to `run_dir/logs/<name>.log` (appended across
    /// restarts). Its own process group keeps a terminal Ctrl-C away from it: the launcher
    /// decides the shutdown order.
    fn start(&self, kind: ChildKind, incarnation: u32) -> anyhow::Result<Child> {
        let log_path = self
            .ctx
            .run_dir
            .join("logs")
            .join(format!("{}.log", kind.name()));
        let log = File::options().create(true).append(true).open(&log_path)?;
        let mut command = Command::new(&self.exe);
        match kind {
            ChildKind::GraphService => command.arg("graph-service"),
            ChildKind::Learner => command.arg("learner"),
            ChildKind::Actor(id) => command.args([
                "actor",
                "--actor-id",
                &id.to_string(),
                "--incarnation",
                &incarnation.to_string(),
            ]),
            ChildKind::Evaluator => command.arg("evaluator"),
        };
        command
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
        Ok(child)
    }

    /// `Some(message)` if the learner or graph-service has exited (they are not restarted
    /// here: their state would be lost; checkpoint-based restarts come with resume).
    pub fn check_services(&mut self) -> anyhow::Result<Option<String>> {
        for child in &mut self.children {
            if child.kind.restartable() {
                continue;
            }
            if let Some(process) = &mut child.process {
                if let Some(status) = process.try_wait()? {
                    return Ok(Some(format!(
                        "{} exited unexpectedly ({status}); see {}",
                        child.kind.name(),
                        self.ctx
                            .run_dir
                            .join("logs")
                            .join(format!("{}.log", child.kind.name()))
                            .display()
                    )));
                }
            }
        }
        Ok(None)
    }

    /// Restarts actors (and the evaluator) that have exited, each after a back-off that
    /// doubles per crash.
    pub fn restart_crashed_actors(&mut self) -> anyhow::Result<()> {
        let now = Instant::now();
        for i in 0..self.children.len() {
            let kind = self.children[i].kind;
            if !kind.restartable() {
                continue;
            }
            if let Some(process) = &mut self.children[i].process {
                if let Some(status) = process.try_wait()? {
                    let child = &mut self.children[i];
                    let delay = backoff(child.incarnation);
                    tracing::warn!("{} exited ({status}); restarting in {delay:?}", kind.name());
                    child.process = None;
                    child.restart_at = Some(now + delay);
                }
            }
            if self.children[i].restart_at.is_some_and(|at| at <= now) {
                let incarnation = self.children[i].incarnation + 1;
                let process = self.start(kind, incarnation)?;
                let child = &mut self.children[i];
                child.process = Some(process);
                child.incarnation = incarnation;
                child.restart_at = None;
                self.restarts += 1;
                tracing::info!("{} restarted (incarnation {incarnation})", kind.name());
            }
        }
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

fn backoff(incarnation: u32) -> Duration {
    FIRST_BACKOFF
        .saturating_mul(1 << incarnation.min(16))
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
