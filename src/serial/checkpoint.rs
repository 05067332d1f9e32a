//! The serial part of a serial-mode checkpoint: what `asi train --serial` holds besides the
//! learner and the graph-service (whose checkpoints sit beside it), so that a resumed serial
//! run continues bit-exactly (issue #7).
//!
//! Written to `checkpoints/serial/ckpt-NNNNNN/` ([`SUBDIR`]) after the learner's checkpoint of
//! the same moment:
//!
//! | file | contents |
//! |---|---|
//! | `state.json` | every actor's [`ActorState`] (generator, episode counter, counters), the steps each actor published, the evaluator's schedule and latest metrics, the coverage grid, the header of the last weights broadcast |
//! | `weights.safetensors` | the payload of the last weights broadcast (the weights the actors act with, which may be older than the learner's) |
//! | `graph_log.json`, `graph_log.bin` | the graph-service's inputs since its base checkpoint ([`GraphInput`]: chunk and request headers field by field; records as little-endian f32 and request bodies) |
//! | `manifest.json` | format and protocol versions, actors, seed, task, the learner's env steps and the graph-service's stored steps when written, open episodes, the graph-service base checkpoint and whether the log is complete, size and checksum of each file above |
//!
//! Invariants:
//! - Atomic and checked as the other parts (the `ckpt` crate); the newest [`KEEP`] are kept.
//! - Exact when [`Manifest::exact`]: written between episodes (one written with open episodes,
//!   at a run's env-step budget, restores as if they had been abandoned), with a complete log.
//! - Matched: the log replays onto the graph-service checkpoint it names, and the learner's env
//!   steps and the graph's stored steps after the replay must equal the manifest's, else the
//!   parts are of different moments and the resume is not exact (logged).
//! - Refused with a clear error: another format or protocol version, another number of
//!   actors, seed or task; a corrupt or truncated file.

use std::path::{Path, PathBuf};

use actor::resume::ActorState;
use anyhow::{bail, Context};
use ckpt::{FileEntry, TmpFolder};
use protocol::graph::GraphRequestHeader;
use protocol::{
    ActorId, EpisodeId, PhiVersion, PolicyVersion, RunSchedule, TrajectoryFlags, TrajectoryHeader,
    WeightsHeader, PROTOCOL_VERSION,
};
use serde::{Deserialize, Serialize};

use crate::proc::evaluator::EvalSchedule;

/// Version of the serial checkpoint format; a checkpoint of another version is refused, but
/// for format 1 (the same files, checksummed with [`ckpt::fingerprint`]; see
/// [`ckpt::Checksum`]).
pub const FORMAT_VERSION: u32 = 2;
/// Folder of the serial checkpoints inside a run's `checkpoints/`.
pub const SUBDIR: &str = "serial";
/// Checkpoints kept (older ones are removed after a new one is written).
pub const KEEP: usize = 2;
const PREFIX: &str = "ckpt-";
const TMP_PREFIX: &str = ".tmp-ckpt-";
const MANIFEST: &str = "manifest.json";
const STATE_FILE: &str = "state.json";
const WEIGHTS_FILE: &str = "weights.safetensors";
const LOG_INDEX_FILE: &str = "graph_log.json";
const LOG_DATA_FILE: &str = "graph_log.bin";

/// `manifest.json` of a serial checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// [`PROTOCOL_VERSION`] of the writer.
    pub protocol_version: u32,
    /// `run.n_actors`.
    pub n_actors: u32,
    /// `run.seed` (the actors' env seeds derive from it).
    pub seed: u64,
    /// `env.task`.
    pub task: String,
    /// `eval.interval_episodes` (the saved evaluation schedule counts in its units).
    pub eval_interval_episodes: u64,
    /// Env steps the learner had ingested when it was written.
    pub learner_env_steps: u64,
    /// States the graph-service stored when it was written.
    pub graph_stored_steps: u64,
    /// Actors that had an open episode (lost on restore).
    pub n_open_episodes: u32,
    /// The graph-service checkpoint (folder name under `checkpoints/graph-service/`) the
    /// input log starts from: the one written at the last φ re-map.
    pub graph_base: Option<String>,
    /// The input log holds every graph-service input since `graph_base` (false after a failed
    /// base write: then the restored graph-service is the base's, without the later inputs).
    pub graph_log_complete: bool,
    /// Every other file of the folder.
    pub files: Vec<FileEntry>,
}

/// The header fields of the last weights broadcast (its payload is `weights.safetensors`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedHeader {
    pub policy_version: PolicyVersion,
    pub phi_version: PhiVersion,
    pub layout_hash: u64,
    /// `(train_episodes, count_prob, fr_prob)`.
    pub schedule: (u64, f32, f32),
}

impl SavedHeader {
    pub fn of(header: &WeightsHeader) -> Self {
        let s = header.schedule;
        Self {
            policy_version: header.policy_version,
            phi_version: header.phi_version,
            layout_hash: header.layout_hash,
            schedule: (s.train_episodes, s.count_prob, s.fr_prob),
        }
    }

    /// The header again, for a payload of `byte_len` bytes.
    pub fn header(&self, byte_len: usize) -> WeightsHeader {
        let (train_episodes, count_prob, fr_prob) = self.schedule;
        WeightsHeader::new(
            self.policy_version,
            self.phi_version,
            self.layout_hash,
            byte_len,
        )
        .with_schedule(RunSchedule {
            train_episodes,
            count_prob,
            fr_prob,
        })
    }
}

impl Manifest {
    /// A restore continues bit-exactly: no open episode, and a complete graph input log.
    pub fn exact(&self) -> bool {
        self.n_open_episodes == 0 && self.graph_log_complete
    }

    /// Whether a restore is bit-exact, and if not why, in words.
    pub fn exactness(&self) -> String {
        let mut problems = Vec::new();
        if self.n_open_episodes > 0 {
            problems.push(format!("{} open episodes are lost", self.n_open_episodes));
        }
        if !self.graph_log_complete {
            problems.push(
                "the graph-service's inputs since its last base checkpoint are not all saved"
                    .to_owned(),
            );
        }
        match problems.is_empty() {
            true => "a resume from it is bit-exact".to_owned(),
            false => format!("a resume from it is not bit-exact: {}", problems.join("; ")),
        }
    }
}

/// When a serial checkpoint is written, to match it with the learner and graph-service, and
/// the graph-service's input log.
pub struct Moment<'a> {
    pub learner_env_steps: u64,
    pub graph_stored_steps: u64,
    pub graph_base: Option<String>,
    /// `None` when incomplete.
    pub graph_log: Option<&'a [GraphInput]>,
}

/// One input of the graph-service (a state machine) since its base checkpoint; replayed in
/// order after restoring the base, they rebuild its state exactly.
#[derive(Debug, Clone, PartialEq)]
pub enum GraphInput {
    /// A trajectory chunk (`GraphService::ingest`).
    Chunk(TrajectoryHeader, Vec<f32>),
    /// A request (`GraphService::handle`); the answer is not kept.
    Request(GraphRequestHeader, Vec<u8>),
}

/// `graph_log.json`: the headers of the log, field by field; payloads in `graph_log.bin`.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
enum LogEntry {
    /// [`trajectory_fields`] and the number of f32 records values.
    Chunk { header: Vec<u64>, n_values: u64 },
    /// [`request_fields`] and the number of body bytes.
    Request { header: Vec<u64>, n_bytes: u64 },
}

fn trajectory_fields(h: &TrajectoryHeader) -> Vec<u64> {
    let small = [
        h.actor_id.0,
        h.chunk_index,
        h.n_steps,
        h.obs_dim,
        h.action_dim,
        h.goal_dim,
        h.latent_dim,
        h.flags.0,
        h.protocol_version,
        h.reserved,
    ];
    let mut fields = vec![
        h.episode_id.0,
        h.first_env_step,
        h.policy_version.0,
        h.phi_version.0,
    ];
    fields.extend(small.map(u64::from));
    fields
}

fn trajectory_header(f: &[u64]) -> Result<TrajectoryHeader, String> {
    let n = |i: usize| -> Result<u32, String> {
        u32::try_from(f[i]).map_err(|_| format!("header field {i} = {} is not a u32", f[i]))
    };
    if f.len() != 14 {
        return Err(format!("a chunk header has 14 fields, not {}", f.len()));
    }
    Ok(TrajectoryHeader {
        episode_id: EpisodeId(f[0]),
        first_env_step: f[1],
        policy_version: PolicyVersion(f[2]),
        phi_version: PhiVersion(f[3]),
        actor_id: ActorId(n(4)?),
        chunk_index: n(5)?,
        n_steps: n(6)?,
        obs_dim: n(7)?,
        action_dim: n(8)?,
        goal_dim: n(9)?,
        latent_dim: n(10)?,
        flags: TrajectoryFlags(n(11)?),
        protocol_version: n(12)?,
        reserved: n(13)?,
    })
}

fn request_fields(h: &GraphRequestHeader) -> Vec<u64> {
    vec![
        h.request_id,
        h.phi_version.0,
        u64::from(h.kind),
        u64::from(h.protocol_version),
    ]
}

fn request_header(f: &[u64]) -> Result<GraphRequestHeader, String> {
    if f.len() != 4 {
        return Err(format!("a request header has 4 fields, not {}", f.len()));
    }
    let n = |i: usize| u32::try_from(f[i]).map_err(|_| format!("header field {i} is not a u32"));
    Ok(GraphRequestHeader {
        request_id: f[0],
        phi_version: PhiVersion(f[1]),
        kind: n(2)?,
        protocol_version: n(3)?,
    })
}

/// The log as (`graph_log.json`, `graph_log.bin`).
fn encode_log(log: &[GraphInput]) -> anyhow::Result<(Vec<u8>, Vec<u8>)> {
    let mut entries = Vec::with_capacity(log.len());
    let mut data = Vec::new();
    for input in log {
        match input {
            GraphInput::Chunk(header, records) => {
                entries.push(LogEntry::Chunk {
                    header: trajectory_fields(header),
                    n_values: records.len() as u64,
                });
                data.extend(records.iter().flat_map(|v| v.to_le_bytes()));
            }
            GraphInput::Request(header, body) => {
                entries.push(LogEntry::Request {
                    header: request_fields(header),
                    n_bytes: body.len() as u64,
                });
                data.extend_from_slice(body);
            }
        }
    }
    Ok((serde_json::to_vec(&entries)?, data))
}

fn decode_log(index: &[u8], data: &[u8]) -> Result<Vec<GraphInput>, String> {
    let entries: Vec<LogEntry> = serde_json::from_slice(index).map_err(|e| e.to_string())?;
    let mut rest = data;
    let mut take = |n: u64| -> Result<&[u8], String> {
        let n = usize::try_from(n).map_err(|e| e.to_string())?;
        if n > rest.len() {
            return Err(format!(
                "the log needs {n} more bytes, {} are left",
                rest.len()
            ));
        }
        let (head, tail) = rest.split_at(n);
        rest = tail;
        Ok(head)
    };
    let mut log = Vec::with_capacity(entries.len());
    for entry in entries {
        log.push(match entry {
            LogEntry::Chunk { header, n_values } => {
                let bytes = take(n_values * 4)?;
                let values = bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect();
                GraphInput::Chunk(trajectory_header(&header)?, values)
            }
            LogEntry::Request { header, n_bytes } => {
                GraphInput::Request(request_header(&header)?, take(n_bytes)?.to_vec())
            }
        });
    }
    if !rest.is_empty() {
        return Err(format!("{} bytes after the last entry", rest.len()));
    }
    Ok(log)
}

/// `state.json`: the serial loop's own state at a round boundary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialState {
    /// One per actor, in actor id order.
    pub actors: Vec<ActorState>,
    /// Env steps each actor published (its `actor/published_steps`), in actor id order.
    pub published_steps: Vec<u64>,
    /// The evaluator's schedule (evaluations done and skipped).
    pub eval_schedule: EvalSchedule,
    /// The latest evaluation's metrics (repeated on every metrics line).
    pub eval_latest: Vec<(String, f64)>,
    /// The coverage grid's counts and outside visits, if the task has a maze.
    pub coverage: Option<(Vec<u64>, u64)>,
    /// Header of the last weights broadcast.
    pub weights: SavedHeader,
}

/// A serial checkpoint read back: its state, the last broadcast and its manifest.
pub struct Restored {
    pub state: SerialState,
    pub weights: (WeightsHeader, Vec<u8>),
    pub manifest: Manifest,
    pub path: PathBuf,
    /// The graph-service's inputs since `manifest.graph_base` (empty when incomplete).
    pub graph_log: Vec<GraphInput>,
}

/// Writes `state` and the last broadcast `bytes` as the next checkpoint in `dir`.
pub fn write(
    dir: &Path,
    config: &protocol::Config,
    state: &SerialState,
    bytes: &[u8],
    moment: Moment,
) -> anyhow::Result<(PathBuf, Manifest)> {
    let mut folder = TmpFolder::begin(dir, PREFIX, TMP_PREFIX)?;
    folder.add(STATE_FILE, &serde_json::to_vec_pretty(state)?)?;
    folder.add(WEIGHTS_FILE, bytes)?;
    let (index, data) = encode_log(moment.graph_log.unwrap_or_default())?;
    folder.add(LOG_INDEX_FILE, &index)?;
    folder.add(LOG_DATA_FILE, &data)?;
    let manifest = Manifest {
        format_version: FORMAT_VERSION,
        protocol_version: PROTOCOL_VERSION,
        n_actors: config.run.n_actors as u32,
        seed: config.run.seed,
        task: config.env.task.clone(),
        eval_interval_episodes: config.eval.interval_episodes,
        learner_env_steps: moment.learner_env_steps,
        graph_stored_steps: moment.graph_stored_steps,
        n_open_episodes: state.actors.iter().filter(|a| a.had_open_episode).count() as u32,
        graph_base: moment.graph_base,
        graph_log_complete: moment.graph_log.is_some(),
        files: folder.files().to_vec(),
    };
    let path = folder.commit(MANIFEST, &serde_json::to_vec_pretty(&manifest)?, KEEP)?;
    Ok((path, manifest))
}

/// The newest serial checkpoint in `dir`, checked against `config` (see the module doc);
/// `None` when there is none.
pub fn read_latest(dir: &Path, config: &protocol::Config) -> anyhow::Result<Option<Restored>> {
    let Some((_, path)) = ckpt::list(dir, PREFIX)?.pop() else {
        return Ok(None);
    };
    let manifest: Manifest = ckpt::read_manifest(&path, MANIFEST)?;
    let sum = check_compatible(&manifest, config, &path)?;
    let manifest_path = path.join(MANIFEST);
    let mut blobs = ckpt::read_checked(&path, &manifest.files, &manifest_path, sum)?;
    let mut take = |name: &str| {
        blobs
            .remove(name)
            .with_context(|| format!("{}: {name} is not listed", manifest_path.display()))
    };
    let state_bytes = take(STATE_FILE)?;
    let bytes = take(WEIGHTS_FILE)?;
    let state: SerialState = serde_json::from_slice(&state_bytes)
        .with_context(|| format!("{} is corrupt", path.join(STATE_FILE).display()))?;
    if state.actors.len() != manifest.n_actors as usize
        || state.published_steps.len() != state.actors.len()
    {
        bail!(
            "{} is corrupt: {} actor states and {} step counts for {} actors",
            path.join(STATE_FILE).display(),
            state.actors.len(),
            state.published_steps.len(),
            manifest.n_actors
        );
    }
    let (index, data) = (take(LOG_INDEX_FILE)?, take(LOG_DATA_FILE)?);
    let graph_log = decode_log(&index, &data).map_err(|problem| {
        anyhow::anyhow!(
            "{} is corrupt: {problem}",
            path.join(LOG_INDEX_FILE).display()
        )
    })?;
    let header = state.weights.header(bytes.len());
    Ok(Some(Restored {
        state,
        weights: (header, bytes),
        manifest,
        path,
        graph_log,
    }))
}

/// `manifest` against this run's versions and config; the checksum its format lists files
/// with.
fn check_compatible(
    manifest: &Manifest,
    config: &protocol::Config,
    path: &Path,
) -> anyhow::Result<ckpt::Checksum> {
    let versions = (manifest.format_version, manifest.protocol_version);
    let sum = ckpt::Checksum::of_format(manifest.format_version, FORMAT_VERSION);
    let (Some(sum), PROTOCOL_VERSION) = (sum, manifest.protocol_version) else {
        bail!(
            "serial checkpoint {} has format/protocol version {versions:?}, this build needs \
             (1 to {FORMAT_VERSION}, {PROTOCOL_VERSION}); start over with --restart",
            path.display()
        );
    };
    let ours = (
        config.run.n_actors as u32,
        config.run.seed,
        &config.env.task,
    );
    let theirs = (manifest.n_actors, manifest.seed, &manifest.task);
    if ours != theirs {
        bail!(
            "serial checkpoint {} was written by a run with (actors, seed, task) = {theirs:?}, \
             this run has {ours:?}; resume with the same values or start over with --restart",
            path.display()
        );
    }
    if manifest.eval_interval_episodes != config.eval.interval_episodes {
        tracing::warn!(
            "serial checkpoint {}: eval.interval_episodes was {}, is {}; the checkpoint's \
             evaluation schedule (and interval) is kept",
            path.display(),
            manifest.eval_interval_episodes,
            config.eval.interval_episodes
        );
    }
    Ok(sum)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_graph_input_log_reads_back_as_written_and_a_short_payload_is_refused() {
        let chunk = TrajectoryHeader {
            episode_id: EpisodeId((3 << 40) | 7),
            first_env_step: 50,
            policy_version: PolicyVersion(9),
            phi_version: PhiVersion(2),
            actor_id: ActorId(3),
            chunk_index: 1,
            n_steps: 2,
            obs_dim: 4,
            action_dim: 2,
            goal_dim: 2,
            latent_dim: 2,
            flags: TrajectoryFlags(5),
            protocol_version: PROTOCOL_VERSION,
            reserved: 0,
        };
        let request = GraphRequestHeader {
            request_id: 11,
            phi_version: PhiVersion(2),
            kind: 3,
            protocol_version: PROTOCOL_VERSION,
        };
        let log = vec![
            GraphInput::Chunk(chunk, vec![1.5, -0.0, f32::MAX, f32::MIN_POSITIVE]),
            GraphInput::Request(request, vec![0, 255, 7]),
            GraphInput::Chunk(chunk, Vec::new()),
        ];
        let (index, data) = encode_log(&log).unwrap();
        assert_eq!(decode_log(&index, &data).unwrap(), log);
        assert!(decode_log(&index, &data[..data.len() - 1]).is_err());
        assert!(decode_log(&index, &[data.as_slice(), &[0]].concat()).is_err());
    }
}
