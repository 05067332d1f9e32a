//! The graph-service's copy of the encoder φ: loading it from a weights message and mapping
//! stored states through it in batches (candle, CPU).
//!
//! Which weights messages are accepted: the learner publishes the actor-side set (encoder,
//! high policy, low policy; `nets::prefix::ACTOR_SIDE`) on `…/weights`. The header's layout
//! hash (as `nets::layout_hash` computes it) must equal either
//! - the hash of this service's actor-side set built from the run's config and task dims: the
//!   whole payload is loaded strictly (every tensor checked) and only φ is used; or
//! - the hash of the encoder tensors alone (`encoder.*`): a φ-only payload, loaded strictly.
//!
//! Anything else is refused with both expected hashes named. Loading goes into a fresh
//! parameter set, so a refused payload never touches the φ in use.

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use nets::{prefix, Encoder, NetsSpec, PolicySet};
use protocol::{LatentPoint, PhiVersion, Versioned, WeightsHeader};

use crate::error::GraphServiceError;

/// States per encoder forward pass when re-mapping the store: large enough to amortise the
/// call overhead, small enough that the `[rows, hidden]` activations stay a few MB.
const MAP_BATCH_ROWS: usize = 4096;

/// Builds φ's from weights messages for one network spec.
#[derive(Debug, Clone)]
pub struct PhiLoader {
    spec: NetsSpec,
    seed: u64,
    actor_side_hash: u64,
    encoder_hash: u64,
}

/// Which parameter set a weights payload holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Payload {
    ActorSide,
    EncoderOnly,
}

/// A loaded encoder and its version. The encoder's tensors share storage with the parameter
/// set they were loaded into, so they keep the loaded values after the set is dropped.
#[derive(Debug, Clone)]
pub struct Phi {
    encoder: Encoder,
    version: PhiVersion,
}

impl PhiLoader {
    /// A loader for `spec` (validated by `nets`); `seed` only fills parameters that every
    /// accepted payload overwrites.
    pub fn new(spec: NetsSpec, seed: u64) -> Result<Self, GraphServiceError> {
        let (params, _) = build_set(&spec, seed)?;
        let actor_side_hash = nets::layout_hash(&params);
        let encoder_hash = nets::layout_hash(&nets::subset(&params, &[prefix::ENCODER])?);
        Ok(Self {
            spec,
            seed,
            actor_side_hash,
            encoder_hash,
        })
    }

    /// Observation size φ expects.
    pub fn obs_dim(&self) -> usize {
        self.spec.obs_dim
    }

    /// Checks `header` (version, layout hash, length) against `bytes`.
    pub fn check(&self, header: &WeightsHeader, bytes: &[u8]) -> Result<(), GraphServiceError> {
        self.payload_kind(header, bytes).map(|_| ())
    }

    /// Loads φ from a checked weights message.
    pub fn load(&self, header: &WeightsHeader, bytes: &[u8]) -> Result<Phi, GraphServiceError> {
        let kind = self.payload_kind(header, bytes)?;
        let (params, set) = build_set(&self.spec, self.seed)?;
        match kind {
            Payload::ActorSide => nets::load_safetensors_bytes(&params, bytes)?,
            Payload::EncoderOnly => {
                nets::load_safetensors_bytes(&nets::subset(&params, &[prefix::ENCODER])?, bytes)?
            }
        }
        Ok(Phi {
            encoder: set.encoder,
            version: header.phi_version,
        })
    }

    fn payload_kind(
        &self,
        header: &WeightsHeader,
        bytes: &[u8],
    ) -> Result<Payload, GraphServiceError> {
        header.check_version()?;
        let (kind, hash) = if header.layout_hash == self.actor_side_hash {
            (Payload::ActorSide, self.actor_side_hash)
        } else if header.layout_hash == self.encoder_hash {
            (Payload::EncoderOnly, self.encoder_hash)
        } else {
            return Err(GraphServiceError::LayoutHash {
                found: header.layout_hash,
                actor_side: self.actor_side_hash,
                encoder_only: self.encoder_hash,
            });
        };
        header.check(hash, bytes.len())?;
        Ok(kind)
    }
}

/// A fresh actor-side parameter set and its networks.
fn build_set(spec: &NetsSpec, seed: u64) -> Result<(VarMap, PolicySet), GraphServiceError> {
    let params = VarMap::new();
    let vb = nets::seeded_var_builder(&params, seed, &Device::Cpu);
    let set = PolicySet::new(spec, &vb)?;
    Ok((params, set))
}

impl Phi {
    /// φ from an encoder built elsewhere (benchmarks, tests), at `version`.
    pub fn new(encoder: Encoder, version: PhiVersion) -> Self {
        Self { encoder, version }
    }

    /// Version of these weights.
    pub fn version(&self) -> PhiVersion {
        self.version
    }

    /// φ of each state in `obs` (`n × obs_dim` floats, row-major), in batches.
    pub fn map(&self, obs: &[f32]) -> Result<Vec<LatentPoint>, GraphServiceError> {
        let obs_dim = self.encoder.obs_dim();
        let mut out = Vec::with_capacity(obs.len() / obs_dim.max(1));
        for batch in obs.chunks(MAP_BATCH_ROWS * obs_dim) {
            let rows = batch.len() / obs_dim;
            let input = Tensor::from_slice(batch, (rows, obs_dim), &Device::Cpu)?;
            let latents = self.encoder.forward(&input)?.to_vec2::<f32>()?;
            out.extend(latents.into_iter().map(|row| to_point(&row)));
        }
        Ok(out)
    }
}

/// The first two coordinates of a latent row (`encoder.out_dim` is 2, checked at start-up).
fn to_point(row: &[f32]) -> LatentPoint {
    [
        row.first().copied().unwrap_or(f32::NAN),
        row.get(1).copied().unwrap_or(f32::NAN),
    ]
}
