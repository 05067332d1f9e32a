//! The actor-side networks (φ, high policy, low policy) and batch-1 inference on CPU.
//!
//! Role: turn slices into network outputs with as little per-step overhead as candle allows:
//! inputs are concatenated into one reused scratch buffer and wrapped with `Tensor::from_slice`;
//! outputs come back as plain `Vec<f32>`. Stochastic squashing is done by the caller on those
//! vectors ([`crate::exploration`]), which saves the log-probability ops an actor never needs.
//!
//! Invariants:
//! - Two parameter sets of identical layout exist: `active` (used for acting) and `staging`.
//!   Weights are loaded into `staging`, checked (names, shapes, dtypes, finiteness), and only then
//!   swapped in, so a rejected message never changes what the actor runs.
//! - The parameter names are those of [`nets::PolicySet`] on the root of a `VarMap`, hence the
//!   layout hash equals the learner's hash of its actor-side subset.

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use nets::{seeded_var_builder, LowPolicy, NetsSpec, PolicySet};

use crate::error::{ActorError, WeightsRejection};

/// One parameter set and the modules built on it.
struct NetSlot {
    varmap: VarMap,
    set: PolicySet,
}

impl NetSlot {
    fn build(spec: &NetsSpec, seed: u64, device: &Device) -> Result<Self, ActorError> {
        let varmap = VarMap::new();
        let vb = seeded_var_builder(&varmap, seed, device);
        let set = PolicySet::new(spec, &vb)?;
        Ok(Self { varmap, set })
    }
}

/// Output of a tanh-Gaussian policy head for one input row, before sampling.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct GaussianHead {
    /// μ, one value per action dimension.
    pub mean: Vec<f32>,
    /// log σ, already clamped by the policy.
    pub log_std: Vec<f32>,
    /// Action bound: actions are `scale · tanh(μ + σ·ε)`.
    pub scale: f32,
}

/// Output of the low policy for one input row.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum LowHead {
    /// SAC: sample from the tanh-Gaussian.
    Gaussian(GaussianHead),
    /// Reference deterministic actor: the noise-free action and its bound.
    Deterministic {
        /// `scale · tanh(mlp(x))`.
        action: Vec<f32>,
        /// Action bound.
        scale: f32,
    },
}

/// φ, π_hi and π_lo of one actor, with scratch space for inputs.
pub(crate) struct ActorNets {
    active: NetSlot,
    staging: NetSlot,
    layout_hash: u64,
    device: Device,
    input: Vec<f32>,
}

impl ActorNets {
    /// Builds both parameter sets with the seeded initialisation of [`nets::init`].
    pub fn new(spec: &NetsSpec, seed: u64) -> Result<Self, ActorError> {
        let device = Device::Cpu;
        let active = NetSlot::build(spec, seed, &device)?;
        let staging = NetSlot::build(spec, seed, &device)?;
        let layout_hash = nets::layout_hash(&active.varmap);
        Ok(Self {
            active,
            staging,
            layout_hash,
            device,
            input: Vec::new(),
        })
    }

    /// Layout hash of the actor-side tensors (names and shapes).
    pub fn layout_hash(&self) -> u64 {
        self.layout_hash
    }

    /// The parameters acting now, as a `VarMap` (names under [`nets::prefix::ACTOR_SIDE`]).
    pub fn varmap(&self) -> &VarMap {
        &self.active.varmap
    }

    /// Wraps the concatenation of `parts` as a `[rows, width]` tensor (`rows` = 1 unless the
    /// parts are several rows laid out back to back).
    fn input_tensor(&mut self, parts: &[&[f32]], rows: usize) -> Result<Tensor, ActorError> {
        self.input.clear();
        for part in parts {
            self.input.extend_from_slice(part);
        }
        let width = self.input.len() / rows.max(1);
        Ok(Tensor::from_slice(
            &self.input,
            (rows, width),
            &self.device,
        )?)
    }

    /// φ of each of `rows` observations laid out back to back in `obs`; returns the latent
    /// points back to back.
    pub fn phi_rows(&mut self, obs: &[f32], rows: usize) -> Result<Vec<f32>, ActorError> {
        let x = self.input_tensor(&[obs], rows)?;
        flat(&self.active.set.encoder.forward(&x)?)
    }

    /// The high policy's Gaussian head on `[obs, goal]`.
    pub fn high_head(&mut self, obs: &[f32], goal: &[f32]) -> Result<GaussianHead, ActorError> {
        let x = self.input_tensor(&[obs, goal], 1)?;
        let high = &self.active.set.high;
        gaussian_head(high.dist(&x)?, high.scale())
    }

    /// The low policy's head on `[obs, φ(obs), subgoal]`.
    pub fn low_head(
        &mut self,
        obs: &[f32],
        phi: &[f32],
        subgoal: &[f32],
    ) -> Result<LowHead, ActorError> {
        let x = self.input_tensor(&[obs, phi, subgoal], 1)?;
        match &self.active.set.low {
            LowPolicy::Gaussian(policy) => Ok(LowHead::Gaussian(gaussian_head(
                policy.dist(&x)?,
                policy.scale(),
            )?)),
            LowPolicy::Deterministic(policy) => Ok(LowHead::Deterministic {
                action: flat(&policy.forward(&x)?)?,
                scale: policy.scale() as f32,
            }),
        }
    }

    /// Loads safetensors `bytes` into the staging set, checks every value is finite, and swaps
    /// it in. On any error the acting parameters are untouched.
    pub fn load(&mut self, bytes: &[u8]) -> Result<(), WeightsRejection> {
        nets::load_safetensors_bytes(&self.staging.varmap, bytes)?;
        check_finite(&self.staging.varmap)?;
        std::mem::swap(&mut self.active, &mut self.staging);
        Ok(())
    }
}

/// Row-major values of a tensor.
fn flat(t: &Tensor) -> Result<Vec<f32>, ActorError> {
    Ok(t.flatten_all()?.to_vec1::<f32>()?)
}

fn gaussian_head(
    (mean, log_std): (Tensor, Tensor),
    scale: f64,
) -> Result<GaussianHead, ActorError> {
    Ok(GaussianHead {
        mean: flat(&mean)?,
        log_std: flat(&log_std)?,
        scale: scale as f32,
    })
}

/// `Err` naming the first tensor (in name order) that holds NaN or infinity.
fn check_finite(varmap: &VarMap) -> Result<(), WeightsRejection> {
    let data = varmap
        .data()
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort_unstable();
    for name in names {
        let values = data[name].as_tensor().flatten_all()?.to_vec1::<f32>()?;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(WeightsRejection::NonFinite { name: name.clone() });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_distr::StandardNormal;
    use rand_pcg::Pcg64Mcg;

    use super::*;
    use crate::exploration::sample_gaussian;

    fn small_spec() -> NetsSpec {
        NetsSpec {
            obs_dim: 4,
            action_dim: 2,
            encoder_hidden: vec![16],
            high_hidden: vec![32, 32],
            low_hidden: vec![32, 32],
            low_critic_hidden: vec![32],
            low_action_scale: 1.0,
            ..NetsSpec::default()
        }
    }

    /// The actor's squashing of `dist` must be the map `GaussianPolicy::sample` applies.
    #[test]
    fn sampling_from_the_head_matches_the_policy_sample_for_the_same_noise() {
        let mut nets = ActorNets::new(&small_spec(), 5).unwrap();
        let (obs, goal) = ([0.3, -1.2, 0.5, 0.1], [4.0, 8.0]);
        let head = nets.high_head(&obs, &goal).unwrap();
        let mut ours = [0.0f32; 2];
        sample_gaussian(&head, &mut Pcg64Mcg::seed_from_u64(9), &mut ours);
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        let eps: Vec<f32> = (0..2)
            .map(|_| rand::Rng::sample(&mut rng, StandardNormal))
            .collect();
        let x = Tensor::from_slice(&[&obs[..], &goal[..]].concat(), (1, 6), &Device::Cpu).unwrap();
        let eps = Tensor::from_slice(&eps, (1, 2), &Device::Cpu).unwrap();
        let (reference, _) = nets.active.set.high.sample(&x, &eps).unwrap();
        let reference = flat(&reference).unwrap();
        for (a, b) in ours.iter().zip(&reference) {
            assert!(
                (a - b).abs() <= 1e-5 * b.abs().max(1.0),
                "ours {ours:?} vs nets {reference:?}"
            );
        }
    }

    #[test]
    fn a_rejected_load_keeps_the_acting_parameters() {
        let mut nets = ActorNets::new(&small_spec(), 5).unwrap();
        let before = nets::to_safetensors_bytes(nets.varmap()).unwrap();
        assert!(nets.load(b"not safetensors").is_err());
        assert_eq!(nets::to_safetensors_bytes(nets.varmap()).unwrap(), before);
    }
}
