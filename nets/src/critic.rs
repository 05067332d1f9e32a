//! Critics: SAC's twin Q networks as one batched network ([`TwinCritic`]) and the reference
//! low level's γ-distance critic ([`DistanceCritic`]).
//!
//! Invariant: critic inputs are the caller's concatenation `[state…, action]` (layouts in
//! [`crate::NetsSpec`]); the networks do not rescale or reorder them.

use candle_core::{Tensor, D};
use candle_nn::VarBuilder;

use crate::error::{NetsError, Result};
use crate::init::LinearInit;
use crate::mlp::{EnsembleMlp, Mlp};

/// Number of Q networks in a [`TwinCritic`].
pub const N_TWIN: usize = 2;

/// Two Q networks `Q₁, Q₂: [state, action] → ℝ` of the same shape, evaluated as one batched
/// network: layer `lᵢ` stores `weight [2, outᵢ, inᵢ]`, `bias [2, outᵢ]` (an [`EnsembleMlp`]).
/// The first layer is one `[batch, in] × [in, 2·out]` gemm, the rest batched matmuls — one
/// forward and one backward pass instead of two.
/// Shapes: `x: [batch, in]` → `q: [batch, 2]` (column `j` is `Q_{j+1}`), `min_q: [batch, 1]`.
/// Member `j` is initialised as an independent network with `init`.
#[derive(Clone, Debug)]
pub struct TwinCritic {
    net: EnsembleMlp,
}

impl TwinCritic {
    /// Two `in → hidden… → 1` networks with ReLU hidden layers.
    pub fn new(vb: &VarBuilder, in_dim: usize, hidden: &[usize], init: LinearInit) -> Result<Self> {
        Ok(Self { net: EnsembleMlp::new(vb, N_TWIN, in_dim, hidden, 1, init)? })
    }

    /// Both Q values: `[batch, in]` → `[batch, 2]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        // [2, batch, 1] → [2, batch] → [batch, 2]
        Ok(self.net.forward(x)?.squeeze(2)?.t()?)
    }

    /// `min(Q₁, Q₂)`: `[batch, in]` → `[batch, 1]`.
    pub fn min_q(&self, x: &Tensor) -> Result<Tensor> {
        Ok(self.forward(x)?.min_keepdim(D::Minus1)?)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.net.in_dim()
    }
}

/// The reference low-level critic (HESS, digest §3.2): an MLP predicts a scalar `d`, read as
/// a discounted step count, and `Q = −(1 − γ^d) / (1 − γ)`, so `Q ≤ 0` whenever `d ≥ 0`.
/// Shapes: `x: [batch, in]` → `d, Q: [batch, 1]`. The reference feeds it
/// `[obs, φ(obs), action / scale, subgoal]`; the caller builds that input.
/// Parameters `l0…` under the builder's prefix.
#[derive(Clone, Debug)]
pub struct DistanceCritic {
    mlp: Mlp,
}

impl DistanceCritic {
    /// `in → hidden… → 1` with ReLU hidden layers.
    pub fn new(vb: &VarBuilder, in_dim: usize, hidden: &[usize], init: LinearInit) -> Result<Self> {
        Ok(Self { mlp: Mlp::new(vb, in_dim, hidden, 1, init)? })
    }

    /// The raw output `d`, `[batch, 1]`.
    pub fn distance(&self, x: &Tensor) -> Result<Tensor> {
        self.mlp.forward(x)
    }

    /// `Q = −(1 − γ^d)/(1 − γ)`, `[batch, 1]`; `gamma` ∈ (0, 1) is the learner's discount.
    pub fn q(&self, x: &Tensor, gamma: f64) -> Result<Tensor> {
        q_from_distance(&self.distance(x)?, gamma)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.mlp.in_dim()
    }
}

/// `Q = −(1 − γ^d)/(1 − γ) = (exp(d · ln γ) − 1)/(1 − γ)`, elementwise; `gamma` ∈ (0, 1).
pub fn q_from_distance(d: &Tensor, gamma: f64) -> Result<Tensor> {
    if !(gamma > 0.0 && gamma < 1.0) {
        return Err(NetsError::Spec(format!("distance critic: gamma must lie in (0, 1), got {gamma}")));
    }
    let inv = 1.0 / (1.0 - gamma);
    Ok(d.affine(gamma.ln(), 0.0)?.exp()?.affine(inv, -inv)?)
}
