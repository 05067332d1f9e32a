//! φ losses as pure functions (paper Eq. 5–7 in the released code's form, digest §4).
//!
//! Symbols: `anchor = φ(s_t)`, `positive = φ(s_{t+1})`, `negative = φ(s_{t+k})`, all
//! `[B, d]`; `phi = φ(s)` and `phi_old = φ_old(s)` for the regularised states, `[B, d]`.
//!
//! - Triplet (Eq. 5, code form): per sample
//!   `l_b = mean_d (anchor − positive)² + max(0, δ − mean_d (anchor − negative)²)`,
//!   loss = `mean_b l_b`. The paper writes plain L2 norms; the code's squared mean over the d
//!   latent dims is what the published runs used, so δ acts on half the squared distance
//!   for d = 2.
//! - Stable (Eq. 6): `coeff · mean_{b,d} λ_b (phi − phi_old)²`, `phi_old` detached here.
//!   λ is optional (`None` = 1 for every state, the code); the paper's λ(s) can be realised
//!   either by this weight or by how the states are sampled (see [`super::round`]).

use candle_core::{Tensor, D};

use crate::error::LearnerError;

/// Triplet-loss statistics (batch means).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TripletStats {
    /// The loss `mean_b l_b`.
    pub loss: f64,
    /// `mean_b mean_d (anchor − positive)²`.
    pub positive_sq: f64,
    /// `mean_b mean_d (anchor − negative)²`.
    pub negative_sq: f64,
    /// Fraction of samples whose hinge is active (`mean_d (anchor − negative)² < δ`).
    pub hinge_active: f64,
}

/// The triplet loss: `(loss scalar, per-sample l [B], stats)`. See the module doc.
pub fn triplet_loss(
    anchor: &Tensor,
    positive: &Tensor,
    negative: &Tensor,
    margin: f64,
) -> Result<(Tensor, Tensor, TripletStats), LearnerError> {
    let (b, d) = dims2("triplet_loss: anchor", anchor)?;
    expect_shape("triplet_loss: positive", positive, b, d)?;
    expect_shape("triplet_loss: negative", negative, b, d)?;
    let pos_sq = (anchor - positive)?.sqr()?.mean(D::Minus1)?;
    let neg_sq = (anchor - negative)?.sqr()?.mean(D::Minus1)?;
    let hinge = neg_sq.affine(-1.0, margin)?.relu()?;
    let per_sample = (&pos_sq + &hinge)?;
    let loss = per_sample.mean_all()?;
    let stats = TripletStats {
        loss: scalar(&loss)?,
        positive_sq: scalar(&pos_sq.mean_all()?)?,
        negative_sq: scalar(&neg_sq.mean_all()?)?,
        hinge_active: scalar(
            &hinge
                .gt(0.0)?
                .to_dtype(candle_core::DType::F32)?
                .mean_all()?,
        )?,
    };
    Ok((loss, per_sample, stats))
}

/// The stable loss `coeff · mean_{b,d} λ_b (phi − phi_old)²` and its value; `weight` is λ as
/// `[B, 1]` (or `None` for λ = 1). See the module doc.
pub fn stable_loss(
    phi: &Tensor,
    phi_old: &Tensor,
    weight: Option<&Tensor>,
    coeff: f64,
) -> Result<(Tensor, f64), LearnerError> {
    let (b, d) = dims2("stable_loss: phi", phi)?;
    expect_shape("stable_loss: phi_old", phi_old, b, d)?;
    let sq = (phi - phi_old.detach())?.sqr()?;
    let weighted = match weight {
        Some(w) => {
            expect_shape("stable_loss: weight", w, b, 1)?;
            sq.broadcast_mul(&w.detach())?
        }
        None => sq,
    };
    let loss = weighted.mean_all()?.affine(coeff, 0.0)?;
    let value = scalar(&loss)?;
    Ok((loss, value))
}

/// `[rows, cols]` of a rank-2 tensor, or a shape error naming it.
fn dims2(what: &'static str, t: &Tensor) -> Result<(usize, usize), LearnerError> {
    t.dims2().map_err(|_| LearnerError::Shape {
        what,
        expected: "[batch, latent]".to_owned(),
        got: t.dims().to_vec(),
    })
}

/// Checks `t` is `[b, d]`.
fn expect_shape(what: &'static str, t: &Tensor, b: usize, d: usize) -> Result<(), LearnerError> {
    if t.dims() == [b, d] {
        Ok(())
    } else {
        Err(LearnerError::Shape {
            what,
            expected: format!("[{b}, {d}]"),
            got: t.dims().to_vec(),
        })
    }
}

/// A scalar tensor as f64.
fn scalar(t: &Tensor) -> Result<f64, LearnerError> {
    Ok(f64::from(
        t.to_dtype(candle_core::DType::F32)?.to_scalar::<f32>()?,
    ))
}
