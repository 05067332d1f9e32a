//! The all-pairs route table: after each rebuild, Dijkstra runs once from every node and its
//! predecessor row is kept, so a route query is a walk back through one row — O(route length)
//! instead of a search over the graph.
//!
//! The graph changes only when it is rebuilt (a new φ, SPEC §6.5), while routes are asked for
//! all the time (a batch per self-imitation step, one per frontier-reaching episode), so the
//! `n` searches pay for themselves quickly. Rows hold `u16` node ids: `2·n²` bytes, 50 MB at the
//! default cap of 5,000 nodes; graphs above `graph.route_table_max_nodes` (at most 65,535) get
//! no table and are searched per query. The table is filled on a background thread
//! ([`crate::graph::LatentGraph::spawn_route_table`]); until it is ready, and for a graph
//! without one, queries run Dijkstra — with the same predecessors, so the answer is the same
//! route either way.

use std::time::Instant;

use crate::dijkstra::predecessors_into;
use crate::graph::{Adjacency, NodeId};

/// Predecessor marker of the row's source and of unreachable nodes.
const NO_PRED: u16 = u16::MAX;
/// Largest graph a table can hold: node ids must fit in `u16` beside [`NO_PRED`].
pub const MAX_TABLE_NODES: usize = NO_PRED as usize;

/// Predecessors on shortest paths between every pair of nodes.
pub struct RouteTable {
    n: usize,
    /// Row `s` (`pred[s·n..(s+1)·n]`): the predecessor of each node on its shortest path from `s`.
    pred: Vec<u16>,
    build_secs: f64,
}

impl std::fmt::Debug for RouteTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RouteTable")
            .field("nodes", &self.n)
            .field("bytes", &self.bytes())
            .field("build_secs", &self.build_secs)
            .finish()
    }
}

impl RouteTable {
    /// Runs Dijkstra from every node of `adjacency`, the sources split over `threads` scoped
    /// workers. `None` if the graph has more than [`MAX_TABLE_NODES`] nodes, if `cancelled`
    /// returns true (checked before each source), or if a worker failed.
    pub fn build(
        adjacency: &Adjacency,
        threads: usize,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<RouteTable> {
        let start = Instant::now();
        let n = adjacency.len();
        if n > MAX_TABLE_NODES {
            return None;
        }
        let mut pred = vec![NO_PRED; n * n];
        if n > 0 {
            let rows_per_worker = n.div_ceil(threads.clamp(1, n));
            let complete = std::thread::scope(|scope| {
                let workers: Vec<_> = pred
                    .chunks_mut(rows_per_worker * n)
                    .enumerate()
                    .map(|(worker, rows)| {
                        scope.spawn(move || {
                            let first = worker * rows_per_worker;
                            fill_rows(adjacency, first, rows, cancelled)
                        })
                    })
                    .collect();
                // Join every worker (no short-circuit) before deciding.
                let results: Vec<bool> = workers
                    .into_iter()
                    .map(|w| w.join().unwrap_or(false))
                    .collect();
                results.into_iter().all(|done| done)
            });
            if !complete {
                return None;
            }
        }
        Some(RouteTable {
            n,
            pred,
            build_secs: start.elapsed().as_secs_f64(),
        })
    }

    /// The shortest route from `from` to `to`, both included (`[from]` when they are equal),
    /// or `None` if `to` is unreachable or either is not a node. The same route as
    /// [`crate::dijkstra::shortest_path_to`].
    pub fn path(&self, from: NodeId, to: NodeId) -> Option<Vec<NodeId>> {
        let (source, target) = (from as usize, to as usize);
        if source >= self.n || target >= self.n {
            return None;
        }
        let row = &self.pred[source * self.n..(source + 1) * self.n];
        let mut path = vec![to];
        let mut node = target;
        while node != source {
            let prev = row[node];
            // A route visits each node once; the length check only guards the loop.
            if prev == NO_PRED || path.len() > self.n {
                return None;
            }
            node = usize::from(prev);
            path.push(NodeId::from(prev));
        }
        path.reverse();
        Some(path)
    }

    /// Number of nodes.
    pub fn n_nodes(&self) -> usize {
        self.n
    }

    /// Memory held by the rows.
    pub fn bytes(&self) -> usize {
        self.pred.len() * std::mem::size_of::<u16>()
    }

    /// Wall time the build took.
    pub fn build_secs(&self) -> f64 {
        self.build_secs
    }
}

/// Fills consecutive rows starting at source `first`; false if cancelled.
fn fill_rows(
    adjacency: &Adjacency,
    first: usize,
    rows: &mut [u16],
    cancelled: &(dyn Fn() -> bool + Sync),
) -> bool {
    let n = adjacency.len();
    let mut dist = vec![0u64; n];
    let mut pred = vec![0 as NodeId; n];
    for (i, row) in rows.chunks_mut(n).enumerate() {
        if cancelled() {
            return false;
        }
        predecessors_into(adjacency, (first + i) as NodeId, &mut dist, &mut pred);
        for (slot, &p) in row.iter_mut().zip(&pred) {
            // Node ids are < n ≤ MAX_TABLE_NODES, so they fit; the marker maps to the marker.
            *slot = u16::try_from(p).unwrap_or(NO_PRED);
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::dijkstra::{shortest_path_to, shortest_paths};

    fn adjacency(n: usize, edges: &[(u32, u32, u32)]) -> Adjacency {
        let mut lists = vec![Vec::new(); n];
        for &(a, b, w) in edges {
            lists[a as usize].push((b, w));
            lists[b as usize].push((a, w));
        }
        Adjacency::from_lists(&lists)
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

        /// Every pair, every worker count: the table's route is Dijkstra's route (same
        /// tie-breaking), including unreachable pairs and `from == to`.
        #[test]
        fn table_routes_equal_dijkstra_routes(
            n in 1usize..60,
            raw in proptest::collection::vec((0u32..60, 0u32..60, 1u32..8), 0..150),
            threads in 1usize..5,
        ) {
            let edges: Vec<_> = raw.into_iter()
                .map(|(a, b, w)| (a % n as u32, b % n as u32, w))
                .collect();
            let adj = adjacency(n, &edges);
            let table = RouteTable::build(&adj, threads, &|| false).expect("small graph");
            for from in 0..n as u32 {
                let full = shortest_paths(&adj, from);
                for to in 0..n as u32 {
                    let expected = shortest_path_to(&adj, from, to);
                    prop_assert_eq!(&table.path(from, to), &expected);
                    prop_assert_eq!(expected, full.path_to(to));
                }
            }
        }
    }

    #[test]
    fn hand_built_graph_routes_and_unreachable_pairs() {
        // 0 -1- 1 -1- 2, and 0 -5- 2 (longer); 3 isolated.
        let adj = adjacency(4, &[(0, 1, 1), (1, 2, 1), (0, 2, 5)]);
        let table = RouteTable::build(&adj, 2, &|| false).expect("small graph");
        assert_eq!(table.path(0, 2), Some(vec![0, 1, 2]));
        assert_eq!(table.path(2, 0), Some(vec![2, 1, 0]));
        assert_eq!(table.path(1, 1), Some(vec![1]));
        assert_eq!(table.path(0, 3), None);
        assert_eq!(table.path(3, 3), Some(vec![3]));
        assert_eq!(table.path(0, 4), None, "not a node");
        assert_eq!(table.bytes(), 4 * 4 * 2);
    }

    #[test]
    fn a_cancelled_build_gives_no_table_and_an_empty_graph_an_empty_one() {
        let adj = adjacency(3, &[(0, 1, 1)]);
        assert!(RouteTable::build(&adj, 1, &|| true).is_none());
        let empty = RouteTable::build(&Adjacency::default(), 2, &|| false).expect("empty graph");
        assert_eq!(empty.n_nodes(), 0);
        assert_eq!(empty.path(0, 0), None);
    }
}
