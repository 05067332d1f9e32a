//! SAC losses (Haarnoja et al. 2018, as CleanRL's `sac_continuous_action.py`), one module for
//! both levels: pure functions, tensors in, loss (and statistics) out.
//!
//! Symbols → code names: r → `reward`, d → `terminal` (1 where bootstrapping stops: env
//! `terminated`, or the level's own goal — low: subgoal reached; high: mask = 0 — never
//! `truncated`), γ → `gamma`, α → `alpha`, Q'ᵢ → the target critics, log π(a'|s') →
//! `next_log_prob`. Shapes: per-sample columns are `[batch, 1]`; twin Q values `[batch, 2]`.
//!
//! - Soft target (SAC Eq. 3 with the clipped double-Q of TD3):
//!   `y = r + γ · (1 − d) · (min(Q'₁, Q'₂)(s', a') − α · log π(a'|s'))`, `a' ~ π(·|s')`,
//!   built from detached inputs; optionally clamped to `[low, high]` ([`clip_target`], the
//!   reference code's clamp of the high level's target to `[−T, 0]` under a sparse reward).
//! - Critic (SAC Eq. 5 for each twin, summed): `L_Q = mean((Q₁ − y)²) + mean((Q₂ − y)²)`.
//! - Actor (SAC Eq. 7, reparameterised): `L_π = mean(α · log π(ã|s) − min(Q₁, Q₂)(s, ã))`.
//! - Temperature (SAC v2 Eq. 18, CleanRL form):
//!   `L_α = mean(−exp(log α) · (log π(ã|s) + H̄))`, log π detached, H̄ = target entropy.

use candle_core::Tensor;

use crate::error::LearnerError;

/// Statistics of a critic loss.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CriticStats {
    /// L_Q (sum of the twin MSEs).
    pub loss: f64,
    /// mean Q₁(s, a).
    pub q1_mean: f64,
    /// mean Q₂(s, a).
    pub q2_mean: f64,
    /// mean y.
    pub target_mean: f64,
}

/// Statistics of an actor loss.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ActorStats {
    /// L_π.
    pub loss: f64,
    /// −mean log π(ã|s), a sample estimate of the policy entropy.
    pub entropy: f64,
}

/// `Err(Shape)` unless `t` is `[batch, cols]`.
fn check_shape(
    what: &'static str,
    t: &Tensor,
    batch: usize,
    cols: usize,
) -> Result<(), LearnerError> {
    if t.dims() == [batch, cols] {
        Ok(())
    } else {
        Err(LearnerError::Shape {
            what,
            expected: format!("[{batch}, {cols}]"),
            got: t.dims().to_vec(),
        })
    }
}

/// Batch size of a `[batch, 1]` column.
fn batch_of(what: &'static str, t: &Tensor) -> Result<usize, LearnerError> {
    match t.dims() {
        [batch, 1] => Ok(*batch),
        got => Err(LearnerError::Shape {
            what,
            expected: "[batch, 1]".to_owned(),
            got: got.to_vec(),
        }),
    }
}

/// The soft TD target `y = r + γ(1 − d)(min Q'(s',a') − α log π(a'|s'))`, detached.
/// `reward`, `terminal`, `next_min_q`, `next_log_prob`: `[batch, 1]`.
pub fn soft_target(
    reward: &Tensor,
    terminal: &Tensor,
    next_min_q: &Tensor,
    next_log_prob: &Tensor,
    gamma: f64,
    alpha: f64,
) -> Result<Tensor, LearnerError> {
    let batch = batch_of("soft_target: reward", reward)?;
    check_shape("soft_target: terminal", terminal, batch, 1)?;
    check_shape("soft_target: next_min_q", next_min_q, batch, 1)?;
    check_shape("soft_target: next_log_prob", next_log_prob, batch, 1)?;
    let soft_value = next_min_q
        .detach()
        .sub(&next_log_prob.detach().affine(alpha, 0.0)?)?;
    let continuation = terminal.affine(-gamma, gamma)?; // γ(1 − d)
    Ok(reward.add(&continuation.mul(&soft_value)?)?.detach())
}

/// Bounds on the soft target y (`learner.high.clip_target`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetClip {
    /// Lower bound (the reference's −T: episode length × per-step penalty).
    pub low: f64,
    /// Upper bound (0: no step pays a positive reward).
    pub high: f64,
}

/// `clamp(y, low, high)` elementwise where `clip` is set; `y` itself otherwise. `target`:
/// `[batch, 1]`.
pub fn clip_target(target: &Tensor, clip: Option<TargetClip>) -> Result<Tensor, LearnerError> {
    batch_of("clip_target: target", target)?;
    Ok(match clip {
        Some(TargetClip { low, high }) => target.clamp(low, high)?.detach(),
        None => target.clone(),
    })
}

/// The twin critic loss `mean((Q₁ − y)²) + mean((Q₂ − y)²)`; `q: [batch, 2]`, `target: [batch, 1]`.
pub fn twin_critic_loss(
    q: &Tensor,
    target: &Tensor,
) -> Result<(Tensor, CriticStats), LearnerError> {
    let batch = batch_of("twin_critic_loss: target", target)?;
    check_shape("twin_critic_loss: q", q, batch, 2)?;
    let target = target.detach();
    // Per-column MSE summed over the two columns = sum over both of mean over the batch.
    let loss = q.broadcast_sub(&target)?.sqr()?.mean(0)?.sum_all()?;
    let q_means: Vec<f32> = q.mean(0)?.to_vec1()?;
    let stats = CriticStats {
        loss: f64::from(loss.to_scalar::<f32>()?),
        q1_mean: f64::from(q_means[0]),
        q2_mean: f64::from(q_means[1]),
        target_mean: f64::from(target.mean_all()?.to_scalar::<f32>()?),
    };
    Ok((loss, stats))
}

/// The actor loss `mean(α log π(ã|s) − min Q(s, ã))`; `log_prob`, `min_q`: `[batch, 1]`.
pub fn actor_loss(
    log_prob: &Tensor,
    min_q: &Tensor,
    alpha: f64,
) -> Result<(Tensor, ActorStats), LearnerError> {
    let batch = batch_of("actor_loss: log_prob", log_prob)?;
    check_shape("actor_loss: min_q", min_q, batch, 1)?;
    let loss = log_prob.affine(alpha, 0.0)?.sub(min_q)?.mean_all()?;
    let stats = ActorStats {
        loss: f64::from(loss.to_scalar::<f32>()?),
        entropy: -f64::from(log_prob.mean_all()?.to_scalar::<f32>()?),
    };
    Ok((loss, stats))
}

/// The temperature loss `mean(−exp(log α) · (log π + H̄))`, log π detached.
/// `log_alpha`: `[1]`; `log_prob`: `[batch, 1]`.
pub fn temperature_loss(
    log_alpha: &Tensor,
    log_prob: &Tensor,
    target_entropy: f64,
) -> Result<Tensor, LearnerError> {
    batch_of("temperature_loss: log_prob", log_prob)?;
    if log_alpha.dims() != [1] {
        return Err(LearnerError::Shape {
            what: "temperature_loss: log_alpha",
            expected: "[1]".to_owned(),
            got: log_alpha.dims().to_vec(),
        });
    }
    let shifted = log_prob
        .detach()
        .affine(1.0, target_entropy)?
        .mean_all()?
        .reshape(1)?;
    Ok(log_alpha.exp()?.neg()?.mul(&shifted)?.sum_all()?)
}
