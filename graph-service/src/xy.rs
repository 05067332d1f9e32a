//! Where the latent graph lies in the world: each node placed at the mean achieved-goal xy of
//! the stored states in its cell, for the maze picture of the run (`plots/graph_latest.png`).
//!
//! The store keeps raw observations only, so the xy of a state comes from a caller-supplied
//! function of its observation (the task's achieved goal: `obs[0..2]` for the maze robots).
//! A state whose xy is not finite, or whose cell has no node, places nothing.
//!
//! Invariant: [`XyGraph::nodes`] is indexed by [`NodeId`], like the graph it describes.

use crate::graph::{LatentGraph, NodeId};
use crate::service::GraphService;
use crate::store::TrajectoryStore;

/// One node in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XyNode {
    /// Mean xy of the stored states in the node's cell; `None` when no stored state has a
    /// finite xy there.
    pub xy: Option<[f32; 2]>,
    /// Stored states that placed the node.
    pub n_states: u64,
    /// Visit count n(v) of the node's cell.
    pub visits: u64,
}

/// The last frontier the service answered, in the world.
#[derive(Debug, Clone, PartialEq)]
pub struct XyFrontier {
    /// The frontier node's xy, if placed.
    pub frontier: Option<[f32; 2]>,
    /// The route's nodes (start to frontier) that are placed, in route order.
    pub route: Vec<[f32; 2]>,
}

/// The current graph in the world.
#[derive(Debug, Clone, PartialEq)]
pub struct XyGraph {
    /// Graph version drawn.
    pub graph_version: u64,
    /// Per node id.
    pub nodes: Vec<XyNode>,
    /// Undirected edges `(a, b)`, as in the graph.
    pub edges: Vec<(NodeId, NodeId)>,
    /// The last frontier answered on this graph version, if any.
    pub frontier: Option<XyFrontier>,
}

/// The last frontier answered: node ids, valid for `graph_version` only.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct LastFrontier {
    pub graph_version: u64,
    pub node: NodeId,
    pub route: Vec<NodeId>,
}

/// Mean xy and state count per node of `graph`: one pass over `store`, each state's cell
/// looked up from its latent point; `xy_of` maps a state's observation to its xy.
pub fn node_means(
    store: &TrajectoryStore,
    graph: &LatentGraph,
    xy_of: impl Fn(&[f32]) -> [f32; 2],
) -> Vec<(Option<[f32; 2]>, u64)> {
    let mut sums = vec![([0.0f64; 2], 0u64); graph.n_nodes()];
    let obs_dim = store.obs_dim().max(1);
    for trajectory in store.trajectories() {
        let states = trajectory.obs().chunks_exact(obs_dim);
        for (obs, &latent) in states.zip(trajectory.latents()) {
            let xy = xy_of(obs);
            let node = graph.node_at(latent);
            if let (Some(node), true) = (node, xy.iter().all(|v| v.is_finite())) {
                let (sum, n) = &mut sums[node as usize];
                sum[0] += f64::from(xy[0]);
                sum[1] += f64::from(xy[1]);
                *n += 1;
            }
        }
    }
    sums.into_iter()
        .map(|(sum, n)| {
            let mean = (n > 0).then(|| sum.map(|s| (s / n as f64) as f32));
            (mean, n)
        })
        .collect()
}

impl GraphService {
    /// The current graph placed in the world ([`node_means`]) with visit counts and the last
    /// frontier answered on it; `None` before the first graph.
    pub fn xy_graph(&self, xy_of: impl Fn(&[f32]) -> [f32; 2]) -> Option<XyGraph> {
        let graph = self.graph.as_ref()?;
        let means = node_means(&self.store, graph, xy_of);
        let nodes: Vec<XyNode> = graph
            .keys()
            .iter()
            .zip(&means)
            .map(|(&key, &(xy, n_states))| XyNode {
                xy,
                n_states,
                visits: self.counts.of_key(key),
            })
            .collect();
        let xy_at = |node: NodeId| nodes.get(node as usize).and_then(|n| n.xy);
        let frontier = self
            .last_frontier
            .as_ref()
            .filter(|last| last.graph_version == self.graph_version)
            .map(|last| XyFrontier {
                frontier: xy_at(last.node),
                route: last.route.iter().filter_map(|&n| xy_at(n)).collect(),
            });
        Some(XyGraph {
            graph_version: self.graph_version,
            edges: graph.edges().iter().map(|&(a, b, _)| (a, b)).collect(),
            nodes,
            frontier,
        })
    }

    /// Keeps `node` and `route` as the last frontier answered on the current graph.
    pub(crate) fn note_frontier(&mut self, node: NodeId, route: &[NodeId]) {
        self.last_frontier = Some(LastFrontier {
            graph_version: self.graph_version,
            node,
            route: route.to_vec(),
        });
    }
}

#[cfg(test)]
mod tests {
    use protocol::config::NodePosition;
    use protocol::{ActorId, EpisodeId, LatentPoint};

    use super::*;
    use crate::graph::GraphBuilder;
    use crate::grid::Grid;
    use crate::store::ChunkStates;

    /// One closed trajectory of states with obs `[x, y, 9]` and the given latent points.
    fn chunk(episode: u64, xys: &[[f32; 2]], latents: &[LatentPoint]) -> ChunkStates {
        ChunkStates {
            actor: ActorId(0),
            episode: EpisodeId(episode),
            chunk_index: 0,
            first_env_step: 0,
            episode_start: true,
            episode_end: true,
            obs: xys.iter().flat_map(|xy| [xy[0], xy[1], 9.0]).collect(),
            latents: latents.to_vec(),
        }
    }

    #[test]
    fn nodes_sit_at_the_mean_xy_of_the_stored_states_in_their_cell() {
        let mut store = TrajectoryStore::new(3, 1_000);
        // Cell side 1: latents 0.2 and 0.7 share cell (0,0); 1.5 is cell (1,0); 2.5 cell (2,0).
        store.append(chunk(
            0,
            &[[1.0, 2.0], [3.0, 6.0], [10.0, 10.0]],
            &[[0.2, 0.2], [0.7, 0.1], [1.5, 0.5]],
        ));
        // A second episode adds to cell (0,0) and brings a state with a non-finite xy in (2,0).
        store.append(chunk(
            1,
            &[[5.0, -1.0], [f32::NAN, 0.0]],
            &[[0.5, 0.5], [2.5, 0.5]],
        ));
        let mut builder = GraphBuilder::new(Grid::new(1.0, NodePosition::Corner), 100, 1);
        for t in store.trajectories() {
            builder.add_trajectory(t.latents());
        }
        let graph = builder.finish();
        let means = node_means(&store, &graph, |obs| [obs[0], obs[1]]);
        // Node ids in first-seen order: (0,0), (1,0), (2,0).
        // (0,0): xy (1,2), (3,6), (5,-1) → mean (3, 7/3).
        assert_eq!(means.len(), 3);
        let (xy, n) = means[0];
        let xy = xy.expect("cell (0,0) has states");
        assert_eq!(n, 3);
        assert!(
            (xy[0] - 3.0).abs() < 1e-6 && (xy[1] - 7.0 / 3.0).abs() < 1e-6,
            "{xy:?}"
        );
        assert_eq!(means[1], (Some([10.0, 10.0]), 1));
        assert_eq!(means[2], (None, 0), "a non-finite xy places nothing");
    }
}
