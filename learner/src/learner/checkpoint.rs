//! Learner checkpoints: everything a [`Learner`] needs to continue as if uninterrupted —
//! network weights, Adam states, counters, the run schedule, generator states, both replay
//! buffers and the φ store — written to `checkpoints/ckpt-NNNNNN/` under the run folder.
//!
//! Layout of one checkpoint folder (each file is one entry of [`PARTS`]):
//!
//! | file | contents |
//! |---|---|
//! | `policy.safetensors` | published parameters (encoder, high and low policies) |
//! | `critic.safetensors`, `target.safetensors` | online and target critics (and the deterministic low level's target actor) |
//! | `optim.safetensors` | Adam m and v of every optimiser, log α; step counts in metadata |
//! | `replay_low.safetensors`, `replay_high.safetensors` | buffer columns, rows `0..len` (next observations only where they are not the next row's: [`LOW_SUCCESSORS`]); ring in metadata |
//! | `phi_store.safetensors` | φ store runs (observations, priorities); run lengths and stats in metadata |
//! | `si.safetensors` | self-imitation buffer (entries — their observations as indices into the φ store's where it holds them: [`shared`] —, episode serials, start states); due rounds and counters in metadata |
//! | `state.json` | counters, publication bookkeeping, schedule, generators, φ trainer scalars |
//! | `manifest.json` | format and protocol versions, layout hash, config fingerprint, size and checksum of each file above |
//!
//! Invariants:
//! - Atomic: the files are written into `.tmp-ckpt-NNNNNN/`, synced, then the folder is renamed;
//!   a folder named `ckpt-*` is complete. Only the newest [`KEEP`] checkpoints are kept.
//!   The folder, checksum and safetensors work is the `ckpt` crate's (shared with the
//!   graph-service's checkpoints).
//! - All or nothing: a restore checks the manifest (versions, layout, config), then the size
//!   and checksum of every file, then parses every file into a fresh learner; any problem is an
//!   error naming the file, and no learner is returned.
//! - Taken between φ rounds only ([`CheckpointError::RoundActive`]): a round's sampling state
//!   is not saved, so the φ store is thawed and holds no staged run when one is written.
//! - Not saved (by design): the open episodes of the ingest (a resumed run starts new
//!   episodes; chunks of old ones are counted as lost) and timing telemetry (metrics only).
//!   The latest SAC, φ and SI statistics are saved (`state.json`, `telemetry`), so that the
//!   metrics after a resume are those of an uninterrupted run; a checkpoint without them (an
//!   older build, or a value that was not finite) restores them as zeros.
//!
//! Extension: a new piece of state adds one [`Part`] to [`PARTS`] — a file name, a function
//! that serialises it and one that restores it into a fresh learner.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use protocol::{Config, PhiVersion, PolicyVersion, RunSchedule, PROTOCOL_VERSION};
use rand_pcg::Pcg64Mcg;
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};

use ckpt::{array, meta, parse as parse_safetensors, serialize, TmpFolder};
pub use ckpt::{checksum, Checksum, FileEntry, FileError};

use super::{IngestStats, Learner, PublishState};
use crate::adam::{Adam, AdamState};
use crate::deterministic::DeterministicStats;
use crate::error::LearnerError;
use crate::ingest::Episodes;
use crate::phi::losses::TripletStats;
use crate::phi::store::StoreStats;
use crate::replay::{Column, Ring};
use crate::sac::SacStats;
use crate::si::losses::SiLossStats;
use crate::si::{SiBuffer, SiBufferParts, SiStats};
use nets::TaskDims;

mod shared;

/// Version of the checkpoint format; a newer one is refused. Format 3 writes the replay
/// buffers' next observations only where they are not the next row's observation
/// ([`LOW_SUCCESSORS`]); format 2 wrote them whole, as format 1, which also checksummed with
/// [`ckpt::fingerprint`] (see [`ckpt::Checksum`]). All three are read.
pub const FORMAT_VERSION: u32 = 3;
/// Name of the manifest inside a checkpoint folder.
pub const MANIFEST: &str = "manifest.json";
/// Checkpoints kept in `checkpoints/` (older ones are removed after a new one is written).
pub const KEEP: usize = 2;
/// Folder name prefix of a complete checkpoint (`ckpt-` + 6-digit sequence number).
const PREFIX: &str = "ckpt-";
/// Folder name prefix of a checkpoint being written.
const TMP_PREFIX: &str = ".tmp-ckpt-";

/// Why a checkpoint could not be written or restored.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// A file could not be read or written, is corrupt, or the checkpoint is incompatible
    /// (another format, protocol, network layout or config).
    #[error(transparent)]
    File(#[from] FileError),
    /// A φ round is running; its sampling state is not saved (try again after the round).
    #[error("no checkpoint while a φ round runs; retry when the round has finished")]
    RoundActive,
    /// Building the fresh learner failed.
    #[error(transparent)]
    Learner(#[from] LearnerError),
}

/// `manifest.json`: what a checkpoint is and how to check it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// [`PROTOCOL_VERSION`] of the writer.
    pub protocol_version: u32,
    /// Layout hash of the published parameters ([`Learner::weights_layout_hash`]).
    pub layout_hash: u64,
    /// [`config_fingerprint`] of the writer's config, 16 hex digits.
    pub config_fingerprint: String,
    /// Sequence number N of `ckpt-N` (1 for the first checkpoint of a run).
    pub sequence: u64,
    /// Env steps ingested when it was written.
    pub env_steps: u64,
    /// Low-level updates run when it was written.
    pub updates_low: u64,
    /// High-level updates run when it was written.
    pub updates_high: u64,
    /// Episodes completed when it was written (`None` in checkpoints of builds before it was
    /// recorded; it is read back for the launch's "already finished" check only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub episodes_completed: Option<u64>,
    /// Every other file of the folder.
    pub files: Vec<FileEntry>,
}

impl Manifest {
    /// Total size of the listed files in bytes.
    pub fn total_bytes(&self) -> u64 {
        self.files.iter().map(|f| f.bytes).sum()
    }
}

/// A checkpoint on disk: its folder and manifest.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Checkpoint {
    /// The `ckpt-N` folder.
    pub path: PathBuf,
    /// Its manifest.
    pub manifest: Manifest,
}

/// Fingerprint of the config sections that shape the learner's state — `env`, `hierarchy`,
/// `learner`, `replay`, `encoder` — as [`ckpt::fingerprint`] of their JSON. Other sections (run
/// length, seeds, exploration, graph, evaluation, transport) may change on resume, and so may
/// `encoder.background_rounds`: where a round runs is not part of the state (and checkpoints
/// written before the key existed keep their fingerprint).
pub fn config_fingerprint(config: &Config) -> String {
    let mut sections = serde_json::json!({
        "env": config.env,
        "hierarchy": config.hierarchy,
        "learner": config.learner,
        "replay": config.replay,
        "encoder": config.encoder,
    });
    if let Some(encoder) = sections
        .get_mut("encoder")
        .and_then(serde_json::Value::as_object_mut)
    {
        encoder.remove("background_rounds");
    }
    format!(
        "{:016x}",
        ckpt::fingerprint(sections.to_string().as_bytes())
    )
}

/// The newest complete checkpoint in `dir` (a run's `checkpoints/`), if any; `None` when the
/// folder does not exist.
pub fn latest_checkpoint(dir: &Path) -> Result<Option<PathBuf>, CheckpointError> {
    Ok(list_checkpoints(dir)?.pop().map(|(_, path)| path))
}

/// Complete checkpoints in `dir`, oldest first, with their sequence numbers.
fn list_checkpoints(dir: &Path) -> Result<Vec<(u64, PathBuf)>, CheckpointError> {
    Ok(ckpt::list(dir, PREFIX)?)
}

fn corrupt(path: &Path, problem: impl Into<String>) -> CheckpointError {
    ckpt::corrupt(path, problem).into()
}

/// One piece of learner state and its file.
struct Part {
    /// File name inside the checkpoint folder.
    file: &'static str,
    /// The file's contents for this learner.
    save: fn(&Learner) -> Result<Vec<u8>, String>,
    /// Restores the piece into a fresh learner built from the same config; the error says
    /// what is wrong with the contents.
    restore: fn(&mut Learner, &[u8]) -> Result<(), String>,
}

/// Every piece of state a checkpoint carries (see the module doc).
const PARTS: &[Part] = &[
    Part {
        file: "policy.safetensors",
        save: |l| nets::to_safetensors_bytes(&l.nets.policy_vm).map_err(|e| e.to_string()),
        restore: |l, b| {
            nets::load_safetensors_bytes(&l.nets.policy_vm, b).map_err(|e| e.to_string())
        },
    },
    Part {
        file: "critic.safetensors",
        save: |l| nets::to_safetensors_bytes(&l.nets.critic_vm).map_err(|e| e.to_string()),
        restore: |l, b| {
            nets::load_safetensors_bytes(&l.nets.critic_vm, b).map_err(|e| e.to_string())
        },
    },
    Part {
        file: "target.safetensors",
        save: |l| nets::to_safetensors_bytes(&l.nets.target_vm).map_err(|e| e.to_string()),
        restore: |l, b| {
            nets::load_safetensors_bytes(&l.nets.target_vm, b).map_err(|e| e.to_string())
        },
    },
    Part {
        file: "optim.safetensors",
        save: save_optim,
        restore: restore_optim,
    },
    Part {
        file: "replay_low.safetensors",
        save: |l| {
            let r = &l.low_replay;
            save_columns(r.ring(), &r.columns(), LOW_SUCCESSORS)
        },
        restore: |l, b| {
            let (ring, columns) = l.low_replay.parts_mut();
            restore_columns(b, ring, columns, LOW_SUCCESSORS)
        },
    },
    Part {
        file: "replay_high.safetensors",
        save: |l| {
            let r = &l.high_replay;
            save_columns(r.ring(), &r.columns(), HIGH_SUCCESSORS)
        },
        restore: |l, b| {
            let (ring, columns) = l.high_replay.parts_mut();
            restore_columns(b, ring, columns, HIGH_SUCCESSORS)
        },
    },
    Part {
        file: "phi_store.safetensors",
        save: save_phi_store,
        restore: restore_phi_store,
    },
    Part {
        file: "si.safetensors",
        save: save_si,
        restore: restore_si,
    },
    Part {
        file: "state.json",
        save: |l| serde_json::to_vec_pretty(&State::of(l)?).map_err(|e| e.to_string()),
        restore: |l, b| {
            let state: State = serde_json::from_slice(b).map_err(|e| e.to_string())?;
            state.apply(l)
        },
    },
];

impl Learner {
    /// Writes a checkpoint into `dir` (a run's `checkpoints/`, created if missing) as
    /// `ckpt-N` with N one more than the newest there, then removes all but the newest
    /// [`KEEP`]. Refused while a φ round runs ([`CheckpointError::RoundActive`]).
    pub fn save_checkpoint(
        &self,
        config: &Config,
        dir: &Path,
    ) -> Result<Checkpoint, CheckpointError> {
        if self.phi.is_active() || self.phi_store.is_frozen() {
            return Err(CheckpointError::RoundActive);
        }
        let mut folder = TmpFolder::begin(dir, PREFIX, TMP_PREFIX)?;
        for part in PARTS {
            let bytes = (part.save)(self)
                .map_err(|problem| corrupt(&folder.path_of(part.file), problem))?;
            folder.add(part.file, &bytes)?;
        }
        let manifest = Manifest {
            format_version: FORMAT_VERSION,
            protocol_version: PROTOCOL_VERSION,
            layout_hash: self.weights_layout_hash(),
            config_fingerprint: config_fingerprint(config),
            sequence: folder.sequence(),
            env_steps: self.stats.env_steps,
            updates_low: self.updates_low,
            updates_high: self.updates_high,
            episodes_completed: Some(self.stats.episodes_completed),
            files: folder.files().to_vec(),
        };
        let json = serde_json::to_vec_pretty(&manifest)
            .map_err(|e| corrupt(&folder.path_of(MANIFEST), e.to_string()))?;
        let path = folder.commit(MANIFEST, &json, KEEP)?;
        Ok(Checkpoint { path, manifest })
    }

    /// A learner restored from the checkpoint folder `path` (a `ckpt-N`), for `config` and the
    /// task's `dims`. Refused with a [`CheckpointError`] naming the file when the checkpoint
    /// is incompatible (format, protocol, layout, config), corrupt or truncated; nothing is
    /// returned half-loaded.
    pub fn restore_checkpoint(
        config: &Config,
        dims: TaskDims,
        path: &Path,
    ) -> Result<(Learner, Checkpoint), CheckpointError> {
        // The episode length only derives the replay ratio, which the state file restores;
        // the seed only initialises weights and generators, which are all restored.
        let mut learner = Learner::with_episode_length(config, dims, 1, 0)?;
        let manifest: Manifest = ckpt::read_manifest(path, MANIFEST)?;
        let sum = check_compatible(&learner, config, &manifest, &path.join(MANIFEST))?;
        let blobs = ckpt::read_checked(path, &manifest.files, &path.join(MANIFEST), sum)?;
        for part in PARTS {
            let file = path.join(part.file);
            let bytes = blobs
                .get(part.file)
                .ok_or_else(|| corrupt(&file, "missing from the manifest"))?;
            (part.restore)(&mut learner, bytes).map_err(|problem| corrupt(&file, problem))?;
        }
        learner.episodes = Episodes::default();
        Ok((
            learner,
            Checkpoint {
                path: path.to_path_buf(),
                manifest,
            },
        ))
    }

    /// [`Learner::restore_checkpoint`] of the newest checkpoint in `dir` (a run's
    /// `checkpoints/`); `None` when there is none.
    pub fn restore_latest(
        config: &Config,
        dims: TaskDims,
        dir: &Path,
    ) -> Result<Option<(Learner, Checkpoint)>, CheckpointError> {
        match latest_checkpoint(dir)? {
            Some(path) => Self::restore_checkpoint(config, dims, &path).map(Some),
            None => Ok(None),
        }
    }
}

/// Versions, layout and config of `manifest` against this learner's; the checksum its format
/// lists files with.
fn check_compatible(
    learner: &Learner,
    config: &Config,
    manifest: &Manifest,
    path: &Path,
) -> Result<Checksum, CheckpointError> {
    let differ = |what: &str, expected: String, found: String| {
        Err(ckpt::incompatible(path, what, expected, found).into())
    };
    let versions = (manifest.format_version, manifest.protocol_version);
    let sum = ckpt::check_versions(path, versions, FORMAT_VERSION, PROTOCOL_VERSION)?;
    let layout = learner.weights_layout_hash();
    if manifest.layout_hash != layout {
        return differ(
            "network layout hash",
            format!("{layout:016x}"),
            format!("{:016x}", manifest.layout_hash),
        );
    }
    let fingerprint = config_fingerprint(config);
    if manifest.config_fingerprint != fingerprint {
        return differ(
            "config fingerprint (sections env, hierarchy, learner, replay, encoder)",
            fingerprint,
            manifest.config_fingerprint.clone(),
        );
    }
    Ok(sum)
}

/// Safetensors bytes of named f32 arrays `(name, shape, data)` with string metadata.
fn to_safetensors(
    arrays: Vec<(String, Vec<usize>, Vec<f32>)>,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, String> {
    let tensors = arrays
        .into_iter()
        .map(|(name, shape, data)| Tensor::from_vec(data, shape, &Device::Cpu).map(|t| (name, t)))
        .collect::<candle_core::Result<Vec<_>>>()
        .map_err(|e| e.to_string())?;
    serialize(tensors, metadata)
}

/// The f32 array `name` of `st`, checked to have `len` elements.
fn f32_array(st: &SafeTensors, name: &str, len: usize) -> Result<Vec<f32>, String> {
    array(st, name, Some(len))
}

/// Pairs `(derived, source)` of columns where row `i` of `derived` is, for most rows, row
/// `i + 1` of `source` in insertion order: the next observation (and its φ) of a transition is
/// the observation of the next one, except at the end of an episode or where the rows of
/// several actors' chunks meet. A checkpoint stores `derived` only where it is not (format 3).
pub(crate) const LOW_SUCCESSORS: &[(&str, &str)] = &[("next_obs", "obs"), ("next_phi", "phi")];
/// As [`LOW_SUCCESSORS`] for the high buffer (consecutive segments of an episode).
pub(crate) const HIGH_SUCCESSORS: &[(&str, &str)] = &[("next_obs", "obs")];
/// Name of the per-row flag tensor (U8): 1 where every derived column's row is its source's
/// successor row, bit for bit.
const FOLLOWS: &str = "follows";

/// Rows `0..len` of every column, the ring in metadata. A column named as `derived` in
/// `successors` keeps only the rows where [`FOLLOWS`] is 0 (in row order); the others are
/// rebuilt from the source column on restore.
fn save_columns(
    ring: &Ring,
    columns: &[(&'static str, &Column)],
    successors: &[(&str, &str)],
) -> Result<Vec<u8>, String> {
    let len = ring.len();
    let shape: Vec<(&str, usize)> = columns.iter().map(|(n, c)| (*n, c.width())).collect();
    let pairs = successor_pairs(&shape, successors)?;
    let follows: Vec<u8> = (0..len)
        .map(|i| {
            let follows = successor(ring, i).is_some_and(|j| {
                pairs
                    .iter()
                    .all(|&(d, s, _)| bitwise_equal(columns[d].1.row(i), columns[s].1.row(j)))
            });
            u8::from(!pairs.is_empty() && follows)
        })
        .collect();
    let tensor = |name: &str, rows: usize, width: usize, values: Vec<f32>| {
        Tensor::from_vec(values, (rows, width), &Device::Cpu)
            .map(|t| (name.to_owned(), t))
            .map_err(|e| e.to_string())
    };
    let mut tensors = Vec::with_capacity(columns.len() + 1);
    for (k, (name, col)) in columns.iter().enumerate() {
        let (rows, values) = if pairs.iter().any(|&(d, _, _)| d == k) {
            let kept = (0..len).filter(|&i| follows[i] == 0);
            let values: Vec<f32> = kept.flat_map(|i| col.row(i).iter().copied()).collect();
            (values.len() / col.width().max(1), values)
        } else {
            (len, col.export_rows(len))
        };
        tensors.push(tensor(name, rows, col.width(), values)?);
    }
    if !pairs.is_empty() {
        let flags = Tensor::from_vec(follows, len, &Device::Cpu).map_err(|e| e.to_string())?;
        tensors.push((FOLLOWS.to_owned(), flags));
    }
    let metadata = HashMap::from([
        ("capacity".to_owned(), ring.capacity().to_string()),
        ("len".to_owned(), len.to_string()),
        ("next".to_owned(), ring.next().to_string()),
        ("total".to_owned(), ring.total().to_string()),
    ]);
    serialize(tensors, metadata)
}

/// `(derived, source, width)` of each pair of `successors`, as indices into `columns`
/// (`(name, width)`); an error for a name that is no column or a pair whose widths differ.
fn successor_pairs(
    columns: &[(&str, usize)],
    successors: &[(&str, &str)],
) -> Result<Vec<(usize, usize, usize)>, String> {
    let index = |name: &str| {
        columns
            .iter()
            .position(|(n, _)| *n == name)
            .ok_or_else(|| format!("no column `{name}`"))
    };
    successors
        .iter()
        .map(|&(derived, source)| {
            let (d, s) = (index(derived)?, index(source)?);
            if columns[d].1 != columns[s].1 {
                return Err(format!("`{derived}` and `{source}` differ in width"));
            }
            Ok((d, s, columns[d].1))
        })
        .collect()
}

/// The row written after row `i` (physical index; rows `0..len` valid), if any: `None` for
/// the newest row.
fn successor(ring: &Ring, i: usize) -> Option<usize> {
    let j = (i + 1) % ring.capacity();
    (j < ring.len() && j != ring.next()).then_some(j)
}

fn bitwise_equal(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Fills fresh columns and the ring from [`save_columns`] bytes: of format 3 (with
/// [`FOLLOWS`]: the derived columns rebuilt from `successors`) or of formats 1–2 (every column
/// whole).
fn restore_columns(
    bytes: &[u8],
    ring: &mut Ring,
    columns: [(&'static str, &mut Column); 8],
    successors: &[(&str, &str)],
) -> Result<(), String> {
    let (st, metadata) = parse_safetensors(bytes)?;
    let capacity: usize = meta(&metadata, "capacity")?;
    if capacity != ring.capacity() {
        return Err(format!(
            "buffer capacity {capacity}, this config's is {}",
            ring.capacity()
        ));
    }
    let restored = Ring::restored(
        capacity,
        meta(&metadata, "len")?,
        meta(&metadata, "next")?,
        meta(&metadata, "total")?,
    )
    .ok_or("inconsistent ring bookkeeping (len, next, total)")?;
    let len = restored.len();
    let follows = match st.tensor(FOLLOWS) {
        Ok(_) => Some(array::<u8>(&st, FOLLOWS, Some(len))?),
        Err(_) => None,
    };
    let shape: Vec<(&str, usize)> = columns.iter().map(|(n, c)| (*n, c.width())).collect();
    let pairs = successor_pairs(&shape, successors)?;
    let mut data: Vec<Vec<f32>> = Vec::with_capacity(columns.len());
    for (k, &(name, width)) in shape.iter().enumerate() {
        let derived = pairs.iter().any(|&(d, _, _)| d == k);
        let rows = match (&follows, derived) {
            (Some(f), true) => f.iter().filter(|&&x| x == 0).count(),
            _ => len,
        };
        data.push(f32_array(&st, name, rows * width)?);
    }
    if let Some(follows) = &follows {
        if let Some(bad) = follows.iter().position(|&x| x > 1) {
            return Err(format!(
                "`{FOLLOWS}` row {bad} is {}, not 0 or 1",
                follows[bad]
            ));
        }
        for &(d, s, w) in &pairs {
            let (kept, from) = (&data[d], &data[s]);
            let mut whole = Vec::with_capacity(len * w);
            let mut next_kept = kept.chunks_exact(w.max(1));
            for (i, &flag) in follows.iter().enumerate() {
                let row = match flag {
                    1 => {
                        let j = successor(&restored, i).ok_or_else(|| {
                            format!("`{FOLLOWS}` marks the newest row {i} as followed")
                        })?;
                        &from[j * w..(j + 1) * w]
                    }
                    // Invariant: `kept` was read with exactly one row per 0 flag, so it never
                    // runs out here.
                    _ => next_kept.next().unwrap_or(&[]),
                };
                whole.extend_from_slice(row);
            }
            data[d] = whole;
        }
    }
    for ((_, col), values) in columns.into_iter().zip(&data) {
        col.import_rows(values);
    }
    *ring = restored;
    Ok(())
}

/// The φ trainer, which a checkpoint never finds away (no checkpoint while a round runs).
fn phi_trainer(l: &Learner) -> Result<&crate::phi::PhiTrainer, String> {
    l.phi.trainer().map_err(|e| e.to_string())
}

/// Names of the optimisers and log α in `optim.safetensors`: `{level}.{name}`.
fn save_optim(l: &Learner) -> Result<Vec<u8>, String> {
    let mut arrays = Vec::new();
    let mut metadata = HashMap::new();
    let mut opts = vec![("phi".to_owned(), phi_trainer(l)?.checkpoint_parts().0)];
    let levels = [
        ("low", l.nets.low.optimizers()),
        ("high", l.nets.high.optimizers()),
    ];
    for (level, (level_opts, log_alpha)) in levels {
        opts.extend(
            level_opts
                .into_iter()
                .map(|(n, o)| (format!("{level}.{n}"), o)),
        );
        if let Some(var) = log_alpha {
            let values = var
                .as_tensor()
                .flatten_all()
                .and_then(|t| t.to_vec1::<f32>())
                .map_err(|e| e.to_string())?;
            arrays.push((format!("{level}.log_alpha"), vec![values.len()], values));
        }
    }
    for (key, opt) in opts {
        let state = opt.export_state();
        metadata.insert(format!("{key}.step"), state.step.to_string());
        for (i, (m, v)) in state.m.into_iter().zip(state.v).enumerate() {
            arrays.push((format!("{key}.m.{i}"), vec![m.len()], m));
            arrays.push((format!("{key}.v.{i}"), vec![v.len()], v));
        }
    }
    to_safetensors(arrays, metadata)
}

/// One optimiser's state from `optim.safetensors`.
fn adam_state(
    st: &SafeTensors,
    metadata: &HashMap<String, String>,
    key: &str,
    opt: &Adam,
) -> Result<AdamState, String> {
    let lens = opt
        .export_state()
        .m
        .iter()
        .map(Vec::len)
        .collect::<Vec<_>>();
    let mut state = AdamState {
        step: meta(metadata, &format!("{key}.step"))?,
        m: Vec::with_capacity(lens.len()),
        v: Vec::with_capacity(lens.len()),
    };
    for (i, len) in lens.into_iter().enumerate() {
        state.m.push(f32_array(st, &format!("{key}.m.{i}"), len)?);
        state.v.push(f32_array(st, &format!("{key}.v.{i}"), len)?);
    }
    Ok(state)
}

fn restore_optim(l: &mut Learner, bytes: &[u8]) -> Result<(), String> {
    let (st, metadata) = parse_safetensors(bytes)?;
    let levels = [
        ("low", l.nets.low.optimizers_mut()),
        ("high", l.nets.high.optimizers_mut()),
    ];
    for (level, (opts, log_alpha)) in levels {
        if let Some(var) = log_alpha {
            let key = format!("{level}.log_alpha");
            let values = f32_array(&st, &key, var.elem_count())?;
            let tensor =
                Tensor::from_vec(values, var.shape(), &Device::Cpu).map_err(|e| e.to_string())?;
            var.set(&tensor).map_err(|e| e.to_string())?;
        }
        for (name, opt) in opts {
            let key = format!("{level}.{name}");
            let state = adam_state(&st, &metadata, &key, opt)?;
            opt.import_state(state).map_err(|e| format!("{key}: {e}"))?;
        }
    }
    let opt = l
        .phi
        .trainer_mut()
        .map_err(|e| e.to_string())?
        .restore_parts()
        .0;
    let state = adam_state(&st, &metadata, "phi", opt)?;
    opt.import_state(state).map_err(|e| format!("phi: {e}"))
}

fn save_phi_store(l: &Learner) -> Result<Vec<u8>, String> {
    let (mut obs, mut priority, mut lengths) = (Vec::new(), Vec::new(), Vec::new());
    for (o, p) in l.phi_store.runs() {
        obs.extend_from_slice(o);
        priority.extend_from_slice(p);
        lengths.push(p.len());
    }
    let s = l.phi_store.stats();
    let metadata = HashMap::from([
        (
            "run_states".to_owned(),
            serde_json::to_string(&lengths).map_err(|e| e.to_string())?,
        ),
        (
            "stats".to_owned(),
            serde_json::to_string(&[
                s.runs_stored,
                s.fragments,
                s.dropped_short,
                s.evicted,
                s.physics_failures,
            ])
            .map_err(|e| e.to_string())?,
        ),
    ]);
    let (n_obs, n_states) = (obs.len(), priority.len());
    to_safetensors(
        vec![
            ("obs".to_owned(), vec![n_obs], obs),
            ("priority".to_owned(), vec![n_states], priority),
        ],
        metadata,
    )
}

fn restore_phi_store(l: &mut Learner, bytes: &[u8]) -> Result<(), String> {
    let (st, metadata) = parse_safetensors(bytes)?;
    let lengths: Vec<usize> = serde_json::from_str(
        metadata
            .get("run_states")
            .ok_or("metadata `run_states` is missing")?,
    )
    .map_err(|e| format!("metadata `run_states`: {e}"))?;
    let [runs_stored, fragments, dropped_short, evicted, physics_failures]: [u64; 5] =
        serde_json::from_str(metadata.get("stats").ok_or("metadata `stats` is missing")?)
            .map_err(|e| format!("metadata `stats`: {e}"))?;
    let n_states: usize = lengths.iter().sum();
    let obs_dim = l.spec.obs_dim;
    let obs = f32_array(&st, "obs", n_states * obs_dim)?;
    let priority = f32_array(&st, "priority", n_states)?;
    let (mut o, mut p) = (obs.as_slice(), priority.as_slice());
    let mut runs = Vec::with_capacity(lengths.len());
    for n in lengths {
        let (run_obs, rest_obs) = o.split_at(n * obs_dim);
        let (run_p, rest_p) = p.split_at(n);
        runs.push((run_obs.to_vec(), run_p.to_vec()));
        (o, p) = (rest_obs, rest_p);
    }
    let stats = StoreStats {
        runs_stored,
        fragments,
        dropped_short,
        evicted,
        physics_failures,
    };
    l.phi_store.restore(runs, stats)
}

/// Name of the SI file's tensor (I64) of each entry's observation in the φ store
/// ([`shared`]; format 3): `obs` then holds only the entries the store does not.
const OBS_SOURCE: &str = "obs_source";

/// The SI buffer's arrays (`obs` of the entries the φ store does not hold, `goal`, `starts` as
/// F32, `obs_source` and `episode` serials as I64); the serials, due rounds and counters in
/// metadata. Written after the φ store, and restored after it.
fn save_si(l: &Learner) -> Result<Vec<u8>, String> {
    let si = &l.si;
    let p = si.buffer().parts();
    let st = si.stats();
    let episode = p
        .episode
        .iter()
        .map(|&e| i64::try_from(e).map_err(|_| format!("SI episode serial {e} exceeds i64")))
        .collect::<Result<Vec<i64>, _>>()?;
    let counters = [
        st.rounds_due,
        st.high_steps,
        st.low_steps,
        st.skipped_disabled,
        st.skipped_no_answer,
        st.skipped_phi_mismatch,
        st.skipped_no_usable_route,
        st.skipped_empty_buffer,
    ];
    let metadata = HashMap::from([
        ("first_start".to_owned(), p.first_start.to_string()),
        ("next_episode".to_owned(), p.next_episode.to_string()),
        ("evicted".to_owned(), p.evicted.to_string()),
        ("orphaned".to_owned(), p.orphaned.to_string()),
        ("rejected".to_owned(), p.rejected.to_string()),
        ("pending".to_owned(), si.pending().to_string()),
        // Its own key, not a ninth `stats` entry, so that older checkpoints still load.
        (
            "skipped_nonfinite".to_owned(),
            st.skipped_nonfinite.to_string(),
        ),
        (
            "stats".to_owned(),
            serde_json::to_string(&counters).map_err(|e| e.to_string())?,
        ),
    ]);
    let n = episode.len();
    let runs: Vec<&[f32]> = l.phi_store.runs().map(|(obs, _)| obs).collect();
    let (obs_dim, _) = si.buffer().dims();
    let shared = shared::share(&runs, p.obs, p.episode, obs_dim);
    let tensors = vec![
        f32_tensor("obs", shared.literal)?,
        (
            OBS_SOURCE.to_owned(),
            Tensor::from_vec(shared.sources, n, &Device::Cpu).map_err(|e| e.to_string())?,
        ),
        f32_tensor("goal", p.goal.to_vec())?,
        f32_tensor("starts", p.starts.to_vec())?,
        (
            "episode".to_owned(),
            Tensor::from_vec(episode, n, &Device::Cpu).map_err(|e| e.to_string())?,
        ),
    ];
    serialize(tensors, metadata)
}

/// A 1-D f32 tensor named `name`.
fn f32_tensor(name: &str, data: Vec<f32>) -> Result<(String, Tensor), String> {
    let n = data.len();
    Tensor::from_vec(data, n, &Device::Cpu)
        .map(|t| (name.to_owned(), t))
        .map_err(|e| e.to_string())
}

fn restore_si(l: &mut Learner, bytes: &[u8]) -> Result<(), String> {
    let (st, metadata) = parse_safetensors(bytes)?;
    let len_of = |name: &str| {
        st.tensor(name)
            .map(|v| v.shape().iter().product::<usize>())
            .map_err(|_| format!("tensor `{name}` is missing"))
    };
    let (obs_dim, goal_dim) = l.si.buffer().dims();
    let obs = f32_array(&st, "obs", len_of("obs")?)?;
    let obs = match st.tensor(OBS_SOURCE) {
        // Format 3: the observations the φ store (restored before) holds are taken from it.
        Ok(_) => {
            let sources: Vec<i64> = array(&st, OBS_SOURCE, None)?;
            let runs: Vec<&[f32]> = l.phi_store.runs().map(|(obs, _)| obs).collect();
            shared::unshare(&runs, &sources, &obs, obs_dim)?
        }
        // Formats 1–2: every entry's observation.
        Err(_) => obs,
    };
    let goal = f32_array(&st, "goal", len_of("goal")?)?;
    let starts = f32_array(&st, "starts", len_of("starts")?)?;
    let view = st
        .tensor("episode")
        .map_err(|_| "tensor `episode` is missing".to_owned())?;
    if view.dtype() != safetensors::Dtype::I64 {
        return Err(format!("tensor `episode` is {:?}, not I64", view.dtype()));
    }
    let episode = view
        .data()
        .chunks_exact(8)
        .map(|b| {
            let v = i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]);
            u64::try_from(v).map_err(|_| format!("negative SI episode serial {v}"))
        })
        .collect::<Result<Vec<u64>, _>>()?;
    let [rounds_due, high_steps, low_steps, skipped_disabled, skipped_no_answer, skipped_phi_mismatch, skipped_no_usable_route, skipped_empty_buffer]: [u64; 8] =
        serde_json::from_str(metadata.get("stats").ok_or("metadata `stats` is missing")?)
            .map_err(|e| format!("metadata `stats`: {e}"))?;
    let current = l.si.buffer();
    let parts = SiBufferParts {
        obs: &obs,
        goal: &goal,
        episode: &episode,
        starts: &starts,
        first_start: meta(&metadata, "first_start")?,
        next_episode: meta(&metadata, "next_episode")?,
        evicted: meta(&metadata, "evicted")?,
        orphaned: meta(&metadata, "orphaned")?,
        rejected: meta(&metadata, "rejected")?,
    };
    let buffer = SiBuffer::from_parts(obs_dim, goal_dim, current.capacity(), parts)?;
    // Absent (0) in checkpoints written before non-finite SI steps were skipped.
    let skipped_nonfinite = match metadata.get("skipped_nonfinite") {
        Some(_) => meta(&metadata, "skipped_nonfinite")?,
        None => 0,
    };
    let stats = SiStats {
        rounds_due,
        high_steps,
        low_steps,
        skipped_disabled,
        skipped_no_answer,
        skipped_phi_mismatch,
        skipped_no_usable_route,
        skipped_empty_buffer,
        skipped_nonfinite,
        ..SiStats::default()
    };
    l.si.restore(buffer, meta(&metadata, "pending")?, stats)
}

/// `state.json`: the scalar state of the learner.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct State {
    updates_low: u64,
    updates_high: u64,
    policy_version: PolicyVersion,
    phi_version: PhiVersion,
    low_per_env_step: f64,
    ingest: IngestState,
    publish: PublishSaved,
    schedule: (u64, u64, f64),
    /// Episodes in the current `count_prob` window (absent in checkpoints of builds before
    /// `asi.fr_in_count_window`, whose windows were `train_episodes` modulo their length).
    #[serde(default)]
    count_window_episodes: Option<u64>,
    max_policy_lag: u64,
    sampling_rng: Pcg64Mcg,
    phi: PhiSaved,
    /// The latest statistics the metrics show (absent in checkpoints of older builds, and when
    /// a value was not finite, as JSON has no NaN: then they restart from zero).
    #[serde(default)]
    telemetry: Option<TelemetrySaved>,
}

/// The latest update, φ step and SI step statistics and the telemetry counters: what the
/// metrics show until the next update of each kind, saved so that a resumed serial run writes
/// the same metrics as an uninterrupted one.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TelemetrySaved {
    low: SacStats,
    low_deterministic: DeterministicStats,
    high: SacStats,
    skipped_nonfinite_low: u64,
    skipped_nonfinite_high: u64,
    last_policy_lag: u64,
    phi_triplet: TripletStats,
    phi_stable_loss: f64,
    si_high: SiLossStats,
    si_low: SiLossStats,
    si_usable_fraction: f64,
    si_low_usable_fraction: f64,
    si_via_frontier_fraction: f64,
    /// Absent (0) in checkpoints of builds before the SI gradient norms.
    #[serde(default)]
    si_high_grad_norm: f64,
    /// Likewise.
    #[serde(default)]
    si_low_grad_norm: f64,
}

impl TelemetrySaved {
    /// `None` when a value is not finite (JSON would write it as `null` and refuse it back).
    fn of(l: &Learner) -> Option<TelemetrySaved> {
        let t = &l.telemetry;
        let phi = l.phi.stats();
        let si = l.si.stats();
        let saved = TelemetrySaved {
            low: t.low,
            low_deterministic: t.low_deterministic,
            high: t.high,
            skipped_nonfinite_low: t.skipped_nonfinite_low,
            skipped_nonfinite_high: t.skipped_nonfinite_high,
            last_policy_lag: t.last_policy_lag,
            phi_triplet: phi.triplet,
            phi_stable_loss: phi.stable_loss,
            si_high: si.high,
            si_low: si.low,
            si_usable_fraction: si.usable_fraction,
            si_low_usable_fraction: si.low_usable_fraction,
            si_via_frontier_fraction: si.via_frontier_fraction,
            si_high_grad_norm: si.high_grad_norm,
            si_low_grad_norm: si.low_grad_norm,
        };
        // Left out (`"telemetry": null` in the file) rather than written as an unreadable file.
        let finite = serde_json::to_value(&saved).is_ok_and(|v| !has_null(&v));
        finite.then_some(saved)
    }

    fn apply(self, l: &mut Learner) -> Result<(), String> {
        let t = &mut l.telemetry;
        t.low = self.low;
        t.low_deterministic = self.low_deterministic;
        t.high = self.high;
        t.skipped_nonfinite_low = self.skipped_nonfinite_low;
        t.skipped_nonfinite_high = self.skipped_nonfinite_high;
        t.last_policy_lag = self.last_policy_lag;
        let (_, _, _, phi) = l
            .phi
            .trainer_mut()
            .map_err(|e| e.to_string())?
            .restore_parts();
        phi.triplet = self.phi_triplet;
        phi.stable_loss = self.phi_stable_loss;
        let si = l.si.stats_mut();
        si.high = self.si_high;
        si.low = self.si_low;
        si.usable_fraction = self.si_usable_fraction;
        si.low_usable_fraction = self.si_low_usable_fraction;
        si.via_frontier_fraction = self.si_via_frontier_fraction;
        si.high_grad_norm = self.si_high_grad_norm;
        si.low_grad_norm = self.si_low_grad_norm;
        Ok(())
    }
}

fn has_null(value: &serde_json::Value) -> bool {
    match value {
        serde_json::Value::Null => true,
        serde_json::Value::Array(items) => items.iter().any(has_null),
        serde_json::Value::Object(map) => map.values().any(has_null),
        _ => false,
    }
}

/// [`IngestStats`] as saved.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct IngestState {
    chunks: u64,
    env_steps: u64,
    per_actor_steps: Vec<(u32, u64)>,
    lost_chunks: u64,
    duplicate_chunks: u64,
    rejected_chunks: u64,
    episodes_completed: u64,
    high_transitions: u64,
    dropped_segments: u64,
    abandoned_episodes: u64,
    /// Absent (0) in checkpoints written before FR steps were counted.
    #[serde(default)]
    frontier_steps: u64,
}

/// [`PublishState`] as saved.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PublishSaved {
    published_once: bool,
    steps_at_last: u64,
    updates_at_last: u64,
    phi_at_last: PhiVersion,
    schedule_at_last: (u64, f32, f32),
}

/// The φ trainer's scalars between rounds.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PhiSaved {
    rng: Pcg64Mcg,
    next_round: u64,
    rounds: u64,
    skipped_rounds: u64,
    coalesced_rounds: u64,
    steps: u64,
    round_start_loss: f64,
    round_end_loss: f64,
    /// Absent (0) in checkpoints written before non-finite φ steps were skipped.
    #[serde(default)]
    skipped_nonfinite_steps: u64,
    #[serde(default)]
    nonfinite_rounds: u64,
}

impl State {
    fn of(l: &Learner) -> Result<State, String> {
        let s = &l.stats;
        let p = &l.publish;
        let (_, phi_rng, next_round, phi_stats) = phi_trainer(l)?.checkpoint_parts();
        Ok(State {
            updates_low: l.updates_low,
            updates_high: l.updates_high,
            policy_version: l.policy_version,
            phi_version: l.phi_version,
            low_per_env_step: l.ratio.low_per_env_step,
            ingest: IngestState {
                chunks: s.chunks,
                env_steps: s.env_steps,
                per_actor_steps: s.per_actor_steps.iter().map(|(&a, &n)| (a, n)).collect(),
                lost_chunks: s.lost_chunks,
                duplicate_chunks: s.duplicate_chunks,
                rejected_chunks: s.rejected_chunks,
                episodes_completed: s.episodes_completed,
                high_transitions: s.high_transitions,
                dropped_segments: s.dropped_segments,
                abandoned_episodes: s.abandoned_episodes,
                frontier_steps: s.frontier_steps,
            },
            publish: PublishSaved {
                published_once: p.published_once,
                steps_at_last: p.steps_at_last,
                updates_at_last: p.updates_at_last,
                phi_at_last: p.phi_at_last,
                schedule_at_last: (
                    p.schedule_at_last.train_episodes,
                    p.schedule_at_last.count_prob,
                    p.schedule_at_last.fr_prob,
                ),
            },
            schedule: l.schedule.counters(),
            count_window_episodes: Some(l.schedule.window_episodes()),
            max_policy_lag: l.telemetry.max_policy_lag,
            sampling_rng: l.rng.clone(),
            telemetry: TelemetrySaved::of(l),
            phi: PhiSaved {
                rng: phi_rng.clone(),
                next_round,
                rounds: phi_stats.rounds,
                skipped_rounds: phi_stats.skipped_rounds,
                coalesced_rounds: phi_stats.coalesced_rounds,
                steps: phi_stats.steps,
                round_start_loss: phi_stats.round_start_loss,
                round_end_loss: phi_stats.round_end_loss,
                skipped_nonfinite_steps: phi_stats.skipped_nonfinite_steps,
                nonfinite_rounds: phi_stats.nonfinite_rounds,
            },
        })
    }

    fn apply(self, l: &mut Learner) -> Result<(), String> {
        if !(self.low_per_env_step.is_finite() && self.low_per_env_step >= 0.0) {
            return Err(format!(
                "low_per_env_step = {} is not a finite ratio ≥ 0",
                self.low_per_env_step
            ));
        }
        let i = self.ingest;
        l.updates_low = self.updates_low;
        l.updates_high = self.updates_high;
        l.policy_version = self.policy_version;
        l.phi_version = self.phi_version;
        l.ratio.low_per_env_step = self.low_per_env_step;
        l.stats = IngestStats {
            chunks: i.chunks,
            env_steps: i.env_steps,
            per_actor_steps: i.per_actor_steps.into_iter().collect(),
            lost_chunks: i.lost_chunks,
            duplicate_chunks: i.duplicate_chunks,
            rejected_chunks: i.rejected_chunks,
            episodes_completed: i.episodes_completed,
            high_transitions: i.high_transitions,
            dropped_segments: i.dropped_segments,
            abandoned_episodes: i.abandoned_episodes,
            frontier_steps: i.frontier_steps,
        };
        let p = self.publish;
        let (train_episodes, count_prob, fr_prob) = p.schedule_at_last;
        l.publish = PublishState {
            published_once: p.published_once,
            steps_at_last: p.steps_at_last,
            updates_at_last: p.updates_at_last,
            phi_at_last: p.phi_at_last,
            schedule_at_last: RunSchedule {
                train_episodes,
                count_prob,
                fr_prob,
            },
        };
        l.schedule
            .restore_counters(self.schedule, self.count_window_episodes);
        l.telemetry.max_policy_lag = self.max_policy_lag;
        l.rng = self.sampling_rng;
        let (_, rng, next_round, stats) = l
            .phi
            .trainer_mut()
            .map_err(|e| e.to_string())?
            .restore_parts();
        let f = self.phi;
        *rng = f.rng;
        *next_round = f.next_round;
        stats.rounds = f.rounds;
        stats.skipped_rounds = f.skipped_rounds;
        stats.coalesced_rounds = f.coalesced_rounds;
        stats.steps = f.steps;
        stats.round_start_loss = f.round_start_loss;
        stats.round_end_loss = f.round_end_loss;
        stats.skipped_nonfinite_steps = f.skipped_nonfinite_steps;
        stats.nonfinite_rounds = f.nonfinite_rounds;
        if let Some(telemetry) = self.telemetry {
            telemetry.apply(l)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
