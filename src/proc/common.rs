//! What every child process shares: its node, the stop conditions, metrics publishing, and
//! the task's dimensions.

use std::time::{Duration, Instant};

use anyhow::Context;
use iceoryx2::prelude::*;
use nets::TaskDims;
use protocol::transport::{open_node, Ipc, ValuePublisher};
use protocol::{Config, MetricsSample, ProcessRole, StepLayout};

use crate::run::RunContext;

/// What the processes need to know about the run's task.
pub struct TaskInfo {
    pub dims: TaskDims,
    pub layout: StepLayout,
    /// Episode length in control steps (the task's own, or `env.episode_length`).
    pub episode_length: u32,
}

/// Builds the run's environment once to learn its dimensions (and to fail early, with the
/// registry's list of names, on an unknown task).
pub fn task_info(config: &Config) -> anyhow::Result<TaskInfo> {
    let options = envs::EnvOptions { max_steps: config.env.episode_length };
    let env = envs::make_with(&config.env.task, options).with_context(|| format!("building task `{}`", config.env.task))?;
    let spec = env.spec();
    let dims = TaskDims {
        obs_dim: spec.obs_dim,
        goal_dim: spec.goal_dim,
        action_dim: spec.action_dim,
        action_scale: f64::from(spec.action_high.iter().copied().fold(0.0f32, f32::max)),
    };
    let layout = StepLayout::new(spec.obs_dim, spec.action_dim, spec.goal_dim, config.encoder.out_dim)?;
    Ok(TaskInfo { dims, layout, episode_length: spec.max_steps })
}

/// The process's iceoryx2 node, named after run and role.
pub fn node(ctx: &RunContext, role: &str) -> anyhow::Result<Node<Ipc>> {
    Ok(open_node(&ctx.run_id.node_name(role))?)
}

/// Why a child loop should stop, checked once per iteration without blocking.
pub struct StopWatch {
    parent: u32,
}

impl StopWatch {
    pub fn new() -> Self {
        Self { parent: std::os::unix::process::parent_id() }
    }

    /// A termination signal arrived (iceoryx2's handler), or the launcher died (we were
    /// re-parented), in which case nobody would ever stop us.
    pub fn should_stop(&self, node: &Node<Ipc>) -> Option<&'static str> {
        if node.wait(Duration::ZERO).is_err() {
            return Some("termination signal");
        }
        if std::os::unix::process::parent_id() != self.parent {
            return Some("launcher exited");
        }
        None
    }
}

/// Publishes named values at most once per interval.
pub struct MetricsOut {
    publisher: ValuePublisher<MetricsSample>,
    role: ProcessRole,
    source_id: u32,
    interval: Duration,
    last: Option<Instant>,
    started: Instant,
}

impl MetricsOut {
    pub fn new(publisher: ValuePublisher<MetricsSample>, role: ProcessRole, source_id: u32, config: &Config) -> Self {
        Self {
            publisher,
            role,
            source_id,
            interval: Duration::from_secs_f64(config.run.metrics_interval_secs.min(1.0)),
            last: None,
            started: Instant::now(),
        }
    }

    /// Whether an interval has passed since the last publish.
    pub fn due(&self) -> bool {
        self.last.is_none_or(|t| t.elapsed() >= self.interval)
    }

    /// Sends every `(name, value)` now; a bad name or a full launcher buffer is logged, not fatal.
    pub fn publish(&mut self, env_step: u64, values: &[(String, f64)]) {
        let wall_ms = self.started.elapsed().as_millis() as u64;
        for (name, value) in values {
            let sent = MetricsSample::new(self.role, self.source_id, name, *value, env_step, wall_ms)
                .map_err(anyhow::Error::from)
                .and_then(|sample| self.publisher.send(sample).map_err(anyhow::Error::from));
            if let Err(err) = sent {
                tracing::warn!("metric `{name}` not sent: {err:#}");
            }
        }
        self.last = Some(Instant::now());
    }
}

/// The newest weights message waiting on `weights`, if any (older ones are superseded).
/// A receive failure is logged; the caller simply keeps its current weights.
pub fn newest_weights(weights: &crate::channels::WeightsSubscriber) -> Option<(protocol::WeightsHeader, Vec<u8>)> {
    let mut newest = None;
    if let Err(err) = weights.drain(|header, bytes| newest = Some((*header, bytes.to_vec()))) {
        tracing::warn!("receiving weights failed: {err:#}");
    }
    newest
}

/// The xy coverage of the training data (SPEC §7, digest §10): every achieved position of every
/// stored step, on the maze's 0.6 m coverage grid (`envs::Coverage`, cumulative, visited free
/// cells / free cells). Tasks without a maze have no coverage.
pub struct CoverageTracker {
    coverage: Option<envs::Coverage>,
    layout: StepLayout,
}

impl CoverageTracker {
    pub fn new(config: &Config, layout: StepLayout) -> anyhow::Result<Self> {
        let options = envs::EnvOptions { max_steps: config.env.episode_length };
        let env = envs::make_with(&config.env.task, options).with_context(|| format!("building task `{}`", config.env.task))?;
        Ok(Self { coverage: env.maze().map(envs::Coverage::new), layout })
    }

    /// Counts the achieved xy of every record of an accepted chunk payload (records that do not
    /// decode were refused by the learner already and are skipped here).
    pub fn observe(&mut self, payload: &[f32]) {
        let Some(coverage) = self.coverage.as_mut() else { return };
        let len = self.layout.record_len();
        if len == 0 || self.layout.goal_dim < 2 {
            return;
        }
        for record in payload.chunks_exact(len) {
            if let Ok(view) = self.layout.view(record) {
                coverage.visit([view.achieved_goal[0], view.achieved_goal[1]]);
            }
        }
    }

    /// `charts/coverage` and `charts/coverage_free_cells_visited`, if the task has a maze.
    pub fn metrics(&self) -> Vec<(String, f64)> {
        match &self.coverage {
            Some(c) => vec![
                ("charts/coverage".to_owned(), c.coverage()),
                ("charts/coverage_free_cells_visited".to_owned(), c.n_visited_free_cells() as f64),
            ],
            None => Vec::new(),
        }
    }
}
