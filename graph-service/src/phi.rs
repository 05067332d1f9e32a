//! The graph-service's copy of the encoder φ: loading it from a weights message and mapping
//! stored states through it (the fused CPU forward of [`crate::fused`], bit-identical to the
//! candle encoder on the default network; a re-map splits the store over scoped threads).
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
//!
//! A loaded φ keeps its encoder tensors as safetensors bytes ([`Phi::encoder_weights`]), which
//! graph-service checkpoints save and [`PhiLoader::restore`] loads back (strictly).

use candle_core::Device;
use candle_nn::VarMap;
use nets::{prefix, Encoder, NetsSpec, PolicySet};
use protocol::{LatentPoint, PhiVersion, Versioned, WeightsHeader};

use crate::error::GraphServiceError;
use crate::fused::{FusedMlp, Scratch};

/// Fewest rows worth a thread of their own in [`Phi::map_all`] (a thread costs tens of µs;
/// this many rows take about a millisecond).
const MIN_ROWS_PER_THREAD: usize = 16_384;

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

/// A loaded encoder, its fused copy for mapping ([`crate::fused`]) and its version. The
/// encoder's tensors share storage with the parameter set they were loaded into, so they keep
/// the loaded values after the set is dropped.
#[derive(Debug, Clone)]
pub struct Phi {
    encoder: Encoder,
    fused: FusedMlp,
    version: PhiVersion,
    /// The encoder tensors as safetensors bytes, when loaded by a [`PhiLoader`].
    encoder_weights: Option<Vec<u8>>,
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
        let encoder_params = nets::subset(&params, &[prefix::ENCODER])?;
        match kind {
            Payload::ActorSide => nets::load_safetensors_bytes(&params, bytes)?,
            Payload::EncoderOnly => nets::load_safetensors_bytes(&encoder_params, bytes)?,
        }
        let mut phi = Phi::new(set.encoder, header.phi_version)?;
        phi.encoder_weights = Some(nets::to_safetensors_bytes(&encoder_params)?);
        Ok(phi)
    }

    /// φ at `version` from encoder tensors saved by a checkpoint ([`Phi::encoder_weights`]),
    /// loaded strictly (every tensor of this config's encoder, with its shape).
    pub fn restore(
        &self,
        encoder_weights: &[u8],
        version: PhiVersion,
    ) -> Result<Phi, GraphServiceError> {
        let (params, set) = build_set(&self.spec, self.seed)?;
        nets::load_safetensors_bytes(&nets::subset(&params, &[prefix::ENCODER])?, encoder_weights)?;
        let mut phi = Phi::new(set.encoder, version)?;
        phi.encoder_weights = Some(encoder_weights.to_vec());
        Ok(phi)
    }

    /// φ at `version` with this loader's seeded initial parameters (benchmarks, tests), its
    /// encoder tensors kept like a loaded one's.
    pub fn seeded(&self, version: PhiVersion) -> Result<Phi, GraphServiceError> {
        let (params, set) = build_set(&self.spec, self.seed)?;
        let mut phi = Phi::new(set.encoder, version)?;
        phi.encoder_weights = Some(nets::to_safetensors_bytes(&nets::subset(
            &params,
            &[prefix::ENCODER],
        )?)?);
        Ok(phi)
    }

    /// Layout hash of this config's encoder tensors alone.
    pub fn encoder_hash(&self) -> u64 {
        self.encoder_hash
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
    pub fn new(encoder: Encoder, version: PhiVersion) -> Result<Self, GraphServiceError> {
        let fused = FusedMlp::from_mlp(encoder.mlp())?;
        Ok(Self {
            encoder,
            fused,
            version,
            encoder_weights: None,
        })
    }

    /// The encoder tensors as safetensors bytes; `None` for a φ built with [`Phi::new`].
    pub fn encoder_weights(&self) -> Option<&[u8]> {
        self.encoder_weights.as_deref()
    }

    /// Version of these weights.
    pub fn version(&self) -> PhiVersion {
        self.version
    }

    /// The candle encoder these weights were loaded into (the reference for [`Phi::map`]).
    pub fn encoder(&self) -> &Encoder {
        &self.encoder
    }

    /// The fused copy that [`Phi::map`] and [`Phi::map_all`] run.
    pub fn fused(&self) -> &FusedMlp {
        &self.fused
    }

    /// φ of each state in `obs` (`n × obs_dim` floats, row-major), on this thread.
    pub fn map(&self, obs: &[f32]) -> Result<Vec<LatentPoint>, GraphServiceError> {
        let mut out = Vec::new();
        self.fused
            .map_into(obs, &mut out, &mut Scratch::default())?;
        Ok(out)
    }

    /// [`Phi::map`] of every batch, the batches split into at most `n_threads` contiguous groups
    /// of about equal rows, one scoped thread each (the calling thread takes the first group).
    /// The result does not depend on `n_threads`: every row is mapped by the same code.
    pub fn map_all(
        &self,
        batches: &[&[f32]],
        n_threads: usize,
    ) -> Result<Vec<Vec<LatentPoint>>, GraphServiceError> {
        let groups = split_evenly(
            batches,
            n_threads.max(1),
            MIN_ROWS_PER_THREAD * self.fused.in_dim(),
        );
        let map_group = |group: &[&[f32]]| -> Result<Vec<Vec<LatentPoint>>, GraphServiceError> {
            let mut scratch = Scratch::default();
            group
                .iter()
                .map(|obs| {
                    let mut out = Vec::new();
                    self.fused.map_into(obs, &mut out, &mut scratch)?;
                    Ok(out)
                })
                .collect()
        };
        let results: Vec<Result<Vec<Vec<LatentPoint>>, GraphServiceError>> =
            std::thread::scope(|scope| {
                let (first, rest) = match groups.split_first() {
                    Some((first, rest)) => (*first, rest),
                    None => (&batches[..0], &[][..]),
                };
                let handles: Vec<_> = rest
                    .iter()
                    .map(|group| scope.spawn(move || map_group(group)))
                    .collect();
                let mut results = vec![map_group(first)];
                results.extend(handles.into_iter().map(|handle| {
                    handle.join().unwrap_or_else(|_| {
                        Err(GraphServiceError::Internal(
                            "a φ mapping thread panicked".to_owned(),
                        ))
                    })
                }));
                results
            });
        let mut all = Vec::with_capacity(batches.len());
        for result in results {
            all.extend(result?);
        }
        Ok(all)
    }
}

/// `batches` cut into at most `n_groups` contiguous groups of about equal floats; groups
/// smaller than `min_floats` are not worth a thread, so fewer groups are made for small inputs.
fn split_evenly<'a, 'b>(
    batches: &'b [&'a [f32]],
    n_groups: usize,
    min_floats: usize,
) -> Vec<&'b [&'a [f32]]> {
    let total: usize = batches.iter().map(|b| b.len()).sum();
    let n_groups = n_groups.min(total / min_floats.max(1)).max(1);
    let mut groups = Vec::with_capacity(n_groups);
    let (mut start, mut seen) = (0, 0);
    for (i, batch) in batches.iter().enumerate() {
        seen += batch.len();
        // Close group g once the running total reaches (g + 1) / n_groups of the whole.
        if groups.len() + 1 < n_groups && seen * n_groups >= (groups.len() + 1) * total {
            groups.push(&batches[start..=i]);
            start = i + 1;
        }
    }
    groups.push(&batches[start..]);
    groups
}

#[cfg(test)]
mod tests {
    use candle_core::Tensor;
    use protocol::Config;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    use super::*;
    use crate::bench::random_phi;

    fn random_obs(rows: usize, dim: usize, seed: u64) -> Vec<f32> {
        let mut rng = Pcg64::seed_from_u64(seed);
        (0..rows * dim)
            .map(|_| rng.random_range(-5.0..5.0))
            .collect()
    }

    /// The previous map: candle's encoder on 4096-row batches.
    fn candle_map(phi: &Phi, obs: &[f32]) -> Vec<LatentPoint> {
        let dim = phi.encoder().obs_dim();
        obs.chunks(4096 * dim)
            .flat_map(|batch| {
                let input =
                    Tensor::from_slice(batch, (batch.len() / dim, dim), &Device::Cpu).unwrap();
                let rows = phi
                    .encoder()
                    .forward(&input)
                    .unwrap()
                    .to_vec2::<f32>()
                    .unwrap();
                rows.into_iter().map(|r| [r[0], r[1]])
            })
            .collect()
    }

    fn bits(points: &[LatentPoint]) -> Vec<[u32; 2]> {
        points
            .iter()
            .map(|p| [p[0].to_bits(), p[1].to_bits()])
            .collect()
    }

    #[test]
    fn the_map_gives_the_candle_encoders_bits_for_the_default_network() {
        let phi = random_phi(&Config::default(), 29, 7).unwrap();
        let obs = random_obs(5_000, 29, 8);
        assert_eq!(bits(&phi.map(&obs).unwrap()), bits(&candle_map(&phi, &obs)));
    }

    #[test]
    fn the_threaded_map_is_bit_identical_to_the_single_threaded_one() {
        let phi = random_phi(&Config::default(), 29, 9).unwrap();
        let mut rng = Pcg64::seed_from_u64(10);
        // Uneven batch sizes, empty ones included, enough rows for several threads.
        let sizes: Vec<usize> = (0..60)
            .map(|i| {
                if i % 7 == 0 {
                    0
                } else {
                    rng.random_range(1..2_000)
                }
            })
            .collect();
        let owned: Vec<Vec<f32>> = sizes
            .iter()
            .enumerate()
            .map(|(i, &n)| random_obs(n, 29, 100 + i as u64))
            .collect();
        let batches: Vec<&[f32]> = owned.iter().map(Vec::as_slice).collect();
        let single: Vec<Vec<[u32; 2]>> =
            batches.iter().map(|b| bits(&phi.map(b).unwrap())).collect();
        for n_threads in [1, 2, 3, 8] {
            let threaded = phi.map_all(&batches, n_threads).unwrap();
            let threaded: Vec<Vec<[u32; 2]>> = threaded.iter().map(|p| bits(p)).collect();
            assert_eq!(threaded, single, "{n_threads} threads");
        }
        assert_eq!(phi.map_all(&[], 4).unwrap(), Vec::<Vec<LatentPoint>>::new());
    }

    #[test]
    fn a_ragged_batch_is_an_error_from_any_thread() {
        let phi = random_phi(&Config::default(), 29, 11).unwrap();
        let good = random_obs(MIN_ROWS_PER_THREAD * 2, 29, 12);
        let bad = vec![0.0; 30];
        let err = phi.map_all(&[&good, &good, &bad], 3).unwrap_err();
        assert!(
            matches!(
                err,
                GraphServiceError::ObsLength {
                    len: 30,
                    obs_dim: 29
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn batches_split_into_contiguous_groups_of_about_equal_size() {
        let data = vec![0.0f32; 100];
        let batches: Vec<&[f32]> = (0..10).map(|_| &data[..10]).collect();
        let groups = split_evenly(&batches, 3, 1);
        assert_eq!(
            groups.iter().map(|g| g.len()).collect::<Vec<_>>(),
            [4, 3, 3]
        );
        assert_eq!(
            split_evenly(&batches, 3, 60).len(),
            1,
            "100 floats make one group of ≥ 60"
        );
        assert_eq!(split_evenly(&batches, 1, 1).len(), 1);
        assert_eq!(split_evenly(&[], 4, 1), vec![&[] as &[&[f32]]]);
    }
}
