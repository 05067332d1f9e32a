//! Frontiers and routes on the latent graph (SPEC §6.6–6.7, digest §6–8).
//!
//! - [`route`]: the nodes of a shortest path from the cell of `start` to the cell of `end`,
//!   both included (index 0 is the start node).
//! - [`frontier`]: FR episode start: a node chosen uniformly at random among those whose graph
//!   distance from the start node exceeds `fraction × max` (max over reachable nodes), and the
//!   route to it.
//! - [`answer_route_query`]: one SI query with the fallback of SPEC §6.7: no route start→end
//!   → route start→(random frontier seen from the fallback origin, typically φ(s_0)).
//!
//! Failures are [`NoRoute`] values with the reason; nothing here panics (the released code
//! crashes when the start cell is missing or nothing is reachable, digest §12.24).

use std::fmt;

use protocol::graph::{NoRouteReason, RouteAnswer, RouteQuery};
use protocol::LatentPoint;
use rand::Rng;

use crate::dijkstra::{shortest_path_to, shortest_paths};
use crate::graph::{LatentGraph, NodeId};

/// Why there is no route or frontier.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoRoute {
    /// The graph has no nodes (none built yet, or built from no stored state).
    EmptyGraph,
    /// The start point's cell is not a graph node.
    UnknownStart {
        /// The start point.
        point: LatentPoint,
    },
    /// The end point's cell is not a graph node.
    UnknownEnd {
        /// The end point.
        point: LatentPoint,
    },
    /// The end node is not reachable from the start node.
    Unreachable {
        /// Start node.
        from: NodeId,
        /// End node.
        to: NodeId,
    },
    /// No node other than the start node is reachable (no frontier).
    NothingReachable {
        /// Start node.
        from: NodeId,
    },
}

impl fmt::Display for NoRoute {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NoRoute::EmptyGraph => f.write_str("the graph has no nodes"),
            NoRoute::UnknownStart { point } => {
                write!(f, "start point {point:?} is in no graph node's cell")
            }
            NoRoute::UnknownEnd { point } => {
                write!(f, "end point {point:?} is in no graph node's cell")
            }
            NoRoute::Unreachable { from, to } => {
                write!(f, "node {to} is not reachable from node {from}")
            }
            NoRoute::NothingReachable { from } => {
                write!(
                    f,
                    "no node other than the start node {from} is reachable; no frontier"
                )
            }
        }
    }
}

impl NoRoute {
    /// The wire reason (without the points and node ids).
    pub fn reason(&self) -> NoRouteReason {
        match self {
            NoRoute::EmptyGraph => NoRouteReason::EmptyGraph,
            NoRoute::UnknownStart { .. } => NoRouteReason::StartUnknown,
            NoRoute::UnknownEnd { .. } => NoRouteReason::EndUnknown,
            NoRoute::Unreachable { .. } => NoRouteReason::Unreachable,
            NoRoute::NothingReachable { .. } => NoRouteReason::NothingReachable,
        }
    }
}

/// The node whose cell holds `point`; [`NoRoute::EmptyGraph`] before any node exists, else
/// [`NoRoute::UnknownStart`] if the cell is not a node.
fn start_node(graph: &LatentGraph, point: LatentPoint) -> Result<NodeId, NoRoute> {
    if graph.n_nodes() == 0 {
        return Err(NoRoute::EmptyGraph);
    }
    graph.node_at(point).ok_or(NoRoute::UnknownStart { point })
}

/// A frontier node and the route to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frontier {
    /// The frontier node g_F.
    pub node: NodeId,
    /// Its graph distance from the start node (env steps).
    pub distance: u64,
    /// Route from the start node to `node`, both included.
    pub route: Vec<NodeId>,
}

/// Shortest route from the cell of `start` to the cell of `end`.
pub fn route(
    graph: &LatentGraph,
    start: LatentPoint,
    end: LatentPoint,
) -> Result<Vec<NodeId>, NoRoute> {
    let from = start_node(graph, start)?;
    let to = graph
        .node_at(end)
        .ok_or(NoRoute::UnknownEnd { point: end })?;
    route_between(graph, from, to)
}

/// Shortest route between two nodes, both included: a lookup in the graph's route table
/// when it is built, Dijkstra otherwise (the same route).
pub fn route_between(
    graph: &LatentGraph,
    from: NodeId,
    to: NodeId,
) -> Result<Vec<NodeId>, NoRoute> {
    let path = match graph.route_table() {
        Some(table) => table.path(from, to),
        None => shortest_path_to(graph.adjacency(), from, to),
    };
    path.ok_or(NoRoute::Unreachable { from, to })
}

/// A uniformly random node farther than `fraction × max` from the cell of `from`, with the
/// route to it. `fraction` lies in (0, 1) (config validation), so the farthest node always
/// qualifies once anything else is reachable.
pub fn frontier<R: Rng>(
    graph: &LatentGraph,
    from: LatentPoint,
    fraction: f64,
    rng: &mut R,
) -> Result<Frontier, NoRoute> {
    let start = start_node(graph, from)?;
    let paths = shortest_paths(graph.adjacency(), start);
    let max = paths.max_distance().unwrap_or(0);
    if max == 0 {
        return Err(NoRoute::NothingReachable { from: start });
    }
    let threshold = fraction * max as f64;
    let beyond: Vec<(NodeId, u64)> = (0..graph.n_nodes() as NodeId)
        .filter_map(|node| paths.distance(node).map(|d| (node, d)))
        .filter(|&(_, d)| d as f64 > threshold)
        .collect();
    if beyond.is_empty() {
        return Err(NoRoute::NothingReachable { from: start });
    }
    let (node, distance) = beyond[rng.random_range(0..beyond.len())];
    let route = paths.path_to(node).ok_or(NoRoute::Unreachable {
        from: start,
        to: node,
    })?;
    Ok(Frontier {
        node,
        distance,
        route,
    })
}

/// Answers one SI route query: the direct route, else (with a fallback origin) the route to a
/// random frontier seen from it, else [`RouteAnswer::NoRoute`] with both reasons.
pub fn answer_route_query<R: Rng>(
    graph: &LatentGraph,
    query: &RouteQuery,
    fraction: f64,
    rng: &mut R,
) -> RouteAnswer {
    let direct = match route(graph, query.start, query.end) {
        Ok(nodes) => return RouteAnswer::Direct(positions(graph, &nodes)),
        Err(why) => why.reason(),
    };
    let Some(origin) = query.fallback_origin else {
        return RouteAnswer::NoRoute {
            direct,
            fallback: None,
        };
    };
    // Route to the frontier node by id: its corner position, divided by d again, could
    // round into the neighbouring cell.
    let via_frontier = frontier(graph, origin, fraction, rng).and_then(|f| {
        let start = start_node(graph, query.start)?;
        route_between(graph, start, f.node)
    });
    match via_frontier {
        Ok(nodes) => RouteAnswer::ViaFrontier(positions(graph, &nodes)),
        Err(why) => RouteAnswer::NoRoute {
            direct,
            fallback: Some(why.reason()),
        },
    }
}

/// Node positions of `nodes` in φ-space.
pub fn positions(graph: &LatentGraph, nodes: &[NodeId]) -> Vec<LatentPoint> {
    nodes
        .iter()
        .filter_map(|&node| graph.position(node))
        .collect()
}

#[cfg(test)]
mod tests {
    use protocol::config::NodePosition;
    use rand::SeedableRng;
    use rand_pcg::Pcg64;

    use super::*;
    use crate::dijkstra::shortest_paths;
    use crate::graph::GraphBuilder;
    use crate::grid::Grid;

    /// Unit grid with corner nodes; a point inside cell (x, y).
    fn at(x: i32, y: i32) -> LatentPoint {
        [x as f32 + 0.5, y as f32 + 0.5]
    }

    fn build(trajectories: &[Vec<LatentPoint>]) -> LatentGraph {
        let mut b = GraphBuilder::new(Grid::new(1.0, NodePosition::Corner), 100, 1);
        for t in trajectories {
            b.add_trajectory(t);
        }
        b.finish()
    }

    /// A plus-shaped maze: arms of length 4 from the origin, plus an isolated cell far away.
    fn plus() -> LatentGraph {
        let arm = |dx: i32, dy: i32| (0..=4).map(|i| at(i * dx, i * dy)).collect::<Vec<_>>();
        build(&[
            arm(1, 0),
            arm(-1, 0),
            arm(0, 1),
            arm(0, -1),
            vec![at(50, 50)],
        ])
    }

    #[test]
    fn the_frontier_is_always_beyond_the_fraction_of_the_max_distance() {
        let g = plus();
        let mut rng = Pcg64::seed_from_u64(3);
        for start in [at(0, 0), at(2, 0), at(0, -4)] {
            let max = shortest_paths(g.adjacency(), g.node_at(start).unwrap())
                .max_distance()
                .unwrap();
            for _ in 0..50 {
                let f = frontier(&g, start, 0.9, &mut rng).unwrap();
                assert!(
                    f.distance as f64 > 0.9 * max as f64,
                    "{} vs max {max}",
                    f.distance
                );
                assert_eq!(
                    f.route.len() as u64,
                    f.distance + 1,
                    "unit edges: hops = distance"
                );
                assert_eq!(f.route[0], g.node_at(start).unwrap());
                assert_eq!(*f.route.last().unwrap(), f.node);
            }
        }
    }

    #[test]
    fn the_frontier_is_uniform_over_the_far_nodes() {
        let g = plus();
        let mut rng = Pcg64::seed_from_u64(4);
        let mut seen = std::collections::HashSet::new();
        for _ in 0..200 {
            seen.insert(frontier(&g, at(0, 0), 0.9, &mut rng).unwrap().node);
        }
        assert_eq!(
            seen.len(),
            4,
            "the four arm tips are the only nodes at distance 4"
        );
    }

    #[test]
    fn route_endpoints_are_the_query_cells() {
        let g = plus();
        let nodes = route(&g, [-3.2, 0.7], [0.1, 4.9]).unwrap();
        let points = positions(&g, &nodes);
        assert_eq!(points.first(), Some(&[-4.0, 0.0]));
        assert_eq!(points.last(), Some(&[0.0, 4.0]));
        assert_eq!(points.len(), 9);
    }

    #[test]
    fn unknown_cells_and_unreachable_targets_give_reasons() {
        let g = plus();
        let mut rng = Pcg64::seed_from_u64(5);
        assert!(matches!(
            route(&g, at(9, 9), at(0, 0)),
            Err(NoRoute::UnknownStart { .. })
        ));
        assert!(matches!(
            route(&g, at(0, 0), at(9, 9)),
            Err(NoRoute::UnknownEnd { .. })
        ));
        let err = route(&g, at(0, 0), at(50, 50)).unwrap_err();
        assert!(matches!(err, NoRoute::Unreachable { .. }));
        assert!(err.to_string().contains("not reachable"), "{err}");
        assert!(matches!(
            frontier(&g, at(9, 9), 0.9, &mut rng),
            Err(NoRoute::UnknownStart { .. })
        ));
        let lonely = frontier(&g, at(50, 50), 0.9, &mut rng).unwrap_err();
        assert!(
            matches!(lonely, NoRoute::NothingReachable { .. }),
            "{lonely}"
        );
    }

    #[test]
    fn si_queries_fall_back_to_a_frontier_route() {
        let g = plus();
        let mut rng = Pcg64::seed_from_u64(6);
        let direct = RouteQuery {
            start: at(1, 0),
            end: at(0, 1),
            fallback_origin: None,
        };
        assert!(
            matches!(answer_route_query(&g, &direct, 0.9, &mut rng), RouteAnswer::Direct(r) if r.len() == 3)
        );
        let unreachable = RouteQuery {
            start: at(1, 0),
            end: at(50, 50),
            fallback_origin: Some(at(0, 0)),
        };
        match answer_route_query(&g, &unreachable, 0.9, &mut rng) {
            RouteAnswer::ViaFrontier(r) => {
                assert_eq!(r[0], [1.0, 0.0]);
                let tips = [[4.0, 0.0], [-4.0, 0.0], [0.0, 4.0], [0.0, -4.0]];
                assert!(tips.contains(r.last().unwrap()), "{r:?}");
            }
            other => panic!("expected a frontier route, got {other:?}"),
        }
        let hopeless = RouteQuery {
            start: at(9, 9),
            end: at(0, 0),
            fallback_origin: Some(at(0, 0)),
        };
        assert_eq!(
            answer_route_query(&g, &hopeless, 0.9, &mut rng),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::StartUnknown,
                fallback: Some(NoRouteReason::StartUnknown)
            }
        );
        let isolated_start = RouteQuery {
            start: at(50, 50),
            end: at(0, 0),
            fallback_origin: Some(at(0, 0)),
        };
        assert_eq!(
            answer_route_query(&g, &isolated_start, 0.9, &mut rng),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::Unreachable,
                fallback: Some(NoRouteReason::Unreachable)
            },
            "a frontier exists from the origin but not from the start's island"
        );
        let lonely_origin = RouteQuery {
            start: at(1, 0),
            end: at(9, 9),
            fallback_origin: Some(at(50, 50)),
        };
        assert_eq!(
            answer_route_query(&g, &lonely_origin, 0.9, &mut rng),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::EndUnknown,
                fallback: Some(NoRouteReason::NothingReachable)
            }
        );
        let no_fallback = RouteQuery {
            fallback_origin: None,
            ..unreachable
        };
        assert_eq!(
            answer_route_query(&g, &no_fallback, 0.9, &mut rng),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::Unreachable,
                fallback: None
            }
        );
    }

    #[test]
    fn an_empty_graph_is_its_own_reason() {
        let g = build(&[]);
        let mut rng = Pcg64::seed_from_u64(7);
        assert_eq!(route(&g, at(0, 0), at(1, 1)), Err(NoRoute::EmptyGraph));
        assert_eq!(
            frontier(&g, at(0, 0), 0.9, &mut rng),
            Err(NoRoute::EmptyGraph)
        );
        let query = RouteQuery {
            start: at(0, 0),
            end: at(1, 1),
            fallback_origin: Some(at(0, 0)),
        };
        assert_eq!(
            answer_route_query(&g, &query, 0.9, &mut rng),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::EmptyGraph,
                fallback: Some(NoRouteReason::EmptyGraph)
            }
        );
    }
}
