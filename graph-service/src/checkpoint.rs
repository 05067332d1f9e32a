//! Graph-service checkpoints: everything a restarted [`GraphService`] needs to answer as the
//! old one did — the trajectory store, HESS's maps, the graph and its visit counts, the φ it
//! holds and its generator — in `checkpoints/graph-service/ckpt-NNNNNN/` under the run folder
//! ([`SUBDIR`]; the learner's checkpoints sit beside it in `checkpoints/`).
//!
//! Layout of one checkpoint folder:
//!
//! | file | contents |
//! |---|---|
//! | `store.safetensors` | states (`obs`), their latent points as stored (`latents`), per trajectory actor, episode, first env step, length, next chunk index, closed flag; open trajectories; eviction and gap counters in metadata |
//! | `maps.safetensors` | graph visit counts n(v); HESS visits, future counts and potential per cell (keys as `i32` pairs); HESS counters in metadata |
//! | `phi.safetensors` | the encoder tensors of the φ held (only once weights have arrived) |
//! | `graph.safetensors` | the current graph (only once one is built): node cell keys `[n, 2]` (i32) in node order, edges `[m, 3]` (u32: a, b, weight; a < b, sorted); dropped-cell and unmapped-state counts in metadata |
//! | `state.json` | φ version, graph version, generator state, request and chunk counters |
//! | `manifest.json` | format and protocol versions, the config values the state depends on, size and checksum of each file above |
//!
//! Invariants:
//! - Atomic and checked as the learner's (the `ckpt` crate): files go into a temporary folder
//!   that is renamed when complete, the newest [`KEEP`] are kept, and a restore checks
//!   versions, the state-shaping config values ([`Manifest::shape`]), then the size and
//!   checksum of every file, then parses every file into a fresh service; any problem is an
//!   error naming the file, and no service is returned.
//! - The graph is saved as it is: a running service keeps the graph of its last φ re-map while
//!   new states arrive, and a restore gives back that graph, with its version, not one rebuilt
//!   from the whole store. Checkpoints written before the graph was saved (`state.json`
//!   without `graph_saved`) restore as they did: the graph rebuilt from the restored store,
//!   which counts as one more graph version.
//! - Latent points are restored as they were stored (no re-map): the restored service answers
//!   with the same points, counts and φ.
//! - The visit counts are saved and checked against a recount of the restored store (a
//!   mismatch is corruption).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

pub use ckpt::FileError;
use ckpt::{array, meta, Array, Checksum, FileEntry, TmpFolder};
use protocol::{ActorId, Config, EpisodeId, LatentPoint, PhiVersion, PROTOCOL_VERSION};
use rand_pcg::Pcg64;
use safetensors::SafeTensors;
use serde::{Deserialize, Serialize};

use crate::error::GraphServiceError;
use crate::graph::LatentGraph;
use crate::grid::{CellKey, Grid};
use crate::hess::{HessMaps, HessParts};
use crate::service::GraphService;
use crate::store::{StoreCounters, Trajectory, TrajectoryHead, TrajectoryStore};

/// Version of the checkpoint format; a checkpoint of another version is refused, but for
/// format 1 (the same files, checksummed with [`ckpt::fingerprint`]; see [`ckpt::Checksum`]).
pub const FORMAT_VERSION: u32 = 2;
/// Name of the manifest inside a checkpoint folder.
pub const MANIFEST: &str = "manifest.json";
/// Checkpoints kept (older ones are removed after a new one is written).
pub const KEEP: usize = 2;
/// Folder of the graph-service's checkpoints inside a run's `checkpoints/`.
pub const SUBDIR: &str = "graph-service";
/// Folder name prefix of a complete checkpoint (`ckpt-` + 6-digit sequence number).
const PREFIX: &str = "ckpt-";
/// Folder name prefix of a checkpoint being written.
const TMP_PREFIX: &str = ".tmp-ckpt-";
const STORE_FILE: &str = "store.safetensors";
const MAPS_FILE: &str = "maps.safetensors";
const PHI_FILE: &str = "phi.safetensors";
const GRAPH_FILE: &str = "graph.safetensors";
const STATE_FILE: &str = "state.json";

/// Why a graph-service checkpoint could not be written or restored.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// A file could not be read or written, is corrupt, or the checkpoint is incompatible
    /// (another format or protocol, or other state-shaping config values).
    #[error(transparent)]
    File(#[from] FileError),
    /// Building the fresh service or its φ failed.
    #[error(transparent)]
    Service(#[from] GraphServiceError),
}

fn corrupt(path: &Path, problem: impl Into<String>) -> CheckpointError {
    ckpt::corrupt(path, problem).into()
}

/// `manifest.json`: what a checkpoint is and how to check it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// [`PROTOCOL_VERSION`] of the writer.
    pub protocol_version: u32,
    /// The values the saved state depends on, by name: `obs_dim`, `latent_dim`,
    /// `graph.cell_size`, `graph.max_stored_steps`, `exploration.count_cell_size` and
    /// `encoder.layout_hash`. Graph-only settings (node cap, edge window, node position) are
    /// not here: the graph is rebuilt on restore.
    pub shape: BTreeMap<String, String>,
    /// Sequence number N of `ckpt-N`.
    pub sequence: u64,
    /// States in the store when it was written.
    pub stored_steps: u64,
    /// φ version held when it was written: 0 for none and for the learner's initial φ alike
    /// (`phi.safetensors` is listed exactly when a φ is held).
    pub phi_version: u64,
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

/// Complete checkpoints in `dir` (the graph-service's folder), newest first; empty when the
/// folder does not exist.
pub fn checkpoints_newest_first(dir: &Path) -> Result<Vec<PathBuf>, CheckpointError> {
    let mut all = ckpt::list(dir, PREFIX)?;
    all.reverse();
    Ok(all.into_iter().map(|(_, path)| path).collect())
}

/// The sequence number N of a checkpoint folder named `ckpt-N`.
pub fn sequence_of(folder_name: &str) -> Option<u64> {
    folder_name.strip_prefix(PREFIX)?.parse().ok()
}

/// The result of [`GraphService::restore_newest_valid`].
#[derive(Debug)]
pub struct Resumed {
    /// The service and the checkpoint it came from; `None` when no checkpoint could be used.
    pub restored: Option<(GraphService, Checkpoint)>,
    /// Newer checkpoints that were refused, newest first, with the reason.
    pub refused: Vec<(PathBuf, CheckpointError)>,
}

impl GraphService {
    /// Writes a checkpoint into `dir` (created if missing) as `ckpt-N`, N one more than the
    /// newest there, then removes all but the newest [`KEEP`].
    pub fn save(&self, dir: &Path) -> Result<Checkpoint, CheckpointError> {
        self.save_protecting(dir, None)
    }

    /// [`GraphService::save`], but the checkpoint `ckpt-<protected>` is kept too, however
    /// old (serial mode: the base its newest serial checkpoint replays from).
    pub fn save_protecting(
        &self,
        dir: &Path,
        protected: Option<u64>,
    ) -> Result<Checkpoint, CheckpointError> {
        let mut folder = TmpFolder::begin(dir, PREFIX, TMP_PREFIX)?;
        let store = save_store(&self.store).map_err(|p| corrupt(&folder.path_of(STORE_FILE), p))?;
        folder.add(STORE_FILE, &store)?;
        drop(store);
        let maps = save_maps(self).map_err(|p| corrupt(&folder.path_of(MAPS_FILE), p))?;
        folder.add(MAPS_FILE, &maps)?;
        if let Some(phi) = &self.phi {
            let weights = phi.encoder_weights().ok_or_else(|| {
                corrupt(
                    &folder.path_of(PHI_FILE),
                    "the φ held was not loaded from a weights message; its tensors are unknown",
                )
            })?;
            folder.add(PHI_FILE, weights)?;
        }
        if let Some(graph) = &self.graph {
            let bytes = save_graph(graph).map_err(|p| corrupt(&folder.path_of(GRAPH_FILE), p))?;
            folder.add(GRAPH_FILE, &bytes)?;
        }
        let state = serde_json::to_vec_pretty(&SavedState::of(self))
            .map_err(|e| corrupt(&folder.path_of(STATE_FILE), e.to_string()))?;
        folder.add(STATE_FILE, &state)?;
        let manifest = Manifest {
            format_version: FORMAT_VERSION,
            protocol_version: PROTOCOL_VERSION,
            shape: self.shape(),
            sequence: folder.sequence(),
            stored_steps: self.store.n_states(),
            phi_version: self.phi_version().0,
            files: folder.files().to_vec(),
        };
        let json = serde_json::to_vec_pretty(&manifest)
            .map_err(|e| corrupt(&folder.path_of(MANIFEST), e.to_string()))?;
        let path = folder.commit_protecting(MANIFEST, &json, KEEP, protected)?;
        Ok(Checkpoint { path, manifest })
    }

    /// A service restored from the checkpoint folder `path` (a `ckpt-N`) for `config` and the
    /// task's `dims`, with the graph it had (rebuilt from the store for a checkpoint written
    /// before graphs were saved). Refused with a [`CheckpointError`] naming the file
    /// when the checkpoint is incompatible, corrupt or truncated; nothing is returned
    /// half-loaded.
    pub fn restore(
        path: &Path,
        config: &Config,
        dims: nets::TaskDims,
    ) -> Result<(GraphService, Checkpoint), CheckpointError> {
        // The seed only initialises the generator and φ parameters, which are restored.
        let mut service = GraphService::new(config, dims, config.run.seed)?;
        let manifest_path = path.join(MANIFEST);
        let manifest: Manifest = ckpt::read_manifest(path, MANIFEST)?;
        let sum = check_compatible(&service, &manifest, &manifest_path)?;
        let blobs = ckpt::read_checked(path, &manifest.files, &manifest_path, sum)?;
        let file = |name: &str| {
            blobs
                .get(name)
                .map(Vec::as_slice)
                .ok_or_else(|| corrupt(&path.join(name), "missing from the manifest"))
        };
        let state: SavedState = serde_json::from_slice(file(STATE_FILE)?)
            .map_err(|e| corrupt(&path.join(STATE_FILE), e.to_string()))?;
        let store = restore_store(&service.store, file(STORE_FILE)?)
            .map_err(|p| corrupt(&path.join(STORE_FILE), p))?;
        service.store = store;
        restore_maps(&mut service, file(MAPS_FILE)?)
            .map_err(|p| corrupt(&path.join(MAPS_FILE), p))?;
        // φ version 0 is the learner's initial φ, a φ like any other: whether one is held is
        // whether its tensors were saved (a φ-0 service restored without it would re-map every
        // stored state at the next broadcast of φ 0, which the saved one ignored).
        let phi_saved = manifest.files.iter().any(|f| f.name == PHI_FILE);
        if phi_saved || state.phi_version > 0 {
            let phi = service
                .loader
                .restore(file(PHI_FILE)?, PhiVersion(state.phi_version))
                .map_err(|e| corrupt(&path.join(PHI_FILE), e.to_string()))?;
            service.phi = Some(phi);
        }
        let graph_saved = state.graph_saved;
        state.apply(&mut service);
        if !graph_saved {
            service.rebuild();
        } else if manifest.files.iter().any(|f| f.name == GRAPH_FILE) {
            let graph = restore_graph(service.grid, file(GRAPH_FILE)?)
                .map_err(|p| corrupt(&path.join(GRAPH_FILE), p))?;
            service.set_graph(graph);
        }
        Ok((
            service,
            Checkpoint {
                path: path.to_path_buf(),
                manifest,
            },
        ))
    }

    /// [`GraphService::restore`] of the newest checkpoint in `dir` that restores; the newer
    /// ones that did not are returned with their errors. `Err` only when `dir` cannot be
    /// listed.
    pub fn restore_newest_valid(
        dir: &Path,
        config: &Config,
        dims: nets::TaskDims,
    ) -> Result<Resumed, CheckpointError> {
        let mut refused = Vec::new();
        for path in checkpoints_newest_first(dir)? {
            match Self::restore(&path, config, dims) {
                Ok(restored) => {
                    return Ok(Resumed {
                        restored: Some(restored),
                        refused,
                    })
                }
                Err(err) => refused.push((path, err)),
            }
        }
        Ok(Resumed {
            restored: None,
            refused,
        })
    }

    /// The values the saved state depends on ([`Manifest::shape`]).
    fn shape(&self) -> BTreeMap<String, String> {
        [
            ("obs_dim", self.store.obs_dim().to_string()),
            ("latent_dim", self.layout.latent_dim.to_string()),
            ("graph.cell_size", self.grid.cell_size().to_string()),
            (
                "graph.max_stored_steps",
                self.store.max_states().to_string(),
            ),
            (
                "exploration.count_cell_size",
                self.hess.params().cell_size.to_string(),
            ),
            (
                "encoder.layout_hash",
                format!("{:016x}", self.loader.encoder_hash()),
            ),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect()
    }
}

/// Versions and shape of `manifest` against this service's; the checksum its format lists
/// files with.
fn check_compatible(
    service: &GraphService,
    manifest: &Manifest,
    path: &Path,
) -> Result<Checksum, CheckpointError> {
    let differ = |what: &str, expected: String, found: String| -> CheckpointError {
        ckpt::incompatible(path, what, expected, found).into()
    };
    let versions = (manifest.format_version, manifest.protocol_version);
    let sum = ckpt::check_versions(path, versions, FORMAT_VERSION, PROTOCOL_VERSION)?;
    let ours = service.shape();
    for (key, expected) in &ours {
        let found = manifest.shape.get(key).cloned();
        if found.as_ref() != Some(expected) {
            let found = found.unwrap_or_else(|| "missing".to_owned());
            return Err(differ(key, expected.clone(), found));
        }
    }
    if let Some(key) = manifest.shape.keys().find(|k| !ours.contains_key(*k)) {
        return Err(differ(
            key,
            "absent".to_owned(),
            manifest.shape[key].clone(),
        ));
    }
    Ok(sum)
}

/// `store.safetensors`: see the module doc.
fn save_store(store: &TrajectoryStore) -> Result<Vec<u8>, String> {
    let n = usize::try_from(store.n_states()).map_err(|e| e.to_string())?;
    let heads: Vec<(TrajectoryHead, u64)> = store
        .trajectories()
        .map(|t| (t.head(), t.len() as u64))
        .collect();
    let obs = Array::from_iter(
        vec![n, store.obs_dim()],
        store.trajectories().flat_map(|t| t.obs().iter().copied()),
    )?;
    let latents = Array::from_iter(
        vec![n, 2],
        store
            .trajectories()
            .flat_map(|t| t.latents().iter().flatten().copied()),
    )?;
    let column = |f: fn(&(TrajectoryHead, u64)) -> u64| heads.iter().map(f).collect::<Vec<u64>>();
    let counters = store.counters();
    let arrays = vec![
        ("obs", obs),
        ("latents", latents),
        (
            "actor",
            Array::flat(&heads.iter().map(|(h, _)| h.actor.0).collect::<Vec<u32>>()),
        ),
        ("episode", Array::flat(&column(|(h, _)| h.episode.0))),
        (
            "first_env_step",
            Array::flat(&column(|(h, _)| h.first_env_step)),
        ),
        ("len", Array::flat(&column(|&(_, len)| len))),
        (
            "next_chunk",
            Array::flat(
                &heads
                    .iter()
                    .map(|(h, _)| h.next_chunk)
                    .collect::<Vec<u32>>(),
            ),
        ),
        (
            "closed",
            Array::flat(
                &heads
                    .iter()
                    .map(|(h, _)| u8::from(h.closed))
                    .collect::<Vec<u8>>(),
            ),
        ),
        (
            "open_actor",
            Array::flat(&counters.open.iter().map(|o| o.0 .0).collect::<Vec<u32>>()),
        ),
        (
            "open_episode",
            Array::flat(&counters.open.iter().map(|o| o.1 .0).collect::<Vec<u64>>()),
        ),
        (
            "open_serial",
            Array::flat(&counters.open.iter().map(|o| o.2).collect::<Vec<u64>>()),
        ),
    ];
    let metadata = HashMap::from([
        ("front_serial".to_owned(), counters.front_serial.to_string()),
        ("n_evicted".to_owned(), counters.n_evicted.to_string()),
        ("n_gaps".to_owned(), counters.n_gaps.to_string()),
    ]);
    let tensors = arrays
        .iter()
        .map(|(name, a)| ((*name).to_owned(), a))
        .collect();
    ckpt::serialize(tensors, metadata)
}

/// A store like `fresh` (its width and cap) with the contents of `store.safetensors`.
fn restore_store(fresh: &TrajectoryStore, bytes: &[u8]) -> Result<TrajectoryStore, String> {
    let (st, metadata) = ckpt::parse(bytes)?;
    let obs_dim = fresh.obs_dim();
    let actor = array::<u32>(&st, "actor", None)?;
    let k = Some(actor.len());
    let episode = array::<u64>(&st, "episode", k)?;
    let first_env_step = array::<u64>(&st, "first_env_step", k)?;
    let len = array::<u64>(&st, "len", k)?;
    let next_chunk = array::<u32>(&st, "next_chunk", k)?;
    let closed = array::<u8>(&st, "closed", k)?;
    let lens = len
        .iter()
        .map(|&l| usize::try_from(l).map_err(|e| e.to_string()))
        .collect::<Result<Vec<usize>, _>>()?;
    let n_states = lens
        .iter()
        .try_fold(0usize, |total, &l| total.checked_add(l))
        .filter(|&n| n as u64 <= fresh.max_states())
        .ok_or_else(|| {
            format!(
                "trajectory lengths exceed the cap of {}",
                fresh.max_states()
            )
        })?;
    let obs = array::<f32>(&st, "obs", Some(n_states * obs_dim))?;
    let latents = array::<f32>(&st, "latents", Some(n_states * 2))?;
    let mut trajectories = Vec::with_capacity(lens.len());
    let mut start = 0;
    for (i, &l) in lens.iter().enumerate() {
        let head = TrajectoryHead {
            actor: ActorId(actor[i]),
            episode: EpisodeId(episode[i]),
            first_env_step: first_env_step[i],
            next_chunk: next_chunk[i],
            closed: closed[i] != 0,
        };
        let points: Vec<LatentPoint> = latents[2 * start..2 * (start + l)]
            .chunks_exact(2)
            .map(|p| [p[0], p[1]])
            .collect();
        let rows = obs[start * obs_dim..(start + l) * obs_dim].to_vec();
        let trajectory = Trajectory::from_parts(head, obs_dim, rows, points)
            .ok_or("a trajectory's states and latent points differ in number")?;
        trajectories.push(trajectory);
        start += l;
    }
    let open_actor = array::<u32>(&st, "open_actor", None)?;
    let m = Some(open_actor.len());
    let open_episode = array::<u64>(&st, "open_episode", m)?;
    let open_serial = array::<u64>(&st, "open_serial", m)?;
    let counters = StoreCounters {
        front_serial: meta(&metadata, "front_serial")?,
        open: open_actor
            .into_iter()
            .zip(open_episode)
            .zip(open_serial)
            .map(|((a, e), s)| (ActorId(a), EpisodeId(e), s))
            .collect(),
        n_evicted: meta(&metadata, "n_evicted")?,
        n_gaps: meta(&metadata, "n_gaps")?,
    };
    TrajectoryStore::from_parts(obs_dim, fresh.max_states(), trajectories, counters)
}

/// Cells and values as two arrays: keys `[n, 2]` (i32) and values `[n]`.
fn cell_arrays<V: ckpt::Element>(cells: &[(CellKey, V)]) -> Result<(Array, Array), String> {
    let keys = Array::from_iter(vec![cells.len(), 2], cells.iter().flat_map(|(k, _)| k.0))?;
    let values = Array::flat(&cells.iter().map(|&(_, v)| v).collect::<Vec<V>>());
    Ok((keys, values))
}

/// The cells saved by [`cell_arrays`] under `name`.
fn read_cells<V: ckpt::Element>(st: &SafeTensors, name: &str) -> Result<Vec<(CellKey, V)>, String> {
    let values = array::<V>(st, &format!("{name}.values"), None)?;
    let keys = array::<i32>(st, &format!("{name}.keys"), Some(2 * values.len()))?;
    Ok(keys
        .chunks_exact(2)
        .map(|k| CellKey([k[0], k[1]]))
        .zip(values)
        .collect())
}

/// `graph.safetensors`: see the module doc.
fn save_graph(graph: &LatentGraph) -> Result<Vec<u8>, String> {
    let keys = Array::from_iter(
        vec![graph.n_nodes(), 2],
        graph.keys().iter().flat_map(|k| k.0),
    )?;
    let edges = Array::from_iter(
        vec![graph.n_edges(), 3],
        graph.edges().iter().flat_map(|&(a, b, w)| [a, b, w]),
    )?;
    let metadata = HashMap::from([
        (
            "dropped_cells".to_owned(),
            graph.n_dropped_cells().to_string(),
        ),
        (
            "unmapped_states".to_owned(),
            graph.n_unmapped_states().to_string(),
        ),
    ]);
    ckpt::serialize(
        vec![("keys".to_owned(), &keys), ("edges".to_owned(), &edges)],
        metadata,
    )
}

/// The graph saved by [`save_graph`], on `grid`; checked as [`LatentGraph::from_parts`] does.
fn restore_graph(grid: Grid, bytes: &[u8]) -> Result<LatentGraph, String> {
    let (st, metadata) = ckpt::parse(bytes)?;
    let keys = array::<i32>(&st, "keys", None)?;
    let edges = array::<u32>(&st, "edges", None)?;
    if keys.len() % 2 != 0 || edges.len() % 3 != 0 {
        return Err(format!(
            "{} key values and {} edge values: not [n, 2] and [m, 3]",
            keys.len(),
            edges.len()
        ));
    }
    LatentGraph::from_parts(
        grid,
        keys.chunks_exact(2)
            .map(|k| CellKey([k[0], k[1]]))
            .collect(),
        edges.chunks_exact(3).map(|e| (e[0], e[1], e[2])).collect(),
        meta(&metadata, "dropped_cells")?,
        meta(&metadata, "unmapped_states")?,
    )
}

/// `maps.safetensors`: see the module doc.
fn save_maps(service: &GraphService) -> Result<Vec<u8>, String> {
    let hess = service.hess.parts();
    let mut arrays = Vec::new();
    let mut push = |name: &str, (keys, values): (Array, Array)| {
        arrays.push((format!("{name}.keys"), keys));
        arrays.push((format!("{name}.values"), values));
    };
    push("counts", cell_arrays(&service.counts.entries())?);
    push("visits", cell_arrays(&hess.visits)?);
    push("future", cell_arrays(&hess.future)?);
    push("potential", cell_arrays(&hess.potential)?);
    let metadata = HashMap::from([
        (
            "episodes_since_future".to_owned(),
            hess.episodes_since_future.to_string(),
        ),
        (
            "n_future_recomputes".to_owned(),
            hess.n_future_recomputes.to_string(),
        ),
        (
            "n_reach_samples".to_owned(),
            hess.n_reach_samples.to_string(),
        ),
        (
            "episodes_stored".to_owned(),
            hess.episodes_stored.to_string(),
        ),
    ]);
    let tensors = arrays.iter().map(|(name, a)| (name.clone(), a)).collect();
    ckpt::serialize(tensors, metadata)
}

/// Fills the visit counts and HESS maps of `service` (whose store is already restored) from
/// `maps.safetensors`; the counts must equal a recount of the store.
fn restore_maps(service: &mut GraphService, bytes: &[u8]) -> Result<(), String> {
    let (st, metadata) = ckpt::parse(bytes)?;
    let parts = HessParts {
        visits: read_cells(&st, "visits")?,
        future: read_cells(&st, "future")?,
        potential: read_cells(&st, "potential")?,
        episodes_since_future: meta(&metadata, "episodes_since_future")?,
        n_future_recomputes: meta(&metadata, "n_future_recomputes")?,
        n_reach_samples: meta(&metadata, "n_reach_samples")?,
        // Checkpoints written before the counter existed: the store's closed trajectories
        // (the same number unless the store evicted).
        episodes_stored: match metadata.get("episodes_stored") {
            Some(_) => meta(&metadata, "episodes_stored")?,
            None => service
                .store
                .trajectories()
                .filter(|t| t.is_closed())
                .count() as u64,
        },
    };
    service.hess = HessMaps::from_parts(service.hess.params().clone(), parts)?;
    let saved: Vec<(CellKey, u64)> = read_cells(&st, "counts")?;
    service.counts.clear();
    for trajectory in service.store.trajectories() {
        service.counts.add(trajectory.latents());
    }
    if service.counts.entries() != saved {
        return Err("the visit counts differ from a recount of the stored states".to_owned());
    }
    Ok(())
}

/// `state.json`: the scalar state of the service.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SavedState {
    phi_version: u64,
    graph_version: u64,
    /// The graph is in `graph.safetensors` (none there: there was no graph); false in
    /// checkpoints written before graphs were saved, whose restore rebuilds it.
    #[serde(default)]
    graph_saved: bool,
    rng: Pcg64,
    chunks: u64,
    rejected_chunks: u64,
    per_actor_steps: Vec<(u32, u64)>,
    requests: u64,
    invalid_requests: u64,
    stale_phi_requests: u64,
    explore_answers: u64,
    frontier_not_found: u64,
    routes_not_found: u64,
}

impl SavedState {
    fn of(service: &GraphService) -> Self {
        let s = &service.stats;
        Self {
            phi_version: service.phi_version().0,
            graph_version: service.graph_version,
            graph_saved: true,
            rng: service.rng.clone(),
            chunks: s.chunks,
            rejected_chunks: s.rejected_chunks,
            per_actor_steps: s.per_actor_steps.iter().map(|(&a, &n)| (a, n)).collect(),
            requests: s.requests,
            invalid_requests: s.invalid_requests,
            stale_phi_requests: s.stale_phi_requests,
            explore_answers: s.explore_answers,
            frontier_not_found: s.frontier_not_found,
            routes_not_found: s.routes_not_found,
        }
    }

    /// Sets the counters, generator and graph version (a rebuild after it adds one).
    fn apply(self, service: &mut GraphService) {
        service.graph_version = self.graph_version;
        service.rng = self.rng;
        let s = &mut service.stats;
        s.chunks = self.chunks;
        s.rejected_chunks = self.rejected_chunks;
        s.per_actor_steps = self.per_actor_steps.into_iter().collect();
        s.requests = self.requests;
        s.invalid_requests = self.invalid_requests;
        s.stale_phi_requests = self.stale_phi_requests;
        s.explore_answers = self.explore_answers;
        s.frontier_not_found = self.frontier_not_found;
        s.routes_not_found = self.routes_not_found;
    }
}
