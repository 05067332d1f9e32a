//! Critics: SAC's twin Q networks ([`TwinCritic`]) and the reference
//! low level's γ-distance critic ([`DistanceCritic`]).
//!
//! Invariant: critic inputs are the caller's concatenation `[state…, action]` (layouts in
//! [`crate::NetsSpec`]); the networks do not rescale or reorder them.

use candle_core::Tensor;
use candle_nn::VarBuilder;

use crate::error::{NetsError, Result};
use crate::init::LinearInit;
use crate::mlp::Mlp;

/// Number of Q networks in a [`TwinCritic`].
pub const N_TWIN: usize = 2;

/// Two Q networks `Q₁, Q₂: [state, action] → ℝ` of the same shape, named `q1.l0…`, `q2.l0…`
/// under the builder's prefix, each initialised independently with `init`.
/// Shapes: `x: [batch, in]` → `q: [batch, 2]` (column `j` is `Q_{j+1}`), `min_q: [batch, 1]`.
///
/// Why two networks and not one stacked [`crate::EnsembleMlp`] (`weight [2, out, in]`, batched
/// matmul): with candle 0.11 on CPU the stacked form's forward + backward was measured 15–25 %
/// *slower* than two plain MLPs at batch 128, 2 × 256 (`examples/bench_forward.rs`, which keeps
/// the comparison); the FLOPs are the same and candle's batched-matmul backward adds strided
/// copies. The interface does not expose the layout, so the learner is unaffected if a later
/// candle makes the stacked form win.
#[derive(Clone, Debug)]
pub struct TwinCritic {
    q1: Mlp,
    q2: Mlp,
}

impl TwinCritic {
    /// Two `in → hidden… → 1` networks with ReLU hidden layers.
    pub fn new(vb: &VarBuilder, in_dim: usize, hidden: &[usize], init: LinearInit) -> Result<Self> {
        let q1 = Mlp::new(&vb.pp("q1"), in_dim, hidden, 1, init)?;
        let q2 = Mlp::new(&vb.pp("q2"), in_dim, hidden, 1, init)?;
        Ok(Self { q1, q2 })
    }

    /// Both Q values: `[batch, in]` → `[batch, 2]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let (q1, q2) = self.forward_pair(x)?;
        Ok(Tensor::cat(&[q1, q2], 1)?)
    }

    /// `(Q₁, Q₂)`, each `[batch, 1]`.
    pub fn forward_pair(&self, x: &Tensor) -> Result<(Tensor, Tensor)> {
        Ok((self.q1.forward(x)?, self.q2.forward(x)?))
    }

    /// `min(Q₁, Q₂)`: `[batch, in]` → `[batch, 1]`.
    pub fn min_q(&self, x: &Tensor) -> Result<Tensor> {
        let (q1, q2) = self.forward_pair(x)?;
        Ok(q1.minimum(&q2)?)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.q1.in_dim()
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
        Ok(Self {
            mlp: Mlp::new(vb, in_dim, hidden, 1, init)?,
        })
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
        return Err(NetsError::Spec(format!(
            "distance critic: gamma must lie in (0, 1), got {gamma}"
        )));
    }
    let inv = 1.0 / (1.0 - gamma);
    Ok(d.affine(gamma.ln(), 0.0)?.exp()?.affine(inv, -inv)?)
}
