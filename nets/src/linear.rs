//! Dense layers with named parameters: [`Linear`] and its stacked form [`EnsembleLinear`].
//!
//! Parameters live in a [`VarBuilder`] under the layer's prefix as `weight` and `bias`, so they
//! travel as safetensors with stable names.
//!
//! Why not `candle_nn::Linear`: it adds the bias with `broadcast_add`, whose backward pass
//! reduces the output gradient with a strided `sum_keepdim(0)`. Here the bias enters as a
//! rank-1 matrix product `1 · bᵀ` (a `[batch, 1] × [1, out]` matmul), so its gradient
//! `1ᵀ · ∂L/∂y` is computed by gemm as well. On this 2-core dev machine `sum_keepdim(0)` of a
//! `[128, 256]` gradient took ~650 µs against ~5 µs for the `1ᵀ · G` gemm, and
//! `examples/bench_forward.rs` (forward + backward, 33 → 2 × 256 → 8, batch 128, one thread)
//! measured `candle_nn::Linear` 1.04–1.41× slower than this layer over five loaded runs.
//! Folding the bias into an augmented weight `[W | b]` was measured too and was slower than
//! this form: it copies both the input and the weight every call.
//!
//! Invariants: inputs are checked for rank and feature size before any arithmetic, and errors
//! name the layer by its parameter prefix.

use candle_core::Tensor;
use candle_nn::VarBuilder;

use crate::error::{NetsError, Result};
use crate::init::LinearInit;

/// `y = x Wᵀ + b` with `x: [batch, in]`, `W: [out, in]` (`weight`), `b: [out]` (`bias`),
/// `y: [batch, out]`.
#[derive(Clone, Debug)]
pub struct Linear {
    weight: Tensor,
    bias: Tensor,
    /// The bias as a `[1, out]` row (a view of `bias`), ready for the `1 · bᵀ` product.
    bias_row: Tensor,
    name: String,
    in_dim: usize,
    out_dim: usize,
}

impl Linear {
    /// Creates (or fetches, if the names exist) `weight [out, in]` and `bias [out]` under `vb`.
    pub fn new(vb: &VarBuilder, in_dim: usize, out_dim: usize, init: LinearInit) -> Result<Self> {
        let weight =
            vb.get_with_hints((out_dim, in_dim), "weight", init.weight(in_dim, out_dim))?;
        let bias = vb.get_with_hints(out_dim, "bias", init.bias(in_dim))?;
        let bias_row = bias.unsqueeze(0)?;
        Ok(Self {
            weight,
            bias,
            bias_row,
            name: vb.prefix(),
            in_dim,
            out_dim,
        })
    }

    /// Applies the layer to `x: [batch, in]`, giving `[batch, out]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let batch = check_matrix(&self.name, x, self.in_dim)?;
        let xw = x.matmul(&self.weight.t()?)?;
        let ones = Tensor::ones((batch, 1), x.dtype(), x.device())?;
        Ok(xw.add(&ones.matmul(&self.bias_row)?)?)
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.in_dim
    }

    /// Output features.
    pub fn out_dim(&self) -> usize {
        self.out_dim
    }

    /// The weight `W: [out, in]`.
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    /// The bias `b: [out]`.
    pub fn bias(&self) -> &Tensor {
        &self.bias
    }

    /// The parameter prefix, e.g. `high_policy.trunk.l0`.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// `k` independent dense layers evaluated together:
/// `y[j] = x[j] W[j]ᵀ + b[j]` for `j < k`, with `W: [k, out, in]` (`weight`),
/// `b: [k, out]` (`bias`).
///
/// Input either `[k, batch, in]` (one input per member) or `[batch, in]` (the same input for
/// every member, computed as one `[batch, in] × [in, k·out]` gemm); output `[k, batch, out]`.
/// Each member is initialised as an independent `Linear(in, out)` (fans `in` and `out`).
#[derive(Clone, Debug)]
pub struct EnsembleLinear {
    weight: Tensor,
    bias: Tensor,
    name: String,
    members: usize,
    in_dim: usize,
    out_dim: usize,
}

impl EnsembleLinear {
    /// Creates (or fetches) `weight [k, out, in]` and `bias [k, out]` under `vb`.
    pub fn new(
        vb: &VarBuilder,
        members: usize,
        in_dim: usize,
        out_dim: usize,
        init: LinearInit,
    ) -> Result<Self> {
        let w_shape = (members, out_dim, in_dim);
        let weight = vb.get_with_hints(w_shape, "weight", init.weight(in_dim, out_dim))?;
        let bias = vb.get_with_hints((members, out_dim), "bias", init.bias(in_dim))?;
        Ok(Self {
            weight,
            bias,
            name: vb.prefix(),
            members,
            in_dim,
            out_dim,
        })
    }

    /// Applies every member: `[batch, in]` or `[k, batch, in]` → `[k, batch, out]`.
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        match x.rank() {
            2 => self.forward_shared(x),
            3 => self.forward_stacked(x),
            _ => Err(NetsError::Rank {
                layer: self.name.clone(),
                expected: 3,
                expected_shape: format!(
                    "[{}, batch, {}] or [batch, {}]",
                    self.members, self.in_dim, self.in_dim
                ),
                got: x.dims().to_vec(),
            }),
        }
    }

    /// Same input for all members: `[batch, in] × [in, k·out]`, then split the columns.
    fn forward_shared(&self, x: &Tensor) -> Result<Tensor> {
        let batch = check_matrix(&self.name, x, self.in_dim)?;
        let (k, out) = (self.members, self.out_dim);
        let w_all = self.weight.reshape((k * out, self.in_dim))?;
        let ones = Tensor::ones((batch, 1), x.dtype(), x.device())?;
        let b_all = self.bias.reshape((1, k * out))?;
        let y = x.matmul(&w_all.t()?)?.add(&ones.matmul(&b_all)?)?;
        Ok(y.reshape((batch, k, out))?.transpose(0, 1)?)
    }

    /// One input per member: a batched matmul over the leading `k` axis.
    fn forward_stacked(&self, x: &Tensor) -> Result<Tensor> {
        let dims = x.dims();
        if dims[0] != self.members {
            return Err(self.dim_error("ensemble size", self.members, dims[0], dims));
        }
        if dims[2] != self.in_dim {
            return Err(self.dim_error("input features", self.in_dim, dims[2], dims));
        }
        let ones = Tensor::ones((self.members, dims[1], 1), x.dtype(), x.device())?;
        let xw = x.matmul(&self.weight.transpose(1, 2)?)?;
        Ok(xw.add(&ones.matmul(&self.bias.unsqueeze(1)?)?)?)
    }

    fn dim_error(
        &self,
        what: &'static str,
        expected: usize,
        got: usize,
        shape: &[usize],
    ) -> NetsError {
        NetsError::Dim {
            layer: self.name.clone(),
            what,
            expected,
            got,
            shape: shape.to_vec(),
        }
    }

    /// Number of members `k`.
    pub fn members(&self) -> usize {
        self.members
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.in_dim
    }

    /// Output features.
    pub fn out_dim(&self) -> usize {
        self.out_dim
    }
}

/// Checks that `x` is `[batch, in_dim]` and returns `batch`.
pub(crate) fn check_matrix(layer: &str, x: &Tensor, in_dim: usize) -> Result<usize> {
    match *x.dims() {
        [batch, features] if features == in_dim => Ok(batch),
        [_, features] => Err(NetsError::Dim {
            layer: layer.to_string(),
            what: "input features",
            expected: in_dim,
            got: features,
            shape: x.dims().to_vec(),
        }),
        _ => Err(NetsError::Rank {
            layer: layer.to_string(),
            expected: 2,
            expected_shape: format!("[batch, {in_dim}]"),
            got: x.dims().to_vec(),
        }),
    }
}
