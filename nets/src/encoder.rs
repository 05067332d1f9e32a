//! The subgoal representation φ: observation → latent point (HESS `RepresentationNetwork`).
//!
//! Invariant: no output squashing — φ-space is unbounded, and the latent graph, subgoals and
//! low-level rewards are all measured in it.

use candle_core::Tensor;
use candle_nn::VarBuilder;

use crate::error::Result;
use crate::init::LinearInit;
use crate::mlp::Mlp;

/// `φ(s) = L₂(relu(L₁(relu(L₀(s)))))` for the default two hidden layers:
/// `s: [batch, obs_dim]` → `φ(s): [batch, latent_dim]`.
/// PyTorch-default init (digest §4). Parameters `l0…` under the builder's prefix.
#[derive(Clone, Debug)]
pub struct Encoder {
    mlp: Mlp,
}

impl Encoder {
    /// `obs_dim → hidden… → latent_dim` with ReLU between layers.
    pub fn new(
        vb: &VarBuilder,
        obs_dim: usize,
        hidden: &[usize],
        latent_dim: usize,
    ) -> Result<Self> {
        Ok(Self {
            mlp: Mlp::new(vb, obs_dim, hidden, latent_dim, LinearInit::TorchDefault)?,
        })
    }

    /// `[batch, obs_dim]` → `[batch, latent_dim]`.
    pub fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        self.mlp.forward(obs)
    }

    /// Observation size.
    pub fn obs_dim(&self) -> usize {
        self.mlp.in_dim()
    }

    /// Latent size.
    pub fn latent_dim(&self) -> usize {
        self.mlp.out_dim()
    }

    /// The underlying MLP (its layers' weights, e.g. for a fused inference copy).
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }
}
