//! The run-wide schedule ([`RunSchedule`]) computed from every ingested episode, over all
//! actors (SPEC §6.4, §6.6; digest §2.2, §5.1).
//!
//! - `train_episodes`: training episodes whose final chunk was ingested (every chunk that
//!   reaches the learner comes from a training episode: evaluation episodes are not sent).
//! - `count_prob`: starts at 1; after every `exploration.count_prob_interval_episodes`-th
//!   completed episode it becomes `1 / (1 + exp(2x − 1))`, x = (episodes of that window that
//!   carried [`TrajectoryFlags::FAR_GOAL`](protocol::TrajectoryFlags::FAR_GOAL) and succeeded) / `exploration.count_prob_success_unit`.
//!   "Succeeded" as in the code (`train_success`): the env reported success at any step of the
//!   episode (training episodes do not stop on success). Windows are consecutive blocks of
//!   episodes in the order their final chunks arrived. With `asi.fr_in_count_window = false`
//!   an FR episode (final chunk flagged [`TrajectoryFlags::FRONTIER`](protocol::TrajectoryFlags::FRONTIER))
//!   is left out: it neither fills the window nor adds a success, so a window holds that many
//!   ordinary episodes.
//! - `fr_prob`: 0 unless `asi.frontier_reaching`; otherwise, for the next episode (index
//!   `train_episodes`, 0-based like the code's `epoch`), `asi.fr_prob(train_episodes)` once
//!   `train_episodes > asi.fr_start_episode` (code: `epoch > 200`), else 0.

use protocol::config::AsiConfig;
use protocol::{Config, RunSchedule};

/// `1 / (1 + exp(2x − 1))` with `x = successes / unit` (digest §5.1).
pub fn count_prob(successes: u64, unit: f64) -> f64 {
    let x = successes as f64 / unit;
    1.0 / (1.0 + (2.0 * x - 1.0).exp())
}

/// Running computation of the [`RunSchedule`]; see the module doc.
#[derive(Debug, Clone)]
pub struct ScheduleTracker {
    interval: u64,
    success_unit: f64,
    asi: AsiConfig,
    train_episodes: u64,
    window_episodes: u64,
    window_successes: u64,
    count_prob: f64,
}

impl ScheduleTracker {
    /// The tracker for `config`, before any episode.
    pub fn new(config: &Config) -> Self {
        Self {
            interval: config.exploration.count_prob_interval_episodes.max(1),
            success_unit: config.exploration.count_prob_success_unit,
            asi: config.asi.clone(),
            train_episodes: 0,
            window_episodes: 0,
            window_successes: 0,
            count_prob: f64::from(RunSchedule::START.count_prob),
        }
    }

    /// One more completed training episode; `far_goal_success` = it had the `FAR_GOAL` flag and
    /// reported success at some step, `frontier` = it was an FR episode (`FRONTIER` flag).
    pub fn on_episode_end(&mut self, far_goal_success: bool, frontier: bool) {
        self.train_episodes += 1;
        if frontier && !self.asi.fr_in_count_window {
            return;
        }
        self.window_episodes += 1;
        self.window_successes += u64::from(far_goal_success);
        if self.window_episodes == self.interval {
            self.count_prob = count_prob(self.window_successes, self.success_unit);
            self.window_episodes = 0;
            self.window_successes = 0;
        }
    }

    /// Completed training episodes.
    pub fn train_episodes(&self) -> u64 {
        self.train_episodes
    }

    /// Far-goal successes in the current (incomplete) window.
    pub fn window_successes(&self) -> u64 {
        self.window_successes
    }

    /// Episodes in the current (incomplete) window.
    pub fn window_episodes(&self) -> u64 {
        self.window_episodes
    }

    /// FR probability for the next episode.
    pub fn fr_prob(&self) -> f64 {
        if self.asi.frontier_reaching && self.train_episodes > self.asi.fr_start_episode {
            self.asi.fr_prob(self.train_episodes)
        } else {
            0.0
        }
    }

    /// The state that changes with episodes: `(train_episodes, window_successes, count_prob)`
    /// (checkpoints, with [`ScheduleTracker::window_episodes`]).
    pub(crate) fn counters(&self) -> (u64, u64, f64) {
        (self.train_episodes, self.window_successes, self.count_prob)
    }

    /// Sets the state saved by [`ScheduleTracker::counters`] (checkpoints). `window_episodes`
    /// is `None` in checkpoints of builds before `asi.fr_in_count_window`, which counted every
    /// episode: then it is `train_episodes` modulo the window length.
    pub(crate) fn restore_counters(
        &mut self,
        (train, window, count_prob): (u64, u64, f64),
        window_episodes: Option<u64>,
    ) {
        self.train_episodes = train;
        self.window_episodes = window_episodes.unwrap_or(train % self.interval);
        self.window_successes = window;
        self.count_prob = count_prob;
    }

    /// The schedule to broadcast now.
    pub fn current(&self) -> RunSchedule {
        RunSchedule {
            train_episodes: self.train_episodes,
            count_prob: self.count_prob as f32,
            fr_prob: self.fr_prob() as f32,
        }
    }
}
