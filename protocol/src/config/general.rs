//! Config sections for the run itself, the environment, the hierarchy, replay, evaluation and
//! transport. Each struct has its `Default` beside it and a `check` that records every problem.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::error::Checker;
use crate::services::RunId;

/// Upper bound on the default number of actor processes (ours: beyond this the learner, not the
/// actors, limits throughput on one machine).
pub const MAX_DEFAULT_ACTORS: usize = 16;

/// `[run]`: naming, seeding, budgets and bookkeeping intervals of one training run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Run name; also the iceoryx2 namespace `asi/<name>/…` and the run folder name, so it
    /// follows [`RunId`] rules (1–64 of `A-Z a-z 0-9 _ -`, starting alphanumeric).
    /// Default `"antmaze-u"`. Source: ours.
    pub name: String,
    /// Master seed; every process derives its own stream from it (actor i: seed + 1 + i).
    /// Default 0. Source: ours.
    pub seed: u64,
    /// Folder that holds run folders; the run writes into `<root_dir>/<name>/`
    /// (see [`RunConfig::run_dir`]). Default `"runs"`. Source: ours (SPEC §7).
    pub root_dir: PathBuf,
    /// Number of training actor processes (the evaluator is extra). Default: available cores
    /// minus two (learner and graph-service), at least 1, at most [`MAX_DEFAULT_ACTORS`].
    /// Source: ours.
    pub n_actors: usize,
    /// Training budget in training episodes (summed over actors). Default 40 000.
    /// Source: code (`n_epochs`).
    pub max_episodes: u64,
    /// Optional training budget in environment steps; the run stops at whichever budget is hit
    /// first. Default: absent (no step budget). Unit: env steps. Source: ours.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_env_steps: Option<u64>,
    /// How often processes publish metrics and the launcher flushes metric files.
    /// Default 5. Unit: seconds. Source: ours.
    pub metrics_interval_secs: f64,
    /// How often the learner writes a checkpoint (also written at clean shutdown).
    /// Default 30. Unit: minutes. Source: ours.
    pub checkpoint_interval_mins: f64,
    /// Crash-loop guard of `asi train`: how many times the launcher restarts crashed processes
    /// of one kind (actors, evaluator, learner, graph-service) within
    /// [`RunConfig::restart_window_mins`]; one more crash of that kind in the window stops the
    /// run with an error naming the process and its log (0: the first crash stops the run).
    /// Default 5. Unit: restarts. Source: ours.
    pub max_restarts: u32,
    /// The sliding window of [`RunConfig::max_restarts`]. Default 10. Unit: minutes.
    /// Source: ours.
    pub restart_window_mins: f64,
    /// How long `asi train` waits for the learner and graph-service to report ready before it
    /// stops the start with an error naming the process that is not (and stops them all).
    /// Raise it when restoring a large checkpoint takes longer. Default 60. Unit: seconds.
    /// Source: ours.
    pub startup_timeout_secs: f64,
}

impl Default for RunConfig {
    fn default() -> Self {
        Self {
            name: "antmaze-u".to_owned(),
            seed: 0,
            root_dir: PathBuf::from("runs"),
            n_actors: default_n_actors(),
            max_episodes: 40_000,
            max_env_steps: None,
            metrics_interval_secs: 5.0,
            checkpoint_interval_mins: 30.0,
            max_restarts: 5,
            restart_window_mins: 10.0,
            startup_timeout_secs: 60.0,
        }
    }
}

/// Default actor count: cores minus two, clamped to `1..=MAX_DEFAULT_ACTORS`.
fn default_n_actors() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    cores.saturating_sub(2).clamp(1, MAX_DEFAULT_ACTORS)
}

impl RunConfig {
    /// The run's own folder, `<root_dir>/<name>`.
    pub fn run_dir(&self) -> PathBuf {
        self.root_dir.join(&self.name)
    }

    pub(crate) fn check(&self, c: &mut Checker) {
        if let Err(err) = RunId::new(&self.name) {
            c.issue("run.name", format!("{:?}", self.name), err.to_string());
        }
        if self.root_dir.as_os_str().is_empty() {
            c.issue("run.root_dir", "\"\"", "must name a folder, e.g. \"runs\"");
        }
        c.at_least_one("run.n_actors", self.n_actors as u64);
        c.at_least_one("run.max_episodes", self.max_episodes);
        if let Some(steps) = self.max_env_steps {
            c.at_least_one("run.max_env_steps", steps);
        }
        c.positive("run.metrics_interval_secs", self.metrics_interval_secs);
        c.positive(
            "run.checkpoint_interval_mins",
            self.checkpoint_interval_mins,
        );
        c.positive("run.restart_window_mins", self.restart_window_mins);
        c.positive("run.startup_timeout_secs", self.startup_timeout_secs);
    }
}

/// `[env]`: which task to train on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvConfig {
    /// Task name, e.g. `"antmaze-u"`, `"antmaze-s"`, `"antmaze-w"`, `"ant-fourrooms"`,
    /// `"halfcheetah-hurdle"`, `"pointmaze-u"`. The `envs` crate resolves and validates it;
    /// here it only has to be non-empty. Default `"antmaze-u"`. Source: paper.
    pub task: String,
    /// Optional episode length override (training and evaluation); absent = the task's own
    /// length (500 for U, 1000 otherwise). Unit: env steps. Source: code (default lengths).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub episode_length: Option<u32>,
}

impl Default for EnvConfig {
    fn default() -> Self {
        Self {
            task: "antmaze-u".to_owned(),
            episode_length: None,
        }
    }
}

impl EnvConfig {
    pub(crate) fn check(&self, c: &mut Checker, subgoal_interval: u32) {
        if self.task.trim().is_empty() {
            c.issue("env.task", "\"\"", "must name a task, e.g. \"antmaze-u\"");
        }
        if let Some(len) = self.episode_length {
            if len < subgoal_interval {
                c.issue(
                    "env.episode_length",
                    len,
                    format!(
                        "must be at least hierarchy.c = {subgoal_interval} (one high-level step)"
                    ),
                );
            }
        }
    }
}

/// `[hierarchy]`: the two-level structure (SPEC §6.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HierarchyConfig {
    /// High-level action interval c: a subgoal is held for c env steps. Default 20.
    /// Unit: env steps. Source: paper and code.
    pub c: u32,
    /// Half-width of the high-level action box: deltas lie in [−abs_range, abs_range]².
    /// Default 10. Unit: φ units. Source: code (`abs_range`).
    pub abs_range: f64,
    /// Low-level reward scale: r_lo = −scale·‖φ(s_{t+1}) − sg‖ (Eq. 2). Default 0.1.
    /// Source: code (the paper has no factor).
    pub low_reward_scale: f64,
    /// Low-level "reached" threshold: low done when ‖φ(s_{t+1}) − sg‖ ≤ this. Default 0.1.
    /// Unit: φ units. Source: code (`args.distance`).
    pub low_reach_threshold: f64,
}

impl Default for HierarchyConfig {
    fn default() -> Self {
        Self {
            c: 20,
            abs_range: 10.0,
            low_reward_scale: 0.1,
            low_reach_threshold: 0.1,
        }
    }
}

impl HierarchyConfig {
    pub(crate) fn check(&self, c: &mut Checker) {
        c.at_least_one("hierarchy.c", u64::from(self.c));
        c.positive("hierarchy.abs_range", self.abs_range);
        c.positive("hierarchy.low_reward_scale", self.low_reward_scale);
        c.non_negative("hierarchy.low_reach_threshold", self.low_reach_threshold);
    }
}

/// `[replay]`: replay buffer sizes and the actor throttle (SPEC §6.8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// Low-level replay capacity; the high-level buffer holds `capacity_steps / c` transitions.
    /// Oldest data is overwritten first. Default 8 000 000. Unit: env steps.
    /// Source: code (`buffer_size`); the supplement says 5 000 000.
    pub capacity_steps: u64,
    /// Throttle: actors pause when the env steps they produced exceed the steps the learner has
    /// consumed (at its configured update ratio) by more than this. Default 20 000.
    /// Unit: env steps. Source: ours (Reverb-style sample-to-insert limiter).
    pub replay_slack_steps: u64,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            capacity_steps: 8_000_000,
            replay_slack_steps: 20_000,
        }
    }
}

impl ReplayConfig {
    pub(crate) fn check(&self, c: &mut Checker, subgoal_interval: u32) {
        if self.capacity_steps < u64::from(subgoal_interval).max(1) * 128 {
            c.issue(
                "replay.capacity_steps",
                self.capacity_steps,
                "must hold at least 128 high-level transitions (128 × hierarchy.c env steps)",
            );
        }
        c.at_least_one("replay.replay_slack_steps", self.replay_slack_steps);
    }
}

/// `[eval]`: periodic evaluation on the fixed-goal test variant (SPEC §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Evaluate after every this many training episodes. Default 50. Unit: episodes.
    /// Source: code (`eval_interval`).
    pub interval_episodes: u64,
    /// Episodes per evaluation; success rate = their mean. Default 10. Source: code
    /// (`n_test_rollouts`).
    pub n_episodes: u32,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            interval_episodes: 50,
            n_episodes: 10,
        }
    }
}

impl EvalConfig {
    pub(crate) fn check(&self, c: &mut Checker) {
        c.at_least_one("eval.interval_episodes", self.interval_episodes);
        c.at_least_one("eval.n_episodes", u64::from(self.n_episodes));
    }
}

/// `[transport]`: iceoryx2 sizing and timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TransportConfig {
    /// Maximum number of actor processes a run's services are sized for (publishers on the
    /// trajectory service, subscribers on the weights service). Must be ≥ `run.n_actors` + 1
    /// (the evaluator). Default 64. Source: ours.
    pub max_actors: usize,
    /// Env steps per trajectory chunk (the last chunk of an episode may be shorter).
    /// Default 100. Unit: env steps. Source: ours.
    pub chunk_steps: u32,
    /// Actors look for new weights at every episode start and at least every this many steps.
    /// Default 1000. Unit: env steps. Source: ours (SPEC §3).
    pub weights_check_interval_steps: u32,
    /// How long a publisher waits for buffer space (or the throttle) before reporting the
    /// peer as stalled. Default 5000. Unit: milliseconds. Source: ours.
    pub backpressure_timeout_ms: u64,
    /// How long a client waits for a graph-service response. Default 10 000.
    /// Unit: milliseconds. Source: ours.
    pub graph_request_timeout_ms: u64,
}

impl Default for TransportConfig {
    fn default() -> Self {
        Self {
            max_actors: 64,
            chunk_steps: 100,
            weights_check_interval_steps: 1000,
            backpressure_timeout_ms: 5000,
            graph_request_timeout_ms: 10_000,
        }
    }
}

impl TransportConfig {
    pub(crate) fn check(&self, c: &mut Checker, n_actors: usize) {
        if self.max_actors < n_actors.saturating_add(1) {
            c.issue(
                "transport.max_actors",
                self.max_actors,
                format!(
                    "must be at least run.n_actors + 1 = {} (the evaluator is an actor too)",
                    n_actors.saturating_add(1)
                ),
            );
        }
        c.at_least_one("transport.chunk_steps", u64::from(self.chunk_steps));
        c.at_least_one(
            "transport.weights_check_interval_steps",
            u64::from(self.weights_check_interval_steps),
        );
        c.at_least_one(
            "transport.backpressure_timeout_ms",
            self.backpressure_timeout_ms,
        );
        c.at_least_one(
            "transport.graph_request_timeout_ms",
            self.graph_request_timeout_ms,
        );
    }
}
