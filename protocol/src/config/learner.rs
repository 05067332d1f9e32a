//! Config sections for the two learners: `[learner.high]` (SAC) and `[learner.low]` (SAC by
//! default, or the reference code's deterministic actor-critic in `[learner.low.deterministic]`).

use serde::{Deserialize, Serialize};

use super::error::Checker;

/// `[learner]`: both levels.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LearnerConfig {
    /// High-level learner (SAC on φ-space deltas).
    pub high: HighLearnerConfig,
    /// Low-level learner (SAC, or the deterministic variant).
    pub low: LowLearnerConfig,
}

impl LearnerConfig {
    pub(crate) fn check(&self, c: &mut Checker) {
        self.high.check(c);
        self.low.check(c);
    }
}

/// `[learner.high]`: SAC for the high level (SPEC §6.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HighLearnerConfig {
    /// Discount per high-level step. Default 0.99. Source: paper and code.
    pub gamma: f64,
    /// Polyak rate of the target critics, applied after every update. Default 0.005.
    /// Source: code.
    pub tau: f64,
    /// Adam learning rate of policy, critics (and α when tuned). Default 3e-4.
    /// Source: code (`args.lr`); the supplement says 2e-4.
    pub lr: f64,
    /// Minibatch size. Default 128. Source: paper and code.
    pub batch_size: usize,
    /// Entropy temperature α (initial value when `auto_alpha`). Default 0.2. Source: code.
    pub alpha: f64,
    /// Tune α towards the target entropy −dim(action). Default false. Source: code (off).
    pub auto_alpha: bool,
    /// Hidden layer widths of the policy and of each twin critic. Default [256, 256].
    /// Source: paper (supplement) and code.
    pub hidden: Vec<usize>,
    /// Gradient updates per new high-level transition. Default 1. Source: code.
    pub updates_per_transition: f64,
    /// Updates start once this many transitions are stored. Default 128 (= one batch).
    /// Unit: transitions. Source: code.
    pub min_transitions: u64,
    /// Training episodes at the start of the run that use uniform random high actions (when
    /// the subgoal is not chosen by exploration), shared by the actors: an actor takes
    /// ⌈left / `run.n_actors`⌉ of its first episodes, `left` being what the run has not done
    /// of them when the actor starts (all of them at the start; less for an actor restarted or
    /// resumed later). Default 300. Unit: episodes. Source: code (`start_epoch`).
    pub random_episodes: u64,
    /// Clamp the critic target `y = R + mask·γ·(min Q' − α log π)` to `[−T · p, 0]`, T the
    /// episode length in env steps (the task's own or `env.episode_length`), p the task's
    /// per-step penalty (1 on every registered task; `envs::registry::sparse_reward`), as the
    /// reference code does for its "sparse" reward (digest §3.1). The Ant's fall penalty (−10
    /// per fall step) is left out of the bound, as in the reference, and the high level
    /// bootstraps through truncation, so true values can lie below −T: the clamp is the
    /// reference's heuristic, not a bound on the return. Default false (ours: the runs in
    /// progress use the unclamped target; the default awaits a measured comparison). Written
    /// to the resolved TOML only when true, so configs and checkpoints from before the switch
    /// keep their fingerprint.
    #[serde(skip_serializing_if = "is_false")]
    pub clip_target: bool,
}

/// `skip_serializing_if` helper: a switch that is off is not written.
fn is_false(value: &bool) -> bool {
    !*value
}

impl Default for HighLearnerConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            tau: 0.005,
            lr: 3e-4,
            batch_size: 128,
            alpha: 0.2,
            auto_alpha: false,
            hidden: vec![256, 256],
            updates_per_transition: 1.0,
            min_transitions: 128,
            random_episodes: 300,
            clip_target: false,
        }
    }
}

impl HighLearnerConfig {
    fn check(&self, c: &mut Checker) {
        check_sac_common(
            c,
            "learner.high",
            self.gamma,
            self.tau,
            self.lr,
            self.batch_size,
            self.alpha,
        );
        c.layer_sizes("learner.high.hidden", &self.hidden);
        c.positive(
            "learner.high.updates_per_transition",
            self.updates_per_transition,
        );
        if self.min_transitions < self.batch_size as u64 {
            c.issue(
                "learner.high.min_transitions",
                self.min_transitions,
                format!(
                    "must be at least learner.high.batch_size = {}",
                    self.batch_size
                ),
            );
        }
    }
}

/// Which algorithm trains the low level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LowAlgo {
    /// Tanh-Gaussian SAC with twin critics, as the paper states. Default.
    Sac,
    /// The reference code's DDPG-style actor-critic (γ-distance Q, Gaussian + ε-random noise),
    /// configured by `[learner.low.deterministic]`.
    Deterministic,
}

/// `[learner.low]`: the low-level learner (SPEC §6.2, §5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LowLearnerConfig {
    /// Algorithm: `"sac"` (default, paper) or `"deterministic"` (code).
    pub algo: LowAlgo,
    /// Discount per env step. Default 0.99. Source: paper and code.
    pub gamma: f64,
    /// SAC: Polyak rate of the target critics. Default 0.005. Source: paper (SAC default).
    pub tau: f64,
    /// SAC: Adam learning rate. Default 3e-4. Source: ours (matches the high level).
    pub lr: f64,
    /// Minibatch size (both algorithms). Default 128. Source: code.
    pub batch_size: usize,
    /// SAC: entropy temperature α (initial value when `auto_alpha`). Default 0.2. Source: ours.
    pub alpha: f64,
    /// SAC: tune α towards the target entropy −dim(action). Default true. Source: ours
    /// (CleanRL's SAC default; SPEC §6.2 fixes α = 0.2, but on the Ant a fixed 0.2 lets the
    /// entropy bonus, about 5 per step, swamp the reward −0.1·‖φ(s') − sg‖ (about −0.75): the
    /// low level stays near-uniform and learns no reaching — docs/RESULTS.md, AntMaze-U).
    pub auto_alpha: bool,
    /// SAC: feed the critics the action divided by the env's action bound (in [−1, 1]) instead
    /// of the raw torque, as the reference code's low critic does (`action / 16`), and take the
    /// `auto_alpha` target entropy −dim(action) in those normalised units. Default true.
    /// Source: ours (digest §3.2 for the reference's critic input): with raw ±16 N·m torques
    /// the Ant's low critics diverged (Q rose to +1,500 under rewards ≤ 0; docs/RESULTS.md).
    /// No effect where the bound is 1 (PointMaze, the cheetah).
    pub critic_normalized_action: bool,
    /// SAC: hidden layer widths of policy and critics. Default [256, 256]. Source: supplement.
    pub hidden: Vec<usize>,
    /// Gradient updates per training episode, used to derive the per-step ratio when
    /// `updates_per_env_step` is absent. Default 200. Source: code (`n_batches`).
    pub updates_per_episode: u32,
    /// Explicit updates per env step; absent = `updates_per_episode / episode length`
    /// (0.4 for U, 0.2 otherwise). See [`LowLearnerConfig::updates_per_env_step_for`].
    /// Source: SPEC §6.2.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub updates_per_env_step: Option<f64>,
    /// Settings used when `algo = "deterministic"`.
    pub deterministic: DeterministicLowConfig,
}

impl Default for LowLearnerConfig {
    fn default() -> Self {
        Self {
            algo: LowAlgo::Sac,
            gamma: 0.99,
            tau: 0.005,
            lr: 3e-4,
            batch_size: 128,
            alpha: 0.2,
            auto_alpha: true,
            critic_normalized_action: true,
            hidden: vec![256, 256],
            updates_per_episode: 200,
            updates_per_env_step: None,
            deterministic: DeterministicLowConfig::default(),
        }
    }
}

impl LowLearnerConfig {
    /// Low-level updates per env step for an episode of `episode_length` steps: the explicit
    /// value if set, else `updates_per_episode / episode_length`.
    pub fn updates_per_env_step_for(&self, episode_length: u32) -> f64 {
        self.updates_per_env_step.unwrap_or_else(|| {
            f64::from(self.updates_per_episode) / f64::from(episode_length.max(1))
        })
    }

    fn check(&self, c: &mut Checker) {
        check_sac_common(
            c,
            "learner.low",
            self.gamma,
            self.tau,
            self.lr,
            self.batch_size,
            self.alpha,
        );
        c.layer_sizes("learner.low.hidden", &self.hidden);
        c.at_least_one(
            "learner.low.updates_per_episode",
            u64::from(self.updates_per_episode),
        );
        if let Some(ratio) = self.updates_per_env_step {
            c.positive("learner.low.updates_per_env_step", ratio);
        }
        self.deterministic.check(c);
    }
}

/// `[learner.low.deterministic]`: the reference code's low level (digest §3.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeterministicLowConfig {
    /// Actor hidden widths. Default [400, 400, 400, 400]. Source: code.
    pub actor_hidden: Vec<usize>,
    /// Critic hidden widths (γ-distance Q head). Default [400; 5]. Source: code.
    pub critic_hidden: Vec<usize>,
    /// Adam learning rate of actor and critic. Default 2e-4. Source: code and supplement.
    pub lr: f64,
    /// Multiply both learning rates by `lr_decay_factor` every this many episodes.
    /// Default 3000. Unit: episodes. Source: code (`lr_decay_actor`).
    pub lr_decay_episodes: u64,
    /// Learning-rate decay factor. Default 0.5. Source: code.
    pub lr_decay_factor: f64,
    /// Critic Adam weight decay. Default 1e-5. Source: code.
    pub critic_weight_decay: f64,
    /// Gaussian exploration noise std as a fraction of the action bound. Default 0.2.
    /// Source: code.
    pub noise_scale: f64,
    /// Probability of replacing the action by a uniform random one. Default 0.2. Source: code.
    pub random_eps: f64,
    /// Target update `target ← polyak·target + (1 − polyak)·online`. Default 0.99.
    /// Source: code.
    pub polyak: f64,
    /// Apply the target update every this many gradient steps. Default 3. Source: code.
    pub target_update_period: u32,
    /// Gradient-norm clip for actor and critic. Default 1.0. Source: code.
    pub grad_clip: f64,
}

impl Default for DeterministicLowConfig {
    fn default() -> Self {
        Self {
            actor_hidden: vec![400; 4],
            critic_hidden: vec![400; 5],
            lr: 2e-4,
            lr_decay_episodes: 3000,
            lr_decay_factor: 0.5,
            critic_weight_decay: 1e-5,
            noise_scale: 0.2,
            random_eps: 0.2,
            polyak: 0.99,
            target_update_period: 3,
            grad_clip: 1.0,
        }
    }
}

impl DeterministicLowConfig {
    fn check(&self, c: &mut Checker) {
        let p = "learner.low.deterministic";
        c.layer_sizes(&format!("{p}.actor_hidden"), &self.actor_hidden);
        c.layer_sizes(&format!("{p}.critic_hidden"), &self.critic_hidden);
        c.positive(&format!("{p}.lr"), self.lr);
        c.at_least_one(&format!("{p}.lr_decay_episodes"), self.lr_decay_episodes);
        c.fraction(&format!("{p}.lr_decay_factor"), self.lr_decay_factor);
        c.non_negative(
            &format!("{p}.critic_weight_decay"),
            self.critic_weight_decay,
        );
        c.non_negative(&format!("{p}.noise_scale"), self.noise_scale);
        c.closed_interval(&format!("{p}.random_eps"), self.random_eps, 0.0, 1.0);
        c.closed_interval(&format!("{p}.polyak"), self.polyak, 0.0, 1.0);
        c.at_least_one(
            &format!("{p}.target_update_period"),
            u64::from(self.target_update_period),
        );
        c.positive(&format!("{p}.grad_clip"), self.grad_clip);
    }
}

/// Checks the fields SAC shares at both levels under `prefix`.
fn check_sac_common(
    c: &mut Checker,
    prefix: &str,
    gamma: f64,
    tau: f64,
    lr: f64,
    batch: usize,
    alpha: f64,
) {
    c.open_interval(&format!("{prefix}.gamma"), gamma, 0.0, 1.0);
    c.fraction(&format!("{prefix}.tau"), tau);
    c.positive(&format!("{prefix}.lr"), lr);
    c.at_least_one(&format!("{prefix}.batch_size"), batch as u64);
    c.non_negative(&format!("{prefix}.alpha"), alpha);
}
