//! Losses of the deterministic low level (digest §3.2; HESS `_update_network`).
//!
//! Symbols: the critic outputs a distance `d`, read as `Q = −(1 − γ^d)/(1 − γ)`
//! ([`nets::q_from_distance`]); `r` the stored low reward, `not_done = ‖ag_{t+1} − sg‖ > ε`
//! (ε = `hierarchy.low_reach_threshold`, 0.1), `next_q = Q_targ(s', π_targ(s'), sg)`.
//!
//! - Target: `y = min(r + γ · not_done · next_q, 0)`, detached (the code clips only from above:
//!   its lower clip applies to sparse rewards only).
//! - Critic: `mean (Q(s, a, sg) − y)²` (the code's L2 term is multiplied by 0, inert).
//! - Actor: `−mean Q(s, π(s), sg)` (`action_l2 = 0`).

use candle_core::{DType, Tensor};

use crate::error::LearnerError;

/// `not_done` `[B, 1]`: 1 where `‖next_achieved − subgoal‖ > threshold`, else 0; both `[B, d]`.
pub fn not_done(
    next_achieved: &Tensor,
    subgoal: &Tensor,
    threshold: f64,
) -> Result<Tensor, LearnerError> {
    let (b, d) = rank2("not_done: next_achieved", next_achieved)?;
    same("not_done: subgoal", subgoal, &[b, d])?;
    let dist = (next_achieved - subgoal)?.sqr()?.sum_keepdim(1)?.sqrt()?;
    Ok(dist.gt(threshold)?.to_dtype(DType::F32)?)
}

/// The target `y = min(r + γ · not_done · next_q, 0)`, detached; all `[B, 1]`.
pub fn distance_target(
    reward: &Tensor,
    not_done: &Tensor,
    next_q: &Tensor,
    gamma: f64,
) -> Result<Tensor, LearnerError> {
    let (b, _) = rank2("distance_target: reward", reward)?;
    same("distance_target: reward", reward, &[b, 1])?;
    same("distance_target: not_done", not_done, &[b, 1])?;
    same("distance_target: next_q", next_q, &[b, 1])?;
    let boot = (not_done * next_q.detach())?.affine(gamma, 0.0)?;
    Ok((reward + boot)?.minimum(0.0)?.detach())
}

/// Critic statistics.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DistanceCriticStats {
    /// The loss.
    pub loss: f64,
    /// Mean Q over the batch.
    pub q_mean: f64,
    /// Mean target.
    pub target_mean: f64,
}

/// `mean (q − y)²` with `q, target: [B, 1]`.
pub fn distance_critic_loss(
    q: &Tensor,
    target: &Tensor,
) -> Result<(Tensor, DistanceCriticStats), LearnerError> {
    let (b, _) = rank2("distance_critic_loss: q", q)?;
    same("distance_critic_loss: q", q, &[b, 1])?;
    same("distance_critic_loss: target", target, &[b, 1])?;
    let loss = (q - target.detach())?.sqr()?.mean_all()?;
    let stats = DistanceCriticStats {
        loss: scalar(&loss)?,
        q_mean: scalar(&q.mean_all()?)?,
        target_mean: scalar(&target.mean_all()?)?,
    };
    Ok((loss, stats))
}

/// `−mean q_pi` with `q_pi: [B, 1]` (Q of the actor's own action).
pub fn deterministic_actor_loss(q_pi: &Tensor) -> Result<Tensor, LearnerError> {
    let (b, _) = rank2("deterministic_actor_loss: q_pi", q_pi)?;
    same("deterministic_actor_loss: q_pi", q_pi, &[b, 1])?;
    Ok(q_pi.mean_all()?.neg()?)
}

fn rank2(what: &'static str, t: &Tensor) -> Result<(usize, usize), LearnerError> {
    t.dims2().map_err(|_| LearnerError::Shape {
        what,
        expected: "[batch, n]".to_owned(),
        got: t.dims().to_vec(),
    })
}

fn same(what: &'static str, t: &Tensor, dims: &[usize]) -> Result<(), LearnerError> {
    if t.dims() == dims {
        Ok(())
    } else {
        Err(LearnerError::Shape {
            what,
            expected: format!("{dims:?}"),
            got: t.dims().to_vec(),
        })
    }
}

fn scalar(t: &Tensor) -> Result<f64, LearnerError> {
    Ok(f64::from(t.to_dtype(DType::F32)?.to_scalar::<f32>()?))
}
