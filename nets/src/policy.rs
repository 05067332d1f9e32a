//! Policies: the tanh-squashed Gaussian of SAC ([`GaussianPolicy`], both levels by default) and
//! the deterministic low-level actor of the reference code ([`DeterministicActor`]).
//!
//! Invariants:
//! - Actions lie in `[−scale, scale]` per dimension (`scale · tanh`).
//! - Sampling takes its standard-normal noise `eps` from the caller, so the networks hold no
//!   random state: the actor and learner own their generators, and tests are deterministic.
//! - The log-std is clamped to `[LOG_STD_MIN, LOG_STD_MAX]` before use.

use candle_core::{Tensor, D};
use candle_nn::VarBuilder;

use crate::error::{NetsError, Result};
use crate::init::LinearInit;
use crate::linear::Linear;
use crate::mlp::Mlp;

/// Lower clamp of the policy log-std (reference SAC, digest §3.1).
pub const LOG_STD_MIN: f64 = -20.0;
/// Upper clamp of the policy log-std (reference SAC, digest §3.1).
pub const LOG_STD_MAX: f64 = 2.0;
/// Added inside the tanh log-det correction to keep it finite at saturation (reference SAC).
pub const TANH_LOG_EPS: f64 = 1e-6;

/// `½ · ln(2π)`, the Gaussian log-density constant.
const HALF_LN_2PI: f64 = 0.918_938_533_204_672_8;

/// Tanh-squashed Gaussian policy (SAC).
///
/// `h = trunk(x)` (ReLU after every layer), `μ = L_mean(h)`, `log σ = clamp(L_logstd(h), −20, 2)`;
/// with `ε ~ N(0, I)`: `u = μ + σ ⊙ ε`, `a = scale · tanh(u)`, and
/// `log π(a|x) = Σ_i [ −½ ε_i² − log σ_i − ½ ln 2π − ln(scale · (1 − tanh²(u_i)) + 1e−6) ]`.
/// Shapes: `x: [batch, in]`, `ε, μ, log σ, a: [batch, action_dim]`, `log π: [batch, 1]`.
/// Parameters: `trunk.l0…`, `mean`, `log_std` under the builder's prefix.
#[derive(Clone, Debug)]
pub struct GaussianPolicy {
    trunk: Mlp,
    mean: Linear,
    log_std: Linear,
    scale: f64,
    name: String,
}

impl GaussianPolicy {
    /// `in → hidden… → (mean, log_std)` heads of `action_dim`, actions scaled by `scale`.
    pub fn new(
        vb: &VarBuilder,
        in_dim: usize,
        hidden: &[usize],
        action_dim: usize,
        scale: f64,
        init: LinearInit,
    ) -> Result<Self> {
        check_scale(&vb.prefix(), scale)?;
        let trunk = Mlp::trunk(&vb.pp("trunk"), in_dim, hidden, init)?;
        let width = trunk.out_dim();
        let mean = Linear::new(&vb.pp("mean"), width, action_dim, init)?;
        let log_std = Linear::new(&vb.pp("log_std"), width, action_dim, init)?;
        Ok(Self {
            trunk,
            mean,
            log_std,
            scale,
            name: vb.prefix(),
        })
    }

    /// The pre-squash Gaussian: `(μ, log σ)`, each `[batch, action_dim]`, log σ clamped.
    pub fn dist(&self, x: &Tensor) -> Result<(Tensor, Tensor)> {
        let h = self.trunk.forward(x)?;
        let mean = self.mean.forward(&h)?;
        let log_std = self.log_std.forward(&h)?.clamp(LOG_STD_MIN, LOG_STD_MAX)?;
        Ok((mean, log_std))
    }

    /// Reparameterised sample with caller-supplied noise `eps: [batch, action_dim]`:
    /// returns `(a, log π(a|x))` with shapes `[batch, action_dim]` and `[batch, 1]`.
    /// Gradients flow to the parameters through `a` and `log π`.
    pub fn sample(&self, x: &Tensor, eps: &Tensor) -> Result<(Tensor, Tensor)> {
        let (mean, log_std) = self.dist(x)?;
        if eps.dims() != mean.dims() {
            return Err(NetsError::Dim {
                layer: format!("{} (noise eps)", self.name),
                what: "noise elements",
                expected: mean.elem_count(),
                got: eps.elem_count(),
                shape: eps.dims().to_vec(),
            });
        }
        let u = mean.add(&log_std.exp()?.mul(eps)?)?;
        let tanh_u = u.tanh()?;
        let action = tanh_u.affine(self.scale, 0.0)?;
        // ln N(u; μ, σ) with (u − μ)/σ = ε exactly; same value and gradients as from u.
        let gauss = eps.sqr()?.affine(-0.5, -HALF_LN_2PI)?.sub(&log_std)?;
        let one_minus_sq = tanh_u.sqr()?.affine(-1.0, 1.0)?;
        let log_det = one_minus_sq.affine(self.scale, TANH_LOG_EPS)?.log()?;
        let log_prob = gauss.sub(&log_det)?.sum_keepdim(D::Minus1)?;
        Ok((action, log_prob))
    }

    /// The deterministic (evaluation) action `scale · tanh(μ)`, `[batch, action_dim]`.
    pub fn deterministic(&self, x: &Tensor) -> Result<Tensor> {
        let h = self.trunk.forward(x)?;
        Ok(self.mean.forward(&h)?.tanh()?.affine(self.scale, 0.0)?)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.trunk.in_dim()
    }

    /// Action size.
    pub fn action_dim(&self) -> usize {
        self.mean.out_dim()
    }

    /// Action bound: actions lie in `[−scale, scale]`.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

/// Deterministic actor of the reference low level (HESS `actor`, digest §3.2):
/// `a = scale · tanh(MLP(x))`, `x: [batch, in]` → `a: [batch, action_dim]`.
/// Exploration noise (Gaussian plus ε-random) belongs to the acting code, not here.
/// Parameters `l0…` under the builder's prefix.
#[derive(Clone, Debug)]
pub struct DeterministicActor {
    mlp: Mlp,
    scale: f64,
}

impl DeterministicActor {
    /// `in → hidden… → action_dim`, then `scale · tanh`.
    pub fn new(
        vb: &VarBuilder,
        in_dim: usize,
        hidden: &[usize],
        action_dim: usize,
        scale: f64,
        init: LinearInit,
    ) -> Result<Self> {
        check_scale(&vb.prefix(), scale)?;
        Ok(Self {
            mlp: Mlp::new(vb, in_dim, hidden, action_dim, init)?,
            scale,
        })
    }

    /// `[batch, in]` → `[batch, action_dim]` in `[−scale, scale]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(self.mlp.forward(x)?.tanh()?.affine(self.scale, 0.0)?)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.mlp.in_dim()
    }

    /// Action size.
    pub fn action_dim(&self) -> usize {
        self.mlp.out_dim()
    }

    /// Action bound.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

fn check_scale(name: &str, scale: f64) -> Result<()> {
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(NetsError::Spec(format!(
            "{name}: action scale must be finite and positive, got {scale}"
        )))
    }
}
