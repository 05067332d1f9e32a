//! Multi-layer perceptrons: [`Mlp`] (one network) and [`EnsembleMlp`] (`k` networks of the
//! same shape evaluated as one batched network).
//!
//! Layers are named `l0`, `l1`, … under the network's prefix. ReLU follows every hidden layer;
//! the output layer is linear, except for a trunk ([`Mlp::trunk`]), which ends on a ReLU
//! because heads follow it.
//!
//! Invariants: every size is positive (checked at construction, `NetsError::Spec`); inputs are
//! checked by the first layer, so a wrong input size names `<prefix>.l0`.

use candle_core::Tensor;
use candle_nn::VarBuilder;

use crate::error::{NetsError, Result};
use crate::init::LinearInit;
use crate::linear::{EnsembleLinear, Linear};

/// `h₀ = x`, `hᵢ₊₁ = relu(Lᵢ(hᵢ))` for the hidden layers, `y = L_last(h)` (or `relu(L_last(h))`
/// for a trunk). Shapes: `x: [batch, in]` → `y: [batch, out]`.
#[derive(Clone, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
    relu_last: bool,
}

impl Mlp {
    /// `in → hidden[0] → … → hidden[n−1] → out`, ReLU after each hidden layer, linear output.
    pub fn new(
        vb: &VarBuilder,
        in_dim: usize,
        hidden: &[usize],
        out_dim: usize,
        init: LinearInit,
    ) -> Result<Self> {
        let dims = layer_dims(&vb.prefix(), in_dim, hidden, Some(out_dim))?;
        Self::build(vb, &dims, init, false)
    }

    /// `in → hidden[0] → … → hidden[n−1]`, ReLU after every layer (a trunk that heads follow).
    /// `hidden` must not be empty.
    pub fn trunk(
        vb: &VarBuilder,
        in_dim: usize,
        hidden: &[usize],
        init: LinearInit,
    ) -> Result<Self> {
        let dims = layer_dims(&vb.prefix(), in_dim, hidden, None)?;
        Self::build(vb, &dims, init, true)
    }

    fn build(vb: &VarBuilder, dims: &[usize], init: LinearInit, relu_last: bool) -> Result<Self> {
        let layers = dims
            .windows(2)
            .enumerate()
            .map(|(i, w)| Linear::new(&vb.pp(format!("l{i}")), w[0], w[1], init))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { layers, relu_last })
    }

    /// `[batch, in]` → `[batch, out]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let last = self.layers.len() - 1;
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            if i < last || self.relu_last {
                h = h.relu()?;
            }
        }
        Ok(h)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.layers[0].in_dim()
    }

    /// Output features.
    pub fn out_dim(&self) -> usize {
        self.layers[self.layers.len() - 1].out_dim()
    }

    /// The layers, first to last.
    pub fn layers(&self) -> &[Linear] {
        &self.layers
    }
}

/// `k` MLPs of identical shape, stacked: layer `lᵢ` holds `weight [k, outᵢ, inᵢ]` and
/// `bias [k, outᵢ]`. Input `[batch, in]` (shared by all members) or `[k, batch, in]`;
/// output `[k, batch, out]`. ReLU after each hidden layer, linear output.
#[derive(Clone, Debug)]
pub struct EnsembleMlp {
    layers: Vec<EnsembleLinear>,
}

impl EnsembleMlp {
    /// `k` networks `in → hidden… → out`.
    pub fn new(
        vb: &VarBuilder,
        members: usize,
        in_dim: usize,
        hidden: &[usize],
        out_dim: usize,
        init: LinearInit,
    ) -> Result<Self> {
        if members == 0 {
            return Err(NetsError::Spec(format!(
                "{}: an ensemble needs at least one member",
                vb.prefix()
            )));
        }
        let dims = layer_dims(&vb.prefix(), in_dim, hidden, Some(out_dim))?;
        let layers = dims
            .windows(2)
            .enumerate()
            .map(|(i, w)| EnsembleLinear::new(&vb.pp(format!("l{i}")), members, w[0], w[1], init))
            .collect::<Result<Vec<_>>>()?;
        Ok(Self { layers })
    }

    /// `[batch, in]` or `[k, batch, in]` → `[k, batch, out]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let last = self.layers.len() - 1;
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            if i < last {
                h = h.relu()?;
            }
        }
        Ok(h)
    }

    /// Number of members `k`.
    pub fn members(&self) -> usize {
        self.layers[0].members()
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.layers[0].in_dim()
    }

    /// Output features.
    pub fn out_dim(&self) -> usize {
        self.layers[self.layers.len() - 1].out_dim()
    }
}

/// The layer widths `[in, hidden…, out?]`, all positive; at least one layer.
fn layer_dims(
    name: &str,
    in_dim: usize,
    hidden: &[usize],
    out_dim: Option<usize>,
) -> Result<Vec<usize>> {
    let mut dims = Vec::with_capacity(hidden.len() + 2);
    dims.push(in_dim);
    dims.extend_from_slice(hidden);
    dims.extend(out_dim);
    if dims.len() < 2 {
        return Err(NetsError::Spec(format!(
            "{name}: a trunk needs at least one hidden layer"
        )));
    }
    if dims.contains(&0) {
        return Err(NetsError::Spec(format!(
            "{name}: every layer width must be positive, got {dims:?}"
        )));
    }
    Ok(dims)
}
