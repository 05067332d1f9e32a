//! The networks of one SAC level ([`SacNets`]) and a seeded constructor for a level built on its
//! own (benchmarks, examples, tests); the learner proper builds its levels on the shared maps in
//! [`crate::setup`].
//!
//! Invariant: `critic_vars` and `target_vars` hold the same names in the same (sorted) order, so
//! that the target can be copied from and averaged towards the online critic pairwise.

use candle_core::{Device, Var};
use candle_nn::VarMap;
use nets::weights::vars_under;
use nets::{seeded_var_builder, GaussianPolicy, LinearInit, TwinCritic};

use crate::error::LearnerError;

/// The networks of one level handed to [`crate::sac::SacLevel::new`].
#[derive(Debug)]
pub struct SacNets {
    /// The policy (shares its parameters with the published set).
    pub policy: GaussianPolicy,
    /// Its parameters.
    pub policy_vars: Vec<Var>,
    /// Online twin critic.
    pub critic: TwinCritic,
    /// Its parameters, sorted by name.
    pub critic_vars: Vec<Var>,
    /// Target twin critic (same shape).
    pub target: TwinCritic,
    /// Its parameters, sorted by name (same order as `critic_vars`).
    pub target_vars: Vec<Var>,
}

/// The layer shapes of a level built by [`SacNets::seeded`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SacShape<'a> {
    /// Policy input width (`[head, tail]`).
    pub policy_in: usize,
    /// Critic input width (`[head, action, tail]`).
    pub critic_in: usize,
    /// Hidden widths, shared by the policy and both critics.
    pub hidden: &'a [usize],
    /// Action dimension.
    pub action_dim: usize,
    /// The policy's action bound (`scale · tanh`).
    pub action_scale: f64,
    /// Initialisation of every dense layer.
    pub init: LinearInit,
}

impl SacNets {
    /// A level on two fresh maps, on the CPU: the policy under `policy`, then the online critic
    /// under `critic`, drawn in that order from `seed` on the first map; the target critic under
    /// `critic` drawn from `seed + 1` (wrapping) on the second. Returns the maps too (the first
    /// holds the policy and online critic, the second the target).
    ///
    /// The target's own draw is overwritten by [`crate::sac::SacLevel::new`], which starts it as
    /// a copy of the online critic.
    pub fn seeded(shape: &SacShape, seed: u64) -> Result<(SacNets, VarMap, VarMap), LearnerError> {
        let device = Device::Cpu;
        let (vm, tvm) = (VarMap::new(), VarMap::new());
        let vb = seeded_var_builder(&vm, seed, &device);
        let policy = GaussianPolicy::new(
            &vb.pp("policy"),
            shape.policy_in,
            shape.hidden,
            shape.action_dim,
            shape.action_scale,
            shape.init,
        )?;
        let critic = TwinCritic::new(&vb.pp("critic"), shape.critic_in, shape.hidden, shape.init)?;
        let tvb = seeded_var_builder(&tvm, seed.wrapping_add(1), &device);
        let target = TwinCritic::new(&tvb.pp("critic"), shape.critic_in, shape.hidden, shape.init)?;
        let nets = SacNets {
            policy,
            policy_vars: vars_under(&vm, "policy"),
            critic,
            critic_vars: vars_under(&vm, "critic"),
            target,
            target_vars: vars_under(&tvm, "critic"),
        };
        Ok((nets, vm, tvm))
    }
}
