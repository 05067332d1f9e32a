//! [`Adam`]: PyTorch's `torch.optim.Adam` (no weight decay, no AMSGrad) as a
//! [`candle_nn::Optimizer`], with its state exportable for checkpoints ([`AdamState`]).
//!
//! Update at step t (Kingma & Ba 2015, Algorithm 1; PyTorch's documented form), per element:
//!
//! ```text
//! m ← β₁·m + (1 − β₁)·g          v ← β₂·v + (1 − β₂)·g²
//! θ ← θ − lr · (m / (1 − β₁ᵗ)) / (√(v / (1 − β₂ᵗ)) + ε)
//! ```
//!
//! ε is added outside the square root, after bias correction, as in PyTorch. With a weight
//! decay λ > 0 the gradient is first replaced by `g + λ·θ` (PyTorch's `Adam(weight_decay=λ)`,
//! L2 through the moments, not AdamW's decoupled decay). Defaults ([`AdamParams::default`]) are
//! PyTorch's: lr 1e-3, β = (0.9, 0.999), ε = 1e-8, λ = 0.
//!
//! Why not candle's `AdamW`: its moments are private, so a checkpoint could not carry them,
//! and a resumed run would restart Adam from zero moments (a different trajectory). Speed: the
//! moments live in plain `Vec<f32>`s and one pass over each parameter updates m, v and θ (one
//! read of the gradient and θ, one write of θ) instead of a dozen temporary tensors.
//! [`Adam::step_norm`] is that step, also returning the gradient's global L2 norm (a metric);
//! [`Optimizer::step`] calls it, so reading the norm cannot change the update.
//!
//! Invariant: variables are f32 and keep their order; the exported state lists m and v per
//! variable in that order, and an import must match the shapes exactly.

use candle_core::backprop::GradStore;
use candle_core::{DType, Tensor, Var};
use candle_nn::Optimizer;

/// Adam's hyper-parameters (PyTorch names and defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamParams {
    /// Learning rate. Default 1e-3 (PyTorch).
    pub lr: f64,
    /// β₁, decay of the first moment. Default 0.9 (PyTorch).
    pub beta1: f64,
    /// β₂, decay of the second moment. Default 0.999 (PyTorch).
    pub beta2: f64,
    /// ε, added to the bias-corrected √v. Default 1e-8 (PyTorch).
    pub eps: f64,
    /// L2 weight decay λ added to the gradient (`g + λ·θ`). Default 0 (PyTorch).
    pub weight_decay: f64,
}

impl Default for AdamParams {
    fn default() -> Self {
        Self {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 0.0,
        }
    }
}

impl AdamParams {
    /// PyTorch's defaults at learning rate `lr`.
    pub fn with_lr(lr: f64) -> Self {
        Self {
            lr,
            ..Self::default()
        }
    }
}

/// Adam's state: the step count and both moments of every variable, in variable order
/// (each moment flattened row-major, as long as the variable).
#[derive(Debug, Clone, PartialEq)]
pub struct AdamState {
    /// Steps taken (t); the bias corrections use it.
    pub step: u64,
    /// First moments m, one per variable.
    pub m: Vec<Vec<f32>>,
    /// Second moments v, one per variable.
    pub v: Vec<Vec<f32>>,
}

/// A variable with its moments.
#[derive(Debug)]
struct Slot {
    var: Var,
    m: Vec<f32>,
    v: Vec<f32>,
}

/// Adam over a fixed list of f32 variables. See the module doc.
#[derive(Debug)]
pub struct Adam {
    slots: Vec<Slot>,
    params: AdamParams,
    step: u64,
}

impl Adam {
    /// The current state (a copy).
    pub fn export_state(&self) -> AdamState {
        AdamState {
            step: self.step,
            m: self.slots.iter().map(|s| s.m.clone()).collect(),
            v: self.slots.iter().map(|s| s.v.clone()).collect(),
        }
    }

    /// Replaces the state; refused (nothing changed) unless there is one m and one v per
    /// variable, each as long as its variable.
    pub fn import_state(&mut self, state: AdamState) -> Result<(), AdamStateError> {
        let n = self.slots.len();
        if state.m.len() != n || state.v.len() != n {
            return Err(AdamStateError::VarCount {
                expected: n,
                m: state.m.len(),
                v: state.v.len(),
            });
        }
        for (index, slot) in self.slots.iter().enumerate() {
            let want = slot.m.len();
            let (m, v) = (state.m[index].len(), state.v[index].len());
            if m != want || v != want {
                return Err(AdamStateError::Length {
                    index,
                    expected: want,
                    m,
                    v,
                });
            }
        }
        self.step = state.step;
        for (slot, (m, v)) in self.slots.iter_mut().zip(state.m.into_iter().zip(state.v)) {
            slot.m = m;
            slot.v = v;
        }
        Ok(())
    }

    /// The hyper-parameters.
    pub fn params(&self) -> AdamParams {
        self.params
    }

    /// Number of variables.
    pub fn n_vars(&self) -> usize {
        self.slots.len()
    }

    /// [`Optimizer::backward_step`] (the same update, bit for bit) that also returns the global
    /// L2 norm of the loss gradient over this optimiser's variables (see [`Adam::step_norm`]).
    pub fn backward_step_norm(&mut self, loss: &Tensor) -> candle_core::Result<f64> {
        let grads = loss.backward()?;
        self.step_norm(&grads)
    }

    /// [`Optimizer::step`] (it is the same code) that also returns `‖g‖₂ = √(Σ g²)` over the
    /// gradients of this optimiser's variables: the loss gradient as given, before the weight
    /// decay term; a variable without a gradient counts as zero. Summed in f64.
    pub fn step_norm(&mut self, grads: &GradStore) -> candle_core::Result<f64> {
        self.step += 1;
        let coeffs = Coeffs::at(&self.params, self.step);
        let mut sum_sq = 0.0;
        for slot in &mut self.slots {
            if let Some(grad) = grads.get(slot.var.as_tensor()) {
                sum_sq += slot.apply(grad, &coeffs)?;
            }
        }
        Ok(sum_sq.sqrt())
    }
}

/// Why [`Adam::import_state`] refused a state.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AdamStateError {
    /// Not one moment per variable.
    #[error("Adam state has {m} first and {v} second moments for {expected} variables")]
    VarCount {
        /// Variables of the optimiser.
        expected: usize,
        /// First moments given.
        m: usize,
        /// Second moments given.
        v: usize,
    },
    /// A moment of the wrong length.
    #[error(
        "Adam state of variable {index}: moments of {m} and {v} elements for a variable of \
         {expected}"
    )]
    Length {
        /// Variable index.
        index: usize,
        /// Its element count.
        expected: usize,
        /// First moment length given.
        m: usize,
        /// Second moment length given.
        v: usize,
    },
}

impl Optimizer for Adam {
    type Config = AdamParams;

    /// Fails for a variable that is not f32.
    fn new(vars: Vec<Var>, params: AdamParams) -> candle_core::Result<Self> {
        let slots = vars
            .into_iter()
            .map(|var| {
                if var.dtype() != DType::F32 {
                    candle_core::bail!(
                        "Adam: variable of dtype {:?}, only f32 is supported",
                        var.dtype()
                    );
                }
                let n = var.elem_count();
                Ok(Slot {
                    var,
                    m: vec![0.0; n],
                    v: vec![0.0; n],
                })
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Self {
            slots,
            params,
            step: 0,
        })
    }

    fn step(&mut self, grads: &GradStore) -> candle_core::Result<()> {
        self.step_norm(grads).map(|_| ())
    }

    fn learning_rate(&self) -> f64 {
        self.params.lr
    }

    fn set_learning_rate(&mut self, lr: f64) {
        self.params.lr = lr;
    }
}

/// The per-step constants, in f32 (the parameters' precision).
struct Coeffs {
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    /// lr / (1 − β₁ᵗ).
    step_size: f32,
    /// 1 / √(1 − β₂ᵗ).
    inv_sqrt_bc2: f32,
    eps: f32,
    /// λ (0 = none).
    weight_decay: f32,
}

impl Coeffs {
    /// The constants of step `step` (t, counted from 1) under `p`.
    fn at(p: &AdamParams, step: u64) -> Self {
        let t = i32::try_from(step).unwrap_or(i32::MAX);
        Self {
            beta1: p.beta1 as f32,
            beta2: p.beta2 as f32,
            one_minus_beta1: (1.0 - p.beta1) as f32,
            one_minus_beta2: (1.0 - p.beta2) as f32,
            step_size: (p.lr / (1.0 - p.beta1.powi(t))) as f32,
            inv_sqrt_bc2: (1.0 / (1.0 - p.beta2.powi(t)).sqrt()) as f32,
            eps: p.eps as f32,
            weight_decay: p.weight_decay as f32,
        }
    }
}

impl Slot {
    /// One pass: m, v and θ for this variable's gradient; returns Σ g² of the gradient (f64).
    fn apply(&mut self, grad: &Tensor, c: &Coeffs) -> candle_core::Result<f64> {
        let grad = grad.flatten_all()?.to_vec1::<f32>()?;
        let sum_sq = grad.iter().map(|&g| f64::from(g) * f64::from(g)).sum();
        let theta = self.var.as_tensor();
        let mut next = theta.flatten_all()?.to_vec1::<f32>()?;
        for (((x, m), v), g) in next.iter_mut().zip(&mut self.m).zip(&mut self.v).zip(&grad) {
            let g = g + c.weight_decay * *x;
            *m = c.beta1 * *m + c.one_minus_beta1 * g;
            *v = c.beta2 * *v + c.one_minus_beta2 * g * g;
            *x -= c.step_size * *m / (v.sqrt() * c.inv_sqrt_bc2 + c.eps);
        }
        let next = Tensor::from_vec(next, theta.shape(), theta.device())?;
        self.var.set(&next)?;
        Ok(sum_sq)
    }
}
