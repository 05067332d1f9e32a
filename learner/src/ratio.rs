//! Replay-ratio accounting and the actor throttle (SPEC §6.8; Reverb's sample-to-insert
//! limiter is the model).
//!
//! - Low level: after `N` ingested env steps, `floor(N · ρ_low)` updates are allowed in total,
//!   ρ_low = `learner.low.updates_per_env_step` (default `updates_per_episode / episode length`,
//!   0.4 for U, 0.2 otherwise), but none before `learner.low.batch_size` transitions are
//!   stored. Updates not yet run when the batch fills are caught up, so the total always
//!   follows the formula.
//! - High level: after `M` high-level transitions have been added, `floor((M − m + 1) · ρ_high)`
//!   updates are allowed (0 while `M < m`), m = `learner.high.min_transitions`,
//!   ρ_high = `learner.high.updates_per_transition` (default 1: one update per new transition
//!   once m are stored, as the reference code).
//! - Budget: actors stop producing while `env_steps_ingested ≥ env_step_budget`, with
//!   `env_step_budget = max(steps_for(updates_low + 1), warmup) + replay_slack_steps`, where
//!   `steps_for(k)` is the least `N` with `floor(N · ρ_low) ≥ k` — the env steps that the updates
//!   done so far, plus the next one, consume — and `warmup = learner.low.batch_size`.
//!   No deadlock: the budget always exceeds the steps that the next low update needs (and the
//!   warm-up), so once actors have filled it that update is allowed, runs, and raises it.
//!
//! Floor and ceiling use a relative tolerance of 1e-12 so that e.g. `5 · 0.4` counts as 2
//! although 0.4 is not exact in binary.

/// Relative tolerance when rounding `N · ρ` down.
const ROUNDING_TOLERANCE: f64 = 1e-12;

/// The accounting constants of a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayRatio {
    /// ρ_low: low updates per ingested env step.
    pub low_per_env_step: f64,
    /// Low batch size: no low update before this many transitions are stored.
    pub low_batch: u64,
    /// ρ_high: high updates per new high-level transition.
    pub high_per_transition: f64,
    /// m: no high update before this many high-level transitions are stored.
    pub high_min_transitions: u64,
    /// Throttle slack in env steps.
    pub slack_steps: u64,
}

/// `floor(n · ratio)` with the module's tolerance.
pub fn floor_product(n: u64, ratio: f64) -> u64 {
    let x = n as f64 * ratio;
    (x + x.abs() * ROUNDING_TOLERANCE).floor().max(0.0) as u64
}

/// The least `n` with `floor_product(n, ratio) ≥ k` (0 for k = 0). `ratio > 0`.
pub fn steps_for(k: u64, ratio: f64) -> u64 {
    if k == 0 {
        return 0;
    }
    let mut n = (k as f64 / ratio).ceil().max(1.0) as u64;
    while floor_product(n, ratio) < k {
        n += 1;
    }
    while n > 1 && floor_product(n - 1, ratio) >= k {
        n -= 1;
    }
    n
}

impl ReplayRatio {
    /// Total low updates allowed after `env_steps` ingested steps with `stored` transitions.
    pub fn low_allowed(&self, env_steps: u64, stored: u64) -> u64 {
        if stored < self.low_batch {
            0
        } else {
            floor_product(env_steps, self.low_per_env_step)
        }
    }

    /// Total high updates allowed after `added` high-level transitions (`stored` of them still
    /// in the buffer).
    pub fn high_allowed(&self, added: u64, stored: u64) -> u64 {
        if added < self.high_min_transitions || stored < self.high_min_transitions {
            0
        } else {
            floor_product(
                added - self.high_min_transitions + 1,
                self.high_per_transition,
            )
        }
    }

    /// Env steps the actors may have produced in total, given `updates_low` low updates done.
    pub fn env_step_budget(&self, updates_low: u64) -> u64 {
        let next = steps_for(updates_low.saturating_add(1), self.low_per_env_step);
        next.max(self.low_batch).saturating_add(self.slack_steps)
    }
}
