//! The two self-imitation losses (paper Eq. 11–12, digest §8), as pure functions: tensors in,
//! loss and statistics out. Shapes are checked; the targets are detached here, where they are
//! built, so no gradient ever reaches them.
//!
//! Symbols: `B` batch, `D` latent size (2), `A` low-level action size, `U` = |u| references.
//! - High (Eq. 11): `L_hi = α · mean_{B, D} (a − (l_k − φ(s_t)))²` with `a` a reparameterised
//!   sample of π_hi([s_t, g]) (code: `action`), `l_k` the route node at the target index
//!   (`route_target`), `φ(s_t)` the encoder output (`phi`).
//! - Low (Eq. 12): `L_lo = β · mean_{B, U, A} (π_lo(s_t, l_k) − NG(π_lo(s_t, l_{u_i})))²` with
//!   the aligned action (`aligned`, with gradient) and the actions at the nearer route nodes
//!   (`reference`, detached: NG = no gradient).

use candle_core::Tensor;

use crate::error::LearnerError;

/// What an SI loss measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SiLossStats {
    /// The weighted loss (α·mse or β·mse).
    pub loss: f64,
    /// The unweighted mean squared error.
    pub mse: f64,
}

/// `L_hi = α · mean (action − (route_target − phi))²` over batch and latent dims (Eq. 11).
/// Shapes: `action, route_target, phi: [B, D]`. The target `route_target − phi` is detached.
pub fn high_si_loss(
    action: &Tensor,
    route_target: &Tensor,
    phi: &Tensor,
    alpha: f64,
) -> Result<(Tensor, SiLossStats), LearnerError> {
    let dims = matrix("high_si_loss: action", action)?;
    same_shape("high_si_loss: route_target", route_target, dims)?;
    same_shape("high_si_loss: phi", phi, dims)?;
    let target = route_target.sub(phi)?.detach();
    let mse = action.sub(&target)?.sqr()?.mean_all()?;
    weighted(mse, alpha)
}

/// `L_lo = β · mean (aligned − NG(reference))²` over batch, references and action dims
/// (Eq. 12). Shapes: `aligned: [B, A]`, `reference: [B, U, A]` (detached here).
pub fn low_si_loss(
    aligned: &Tensor,
    reference: &Tensor,
    beta: f64,
) -> Result<(Tensor, SiLossStats), LearnerError> {
    let (batch, action_dim) = matrix("low_si_loss: aligned", aligned)?;
    match reference.dims() {
        &[b, u, a] if b == batch && a == action_dim && u > 0 => {}
        got => {
            return Err(LearnerError::Shape {
                what: "low_si_loss: reference",
                expected: format!("[{batch}, U ≥ 1, {action_dim}]"),
                got: got.to_vec(),
            })
        }
    }
    let mse = aligned
        .unsqueeze(1)?
        .broadcast_sub(&reference.detach())?
        .sqr()?
        .mean_all()?;
    weighted(mse, beta)
}

/// `weight · mse` and the statistics.
fn weighted(mse: Tensor, weight: f64) -> Result<(Tensor, SiLossStats), LearnerError> {
    let loss = mse.affine(weight, 0.0)?;
    let stats = SiLossStats {
        loss: f64::from(loss.to_scalar::<f32>()?),
        mse: f64::from(mse.to_scalar::<f32>()?),
    };
    Ok((loss, stats))
}

/// `(rows, cols)` of a non-empty matrix.
fn matrix(what: &'static str, t: &Tensor) -> Result<(usize, usize), LearnerError> {
    match t.dims() {
        &[rows, cols] if rows > 0 && cols > 0 => Ok((rows, cols)),
        got => Err(LearnerError::Shape {
            what,
            expected: "[batch ≥ 1, dim ≥ 1]".to_owned(),
            got: got.to_vec(),
        }),
    }
}

/// `Err` unless `t` is `[rows, cols]`.
fn same_shape(
    what: &'static str,
    t: &Tensor,
    (rows, cols): (usize, usize),
) -> Result<(), LearnerError> {
    if t.dims() == [rows, cols] {
        Ok(())
    } else {
        Err(LearnerError::Shape {
            what,
            expected: format!("[{rows}, {cols}]"),
            got: t.dims().to_vec(),
        })
    }
}
