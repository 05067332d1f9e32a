//! One gradient update of the deterministic low level, in the reference code's order (digest
//! §3.2, HESS `_update_network`):
//!
//! 1. Drop the rows already at their subgoal (`‖φ(s) − sg‖ ≤ ε`, the code's `args.distance`).
//! 2. The target `y = min(r + γ · not_done · Q_targ(s', π_targ(s'), sg), 0)` from the *target*
//!    actor and critic, detached.
//! 3. The actor step on `−mean Q(s, π(s), sg)` against the critic as it is before this update
//!    (the code steps the actor first), gradient norm clipped to `grad_clip`.
//! 4. The critic step on `mean (Q(s, a, sg) − y)²`, gradient norm clipped to `grad_clip`; its
//!    Adam carries the code's L2 weight decay.
//! 5. After update `k` (0-based, counted over the run) with `k % target_update_period == 0`,
//!    both targets move: `target ← polyak·target + (1 − polyak)·online`. The code counts `k`
//!    per episode (batches 0, 3, …, 198 of each 200); the learner's updates are not grouped in
//!    episodes, so the count runs over the whole run — the same one in three.
//!
//! `not_done = 1 − terminal` of the low replay ([`crate::replay::LowReplay::fill`]): 0 where
//! `‖φ(s') − sg‖ ≤ ε` (the code's `not_done`) or the env terminated (never, for the mazes).
//! The critic sees the action divided by its bound (`[obs, φ, a / scale, sg]`), as the code does.
//! Learning rates follow the code's step decay: `lr · factor^⌊episodes / decay_episodes⌋`.
//!
//! Clipping is PyTorch's `clip_grad_norm_`: with `n = ‖g‖₂` over all of a network's gradients,
//! every gradient is multiplied by `max / (n + 1e-6)` when that is below 1.

use candle_core::backprop::GradStore;
use candle_core::{DType, Device, Tensor, Var};
use candle_nn::Optimizer;
use nets::{DeterministicActor, DistanceCritic};

use crate::adam::{Adam, AdamParams};
use crate::deterministic::losses::{
    deterministic_actor_loss, distance_critic_loss, distance_target, DistanceCriticStats,
};
use crate::error::LearnerError;
use crate::sac::SacBatch;

/// The `1e-6` PyTorch's `clip_grad_norm_` adds to the norm.
const CLIP_EPS: f64 = 1e-6;

/// Hyper-parameters (from `[learner.low]` and `[learner.low.deterministic]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeterministicParams {
    /// Discount γ (also the distance critic's γ).
    pub gamma: f64,
    /// Adam learning rate of actor and critic before decay.
    pub lr: f64,
    /// Multiply the rates by `lr_decay_factor` every this many training episodes.
    pub lr_decay_episodes: u64,
    /// The decay factor.
    pub lr_decay_factor: f64,
    /// Critic Adam weight decay (L2).
    pub critic_weight_decay: f64,
    /// `target ← polyak·target + (1 − polyak)·online`.
    pub polyak: f64,
    /// Move the targets after updates `k` with `k % target_update_period == 0`.
    pub target_update_period: u64,
    /// Gradient-norm bound of both networks.
    pub grad_clip: f64,
    /// ε: rows with `‖φ(s) − sg‖ ≤ ε` are dropped (`hierarchy.low_reach_threshold`).
    pub reach_threshold: f64,
}

/// The networks handed to [`DeterministicLevel::new`]; each variable list is sorted by name and
/// a target's list pairs one to one with its online list.
#[derive(Debug)]
pub struct DeterministicNets {
    /// The actor (its parameters are the published `low_policy.*`).
    pub actor: DeterministicActor,
    /// Its parameters.
    pub actor_vars: Vec<Var>,
    /// Target actor π_targ.
    pub actor_target: DeterministicActor,
    /// Its parameters.
    pub actor_target_vars: Vec<Var>,
    /// The γ-distance critic.
    pub critic: DistanceCritic,
    /// Its parameters.
    pub critic_vars: Vec<Var>,
    /// Target critic Q_targ.
    pub critic_target: DistanceCritic,
    /// Its parameters.
    pub critic_target_vars: Vec<Var>,
}

/// What one update measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DeterministicStats {
    /// Critic loss, mean Q and mean target over the kept rows.
    pub critic: DistanceCriticStats,
    /// Actor loss `−mean Q(s, π(s), sg)`.
    pub actor_loss: f64,
    /// Actor gradient norm before clipping.
    pub actor_grad_norm: f64,
    /// Critic gradient norm before clipping.
    pub critic_grad_norm: f64,
    /// Rows of the batch used (not yet at their subgoal).
    pub n_kept: usize,
    /// Rows sampled.
    pub n_sampled: usize,
    /// Whether the targets moved after this update.
    pub targets_moved: bool,
}

/// Networks, optimisers and parameters of the deterministic low level.
#[derive(Debug)]
pub struct DeterministicLevel {
    nets: DeterministicNets,
    actor_opt: Adam,
    critic_opt: Adam,
    params: DeterministicParams,
    scale: f64,
}

impl DeterministicLevel {
    /// A level; copies both online networks into their targets.
    pub fn new(nets: DeterministicNets, params: DeterministicParams) -> Result<Self, LearnerError> {
        check_pairs("actor", &nets.actor_vars, &nets.actor_target_vars)?;
        check_pairs("critic", &nets.critic_vars, &nets.critic_target_vars)?;
        for (target, online) in pairs(&nets) {
            target.set(online.as_tensor())?;
        }
        let actor_opt = Adam::new(nets.actor_vars.clone(), AdamParams::with_lr(params.lr))?;
        let critic_params = AdamParams {
            weight_decay: params.critic_weight_decay,
            ..AdamParams::with_lr(params.lr)
        };
        let critic_opt = Adam::new(nets.critic_vars.clone(), critic_params)?;
        let scale = nets.actor.scale();
        Ok(Self {
            nets,
            actor_opt,
            critic_opt,
            params,
            scale,
        })
    }

    /// Sets both learning rates for `train_episodes` finished training episodes (step decay).
    pub fn set_lr_for_episodes(&mut self, train_episodes: u64) {
        let p = &self.params;
        let halvings = train_episodes / p.lr_decay_episodes.max(1);
        let lr = p.lr
            * p.lr_decay_factor
                .powi(i32::try_from(halvings).unwrap_or(i32::MAX));
        self.actor_opt.set_learning_rate(lr);
        self.critic_opt.set_learning_rate(lr);
    }

    /// Update number `update_index` (0-based over the run; it picks the target-update steps)
    /// on `batch` (low layout: head `[obs, φ]`, tail the subgoal). A batch whose rows are all at
    /// their subgoal changes nothing (`n_kept = 0`, the targets may still move on schedule).
    /// Nothing is stepped if a loss is non-finite.
    pub fn update(
        &mut self,
        batch: &SacBatch,
        update_index: u64,
    ) -> Result<DeterministicStats, LearnerError> {
        let n_sampled = batch.reward.dim(0)?;
        let mut stats = DeterministicStats {
            n_sampled,
            ..DeterministicStats::default()
        };
        if let Some(kept) = self.drop_reached(batch)? {
            stats.n_kept = kept.reward.dim(0)?;
            let target = self.target(&kept)?;
            (stats.actor_loss, stats.actor_grad_norm) = self.actor_step(&kept)?;
            (stats.critic, stats.critic_grad_norm) = self.critic_step(&kept, &target)?;
        }
        if update_index.is_multiple_of(self.params.target_update_period.max(1)) {
            self.polyak()?;
            stats.targets_moved = true;
        }
        Ok(stats)
    }

    /// The rows with `‖φ(s) − sg‖ > ε` (φ(s) = the last columns of the head); `None` if none.
    fn drop_reached(&self, batch: &SacBatch) -> Result<Option<SacBatch>, LearnerError> {
        let subgoal = batch.tail.as_ref().ok_or(LearnerError::Shape {
            what: "deterministic update: subgoal (batch tail)",
            expected: "[batch, latent]".to_owned(),
            got: Vec::new(),
        })?;
        let latent = subgoal.dim(1)?;
        let phi = batch.head.narrow(1, batch.head.dim(1)? - latent, latent)?;
        let far = (phi - subgoal)?
            .sqr()?
            .sum(1)?
            .sqrt()?
            .gt(self.params.reach_threshold)?
            .to_vec1::<u8>()?;
        let keep: Vec<u32> = (0u32..)
            .zip(&far)
            .filter_map(|(i, f)| (*f != 0).then_some(i))
            .collect();
        if keep.len() == far.len() {
            return Ok(Some(batch.clone()));
        }
        if keep.is_empty() {
            return Ok(None);
        }
        let idx = Tensor::from_slice(&keep, keep.len(), &Device::Cpu)?;
        let rows = |t: &Tensor| t.index_select(&idx, 0);
        Ok(Some(SacBatch {
            head: rows(&batch.head)?,
            next_head: rows(&batch.next_head)?,
            tail: Some(rows(subgoal)?),
            action: rows(&batch.action)?,
            reward: rows(&batch.reward)?,
            terminal: rows(&batch.terminal)?,
        }))
    }

    /// y from the target networks, detached.
    fn target(&self, batch: &SacBatch) -> Result<Tensor, LearnerError> {
        let next_action = self
            .nets
            .actor_target
            .forward(&policy_input(batch, &batch.next_head)?)?;
        let next_in = self.critic_input(batch, &batch.next_head, &next_action)?;
        let next_q = self.nets.critic_target.q(&next_in, self.params.gamma)?;
        let not_done = batch.terminal.affine(-1.0, 1.0)?;
        distance_target(&batch.reward, &not_done, &next_q, self.params.gamma)
    }

    /// One clipped Adam step on the actor loss; returns the loss and the pre-clip norm.
    fn actor_step(&mut self, batch: &SacBatch) -> Result<(f64, f64), LearnerError> {
        let action = self
            .nets
            .actor
            .forward(&policy_input(batch, &batch.head)?)?;
        let q_pi = self.nets.critic.q(
            &self.critic_input(batch, &batch.head, &action)?,
            self.params.gamma,
        )?;
        let loss = deterministic_actor_loss(&q_pi)?;
        let value = scalar(&loss)?;
        check_finite("actor loss", value)?;
        let mut grads = loss.backward()?;
        let norm = clip_grad_norm(&mut grads, &self.nets.actor_vars, self.params.grad_clip)?;
        self.actor_opt.step(&grads)?;
        Ok((value, norm))
    }

    /// One clipped Adam step on the critic loss; returns its stats and the pre-clip norm.
    fn critic_step(
        &mut self,
        batch: &SacBatch,
        target: &Tensor,
    ) -> Result<(DistanceCriticStats, f64), LearnerError> {
        let input = self.critic_input(batch, &batch.head, &batch.action)?;
        let q = self.nets.critic.q(&input, self.params.gamma)?;
        let (loss, stats) = distance_critic_loss(&q, target)?;
        check_finite("critic loss", stats.loss)?;
        let mut grads = loss.backward()?;
        let norm = clip_grad_norm(&mut grads, &self.nets.critic_vars, self.params.grad_clip)?;
        self.critic_opt.step(&grads)?;
        Ok((stats, norm))
    }

    /// Critic input `[head, action / scale, subgoal]`.
    fn critic_input(
        &self,
        batch: &SacBatch,
        head: &Tensor,
        action: &Tensor,
    ) -> Result<Tensor, LearnerError> {
        let scaled = action.affine(1.0 / self.scale, 0.0)?;
        Ok(match &batch.tail {
            Some(tail) => Tensor::cat(&[head, &scaled, tail], 1)?,
            None => Tensor::cat(&[head, &scaled], 1)?,
        })
    }

    /// Both targets: `target ← polyak·target + (1 − polyak)·online`.
    fn polyak(&self) -> Result<(), LearnerError> {
        let keep = self.params.polyak;
        for (target, online) in pairs(&self.nets) {
            let mixed = target
                .as_tensor()
                .affine(keep, 0.0)?
                .add(&online.as_tensor().affine(1.0 - keep, 0.0)?)?;
            target.set(&mixed.detach())?;
        }
        Ok(())
    }

    /// One Adam step of the actor's optimiser on an extra policy loss (self-imitation), not
    /// clipped (the code's SI step is a plain optimiser step); `value` is checked finite first.
    /// Returns the global L2 norm of `loss`'s gradient over the actor's variables.
    pub fn policy_step(
        &mut self,
        loss: &Tensor,
        what: &'static str,
        value: f64,
    ) -> Result<f64, LearnerError> {
        check_finite(what, value)?;
        Ok(self.actor_opt.backward_step_norm(loss)?)
    }

    /// The optimisers by name, `actor` and `critic` (checkpoints).
    pub(crate) fn optimizers(&self) -> Vec<(&'static str, &Adam)> {
        vec![("actor", &self.actor_opt), ("critic", &self.critic_opt)]
    }

    /// As [`DeterministicLevel::optimizers`], mutable (checkpoints).
    pub(crate) fn optimizers_mut(&mut self) -> Vec<(&'static str, &mut Adam)> {
        vec![
            ("actor", &mut self.actor_opt),
            ("critic", &mut self.critic_opt),
        ]
    }

    /// The networks.
    pub fn nets(&self) -> &DeterministicNets {
        &self.nets
    }

    /// The current learning rate (actor and critic share it).
    pub fn learning_rate(&self) -> f64 {
        self.actor_opt.learning_rate()
    }
}

/// Policy input `[head, subgoal]`.
fn policy_input(batch: &SacBatch, head: &Tensor) -> Result<Tensor, LearnerError> {
    Ok(match &batch.tail {
        Some(tail) => Tensor::cat(&[head, tail], 1)?,
        None => head.clone(),
    })
}

/// PyTorch's `clip_grad_norm_` over the gradients of `vars` in `grads`: returns the norm before
/// clipping and scales every gradient by `max_norm / (norm + 1e-6)` when that is below 1.
pub fn clip_grad_norm(
    grads: &mut GradStore,
    vars: &[Var],
    max_norm: f64,
) -> Result<f64, LearnerError> {
    let mut sum_sq = 0.0;
    for var in vars {
        if let Some(grad) = grads.get(var.as_tensor()) {
            sum_sq += scalar(&grad.sqr()?.sum_all()?)?;
        }
    }
    let norm = sum_sq.sqrt();
    let coef = max_norm / (norm + CLIP_EPS);
    if coef < 1.0 {
        for var in vars {
            if let Some(grad) = grads.remove(var.as_tensor()) {
                grads.insert(var.as_tensor(), grad.affine(coef, 0.0)?);
            }
        }
    }
    Ok(norm)
}

/// (target, online) pairs of both networks.
fn pairs(nets: &DeterministicNets) -> impl Iterator<Item = (&Var, &Var)> {
    nets.actor_target_vars
        .iter()
        .zip(&nets.actor_vars)
        .chain(nets.critic_target_vars.iter().zip(&nets.critic_vars))
}

fn check_pairs(what: &str, online: &[Var], target: &[Var]) -> Result<(), LearnerError> {
    let same = online.len() == target.len()
        && online.iter().zip(target).all(|(a, b)| a.dims() == b.dims());
    if same {
        Ok(())
    } else {
        let reason = format!("low level: the target {what} does not mirror the online {what}");
        Err(LearnerError::Nets(nets::NetsError::Spec(reason)))
    }
}

fn check_finite(what: &'static str, value: f64) -> Result<(), LearnerError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(LearnerError::NonFinite {
            level: "low",
            what,
            value,
        })
    }
}

fn scalar(t: &Tensor) -> Result<f64, LearnerError> {
    Ok(f64::from(t.to_dtype(DType::F32)?.to_scalar::<f32>()?))
}
