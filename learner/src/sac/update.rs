//! One SAC gradient update for one level, in CleanRL's order: the target under no-grad, the
//! twin critic step, the actor step (against the just-updated critic), the temperature step
//! (when tuned), then Polyak averaging of the target critic.
//!
//! Networks: the policy is the learner's copy of the actor-side [`GaussianPolicy`] (its
//! parameters are the ones published), the online and target critics are [`TwinCritic`]s on
//! two separate `VarMap`s with identical names; the target starts as a copy of the online
//! critic and follows it by `target ← τ·online + (1 − τ)·target` after every update.
//! Optimisers: PyTorch's Adam ([`crate::adam::Adam`], state exportable for checkpoints).
//!
//! Inputs come as a [`SacBatch`]: the policy sees `[head, tail]`, the critic
//! `[head, action, tail]` (low: head `[obs, φ]`, tail `subgoal`; high: head `[obs, goal]`, no
//! tail). Policy noise is passed in (`eps`, standard normal) so the learner owns all randomness.

use candle_core::{Tensor, Var};
use candle_nn::Optimizer;

use crate::adam::{Adam, AdamParams};
use nets::{GaussianPolicy, TwinCritic};

use crate::error::LearnerError;
use crate::sac::losses::{
    actor_loss, clip_target, soft_target, temperature_loss, twin_critic_loss, ActorStats,
    CriticStats, TargetClip,
};
use crate::sac::networks::SacNets;

/// Hyper-parameters of one level (from `[learner.high]` / `[learner.low]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SacParams {
    /// Discount γ.
    pub gamma: f64,
    /// Polyak rate τ.
    pub tau: f64,
    /// Adam learning rate (policy, critics, temperature).
    pub lr: f64,
    /// α (initial value when tuned).
    pub alpha: f64,
    /// Tune α towards `target_entropy`.
    pub auto_alpha: bool,
    /// H̄ = −dim(action) (SAC v2 heuristic).
    pub target_entropy: f64,
    /// The critics see `action / critic_action_scale` (1 = the raw action).
    pub critic_action_scale: f64,
    /// Clamp y to these bounds (`learner.high.clip_target`); `None` leaves it unbounded.
    pub target_clip: Option<TargetClip>,
}

impl SacParams {
    /// SPEC §6.2 for an action of `action_dim`: γ 0.99, τ 0.005, lr 3e-4, α 0.2 fixed,
    /// H̄ = −`action_dim`, critics on the raw action, y unbounded. The learner itself reads
    /// these from the config; this is for a level built on its own (benchmarks, examples).
    pub fn spec_defaults(action_dim: usize) -> Self {
        Self {
            gamma: 0.99,
            tau: 0.005,
            lr: 3e-4,
            alpha: 0.2,
            auto_alpha: false,
            target_entropy: -(action_dim as f64),
            critic_action_scale: 1.0,
            target_clip: None,
        }
    }
}

/// One minibatch as tensors. Shapes: `head, next_head: [B, h]`, `tail: [B, t]` (shared by s and
/// s'), `action: [B, a]`, `reward, terminal: [B, 1]`.
#[derive(Debug, Clone)]
pub struct SacBatch {
    /// State features before the action in the critic input.
    pub head: Tensor,
    /// The same for s'.
    pub next_head: Tensor,
    /// State features after the action (the low level's subgoal); `None` for the high level.
    pub tail: Option<Tensor>,
    /// Stored action.
    pub action: Tensor,
    /// Reward r.
    pub reward: Tensor,
    /// d: 1 where bootstrapping stops.
    pub terminal: Tensor,
}

impl SacBatch {
    /// Policy input `[head, tail]`.
    fn policy_input(&self, head: &Tensor) -> Result<Tensor, LearnerError> {
        Ok(match &self.tail {
            Some(tail) => Tensor::cat(&[head, tail], 1)?,
            None => head.clone(),
        })
    }

    /// Critic input `[head, action / action_scale, tail]`.
    fn critic_input(
        &self,
        head: &Tensor,
        action: &Tensor,
        action_scale: f64,
    ) -> Result<Tensor, LearnerError> {
        let scaled;
        let action = if action_scale == 1.0 {
            action
        } else {
            scaled = action.affine(1.0 / action_scale, 0.0)?;
            &scaled
        };
        Ok(match &self.tail {
            Some(tail) => Tensor::cat(&[head, action, tail], 1)?,
            None => Tensor::cat(&[head, action], 1)?,
        })
    }
}

/// What one update measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SacStats {
    /// Critic loss and Q statistics.
    pub critic: CriticStats,
    /// Actor loss and entropy estimate.
    pub actor: ActorStats,
    /// α used in this update.
    pub alpha: f64,
    /// L_α (0 when α is fixed).
    pub alpha_loss: f64,
    /// ‖∇L_π‖₂: global L2 norm of the actor loss gradient over this level's policy variables,
    /// as the policy's Adam step saw it (absent, 0, in checkpoints of older builds).
    #[serde(default)]
    pub actor_grad_norm: f64,
}

/// α, fixed or tuned.
#[derive(Debug)]
enum Temperature {
    Fixed(f64),
    Tuned {
        log_alpha: Var,
        opt: Adam,
        target_entropy: f64,
    },
}

impl Temperature {
    fn new(params: &SacParams) -> Result<Self, LearnerError> {
        if !params.auto_alpha {
            return Ok(Self::Fixed(params.alpha));
        }
        let init = params.alpha.max(f64::MIN_POSITIVE).ln() as f32;
        let log_alpha = Var::from_slice(&[init], 1, &candle_core::Device::Cpu)?;
        let opt = adam(vec![log_alpha.clone()], params.lr)?;
        Ok(Self::Tuned {
            log_alpha,
            opt,
            target_entropy: params.target_entropy,
        })
    }

    fn alpha(&self) -> Result<f64, LearnerError> {
        Ok(match self {
            Self::Fixed(alpha) => *alpha,
            Self::Tuned { log_alpha, .. } => {
                f64::from(log_alpha.as_tensor().exp()?.sum_all()?.to_scalar::<f32>()?)
            }
        })
    }

    /// One step of L_α; returns the loss (0 when fixed).
    fn step(&mut self, log_prob: &Tensor) -> Result<f64, LearnerError> {
        match self {
            Self::Fixed(_) => Ok(0.0),
            Self::Tuned {
                log_alpha,
                opt,
                target_entropy,
            } => {
                let loss = temperature_loss(log_alpha.as_tensor(), log_prob, *target_entropy)?;
                opt.backward_step(&loss)?;
                Ok(f64::from(loss.to_scalar::<f32>()?))
            }
        }
    }
}

/// Adam with PyTorch's defaults at learning rate `lr`.
fn adam(vars: Vec<Var>, lr: f64) -> Result<Adam, LearnerError> {
    Ok(Adam::new(vars, AdamParams::with_lr(lr))?)
}

/// SAC state of one level: networks, optimisers, temperature.
#[derive(Debug)]
pub struct SacLevel {
    level: &'static str,
    nets: SacNets,
    policy_opt: Adam,
    critic_opt: Adam,
    temperature: Temperature,
    params: SacParams,
}

impl SacLevel {
    /// A level; copies the online critic into the target.
    pub fn new(
        level: &'static str,
        nets: SacNets,
        params: SacParams,
    ) -> Result<Self, LearnerError> {
        check_pairs(level, &nets.critic_vars, &nets.target_vars)?;
        for (target, online) in nets.target_vars.iter().zip(&nets.critic_vars) {
            target.set(online.as_tensor())?;
        }
        let policy_opt = adam(nets.policy_vars.clone(), params.lr)?;
        let critic_opt = adam(nets.critic_vars.clone(), params.lr)?;
        let temperature = Temperature::new(&params)?;
        Ok(Self {
            level,
            nets,
            policy_opt,
            critic_opt,
            temperature,
            params,
        })
    }

    /// The optimisers by name — `policy`, `critic`, and `alpha` when α is tuned — and log α
    /// (checkpoints).
    pub(crate) fn optimizers(&self) -> (Vec<(&'static str, &Adam)>, Option<&Var>) {
        let mut opts = vec![("policy", &self.policy_opt), ("critic", &self.critic_opt)];
        let log_alpha = match &self.temperature {
            Temperature::Fixed(_) => None,
            Temperature::Tuned { log_alpha, opt, .. } => {
                opts.push(("alpha", opt));
                Some(log_alpha)
            }
        };
        (opts, log_alpha)
    }

    /// As [`SacLevel::optimizers`], mutable (checkpoints).
    pub(crate) fn optimizers_mut(&mut self) -> (Vec<(&'static str, &mut Adam)>, Option<&Var>) {
        let mut opts = vec![
            ("policy", &mut self.policy_opt),
            ("critic", &mut self.critic_opt),
        ];
        let log_alpha = match &mut self.temperature {
            Temperature::Fixed(_) => None,
            Temperature::Tuned { log_alpha, opt, .. } => {
                opts.push(("alpha", opt));
                Some(&*log_alpha)
            }
        };
        (opts, log_alpha)
    }

    /// One update on `batch`; `next_eps` and `eps` are standard-normal noise `[B, action_dim]`
    /// for a' ~ π(·|s') and ã ~ π(·|s). Nothing is stepped if a loss is non-finite.
    pub fn update(
        &mut self,
        batch: &SacBatch,
        next_eps: &Tensor,
        eps: &Tensor,
    ) -> Result<SacStats, LearnerError> {
        let alpha = self.temperature.alpha()?;
        let target = self.target(batch, next_eps, alpha)?;
        let critic = self.critic_step(batch, &target)?;
        let (actor, actor_grad_norm, log_prob) = self.actor_step(batch, eps, alpha)?;
        let alpha_loss = self.temperature.step(&log_prob)?;
        self.polyak()?;
        Ok(SacStats {
            critic,
            actor,
            alpha,
            alpha_loss,
            actor_grad_norm,
        })
    }

    /// y as the next [`SacLevel::update`] on `batch` with `next_eps` builds it (target critics
    /// and α as they are now, clamped when `target_clip` is set); `[B, 1]`, detached.
    pub fn critic_target(
        &self,
        batch: &SacBatch,
        next_eps: &Tensor,
    ) -> Result<Tensor, LearnerError> {
        self.target(batch, next_eps, self.temperature.alpha()?)
    }

    /// y under no-grad, clamped to `target_clip` when set.
    fn target(
        &self,
        batch: &SacBatch,
        next_eps: &Tensor,
        alpha: f64,
    ) -> Result<Tensor, LearnerError> {
        let next_in = batch.policy_input(&batch.next_head)?;
        let (next_action, next_log_prob) = self.nets.policy.sample(&next_in, next_eps)?;
        let next_q_in = batch.critic_input(
            &batch.next_head,
            &next_action.detach(),
            self.params.critic_action_scale,
        )?;
        let next_min_q = self.nets.target.min_q(&next_q_in)?;
        let target = soft_target(
            &batch.reward,
            &batch.terminal,
            &next_min_q,
            &next_log_prob,
            self.params.gamma,
            alpha,
        )?;
        clip_target(&target, self.params.target_clip)
    }

    /// One Adam step on L_Q.
    fn critic_step(
        &mut self,
        batch: &SacBatch,
        target: &Tensor,
    ) -> Result<CriticStats, LearnerError> {
        let q = self.nets.critic.forward(&batch.critic_input(
            &batch.head,
            &batch.action,
            self.params.critic_action_scale,
        )?)?;
        let (loss, stats) = twin_critic_loss(&q, target)?;
        self.check_finite("critic loss", stats.loss)?;
        self.critic_opt.backward_step(&loss)?;
        Ok(stats)
    }

    /// One Adam step on L_π against the updated critic; returns the gradient's norm over the
    /// policy variables and log π(ã|s) for the temperature.
    fn actor_step(
        &mut self,
        batch: &SacBatch,
        eps: &Tensor,
        alpha: f64,
    ) -> Result<(ActorStats, f64, Tensor), LearnerError> {
        let (action, log_prob) = self
            .nets
            .policy
            .sample(&batch.policy_input(&batch.head)?, eps)?;
        let min_q = self.nets.critic.min_q(&batch.critic_input(
            &batch.head,
            &action,
            self.params.critic_action_scale,
        )?)?;
        let (loss, stats) = actor_loss(&log_prob, &min_q, alpha)?;
        self.check_finite("actor loss", stats.loss)?;
        // The critic's variables get a gradient too; the norm counts only the policy's.
        let grad_norm = self.policy_opt.backward_step_norm(&loss)?;
        Ok((stats, grad_norm, log_prob.detach()))
    }

    /// One Adam step of the policy optimiser on an extra policy loss (self-imitation,
    /// [`crate::si`]); `value` is the loss as a number, checked to be finite before stepping.
    /// Returns the global L2 norm of `loss`'s gradient over the policy variables.
    pub fn policy_step(
        &mut self,
        loss: &Tensor,
        what: &'static str,
        value: f64,
    ) -> Result<f64, LearnerError> {
        self.check_finite(what, value)?;
        Ok(self.policy_opt.backward_step_norm(loss)?)
    }

    /// target ← τ·online + (1 − τ)·target.
    fn polyak(&self) -> Result<(), LearnerError> {
        let tau = self.params.tau;
        for (target, online) in self.nets.target_vars.iter().zip(&self.nets.critic_vars) {
            let mixed = target
                .as_tensor()
                .affine(1.0 - tau, 0.0)?
                .add(&online.as_tensor().affine(tau, 0.0)?)?;
            target.set(&mixed.detach())?;
        }
        Ok(())
    }

    fn check_finite(&self, what: &'static str, value: f64) -> Result<(), LearnerError> {
        if value.is_finite() {
            Ok(())
        } else {
            Err(LearnerError::NonFinite {
                level: self.level,
                what,
                value,
            })
        }
    }

    /// The policy.
    pub fn policy(&self) -> &GaussianPolicy {
        &self.nets.policy
    }

    /// The online critic.
    pub fn critic(&self) -> &TwinCritic {
        &self.nets.critic
    }

    /// The target critic.
    pub fn target_critic(&self) -> &TwinCritic {
        &self.nets.target
    }

    /// Current α.
    pub fn alpha(&self) -> Result<f64, LearnerError> {
        self.temperature.alpha()
    }
}

/// Online and target parameter lists must pair up one to one with equal shapes.
fn check_pairs(level: &'static str, online: &[Var], target: &[Var]) -> Result<(), LearnerError> {
    let same = online.len() == target.len()
        && online.iter().zip(target).all(|(a, b)| a.dims() == b.dims());
    if same {
        Ok(())
    } else {
        let reason = format!("{level} level: the target critic does not mirror the online critic");
        Err(LearnerError::Nets(nets::NetsError::Spec(reason)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn the_critic_sees_the_action_divided_by_its_scale() {
        let dev = Device::Cpu;
        let t = |v: &[f32], cols: usize| Tensor::from_slice(v, (v.len() / cols, cols), &dev);
        let batch = SacBatch {
            head: t(&[1., 2.], 2).unwrap(),
            next_head: t(&[3., 4.], 2).unwrap(),
            tail: Some(t(&[5.], 1).unwrap()),
            action: t(&[8., -16.], 2).unwrap(),
            reward: t(&[0.], 1).unwrap(),
            terminal: t(&[0.], 1).unwrap(),
        };
        let raw = batch.critic_input(&batch.head, &batch.action, 1.0).unwrap();
        assert_eq!(
            raw.to_vec2::<f32>().unwrap(),
            vec![vec![1., 2., 8., -16., 5.]]
        );
        let scaled = batch
            .critic_input(&batch.head, &batch.action, 16.0)
            .unwrap();
        assert_eq!(
            scaled.to_vec2::<f32>().unwrap(),
            vec![vec![1., 2., 0.5, -1., 5.]]
        );
    }
}
