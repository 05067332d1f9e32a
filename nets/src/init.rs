//! Parameter initialisation: the two schemes the reference code uses, and a seeded
//! [`VarBuilder`] backend so that a run is reproducible from its seed.
//!
//! Invariants:
//! - Initial values are produced only when a name is first requested; a name that already
//!   exists in the [`VarMap`] is returned as is (after a shape check), exactly like
//!   `VarBuilder::from_varmap`. Building the same network twice on one map therefore shares
//!   its parameters.
//! - With [`seeded_var_builder`], the values depend only on the seed and on the order in which
//!   parameters are requested (construction order), never on the thread or the machine.
//!   candle's own CPU generator cannot be seeded (`Device::set_seed` fails on CPU), hence this
//!   backend.

use std::sync::Mutex;

use candle_core::{DType, Device, Shape, Tensor, Var};
use candle_nn::var_builder::SimpleBackend;
use candle_nn::{Init, VarBuilder, VarMap};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

/// How a dense layer's parameters are initialised.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LinearInit {
    /// Xavier/Glorot uniform with gain 1 and a zero bias:
    /// `W ~ U(−a, a)`, `a = √(6 / (fan_in + fan_out))`, `b = 0`.
    /// Source: the reference SAC networks (`algos/sac`, `weights_init_`), digest §3.1.
    XavierUniform,
    /// PyTorch's `nn.Linear` default: `kaiming_uniform_(a = √5)` on the weight, which works out
    /// to `W ~ U(−1/√fan_in, 1/√fan_in)`, and `b ~ U(−1/√fan_in, 1/√fan_in)`.
    /// Source: the reference encoder φ and deterministic low level, digest §3.2 and §4.
    TorchDefault,
}

impl LinearInit {
    /// The initialiser of a weight with the given fans (`[.., fan_out, fan_in]`).
    pub fn weight(self, fan_in: usize, fan_out: usize) -> Init {
        let bound = match self {
            Self::XavierUniform => (6.0 / (fan_in + fan_out) as f64).sqrt(),
            Self::TorchDefault => 1.0 / (fan_in as f64).sqrt(),
        };
        Init::Uniform {
            lo: -bound,
            up: bound,
        }
    }

    /// The initialiser of a bias of a layer with `fan_in` inputs.
    pub fn bias(self, fan_in: usize) -> Init {
        match self {
            Self::XavierUniform => Init::Const(0.0),
            Self::TorchDefault => {
                let bound = 1.0 / (fan_in as f64).sqrt();
                Init::Uniform {
                    lo: -bound,
                    up: bound,
                }
            }
        }
    }
}

/// A `VarBuilder` over `varmap` (f32 on `device`) whose new parameters are drawn from a PCG
/// generator seeded with `seed`. Supports the `Init::Const` and `Init::Uniform` hints, which are
/// the only ones [`LinearInit`] produces; any other hint is an error naming the parameter.
pub fn seeded_var_builder(varmap: &VarMap, seed: u64, device: &Device) -> VarBuilder<'static> {
    let backend = SeededVarMap {
        varmap: varmap.clone(),
        rng: Mutex::new(Pcg64Mcg::seed_from_u64(seed)),
    };
    VarBuilder::from_backend(Box::new(backend), DType::F32, device.clone())
}

/// A `VarMap` backend that draws new parameters from a seeded generator.
struct SeededVarMap {
    varmap: VarMap,
    rng: Mutex<Pcg64Mcg>,
}

impl SeededVarMap {
    /// Draws the initial value of `name` from the hint `init`.
    fn sample(
        &self,
        shape: &Shape,
        name: &str,
        init: Init,
        device: &Device,
    ) -> candle_core::Result<Tensor> {
        let n = shape.elem_count();
        let values: Vec<f32> = match init {
            Init::Const(c) => vec![c as f32; n],
            Init::Uniform { lo, up } => {
                let mut rng = self.rng.lock().map_err(|_| {
                    candle_core::Error::Msg("seeded init: RNG mutex poisoned".into())
                })?;
                (0..n)
                    .map(|_| (lo + (up - lo) * rng.random::<f64>()) as f32)
                    .collect()
            }
            other => candle_core::bail!(
                "seeded init of `{name}`: only Const and Uniform hints are supported, got {other:?}"
            ),
        };
        Tensor::from_vec(values, shape.clone(), device)
    }
}

impl SimpleBackend for SeededVarMap {
    fn get(
        &self,
        shape: Shape,
        name: &str,
        init: Init,
        dtype: DType,
        device: &Device,
    ) -> candle_core::Result<Tensor> {
        let mut data = self
            .varmap
            .data()
            .lock()
            .map_err(|_| candle_core::Error::Msg("VarMap mutex poisoned".into()))?;
        if let Some(var) = data.get(name) {
            if var.shape() != &shape {
                candle_core::bail!(
                    "shape mismatch on {name}: requested {shape:?}, stored {:?}",
                    var.shape()
                )
            }
            return Ok(var.as_tensor().clone());
        }
        let value = self.sample(&shape, name, init, device)?.to_dtype(dtype)?;
        let var = Var::from_tensor(&value)?;
        let tensor = var.as_tensor().clone();
        data.insert(name.to_string(), var);
        Ok(tensor)
    }

    fn get_unchecked(
        &self,
        name: &str,
        _dtype: DType,
        _device: &Device,
    ) -> candle_core::Result<Tensor> {
        candle_core::bail!(
            "`get_unchecked({name})` is not supported by the seeded VarMap backend, use `get`"
        )
    }

    fn contains_tensor(&self, name: &str) -> bool {
        self.varmap
            .data()
            .lock()
            .map(|d| d.contains_key(name))
            .unwrap_or(false)
    }
}
