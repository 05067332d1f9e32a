//! Building the learner's networks from the run config: the actor-side [`PolicySet`] (the
//! parameters that are published), the online critics and their targets, a [`SacLevel`] for
//! the high level and a [`LowLevel`] (SAC, or the reference code's deterministic level).
//!
//! Three `VarMap`s with disjoint roles: `policy` (encoder, high policy, low policy — names and
//! layout hash identical to every actor's), `critic` (high and low critics), `target` (the same
//! critic names, Polyak-averaged copies; with the deterministic low level also the target
//! actor under the `low_policy` names). Initial values come from [`nets::seeded_var_builder`],
//! so a run is reproducible from its seed.

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use nets::weights::vars_under;
use nets::{
    prefix, seeded_var_builder, DeterministicActor, DistanceCritic, GaussianPolicy, LowCritic,
    LowPolicy, NetsSpec, PolicySet, TaskDims, TwinCritic,
};
use protocol::Config;

use crate::adam::Adam;
use crate::deterministic::{DeterministicLevel, DeterministicNets, DeterministicParams};
use crate::error::LearnerError;
use crate::sac::{SacLevel, SacNets, SacParams, TargetClip};

/// Offset of the critic init seed from the run seed (ours; any constant ≠ 0 keeps the policy
/// and critic init streams apart).
const CRITIC_SEED_OFFSET: u64 = 0x0c21_71c5;
/// Offset of the target init seed (its values are overwritten by a copy of the online critic).
const TARGET_SEED_OFFSET: u64 = 0x7a26_e75e;

/// Everything [`crate::Learner`] trains.
pub struct Networks {
    /// The published parameters: `encoder.*`, `high_policy.*`, `low_policy.*`.
    pub policy_vm: VarMap,
    /// Online critics (kept for checkpoints).
    pub critic_vm: VarMap,
    /// Target critics (kept for checkpoints).
    pub target_vm: VarMap,
    /// The actor-side modules over `policy_vm` (φ is used by the encoder trainer).
    pub policies: PolicySet,
    /// High-level SAC.
    pub high: SacLevel,
    /// The low level (`learner.low.algo`).
    pub low: LowLevel,
}

/// The low level of either algorithm. One value per learner, never moved in a hot path, so
/// the size difference of the variants is harmless.
#[derive(Debug)]
#[allow(clippy::large_enum_variant)]
pub enum LowLevel {
    /// SAC, as the high level.
    Sac(SacLevel),
    /// The reference code's deterministic actor-critic.
    Deterministic(DeterministicLevel),
}

impl LowLevel {
    /// One Adam step of the policy's optimiser on an extra policy loss (self-imitation);
    /// returns the global L2 norm of its gradient over the low policy's variables.
    pub fn policy_step(
        &mut self,
        loss: &Tensor,
        what: &'static str,
        value: f64,
    ) -> Result<f64, LearnerError> {
        match self {
            Self::Sac(level) => level.policy_step(loss, what, value),
            Self::Deterministic(level) => level.policy_step(loss, what, value),
        }
    }

    /// The optimisers by name and log α when tuned (checkpoints).
    pub(crate) fn optimizers(&self) -> (Vec<(&'static str, &Adam)>, Option<&candle_core::Var>) {
        match self {
            Self::Sac(level) => level.optimizers(),
            Self::Deterministic(level) => (level.optimizers(), None),
        }
    }

    /// As [`LowLevel::optimizers`], mutable (checkpoints).
    pub(crate) fn optimizers_mut(
        &mut self,
    ) -> (Vec<(&'static str, &mut Adam)>, Option<&candle_core::Var>) {
        match self {
            Self::Sac(level) => level.optimizers_mut(),
            Self::Deterministic(level) => (level.optimizers_mut(), None),
        }
    }
}

/// The sizes the networks are built for, from a task's spec: its observation, goal and action
/// dimensions, and its largest action bound as the low level's symmetric action scale.
pub fn task_dims(spec: &envs::EnvSpec) -> TaskDims {
    TaskDims {
        obs_dim: spec.obs_dim,
        goal_dim: spec.goal_dim,
        action_dim: spec.action_dim,
        action_scale: f64::from(spec.action_high.iter().copied().fold(0.0f32, f32::max)),
    }
}

/// Builds every network of `spec` and both SAC levels.
pub fn build_networks(
    config: &Config,
    spec: &NetsSpec,
    seed: u64,
) -> Result<Networks, LearnerError> {
    let device = Device::Cpu;
    let policy_vm = VarMap::new();
    let policies = PolicySet::new(spec, &seeded_var_builder(&policy_vm, seed, &device))?;
    let critic_vm = VarMap::new();
    let (high_critic, low_critic) =
        critics(spec, &critic_vm, seed.wrapping_add(CRITIC_SEED_OFFSET))?;
    let target_vm = VarMap::new();
    let target_seed = seed.wrapping_add(TARGET_SEED_OFFSET);
    let (high_target, low_target) = critics(spec, &target_vm, target_seed)?;
    let maps = Maps {
        policy: &policy_vm,
        critic: &critic_vm,
        target: &target_vm,
    };
    let high_nets = maps.level(
        policies.high.clone(),
        prefix::HIGH_POLICY,
        high_critic,
        high_target,
        prefix::HIGH_CRITIC,
    );
    let high = SacLevel::new("high", high_nets, high_params(config, spec)?)?;
    let low = match (policies.low.clone(), low_critic, low_target) {
        (LowPolicy::Gaussian(policy), LowCritic::Twin(critic), LowCritic::Twin(target)) => {
            let nets = maps.level(
                policy,
                prefix::LOW_POLICY,
                critic,
                target,
                prefix::LOW_CRITIC,
            );
            LowLevel::Sac(SacLevel::new("low", nets, low_params(config, spec))?)
        }
        (
            LowPolicy::Deterministic(actor),
            LowCritic::Distance(critic),
            LowCritic::Distance(critic_target),
        ) => {
            let actor_target = target_actor(spec, &target_vm, target_seed)?;
            let nets = maps.deterministic(actor, actor_target, critic, critic_target);
            LowLevel::Deterministic(DeterministicLevel::new(nets, deterministic_params(config))?)
        }
        _ => {
            return Err(LearnerError::Nets(nets::NetsError::Spec(
                "low level: policy and critics of different variants".to_owned(),
            )))
        }
    };
    Ok(Networks {
        policy_vm,
        critic_vm,
        target_vm,
        policies,
        high,
        low,
    })
}

/// The target actor of the deterministic low level, under `low_policy` on the target map.
fn target_actor(
    spec: &NetsSpec,
    vm: &VarMap,
    seed: u64,
) -> Result<DeterministicActor, LearnerError> {
    let vb = seeded_var_builder(vm, seed, &Device::Cpu);
    Ok(DeterministicActor::new(
        &vb.pp(prefix::LOW_POLICY),
        spec.low_policy_in(),
        &spec.low_hidden,
        spec.action_dim,
        spec.low_action_scale,
        spec.low_init(),
    )?)
}

/// The high twin critic and the low critic of the configured variant on `vm`.
fn critics(
    spec: &NetsSpec,
    vm: &VarMap,
    seed: u64,
) -> Result<(TwinCritic, LowCritic), LearnerError> {
    let vb = seeded_var_builder(vm, seed, &Device::Cpu);
    let high = spec.high_critic(&vb.pp(prefix::HIGH_CRITIC))?;
    Ok((high, spec.low_critic(&vb.pp(prefix::LOW_CRITIC))?))
}

/// The three maps, to collect one level's parameters.
struct Maps<'a> {
    policy: &'a VarMap,
    critic: &'a VarMap,
    target: &'a VarMap,
}

impl Maps<'_> {
    fn level(
        &self,
        policy: GaussianPolicy,
        policy_prefix: &str,
        critic: TwinCritic,
        target: TwinCritic,
        critic_prefix: &str,
    ) -> SacNets {
        SacNets {
            policy,
            policy_vars: vars_under(self.policy, policy_prefix),
            critic,
            critic_vars: vars_under(self.critic, critic_prefix),
            target,
            target_vars: vars_under(self.target, critic_prefix),
        }
    }

    /// The deterministic low level's networks: the actor on `policy`, its target under the same
    /// names on `target`, the critic on `critic` and its target on `target`.
    fn deterministic(
        &self,
        actor: DeterministicActor,
        actor_target: DeterministicActor,
        critic: DistanceCritic,
        critic_target: DistanceCritic,
    ) -> DeterministicNets {
        DeterministicNets {
            actor,
            actor_vars: vars_under(self.policy, prefix::LOW_POLICY),
            actor_target,
            actor_target_vars: vars_under(self.target, prefix::LOW_POLICY),
            critic,
            critic_vars: vars_under(self.critic, prefix::LOW_CRITIC),
            critic_target,
            critic_target_vars: vars_under(self.target, prefix::LOW_CRITIC),
        }
    }
}

/// `[learner.high]` as SAC parameters; H̄ = −dim(delta).
fn high_params(config: &Config, spec: &NetsSpec) -> Result<SacParams, LearnerError> {
    let c = &config.learner.high;
    Ok(SacParams {
        gamma: c.gamma,
        tau: c.tau,
        lr: c.lr,
        alpha: c.alpha,
        auto_alpha: c.auto_alpha,
        target_entropy: -(spec.latent_dim as f64),
        critic_action_scale: 1.0,
        target_clip: high_target_clip(config)?,
    })
}

/// `learner.high.clip_target`: y ∈ [−T · p, 0] with T the episode length in env steps and p
/// the per-step penalty of `env.task` as the registry builds it (the reference's [−T, 0];
/// the Ant's fall penalty is left out, as there). `None` when the switch is off; an unknown
/// task is an error naming the switch.
pub fn high_target_clip(config: &Config) -> Result<Option<TargetClip>, LearnerError> {
    if !config.learner.high.clip_target {
        return Ok(None);
    }
    let options = envs::EnvOptions {
        max_steps: config.env.episode_length,
    };
    let reward = envs::sparse_reward(&config.env.task, options).map_err(|err| {
        LearnerError::Unsupported {
            key: "learner.high.clip_target",
            reason: format!("the bound −T·(step penalty) needs a registered env.task: {err}"),
        }
    })?;
    Ok(Some(TargetClip {
        low: -f64::from(reward.max_steps) * f64::from(reward.step_penalty),
        high: 0.0,
    }))
}

/// `[learner.low]` as SAC parameters; H̄ = −dim(action), in the units of the normalised action
/// `a / bound` when `critic_normalized_action` (log π carries the `ln bound` Jacobian per
/// dimension, so H̄ = −dim + dim · ln bound in env units, CleanRL's target for a [−1, 1] action).
fn low_params(config: &Config, spec: &NetsSpec) -> SacParams {
    let c = &config.learner.low;
    let dim = spec.action_dim as f64;
    let (target_entropy, critic_action_scale) = if c.critic_normalized_action {
        (
            -dim + dim * spec.low_action_scale.ln(),
            spec.low_action_scale,
        )
    } else {
        (-dim, 1.0)
    };
    SacParams {
        gamma: c.gamma,
        tau: c.tau,
        lr: c.lr,
        alpha: c.alpha,
        auto_alpha: c.auto_alpha,
        target_entropy,
        critic_action_scale,
        target_clip: None,
    }
}

/// `[learner.low]` and `[learner.low.deterministic]` as the deterministic level's parameters.
fn deterministic_params(config: &Config) -> DeterministicParams {
    let c = &config.learner.low;
    let d = &c.deterministic;
    DeterministicParams {
        gamma: c.gamma,
        lr: d.lr,
        lr_decay_episodes: d.lr_decay_episodes,
        lr_decay_factor: d.lr_decay_factor,
        critic_weight_decay: d.critic_weight_decay,
        polyak: d.polyak,
        target_update_period: u64::from(d.target_update_period),
        grad_clip: d.grad_clip,
        reach_threshold: config.hierarchy.low_reach_threshold,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_normalised_low_critic_takes_the_bound_and_the_normalised_entropy_target() {
        let mut config = Config::default();
        assert!(config.learner.low.critic_normalized_action, "the default");
        config.learner.low.critic_normalized_action = false;
        let spec = NetsSpec::default();
        let plain = low_params(&config, &spec);
        assert_eq!(plain.critic_action_scale, 1.0);
        assert_eq!(plain.target_entropy, -(spec.action_dim as f64));
        config.learner.low.critic_normalized_action = true;
        let normalised = low_params(&config, &spec);
        let (dim, bound) = (spec.action_dim as f64, spec.low_action_scale);
        assert_eq!(normalised.critic_action_scale, bound);
        assert!((normalised.target_entropy - (-dim + dim * bound.ln())).abs() < 1e-12);
        assert_eq!(
            high_params(&config, &spec).unwrap().critic_action_scale,
            1.0
        );
    }

    #[test]
    fn the_high_target_clamp_is_minus_the_episode_length_times_the_step_penalty_up_to_zero() {
        let mut config = Config::default();
        assert_eq!(high_target_clip(&config).unwrap(), None, "off by default");
        config.learner.high.clip_target = true;
        let low_of = |config: &Config| high_target_clip(config).unwrap().map(|c| (c.low, c.high));
        for (task, low) in [
            ("antmaze-u", -500.0),
            ("antmaze-s", -1000.0),
            ("ant-fourrooms-test", -1000.0),
            ("pointmaze-u", -500.0),
            ("halfcheetah-hurdle", -1000.0),
        ] {
            config.env.task = task.to_owned();
            assert_eq!(low_of(&config), Some((low, 0.0)), "{task}");
        }
        config.env.episode_length = Some(60);
        assert_eq!(
            low_of(&config),
            Some((-60.0, 0.0)),
            "env.episode_length wins"
        );
        config.env.task = "no-such-task".to_owned();
        let err = high_target_clip(&config).unwrap_err().to_string();
        assert!(
            err.contains("learner.high.clip_target") && err.contains("no-such-task"),
            "{err}"
        );
        let spec = NetsSpec::default();
        config.env.task = "antmaze-u".to_owned();
        let clip = high_params(&config, &spec).unwrap().target_clip;
        assert_eq!(clip.map(|c| c.low), Some(-60.0), "the high level gets it");
        assert_eq!(
            low_params(&config, &spec).target_clip,
            None,
            "the low level never"
        );
    }
}
