//! Building the learner's networks from the run config: the actor-side [`PolicySet`] (the
//! parameters that are published), the online critics and their targets, and one
//! [`SacLevel`] per level.
//!
//! Three `VarMap`s with disjoint roles: `policy` (encoder, high policy, low policy — names and
//! layout hash identical to every actor's), `critic` (high and low twin critics), `target`
//! (the same critic names, Polyak-averaged copies). Initial values come from
//! [`nets::seeded_var_builder`], so a run is reproducible from its seed.

use candle_core::Device;
use candle_nn::VarMap;
use nets::weights::vars_under;
use nets::{
    prefix, seeded_var_builder, GaussianPolicy, LowCritic, LowPolicy, NetsSpec, PolicySet,
    TwinCritic,
};
use protocol::Config;

use crate::error::LearnerError;
use crate::sac::{SacLevel, SacNets, SacParams};

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
    /// Low-level SAC.
    pub low: SacLevel,
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
    let (high_target, low_target) =
        critics(spec, &target_vm, seed.wrapping_add(TARGET_SEED_OFFSET))?;
    let LowPolicy::Gaussian(low_policy) = policies.low.clone() else {
        return Err(deterministic_unsupported());
    };
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
    let low_nets = maps.level(
        low_policy,
        prefix::LOW_POLICY,
        low_critic,
        low_target,
        prefix::LOW_CRITIC,
    );
    let high = SacLevel::new("high", high_nets, high_params(config, spec))?;
    let low = SacLevel::new("low", low_nets, low_params(config, spec))?;
    Ok(Networks {
        policy_vm,
        critic_vm,
        target_vm,
        policies,
        high,
        low,
    })
}

/// The error for `learner.low.algo = "deterministic"`.
pub fn deterministic_unsupported() -> LearnerError {
    LearnerError::Unsupported {
        key: "learner.low.algo",
        reason:
            "the deterministic low-level variant is not trained by this learner yet; use \"sac\""
                .to_owned(),
    }
}

/// High and low twin critics on `vm`.
fn critics(
    spec: &NetsSpec,
    vm: &VarMap,
    seed: u64,
) -> Result<(TwinCritic, TwinCritic), LearnerError> {
    let vb = seeded_var_builder(vm, seed, &Device::Cpu);
    let high = spec.high_critic(&vb.pp(prefix::HIGH_CRITIC))?;
    match spec.low_critic(&vb.pp(prefix::LOW_CRITIC))? {
        LowCritic::Twin(low) => Ok((high, low)),
        LowCritic::Distance(_) => Err(deterministic_unsupported()),
    }
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
}

/// `[learner.high]` as SAC parameters; H̄ = −dim(delta).
fn high_params(config: &Config, spec: &NetsSpec) -> SacParams {
    let c = &config.learner.high;
    SacParams {
        gamma: c.gamma,
        tau: c.tau,
        lr: c.lr,
        alpha: c.alpha,
        auto_alpha: c.auto_alpha,
        target_entropy: -(spec.latent_dim as f64),
    }
}

/// `[learner.low]` as SAC parameters; H̄ = −dim(action).
fn low_params(config: &Config, spec: &NetsSpec) -> SacParams {
    let c = &config.learner.low;
    SacParams {
        gamma: c.gamma,
        tau: c.tau,
        lr: c.lr,
        alpha: c.alpha,
        auto_alpha: c.auto_alpha,
        target_entropy: -(spec.action_dim as f64),
    }
}
