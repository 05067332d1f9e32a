//! The serial part of a serial-mode checkpoint: what `asi train --serial` holds besides the
//! learner and the graph-service (whose checkpoints sit beside it), so that a resumed serial
//! run continues bit-exactly (issue #7).
//!
//! Written to `checkpoints/serial/ckpt-NNNNNN/` ([`SUBDIR`]) after the learner's and the
//! graph-service's checkpoints of the same moment:
//!
//! | file | contents |
//! |---|---|
//! | `state.json` | every actor's [`ActorState`] (generator, episode counter, counters), the steps each actor published, the evaluator's schedule and latest metrics, the coverage grid, the header of the last weights broadcast |
//! | `weights.safetensors` | the payload of the last weights broadcast (the weights the actors act with, which may be older than the learner's) |
//! | `manifest.json` | format and protocol versions, actors, seed, task, the learner's env steps and the graph-service's stored steps when written, whether the restore is exact, size and checksum of each file above |
//!
//! Invariants:
//! - Atomic and checked as the other parts (the `ckpt` crate); the newest [`KEEP`] are kept.
//! - Exact only between episodes and with a current graph ([`Manifest::exact`]): serial mode
//!   writes it at a round boundary where no actor has an open episode; one written with open
//!   episodes (a run ended by its env-step budget) restores as if those episodes had been
//!   abandoned. The graph-service's checkpoint does not save its graph but rebuilds it on
//!   restore from the whole store, while between φ versions a running graph-service keeps the
//!   graph of its last rebuild: so a restore is exact only when the graph held every stored
//!   state, i.e. at the round of a φ re-map ([`Manifest::graph_current`]).
//! - Matched: the manifest's learner env steps and graph stored steps must equal those of the
//!   restored learner and graph-service, else the parts are from different moments (a write
//!   interrupted between them) and the resume is not exact (logged).
//! - Refused with a clear error: another format or protocol version, another number of
//!   actors, seed or task; a corrupt or truncated file.

use std::path::{Path, PathBuf};

use actor::resume::ActorState;
use anyhow::{bail, Context};
use ckpt::{FileEntry, TmpFolder};
use protocol::{PhiVersion, PolicyVersion, RunSchedule, WeightsHeader, PROTOCOL_VERSION};
use serde::{Deserialize, Serialize};

use crate::proc::evaluator::EvalSchedule;

/// Version of the serial checkpoint format; a checkpoint of another version is refused.
pub const FORMAT_VERSION: u32 = 1;
/// Folder of the serial checkpoints inside a run's `checkpoints/`.
pub const SUBDIR: &str = "serial";
/// Checkpoints kept (older ones are removed after a new one is written).
pub const KEEP: usize = 2;
const PREFIX: &str = "ckpt-";
const TMP_PREFIX: &str = ".tmp-ckpt-";
const MANIFEST: &str = "manifest.json";
const STATE_FILE: &str = "state.json";
const WEIGHTS_FILE: &str = "weights.safetensors";

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
    /// Env steps the learner had ingested when it was written.
    pub learner_env_steps: u64,
    /// States the graph-service stored when it was written.
    pub graph_stored_steps: u64,
    /// Actors that had an open episode (lost on restore).
    pub n_open_episodes: u32,
    /// The graph held every stored state (it was rebuilt after the last chunk). Otherwise the
    /// restored graph-service, which rebuilds its graph from the whole store, answers from a
    /// graph that already holds the newer states, unlike the uninterrupted run's.
    pub graph_current: bool,
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
    /// A restore continues bit-exactly: no open episode, and the graph held every state.
    pub fn exact(&self) -> bool {
        self.n_open_episodes == 0 && self.graph_current
    }

    /// Whether a restore is bit-exact, and if not why, in words.
    pub fn exactness(&self) -> String {
        match (self.n_open_episodes, self.graph_current) {
            (0, true) => "a resume from it is bit-exact".to_owned(),
            (0, false) => "a resume from it is not bit-exact: the graph-service rebuilds its \
                           graph with the states stored since its last rebuild"
                .to_owned(),
            (n, _) => format!(
                "a resume from it is not bit-exact: {n} open episodes are lost{}",
                if self.graph_current {
                    ""
                } else {
                    ", and the graph-service rebuilds its graph with newer states"
                }
            ),
        }
    }
}

/// When a serial checkpoint is written, to match it with the learner and graph-service and
/// to tell whether a restore is exact.
pub struct Moment {
    pub learner_env_steps: u64,
    pub graph_stored_steps: u64,
    pub graph_current: bool,
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
    let manifest = Manifest {
        format_version: FORMAT_VERSION,
        protocol_version: PROTOCOL_VERSION,
        n_actors: config.run.n_actors as u32,
        seed: config.run.seed,
        task: config.env.task.clone(),
        learner_env_steps: moment.learner_env_steps,
        graph_stored_steps: moment.graph_stored_steps,
        n_open_episodes: state.actors.iter().filter(|a| a.had_open_episode).count() as u32,
        graph_current: moment.graph_current,
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
    check_compatible(&manifest, config, &path)?;
    let manifest_path = path.join(MANIFEST);
    let mut blobs = ckpt::read_checked(&path, &manifest.files, &manifest_path)?;
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
    let header = state.weights.header(bytes.len());
    Ok(Some(Restored {
        state,
        weights: (header, bytes),
        manifest,
        path,
    }))
}

fn check_compatible(
    manifest: &Manifest,
    config: &protocol::Config,
    path: &Path,
) -> anyhow::Result<()> {
    let versions = (manifest.format_version, manifest.protocol_version);
    if versions != (FORMAT_VERSION, PROTOCOL_VERSION) {
        bail!(
            "serial checkpoint {} has format/protocol version {versions:?}, this build needs \
             ({FORMAT_VERSION}, {PROTOCOL_VERSION}); start over with --restart",
            path.display()
        );
    }
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
    Ok(())
}
