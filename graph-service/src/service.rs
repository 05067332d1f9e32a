//! [`GraphService`]: the graph-service as a transport-agnostic state machine (no I/O, no
//! threads). The `asi graph-service` process feeds it trajectory chunks, weights messages and
//! requests from iceoryx2; serial mode and tests call the same methods directly.
//!
//! Life cycle: chunks are stored as they arrive (latent points from the chunk's own φ labels
//! when they were computed with the φ held here, else from this φ, else — before any weights —
//! from the labels), and visit counts follow. A weights message with a higher φ version
//! re-maps every stored state and rebuilds the graph; between φ versions the graph is static
//! (as the released code), so new data enters it at the next φ round or on [`GraphService::rebuild`].
//!
//! HESS's maps ([`crate::hess`]) count every stored state on arrival, recompute their future
//! counts every `future_count_interval_episodes` closed episodes and after every φ re-map, and
//! accumulate the potential from reach reports.
//!
//! Invariants: a refused chunk or weights message changes nothing but a counter; visit counts
//! always describe the stored states under the current latent mapping.

use std::collections::BTreeMap;

use protocol::config::{Config, CountModeScore};
use protocol::{
    ActorId, EpisodeId, LatentPoint, PhiVersion, StepLayout, StepView, TrajectoryFlags,
    TrajectoryHeader, WeightsHeader,
};
use rand::SeedableRng;
use rand_pcg::Pcg64;

use crate::counts::VisitCounts;
use crate::error::GraphServiceError;
use crate::frontier::{self, Frontier, NoRoute};
use crate::graph::{GraphBuilder, LatentGraph, NodeId};
use crate::grid::Grid;
use crate::hess::{ExploreChoice, HessMaps, HessParams};
use crate::phi::{Phi, PhiLoader};
use crate::store::{ChunkStates, TrajectoryStore};
use crate::xy::LastFrontier;

/// Counters and sizes of the graph-service.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GraphStats {
    /// States in the trajectory store (a complete T-step episode stores T + 1).
    pub stored_steps: u64,
    /// Trajectories in the store (episodes, or pieces of episodes split by lost chunks).
    pub stored_episodes: u64,
    /// States evicted by the store cap so far.
    pub evicted_steps: u64,
    /// Chunks accepted.
    pub chunks: u64,
    /// Chunks refused (bad version, dims, length, values); each left the store unchanged.
    pub rejected_chunks: u64,
    /// Chunks that did not continue their episode (a lost chunk) and started a new trajectory.
    pub chunk_gaps: u64,
    /// Env steps (records) accepted per actor id.
    pub per_actor_steps: BTreeMap<u32, u64>,
    /// Nodes of the current graph.
    pub n_nodes: usize,
    /// Undirected edges of the current graph.
    pub n_edges: usize,
    /// Distinct cells left out of the current graph by the node cap.
    pub dropped_nodes: u64,
    /// States whose cell key did not fit in `i32` at the last rebuild (no node).
    pub unmapped_states: u64,
    /// Graph rebuilds so far; 0 = no graph yet.
    pub graph_version: u64,
    /// φ version of the stored latent points and the graph (0 before any weights).
    pub phi_version: PhiVersion,
    /// Requests answered.
    pub requests: u64,
    /// Requests answered with an error status (malformed, wrong version, non-finite, …).
    pub invalid_requests: u64,
    /// Requests whose φ version differed from the graph's (answered all the same).
    pub stale_phi_requests: u64,
    /// Cells of the HESS count grid with at least one visit.
    pub hess_visited_cells: u64,
    /// HESS future-count recomputations so far.
    pub future_count_recomputes: u64,
    /// Reach samples added to the potential map.
    pub reach_samples: u64,
    /// Explore subgoals answered.
    pub explore_answers: u64,
    /// Frontier requests answered without a frontier (start cell unknown or nothing reachable).
    pub frontier_not_found: u64,
    /// Route queries answered `NoRoute`.
    pub routes_not_found: u64,
}

/// The graph-service state machine.
#[derive(Debug, Clone)]
pub struct GraphService {
    pub(crate) layout: StepLayout,
    pub(crate) grid: Grid,
    max_nodes: usize,
    edge_window: u32,
    /// `graph.remap_threads`.
    remap_threads: usize,
    /// `graph.route_table_max_nodes`.
    route_table_max_nodes: usize,
    pub(crate) frontier_fraction: f64,
    /// How `LeastVisited` scores FR count-mode candidates (`asi.count_mode_score`).
    pub(crate) count_mode_score: CountModeScore,
    pub(crate) loader: PhiLoader,
    pub(crate) phi: Option<Phi>,
    pub(crate) store: TrajectoryStore,
    pub(crate) counts: VisitCounts,
    pub(crate) hess: HessMaps,
    pub(crate) graph: Option<LatentGraph>,
    pub(crate) graph_version: u64,
    pub(crate) rng: Pcg64,
    pub(crate) stats: GraphStats,
    /// The last frontier answered, for the maze picture ([`crate::xy`]); not checkpointed.
    pub(crate) last_frontier: Option<LastFrontier>,
}

impl GraphService {
    /// A service for the run's `config` (validated) and the task's `dims`; `seed` drives the
    /// frontier choices.
    pub fn new(
        config: &Config,
        dims: nets::TaskDims,
        seed: u64,
    ) -> Result<GraphService, GraphServiceError> {
        config
            .validate()
            .map_err(|errors| GraphServiceError::Config(errors.to_string()))?;
        if config.encoder.out_dim != 2 {
            return Err(GraphServiceError::Config(format!(
                "encoder.out_dim is {}; the latent grid is 2-D",
                config.encoder.out_dim
            )));
        }
        let spec = nets::spec_from_config(config, dims)?;
        let layout = StepLayout::new(
            dims.obs_dim,
            dims.action_dim,
            dims.goal_dim,
            spec.latent_dim,
        )?;
        let graph = &config.graph;
        let grid = Grid::new(graph.cell_size, graph.node_position);
        Ok(GraphService {
            layout,
            grid,
            max_nodes: graph.max_nodes,
            edge_window: graph.edge_window,
            remap_threads: graph.remap_threads,
            route_table_max_nodes: graph.route_table_max_nodes,
            frontier_fraction: config.asi.frontier_fraction,
            count_mode_score: config.asi.count_mode_score,
            loader: PhiLoader::new(spec, seed)?,
            phi: None,
            store: TrajectoryStore::new(dims.obs_dim, graph.max_stored_steps),
            counts: VisitCounts::new(grid),
            hess: HessMaps::new(HessParams::from_config(config)),
            graph: None,
            graph_version: 0,
            rng: Pcg64::seed_from_u64(seed),
            stats: GraphStats::default(),
            last_frontier: None,
        })
    }

    /// Checks and stores a trajectory chunk (states s_t of its records, plus s_T when it ends
    /// the episode, with latent points as described in the module doc). A bad chunk is an
    /// `Err`, counted in `rejected_chunks`, and leaves the store unchanged.
    pub fn ingest(
        &mut self,
        header: &TrajectoryHeader,
        payload: &[f32],
    ) -> Result<(), GraphServiceError> {
        match self.chunk_states(header, payload) {
            Ok(chunk) => {
                let n_records = u64::from(header.n_steps);
                let episode_end = chunk.episode_end;
                self.counts.add(&chunk.latents);
                self.hess.count_arrival(&chunk.latents);
                let evicted = self.store.append(chunk);
                self.counts.remove(&evicted);
                if episode_end {
                    self.hess.episode_stored(&self.store);
                }
                self.stats.chunks += 1;
                *self
                    .stats
                    .per_actor_steps
                    .entry(header.actor_id.0)
                    .or_insert(0) += n_records;
                Ok(())
            }
            Err(err) => {
                self.stats.rejected_chunks += 1;
                Err(err)
            }
        }
    }

    /// Validates a chunk and extracts its states and latent points; changes nothing.
    fn chunk_states(
        &self,
        header: &TrajectoryHeader,
        payload: &[f32],
    ) -> Result<ChunkStates, GraphServiceError> {
        let layout = header.check(payload.len())?;
        self.check_dims(header, &layout)?;
        let records = layout.view_chunk(payload, header.n_steps as usize)?;
        let end = header.flags.contains(TrajectoryFlags::EPISODE_END);
        let (obs, labels) = gather_states(&records, end);
        let latents = match &self.phi {
            Some(phi) if phi.version() != header.phi_version => phi.map(&obs)?,
            _ => labels,
        };
        Ok(ChunkStates {
            actor: header.actor_id,
            episode: header.episode_id,
            chunk_index: header.chunk_index,
            first_env_step: header.first_env_step,
            episode_start: header.flags.contains(TrajectoryFlags::EPISODE_START),
            episode_end: end,
            obs,
            latents,
        })
    }

    /// `Err(ChunkDims)` unless the chunk's record layout is this task's.
    fn check_dims(
        &self,
        header: &TrajectoryHeader,
        layout: &StepLayout,
    ) -> Result<(), GraphServiceError> {
        let ours = &self.layout;
        let pairs = [
            ("obs_dim", ours.obs_dim, layout.obs_dim),
            ("action_dim", ours.action_dim, layout.action_dim),
            ("goal_dim", ours.goal_dim, layout.goal_dim),
            ("latent_dim", ours.latent_dim, layout.latent_dim),
        ];
        match pairs
            .into_iter()
            .find(|(_, expected, found)| expected != found)
        {
            None => Ok(()),
            Some((field, expected, found)) => Err(GraphServiceError::ChunkDims {
                actor: header.actor_id.0,
                field,
                expected,
                found,
            }),
        }
    }

    /// Loads new φ weights and, if the φ version went up (or is the first), re-maps every
    /// stored state, recounts visits and rebuilds the graph. A message that is not newer is
    /// checked (version, layout hash, length) and otherwise ignored. See [`crate::phi`] for
    /// which layout hashes are accepted. On `Err` nothing changes.
    pub fn load_weights(
        &mut self,
        header: &WeightsHeader,
        bytes: &[u8],
    ) -> Result<(), GraphServiceError> {
        self.loader.check(header, bytes)?;
        if self
            .phi
            .as_ref()
            .is_some_and(|phi| header.phi_version <= phi.version())
        {
            return Ok(());
        }
        let phi = self.loader.load(header, bytes)?;
        let latents = remap(&phi, &self.store, self.remap_threads)?;
        if !self.store.replace_latents(latents) {
            return Err(GraphServiceError::Internal(
                "re-mapped latents do not match the stored trajectories".to_owned(),
            ));
        }
        self.phi = Some(phi);
        self.recount();
        self.rebuild();
        self.hess.recompute_future(&self.store);
        Ok(())
    }

    /// Rebuilds the graph from every stored trajectory with the current latent points, and
    /// starts the background build of its route table ([`crate::route_table`]).
    pub fn rebuild(&mut self) {
        let mut builder = GraphBuilder::new(self.grid, self.max_nodes, self.edge_window);
        for trajectory in self.store.trajectories() {
            builder.add_trajectory(trajectory.latents());
        }
        self.set_graph(builder.finish());
        self.graph_version += 1;
    }

    /// Makes `graph` the current graph and starts the background build of its route table.
    pub(crate) fn set_graph(&mut self, graph: LatentGraph) {
        if graph.n_nodes() <= self.route_table_max_nodes {
            // Without the table routes are searched per query: slower, same answers.
            let _ = graph.spawn_route_table(self.remap_threads);
        }
        self.graph = Some(graph);
    }

    /// Recounts visits from the store.
    fn recount(&mut self) {
        self.counts.clear();
        for trajectory in self.store.trajectories() {
            self.counts.add(trajectory.latents());
        }
    }

    /// φ version of the latent points and graph (0 before any weights).
    pub fn phi_version(&self) -> PhiVersion {
        self.phi.as_ref().map_or(PhiVersion(0), Phi::version)
    }

    /// The current graph, if one has been built.
    pub fn graph(&self) -> Option<&LatentGraph> {
        self.graph.as_ref()
    }

    /// A random frontier seen from `from` and the route to it ([`frontier::frontier`]).
    /// Without a graph the answer is [`NoRoute::EmptyGraph`].
    pub fn frontier_route(&mut self, from: LatentPoint) -> Result<Frontier, NoRoute> {
        let graph = self.graph.as_ref().ok_or(NoRoute::EmptyGraph)?;
        let found = frontier::frontier(graph, from, self.frontier_fraction, &mut self.rng)?;
        self.note_frontier(found.node, &found.route);
        Ok(found)
    }

    /// The route between the cells of two points ([`frontier::route`]).
    /// Without a graph the answer is [`NoRoute::EmptyGraph`].
    pub fn route(&self, start: LatentPoint, end: LatentPoint) -> Result<Vec<NodeId>, NoRoute> {
        let graph = self.graph.as_ref().ok_or(NoRoute::EmptyGraph)?;
        frontier::route(graph, start, end)
    }

    /// Visit count n(v) of the cell holding `point` (`None` if out of range).
    pub fn visits(&self, point: LatentPoint) -> Option<u64> {
        self.counts.at(point)
    }

    /// HESS's count-based explore subgoal near `from` for training episode `episode`
    /// ([`HessMaps::explore`], drawing with the service's RNG); `None` while the store is empty.
    pub fn explore(&mut self, from: LatentPoint, episode: u64) -> Option<ExploreChoice> {
        let choice = self.hess.explore(&self.store, from, episode, &mut self.rng);
        self.stats.explore_answers += u64::from(choice.is_some());
        choice
    }

    /// HESS's maps (visits, future counts, potential).
    pub fn hess(&self) -> &HessMaps {
        &self.hess
    }

    /// Counters and sizes.
    pub fn stats(&self) -> GraphStats {
        let graph = self.graph.as_ref();
        GraphStats {
            stored_steps: self.store.n_states(),
            stored_episodes: self.store.n_trajectories() as u64,
            evicted_steps: self.store.n_evicted(),
            chunk_gaps: self.store.n_gaps(),
            n_nodes: graph.map_or(0, LatentGraph::n_nodes),
            n_edges: graph.map_or(0, LatentGraph::n_edges),
            dropped_nodes: graph.map_or(0, LatentGraph::n_dropped_cells),
            unmapped_states: graph.map_or(0, LatentGraph::n_unmapped_states),
            graph_version: self.graph_version,
            phi_version: self.phi_version(),
            hess_visited_cells: self.hess.n_visited_cells() as u64,
            future_count_recomputes: self.hess.n_future_recomputes(),
            reach_samples: self.hess.n_reach_samples(),
            ..self.stats.clone()
        }
    }

    /// The trajectory store.
    pub fn store(&self) -> &TrajectoryStore {
        &self.store
    }

    /// The graph's visit counts n(v).
    pub fn counts(&self) -> &VisitCounts {
        &self.counts
    }

    /// The stored trajectories' (actor, episode) pairs, oldest first (for tests and tools).
    pub fn stored_episodes(&self) -> Vec<(ActorId, EpisodeId)> {
        self.store
            .trajectories()
            .map(|t| (t.actor, t.episode))
            .collect()
    }
}

/// States of a chunk's records (their `obs`, plus the last `next_obs` when the chunk ends the
/// episode) as flat floats, and their collection-time φ labels.
fn gather_states(records: &[StepView<'_>], episode_end: bool) -> (Vec<f32>, Vec<LatentPoint>) {
    let mut obs = Vec::new();
    let mut labels = Vec::with_capacity(records.len() + 1);
    for record in records {
        obs.extend_from_slice(record.obs);
        labels.push(point(record.phi));
    }
    if let (true, Some(last)) = (episode_end, records.last()) {
        obs.extend_from_slice(last.next_obs);
        labels.push(point(last.next_phi));
    }
    (obs, labels)
}

/// A 2-D latent point from a `latent_dim` = 2 slice (checked by the dims check).
fn point(values: &[f32]) -> LatentPoint {
    [values[0], values[1]]
}

/// Every stored state mapped through `phi` on `n_threads` threads, per trajectory; refuses
/// non-finite outputs.
pub fn remap(
    phi: &Phi,
    store: &TrajectoryStore,
    n_threads: usize,
) -> Result<Vec<Vec<LatentPoint>>, GraphServiceError> {
    let batches: Vec<&[f32]> = store.trajectories().map(|t| t.obs()).collect();
    let all = phi.map_all(&batches, n_threads)?;
    if let Some(bad) = all
        .iter()
        .flatten()
        .find(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(GraphServiceError::NonFiniteLatent {
            phi_version: phi.version().0,
            point: *bad,
        });
    }
    Ok(all)
}
