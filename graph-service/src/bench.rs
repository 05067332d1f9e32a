//! Speed measurements of the graph-service's heavy steps on synthetic data, for `asi bench
//! graph` (which prints them and runs the scipy comparison). Nothing here is used at run time.
//!
//! Synthetic store: episodes of `episode_len` steps (+1 final state) in an `obs_dim`-D
//! observation space; each episode starts at a uniform point of a square xy region and random
//! walks (uniform steps of ±`XY_STEP` in x and y, ±`JOINT_STEP` in the other dimensions). A
//! random-init φ maps such walks into a handful of cells, which would make the graph trivial,
//! so the graph is built from the walks' xy (what a trained φ resembles: a region of about
//! `REGION_CELLS`² cells of the default side 2, covered densely enough by the walks that the
//! graph is one connected component of about 5,000 nodes, the default cap). The φ re-mapping is
//! timed with the real encoder of the default config on the same observations.
//!
//! A rebuild is what [`crate::GraphService::load_weights`] does: re-map every stored state
//! (the fused forward of [`crate::fused`] on `graph.remap_threads` threads), rebuild the graph,
//! recount the visit counts and recompute HESS's future counts. The three parts are timed
//! separately; [`time_candle_map`] times the former candle re-map for comparison.
//! [`time_checkpoint`] times a graph-service checkpoint of such a store (write, restore).

use std::path::Path;
use std::time::Instant;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use protocol::config::Config;
use protocol::{ActorId, EpisodeId, LatentPoint, PhiVersion};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

use crate::checkpoint::CheckpointError;
use crate::counts::VisitCounts;
use crate::error::GraphServiceError;
use crate::frontier::route_between;
use crate::graph::{GraphBuilder, LatentGraph, NodeId};
use crate::grid::Grid;
use crate::hess::{HessMaps, HessParams};
use crate::phi::Phi;
use crate::service::{remap, GraphService};
use crate::store::{ChunkStates, TrajectoryStore};

/// Largest xy step of the synthetic walks per env step, φ units.
const XY_STEP: f32 = 0.5;
/// Largest step of the other observation dimensions per env step.
const JOINT_STEP: f32 = 0.05;
/// Side of the square start region, in cells of the config's graph grid.
/// 63 makes the 1 M-step store one connected graph of 4,964 nodes (seed 0), just under the
/// default cap of 5,000 (64 already drops cells, 75 leaves 1 % outside the largest component).
pub const REGION_CELLS: f32 = 63.0;

/// Timings of one rebuild.
#[derive(Debug, Clone, PartialEq)]
pub struct RebuildTiming {
    /// Stored states.
    pub n_steps: u64,
    /// Stored trajectories.
    pub n_trajectories: usize,
    /// φ re-mapping of every stored state, seconds.
    pub map_secs: f64,
    /// Graph construction from the latent points, seconds.
    pub build_secs: f64,
    /// Visit recount and HESS future-count recomputation, seconds.
    pub counts_secs: f64,
    /// Nodes of the built graph.
    pub n_nodes: usize,
    /// Undirected edges of the built graph.
    pub n_edges: usize,
}

/// A synthetic store of about `n_steps` states (whole episodes, see the module doc).
pub fn synthetic_store(
    config: &Config,
    obs_dim: usize,
    n_steps: u64,
    episode_len: usize,
    seed: u64,
) -> TrajectoryStore {
    synthetic_store_in(config, obs_dim, n_steps, episode_len, seed, REGION_CELLS)
}

/// [`synthetic_store`] with walks starting in a square of `region_cells` cells a side.
fn synthetic_store_in(
    config: &Config,
    obs_dim: usize,
    n_steps: u64,
    episode_len: usize,
    seed: u64,
    region_cells: f32,
) -> TrajectoryStore {
    let mut rng = Pcg64::seed_from_u64(seed);
    let region = region_cells * config.graph.cell_size as f32;
    let per_episode = (episode_len + 1) as u64;
    let mut store = TrajectoryStore::new(obs_dim, n_steps.max(per_episode));
    for episode in 0..n_steps.div_ceil(per_episode) {
        let (obs, latents) = random_walk(&mut rng, obs_dim, episode_len, region);
        store.append(ChunkStates {
            actor: ActorId(0),
            episode: EpisodeId(episode),
            chunk_index: 0,
            first_env_step: 0,
            episode_start: true,
            episode_end: true,
            obs,
            latents,
        });
    }
    store
}

/// One episode: `episode_len + 1` states, flat observations and their xy.
fn random_walk(
    rng: &mut Pcg64,
    obs_dim: usize,
    episode_len: usize,
    region: f32,
) -> (Vec<f32>, Vec<LatentPoint>) {
    let mut state: Vec<f32> = (0..obs_dim).map(|_| rng.random_range(-0.1..0.1)).collect();
    state[0] = rng.random_range(0.0..region);
    state[1] = rng.random_range(0.0..region);
    let mut obs = Vec::with_capacity((episode_len + 1) * obs_dim);
    let mut latents = Vec::with_capacity(episode_len + 1);
    for _ in 0..=episode_len {
        obs.extend_from_slice(&state);
        latents.push([state[0], state[1]]);
        for (i, value) in state.iter_mut().enumerate() {
            let step = if i < 2 { XY_STEP } else { JOINT_STEP };
            *value += rng.random_range(-step..step);
        }
    }
    (obs, latents)
}

/// The default config's encoder φ for `obs_dim`-D observations, seeded.
pub fn random_phi(config: &Config, obs_dim: usize, seed: u64) -> Result<Phi, GraphServiceError> {
    let dims = nets::TaskDims {
        obs_dim,
        goal_dim: 2,
        action_dim: 8,
        action_scale: 1.0,
    };
    let spec = nets::spec_from_config(config, dims)?;
    let params = VarMap::new();
    let vb = nets::seeded_var_builder(&params, seed, &Device::Cpu);
    let set = nets::PolicySet::new(&spec, &vb)?;
    Phi::new(set.encoder, PhiVersion(1))
}

/// Times one rebuild of `store` (see the module doc), the re-map on
/// `config.graph.remap_threads` threads as the service runs it, and returns the graph with
/// the timings.
pub fn time_rebuild(
    config: &Config,
    store: &TrajectoryStore,
    phi: &Phi,
) -> Result<(RebuildTiming, LatentGraph), GraphServiceError> {
    let start = Instant::now();
    let mapped = remap(phi, store, config.graph.remap_threads)?;
    let map_secs = start.elapsed().as_secs_f64();
    let n_mapped: usize = mapped.iter().map(Vec::len).sum();
    if n_mapped as u64 != store.n_states() {
        return Err(GraphServiceError::Internal(format!(
            "mapped {n_mapped} of {} states",
            store.n_states()
        )));
    }

    let graph_config = &config.graph;
    let grid = Grid::new(graph_config.cell_size, graph_config.node_position);
    let start = Instant::now();
    let mut builder = GraphBuilder::new(grid, graph_config.max_nodes, graph_config.edge_window);
    for trajectory in store.trajectories() {
        builder.add_trajectory(trajectory.latents());
    }
    let graph = builder.finish();
    let build_secs = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let mut counts = VisitCounts::new(grid);
    let mut hess = HessMaps::new(HessParams::from_config(config));
    for trajectory in store.trajectories() {
        counts.add(trajectory.latents());
        hess.count(trajectory.latents());
    }
    hess.recompute_future(store);
    let counts_secs = start.elapsed().as_secs_f64();

    let timing = RebuildTiming {
        n_steps: store.n_states(),
        n_trajectories: store.n_trajectories(),
        map_secs,
        build_secs,
        counts_secs,
        n_nodes: graph.n_nodes(),
        n_edges: graph.n_edges(),
    };
    Ok((timing, graph))
}

/// Times the map of every stored state with the candle encoder on 4096-row batches (the
/// re-map before the fused forward), for comparison; seconds.
pub fn time_candle_map(store: &TrajectoryStore, phi: &Phi) -> Result<f64, GraphServiceError> {
    let obs_dim = phi.encoder().obs_dim();
    let start = Instant::now();
    for trajectory in store.trajectories() {
        for batch in trajectory.obs().chunks(4096 * obs_dim) {
            let input = Tensor::from_slice(batch, (batch.len() / obs_dim, obs_dim), &Device::Cpu)?;
            phi.encoder().forward(&input)?.to_vec2::<f32>()?;
        }
    }
    Ok(start.elapsed().as_secs_f64())
}

/// Size and timings of one graph-service checkpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckpointTiming {
    /// Stored states.
    pub n_steps: u64,
    /// Size of the checkpoint's files, bytes.
    pub bytes: u64,
    /// [`GraphService::save`], seconds (files written and synced, folder renamed).
    pub write_secs: f64,
    /// [`GraphService::restore`], seconds (files read and checked, state and graph parsed and
    /// checked).
    pub restore_secs: f64,
}

/// Times a checkpoint of a service holding `store` (its visit counts and HESS maps counted,
/// future counts computed, a seeded φ held, its graph built) written into `dir` and restored from there; the
/// restored store is checked equal to the saved one. `config.graph.max_stored_steps` is
/// set to the store's cap.
pub fn time_checkpoint(
    config: &Config,
    store: TrajectoryStore,
    dir: &Path,
) -> Result<CheckpointTiming, CheckpointError> {
    let mut config = config.clone();
    config.graph.max_stored_steps = store.max_states();
    let dims = nets::TaskDims {
        obs_dim: store.obs_dim(),
        goal_dim: 2,
        action_dim: 8,
        action_scale: 1.0,
    };
    let mut service = GraphService::new(&config, dims, 0)?;
    for trajectory in store.trajectories() {
        service.counts.add(trajectory.latents());
        service.hess.count(trajectory.latents());
    }
    service.hess.recompute_future(&store);
    service.phi = Some(service.loader.seeded(PhiVersion(1))?);
    service.store = store;
    // A graph of the whole store, as after a φ re-map: the checkpoint holds it.
    service.rebuild();
    let start = Instant::now();
    let ckpt = service.save(dir)?;
    let write_secs = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let (restored, _) = GraphService::restore(&ckpt.path, &config, dims)?;
    let restore_secs = start.elapsed().as_secs_f64();
    if restored.store() != service.store() {
        return Err(GraphServiceError::Internal(
            "the restored store differs from the saved one".to_owned(),
        )
        .into());
    }
    Ok(CheckpointTiming {
        n_steps: service.store().n_states(),
        bytes: ckpt.manifest.total_bytes(),
        write_secs,
        restore_secs,
    })
}

/// One timed route query.
#[derive(Debug, Clone, PartialEq)]
pub struct RouteSample {
    /// Start node.
    pub from: NodeId,
    /// End node.
    pub to: NodeId,
    /// Graph distance (env steps), `None` when unreachable.
    pub distance: Option<u64>,
    /// Wall time of the query, seconds.
    pub secs: f64,
    /// CPU time of the querying thread during the query, seconds (`None` without a clock):
    /// unlike the wall time, it leaves out time the thread spent descheduled.
    pub cpu_secs: Option<f64>,
}

/// Times `n_queries` routes between uniformly random node pairs of `graph` (seeded), each
/// the full query the service runs ([`route_between`]: a lookup in the graph's route table
/// once built, otherwise Dijkstra and path recovery).
/// `thread_cpu_secs`, if given, reads the calling thread's CPU time in seconds.
pub fn time_routes(
    graph: &LatentGraph,
    n_queries: usize,
    seed: u64,
    thread_cpu_secs: Option<fn() -> f64>,
) -> Vec<RouteSample> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let n = graph.n_nodes() as NodeId;
    if n == 0 {
        return Vec::new();
    }
    (0..n_queries)
        .map(|_| {
            let (from, to) = (rng.random_range(0..n), rng.random_range(0..n));
            let cpu_start = thread_cpu_secs.map(|clock| clock());
            let start = Instant::now();
            let route = route_between(graph, from, to);
            let secs = start.elapsed().as_secs_f64();
            let cpu_secs = thread_cpu_secs
                .zip(cpu_start)
                .map(|(clock, begin)| clock() - begin);
            let distance = route.ok().map(|nodes| path_weight(graph, &nodes));
            RouteSample {
                from,
                to,
                distance,
                secs,
                cpu_secs,
            }
        })
        .collect()
}

/// Fraction of the nodes in the largest connected component (0 for an empty graph).
pub fn largest_component_fraction(graph: &LatentGraph) -> f64 {
    let n = graph.n_nodes();
    let mut component = vec![usize::MAX; n];
    let mut largest = 0;
    for root in 0..n {
        if component[root] != usize::MAX {
            continue;
        }
        component[root] = root;
        let (mut stack, mut size) = (vec![root], 0);
        while let Some(u) = stack.pop() {
            size += 1;
            for &(v, _) in &graph.adjacency()[u] {
                if component[v as usize] == usize::MAX {
                    component[v as usize] = root;
                    stack.push(v as usize);
                }
            }
        }
        largest = largest.max(size);
    }
    if n == 0 {
        0.0
    } else {
        largest as f64 / n as f64
    }
}

/// Sum of the edge weights along `nodes`.
fn path_weight(graph: &LatentGraph, nodes: &[NodeId]) -> u64 {
    nodes
        .windows(2)
        .filter_map(|w| graph.edge_weight(w[0], w[1]))
        .map(u64::from)
        .sum()
}

/// The `q`-quantile (0 ≤ q ≤ 1, nearest rank) of `values`; `None` when empty.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.is_empty() {
        return None;
    }
    sorted.sort_by(f64::total_cmp);
    let rank = ((q.clamp(0.0, 1.0) * sorted.len() as f64).ceil() as usize).max(1);
    sorted.get(rank - 1).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_synthetic_store_rebuilds_into_a_connected_looking_graph() {
        let config = Config::default();
        let store = synthetic_store(&config, 29, 5_010, 500, 1);
        assert_eq!(store.n_states(), 5_010);
        assert_eq!(store.n_trajectories(), 10);
        let phi = random_phi(&config, 29, 2).unwrap();
        let (timing, graph) = time_rebuild(&config, &store, &phi).unwrap();
        assert_eq!(timing.n_nodes, graph.n_nodes());
        assert!(timing.n_nodes > 100, "{timing:?}");
        assert!(
            timing.n_edges >= timing.n_nodes - timing.n_trajectories,
            "{timing:?}"
        );
        let samples = time_routes(&graph, 50, 3, None);
        assert_eq!(samples.len(), 50);
        for s in samples.iter().filter(|s| s.from == s.to) {
            assert_eq!(s.distance, Some(0));
        }
    }

    #[test]
    fn the_bench_store_of_1m_steps_builds_one_connected_graph_of_about_5000_nodes() {
        let config = Config::default();
        let store = synthetic_store(&config, 29, 1_000_000, 500, 0);
        let grid = Grid::new(config.graph.cell_size, config.graph.node_position);
        let mut builder = GraphBuilder::new(grid, config.graph.max_nodes, config.graph.edge_window);
        for trajectory in store.trajectories() {
            builder.add_trajectory(trajectory.latents());
        }
        let graph = builder.finish();
        assert!(
            (4_500..=5_000).contains(&graph.n_nodes()),
            "{} nodes",
            graph.n_nodes()
        );
        assert_eq!(largest_component_fraction(&graph), 1.0);
    }

    #[test]
    fn the_largest_component_fraction_counts_nodes() {
        let grid = Grid::new(1.0, protocol::config::NodePosition::Corner);
        let mut builder = GraphBuilder::new(grid, 100, 1);
        builder.add_trajectory(&[[0.5, 0.5], [1.5, 0.5], [2.5, 0.5]]);
        builder.add_trajectory(&[[10.5, 0.5]]);
        assert_eq!(largest_component_fraction(&builder.finish()), 0.75);
        let empty = GraphBuilder::new(grid, 100, 1).finish();
        assert_eq!(largest_component_fraction(&empty), 0.0);
    }

    #[test]
    fn quantiles_use_the_nearest_rank() {
        let values: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(quantile(&values, 0.5), Some(50.0));
        assert_eq!(quantile(&values, 0.99), Some(99.0));
        assert_eq!(quantile(&values, 1.0), Some(100.0));
        assert_eq!(quantile(&[], 0.5), None);
    }
}
