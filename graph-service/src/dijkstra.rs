//! Single-source shortest paths on the latent graph: Dijkstra with Dial's bucket queue and
//! predecessor tracking, `O(V + E + D)` per source (D the largest distance reached).
//!
//! Edge weights are integer temporal distances (env steps), so distances are exact `u64` sums,
//! a bucket per distance replaces the binary heap, and ties are broken deterministically (the
//! bucket order: last queued first). The
//! released code runs an `O(V²)` Dijkstra from every node; distances are the same, route
//! tie-breaking may differ (digest §6).

use std::collections::VecDeque;

use crate::graph::{Adjacency, NodeId};

/// Distance of an unreached node.
const UNREACHED: u64 = u64::MAX;
/// Predecessor of the source and of unreached nodes.
const NO_PRED: NodeId = NodeId::MAX;

/// Distances and predecessors from one source node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShortestPaths {
    source: NodeId,
    dist: Vec<Option<u64>>,
    pred: Vec<Option<NodeId>>,
}

/// Dial's bucket queue: bucket `i` holds the nodes queued at distance `base + i`. Edge
/// weights are integers, so a pop is a bucket pop and a push a bucket push — O(1) each, against
/// O(log n) for a binary heap. A node is queued again only at a strictly smaller distance;
/// entries whose distance is no longer the node's are skipped when popped. The ring of
/// buckets never holds more than `max weight + 1` buckets (rotated, so their allocations are
/// reused).
struct Buckets {
    base: u64,
    ring: VecDeque<Vec<NodeId>>,
    queued: usize,
}

impl Buckets {
    fn new(source: NodeId) -> Self {
        Self {
            base: 0,
            ring: VecDeque::from([vec![source]]),
            queued: 1,
        }
    }

    fn push(&mut self, node: NodeId, distance: u64) {
        // Invariant: distance ≥ base (weights are non-negative, pushes come from the node at
        // `base`), so the offset is at most the largest edge weight.
        let offset = (distance - self.base) as usize;
        while self.ring.len() <= offset {
            self.ring.push_back(Vec::new());
        }
        self.ring[offset].push(node);
        self.queued += 1;
    }

    /// The next queued node with its bucket's distance (smallest distance first; last in,
    /// first out within a bucket).
    fn pop(&mut self) -> Option<(NodeId, u64)> {
        if self.queued == 0 {
            return None;
        }
        loop {
            if let Some(node) = self.ring.front_mut().and_then(Vec::pop) {
                self.queued -= 1;
                return Some((node, self.base));
            }
            let empty = self.ring.pop_front().unwrap_or_default();
            self.ring.push_back(empty);
            self.base += 1;
        }
    }
}

/// The settle loop shared by [`shortest_path_to`] and [`shortest_paths`]: settles nodes in
/// the bucket order until `stop` returns true for a settled node or nothing is queued.
fn settle(
    adjacency: &Adjacency,
    source: NodeId,
    dist: &mut [u64],
    pred: &mut [NodeId],
    mut stop: impl FnMut(NodeId) -> bool,
) {
    dist[source as usize] = 0;
    let mut queue = Buckets::new(source);
    while let Some((u, d)) = queue.pop() {
        if dist[u as usize] != d {
            continue; // a stale entry: u was queued again at a smaller distance
        }
        if stop(u) {
            return;
        }
        for &(v, w) in &adjacency[u as usize] {
            let candidate = d + u64::from(w);
            if candidate < dist[v as usize] {
                dist[v as usize] = candidate;
                pred[v as usize] = u;
                queue.push(v, candidate);
            }
        }
    }
}

/// The shortest path from `source` to `target` (both included), or `None` if unreachable.
/// Dijkstra stopped as soon as `target` is settled: the path is exactly the one
/// [`shortest_paths`] recovers (same queue order; a settled node's predecessor never changes),
/// at a fraction of the cost for nearby targets (SI route batches, `asi graph route`).
pub fn shortest_path_to(
    adjacency: &Adjacency,
    source: NodeId,
    target: NodeId,
) -> Option<Vec<NodeId>> {
    let n = adjacency.len();
    if (source as usize) >= n || (target as usize) >= n {
        return None;
    }
    let mut dist = vec![UNREACHED; n];
    let mut pred = vec![NO_PRED; n];
    let mut found = false;
    settle(adjacency, source, &mut dist, &mut pred, |u| {
        found = u == target;
        found
    });
    found.then(|| walk_back(&pred, target))
}

/// Full Dijkstra from `source` into caller-owned buffers (both of length `adjacency.len()`,
/// overwritten): afterwards `pred[v]` is v's predecessor on the shortest path from `source`
/// (`NodeId::MAX` for the source and unreached nodes) — the same predecessors as
/// [`shortest_paths`], without allocating. Used to fill the all-pairs route table.
pub(crate) fn predecessors_into(
    adjacency: &Adjacency,
    source: NodeId,
    dist: &mut [u64],
    pred: &mut [NodeId],
) {
    dist.fill(UNREACHED);
    pred.fill(NO_PRED);
    if (source as usize) < adjacency.len() {
        settle(adjacency, source, dist, pred, |_| false);
    }
}

/// Nodes from the source to `target` by predecessors (`target` reached).
fn walk_back(pred: &[NodeId], target: NodeId) -> Vec<NodeId> {
    let mut path = vec![target];
    let mut node = target;
    while pred[node as usize] != NO_PRED {
        node = pred[node as usize];
        path.push(node);
    }
    path.reverse();
    path
}

/// Dijkstra from `source` over `adjacency` (`adjacency[u]` = `(v, weight)` pairs). A source
/// outside the graph gives a result in which nothing is reachable.
pub fn shortest_paths(adjacency: &Adjacency, source: NodeId) -> ShortestPaths {
    let n = adjacency.len();
    let mut dist = vec![UNREACHED; n];
    let mut pred = vec![NO_PRED; n];
    if (source as usize) < n {
        settle(adjacency, source, &mut dist, &mut pred, |_| false);
    }
    ShortestPaths {
        source,
        dist: dist
            .into_iter()
            .map(|d| (d != UNREACHED).then_some(d))
            .collect(),
        pred: pred
            .into_iter()
            .map(|p| (p != NO_PRED).then_some(p))
            .collect(),
    }
}

impl ShortestPaths {
    /// The source node.
    pub fn source(&self) -> NodeId {
        self.source
    }

    /// Distance to `node`, `None` if unreachable (or not a node).
    pub fn distance(&self, node: NodeId) -> Option<u64> {
        self.dist.get(node as usize).copied().flatten()
    }

    /// All distances, by node id.
    pub fn distances(&self) -> &[Option<u64>] {
        &self.dist
    }

    /// The largest finite distance (0 when only the source is reachable).
    pub fn max_distance(&self) -> Option<u64> {
        self.dist.iter().flatten().copied().max()
    }

    /// Nodes of a shortest path from the source to `target`, both included, or `None` if
    /// `target` is unreachable.
    pub fn path_to(&self, target: NodeId) -> Option<Vec<NodeId>> {
        self.distance(target)?;
        let mut path = vec![target];
        let mut node = target;
        while let Some(prev) = self.pred[node as usize] {
            path.push(prev);
            node = prev;
        }
        path.reverse();
        Some(path)
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// Brute-force all-pairs shortest paths (Floyd–Warshall) on an undirected weighted graph.
    fn floyd_warshall(n: usize, edges: &[(u32, u32, u32)]) -> Vec<Vec<Option<u64>>> {
        let mut d = vec![vec![None; n]; n];
        for (i, row) in d.iter_mut().enumerate() {
            row[i] = Some(0);
        }
        for &(a, b, w) in edges {
            let (a, b, w) = (a as usize, b as usize, u64::from(w));
            for (x, y) in [(a, b), (b, a)] {
                if d[x][y].is_none_or(|old| w < old) {
                    d[x][y] = Some(w);
                }
            }
        }
        for k in 0..n {
            for i in 0..n {
                for j in 0..n {
                    if let (Some(ik), Some(kj)) = (d[i][k], d[k][j]) {
                        if d[i][j].is_none_or(|old| ik + kj < old) {
                            d[i][j] = Some(ik + kj);
                        }
                    }
                }
            }
        }
        d
    }

    fn adjacency(n: usize, edges: &[(u32, u32, u32)]) -> Adjacency {
        let mut lists = vec![Vec::new(); n];
        for &(a, b, w) in edges {
            lists[a as usize].push((b, w));
            lists[b as usize].push((a, w));
        }
        Adjacency::from_lists(&lists)
    }

    /// A random graph: up to 12 nodes, up to 30 edges (parallel edges and self loops allowed).
    fn random_graph() -> impl Strategy<Value = (usize, Vec<(u32, u32, u32)>)> {
        (1usize..12).prop_flat_map(|n| {
            let edge = (0..n as u32, 0..n as u32, 1u32..20);
            (Just(n), proptest::collection::vec(edge, 0..30))
        })
    }

    proptest! {
        #[test]
        fn early_exit_paths_equal_full_dijkstra_paths((n, edges) in random_graph()) {
            let adj = adjacency(n, &edges);
            for source in 0..n as u32 {
                let full = shortest_paths(&adj, source);
                for target in 0..n as u32 {
                    prop_assert_eq!(shortest_path_to(&adj, source, target), full.path_to(target));
                }
            }
        }

        #[test]
        fn dijkstra_distances_match_floyd_warshall((n, edges) in random_graph()) {
            let expected = floyd_warshall(n, &edges);
            let adj = adjacency(n, &edges);
            for (source, row) in expected.iter().enumerate() {
                let paths = shortest_paths(&adj, source as u32);
                prop_assert_eq!(paths.distances(), &row[..]);
            }
        }

        #[test]
        fn recovered_paths_are_walks_whose_weight_is_the_distance((n, edges) in random_graph()) {
            let adj = adjacency(n, &edges);
            let weight = |a: u32, b: u32| edges.iter()
                .filter(|&&(x, y, _)| (x, y) == (a, b) || (x, y) == (b, a))
                .map(|&(_, _, w)| u64::from(w))
                .min();
            for source in 0..n as u32 {
                let paths = shortest_paths(&adj, source);
                for target in 0..n as u32 {
                    match (paths.path_to(target), paths.distance(target)) {
                        (Some(path), Some(d)) => {
                            prop_assert_eq!(path[0], source);
                            prop_assert_eq!(*path.last().unwrap(), target);
                            let total: Option<u64> = path.windows(2).map(|s| weight(s[0], s[1])).sum();
                            prop_assert_eq!(total, Some(d));
                        }
                        (None, None) => {}
                        other => prop_assert!(false, "path and distance disagree: {:?}", other),
                    }
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

        #[test]
        fn early_exit_paths_equal_full_dijkstra_paths_on_larger_graphs(
            edges in proptest::collection::vec((0u32..300, 0u32..300, 1u32..6), 200..900),
            pairs in proptest::collection::vec((0u32..300, 0u32..300), 20),
        ) {
            let adj = adjacency(300, &edges);
            for (source, target) in pairs {
                let full = shortest_paths(&adj, source);
                prop_assert_eq!(shortest_path_to(&adj, source, target), full.path_to(target));
            }
        }
    }

    #[test]
    fn a_source_outside_the_graph_reaches_nothing() {
        let paths = shortest_paths(&adjacency(2, &[(0, 1, 1)]), 5);
        assert_eq!(adjacency(2, &[(0, 1, 1)]).get(5), None);
        assert_eq!(paths.distances(), &[None, None]);
        assert_eq!(paths.path_to(0), None);
    }
}
