//! The latent subgoal graph of SPEC §6.5 (paper Eq. 8), built from stored trajectories mapped
//! through the current φ.
//!
//! - Nodes are grid cells ([`Grid`]) holding at least one stored state, numbered in first-seen
//!   order (trajectories oldest first, states in time order).
//! - Edge weight between nodes u ≠ v: `min |p − q|` over pairs of states s_p ∈ u, s_q ∈ v of one
//!   trajectory with `0 < |p − q| ≤ edge_window`. Undirected; pairs within one cell (self
//!   pairs) add nothing. With the default window 1 every edge has weight 1 (hop counts, as the
//!   released code).
//! - Node cap: once `max_nodes` nodes exist, states in new cells get no node; each such cell is
//!   counted once in `n_dropped_cells`. Unlike the released code (which stops reading
//!   trajectories altogether) states in known cells keep adding edges; pairs with a node-less
//!   state are skipped, so no edge jumps over a dropped cell by more than the window allows.
//! - States whose cell key is out of range ([`Grid::key`]) get no node and are counted in
//!   `n_unmapped_states`.
//!
//! Invariant: node ids are dense `0..n_nodes`; `adjacency[u]` lists `(v, w)` for every edge
//! once in each direction, sorted by `v`.

use std::collections::{HashMap, HashSet};
use std::sync::{Arc, OnceLock};

use protocol::LatentPoint;

use crate::grid::{CellKey, Grid};
use crate::route_table::{RouteTable, MAX_TABLE_NODES};

/// Index of a node, `0..n_nodes`, in first-seen order.
pub type NodeId = u32;

/// Weight of an edge: a temporal distance in env steps.
pub type EdgeWeight = u32;

/// Neighbour lists in one flat array (compressed sparse rows): `adjacency[u]` is the slice of
/// `(v, weight)` pairs of node `u`. One allocation and no pointer per node, so a search reads
/// neighbours from contiguous memory.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Adjacency {
    /// `offsets[u]..offsets[u + 1]` indexes `arcs` for node `u`; `n + 1` entries.
    offsets: Vec<usize>,
    arcs: Vec<(NodeId, EdgeWeight)>,
}

impl Adjacency {
    /// From one list per node (in node order; each list kept in its order).
    pub fn from_lists(lists: &[Vec<(NodeId, EdgeWeight)>]) -> Self {
        let mut offsets = Vec::with_capacity(lists.len() + 1);
        offsets.push(0);
        let mut arcs = Vec::with_capacity(lists.iter().map(Vec::len).sum());
        for list in lists {
            arcs.extend_from_slice(list);
            offsets.push(arcs.len());
        }
        Self { offsets, arcs }
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// True when there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The neighbours of `u`, `None` if `u` is not a node.
    pub fn get(&self, u: usize) -> Option<&[(NodeId, EdgeWeight)]> {
        let (&start, &end) = (self.offsets.get(u)?, self.offsets.get(u + 1)?);
        self.arcs.get(start..end)
    }
}

impl std::ops::Index<usize> for Adjacency {
    type Output = [(NodeId, EdgeWeight)];

    /// The neighbours of `u`; panics if `u` is not a node (callers check `u < len()`).
    fn index(&self, u: usize) -> &Self::Output {
        &self.arcs[self.offsets[u]..self.offsets[u + 1]]
    }
}

/// An immutable latent graph (rebuilt, never edited).
#[derive(Debug, Clone)]
pub struct LatentGraph {
    grid: Grid,
    keys: Vec<CellKey>,
    index: HashMap<CellKey, NodeId>,
    adjacency: Adjacency,
    edges: Vec<(NodeId, NodeId, EdgeWeight)>,
    n_dropped_cells: u64,
    n_unmapped_states: u64,
    /// The all-pairs route table once built; shared by clones of this graph (they are the
    /// same graph), filled at most once.
    route_table: Arc<OnceLock<RouteTable>>,
}

impl LatentGraph {
    /// The grid the nodes live on.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Number of nodes.
    pub fn n_nodes(&self) -> usize {
        self.keys.len()
    }

    /// Number of undirected edges.
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }

    /// Distinct cells left out because of the node cap.
    pub fn n_dropped_cells(&self) -> u64 {
        self.n_dropped_cells
    }

    /// States whose cell key did not fit (no node).
    pub fn n_unmapped_states(&self) -> u64 {
        self.n_unmapped_states
    }

    /// Neighbour lists, indexed by node id.
    pub fn adjacency(&self) -> &Adjacency {
        &self.adjacency
    }

    /// The all-pairs route table, once built ([`crate::route_table`]).
    pub fn route_table(&self) -> Option<&RouteTable> {
        self.route_table.get()
    }

    /// Builds the route table on this thread with `threads` workers unless it is already
    /// built; returns whether the graph has one afterwards (false above
    /// [`MAX_TABLE_NODES`] nodes).
    pub fn build_route_table(&self, threads: usize) -> bool {
        if self.route_table.get().is_none() {
            if let Some(table) = RouteTable::build(&self.adjacency, threads, &|| false) {
                // Another thread may have filled it meanwhile: the same table, either is fine.
                let _ = self.route_table.set(table);
            }
        }
        self.route_table.get().is_some()
    }

    /// Starts building the route table on a background thread (with `threads` workers) and
    /// returns at once; route queries use the table as soon as it is there. The thread gives
    /// up when every clone of this graph has been dropped (a newer graph replaced it). Does
    /// nothing for graphs above [`MAX_TABLE_NODES`] nodes or with a table already.
    pub fn spawn_route_table(&self, threads: usize) -> std::io::Result<()> {
        if self.route_table.get().is_some() || self.n_nodes() > MAX_TABLE_NODES {
            return Ok(());
        }
        let slot = Arc::downgrade(&self.route_table);
        let adjacency = self.adjacency.clone();
        std::thread::Builder::new()
            .name("route-table".to_owned())
            .spawn(move || {
                let cancelled = || slot.strong_count() == 0;
                if let Some(table) = RouteTable::build(&adjacency, threads, &cancelled) {
                    if let Some(slot) = slot.upgrade() {
                        let _ = slot.set(table);
                    }
                }
            })?;
        Ok(())
    }

    /// Undirected edges `(a, b, weight)` with `a < b`, sorted.
    pub fn edges(&self) -> &[(NodeId, NodeId, EdgeWeight)] {
        &self.edges
    }

    /// The node of `key`, if that cell is in the graph.
    pub fn node_of_key(&self, key: CellKey) -> Option<NodeId> {
        self.index.get(&key).copied()
    }

    /// The node whose cell holds `point`, if any.
    pub fn node_at(&self, point: LatentPoint) -> Option<NodeId> {
        self.grid.key(point).and_then(|key| self.node_of_key(key))
    }

    /// Cell key of `node` (`None` for an id out of range).
    pub fn key(&self, node: NodeId) -> Option<CellKey> {
        self.keys.get(node as usize).copied()
    }

    /// Cell keys of every node, by node id.
    pub fn keys(&self) -> &[CellKey] {
        &self.keys
    }

    /// Position of `node` in φ-space (`None` for an id out of range).
    pub fn position(&self, node: NodeId) -> Option<LatentPoint> {
        self.key(node).map(|key| self.grid.position(key))
    }

    /// Weight of the edge u–v, if there is one.
    pub fn edge_weight(&self, u: NodeId, v: NodeId) -> Option<EdgeWeight> {
        let list = self.adjacency.get(u as usize)?;
        let at = list.binary_search_by_key(&v, |&(n, _)| n).ok()?;
        Some(list[at].1)
    }
}

/// Accumulates trajectories into a [`LatentGraph`].
#[derive(Debug)]
pub struct GraphBuilder {
    grid: Grid,
    max_nodes: usize,
    edge_window: usize,
    keys: Vec<CellKey>,
    index: HashMap<CellKey, NodeId>,
    edges: HashMap<(NodeId, NodeId), EdgeWeight>,
    dropped_cells: HashSet<CellKey>,
    n_unmapped_states: u64,
}

impl GraphBuilder {
    /// An empty builder. `max_nodes` ≤ `u32::MAX` and `edge_window` ≥ 1 are checked by the
    /// config validation.
    pub fn new(grid: Grid, max_nodes: usize, edge_window: u32) -> Self {
        Self {
            grid,
            max_nodes,
            edge_window: edge_window as usize,
            keys: Vec::new(),
            index: HashMap::new(),
            edges: HashMap::new(),
            dropped_cells: HashSet::new(),
            n_unmapped_states: 0,
        }
    }

    /// Adds the states of one trajectory (φ-space, in time order): their nodes, then the
    /// edges between states at most `edge_window` steps apart.
    pub fn add_trajectory(&mut self, latents: &[LatentPoint]) {
        let nodes: Vec<Option<NodeId>> = latents.iter().map(|&p| self.node_for(p)).collect();
        for (p, from) in nodes.iter().enumerate() {
            let Some(from) = *from else { continue };
            let last = (p + self.edge_window).min(nodes.len().saturating_sub(1));
            for (q, to) in nodes.iter().enumerate().take(last + 1).skip(p + 1) {
                if let Some(to) = *to {
                    self.add_edge(from, to, (q - p) as EdgeWeight);
                }
            }
        }
    }

    /// The node of `point`'s cell, creating it unless the cap is reached.
    fn node_for(&mut self, point: LatentPoint) -> Option<NodeId> {
        let Some(key) = self.grid.key(point) else {
            self.n_unmapped_states += 1;
            return None;
        };
        if let Some(&node) = self.index.get(&key) {
            return Some(node);
        }
        if self.keys.len() >= self.max_nodes {
            self.dropped_cells.insert(key);
            return None;
        }
        // Fits: `max_nodes` ≤ u32::MAX (config validation).
        let node = self.keys.len() as NodeId;
        self.keys.push(key);
        self.index.insert(key, node);
        Some(node)
    }

    /// Keeps the smaller weight of an existing edge; self pairs are ignored.
    fn add_edge(&mut self, a: NodeId, b: NodeId, weight: EdgeWeight) {
        if a == b {
            return;
        }
        let pair = (a.min(b), a.max(b));
        self.edges
            .entry(pair)
            .and_modify(|w| *w = (*w).min(weight))
            .or_insert(weight);
    }

    /// The finished graph.
    pub fn finish(self) -> LatentGraph {
        let mut edges: Vec<(NodeId, NodeId, EdgeWeight)> = self
            .edges
            .into_iter()
            .map(|((a, b), w)| (a, b, w))
            .collect();
        edges.sort_unstable();
        LatentGraph::assemble(
            self.grid,
            self.keys,
            self.index,
            edges,
            [self.dropped_cells.len() as u64, self.n_unmapped_states],
        )
    }
}

impl LatentGraph {
    /// The graph with these nodes (cell keys by node id) and edges (`(a, b, weight)`, `a < b`,
    /// sorted), as [`LatentGraph::keys`] and [`LatentGraph::edges`] give them, and the counts of
    /// cells dropped by the node cap and of unmapped states: a graph saved in a checkpoint.
    /// Refused with a message when the parts could not come from a built graph (a key twice,
    /// an edge that is a self pair, names a missing node, has weight 0, or is out of order).
    pub fn from_parts(
        grid: Grid,
        keys: Vec<CellKey>,
        edges: Vec<(NodeId, NodeId, EdgeWeight)>,
        n_dropped_cells: u64,
        n_unmapped_states: u64,
    ) -> Result<Self, String> {
        let n = keys.len();
        if NodeId::try_from(n).is_err() {
            return Err(format!("{n} nodes: more than node ids can number"));
        }
        let mut index = HashMap::with_capacity(n);
        for (node, &key) in keys.iter().enumerate() {
            if index.insert(key, node as NodeId).is_some() {
                return Err(format!(
                    "cell {:?} is node {node} and an earlier one",
                    key.0
                ));
            }
        }
        for (i, &(a, b, w)) in edges.iter().enumerate() {
            if a >= b || b as usize >= n || w == 0 {
                return Err(format!(
                    "edge {i} ({a}, {b}, weight {w}) is not (a, b) with a < b < {n} nodes and a \
                     weight of at least 1"
                ));
            }
            if i > 0 && edges[i - 1] >= (a, b, w) {
                return Err(format!("edge {i} ({a}, {b}) is out of order or repeated"));
            }
        }
        Ok(Self::assemble(
            grid,
            keys,
            index,
            edges,
            [n_dropped_cells, n_unmapped_states],
        ))
    }

    /// The graph of checked parts: the neighbour lists from the sorted edges.
    fn assemble(
        grid: Grid,
        keys: Vec<CellKey>,
        index: HashMap<CellKey, NodeId>,
        edges: Vec<(NodeId, NodeId, EdgeWeight)>,
        [n_dropped_cells, n_unmapped_states]: [u64; 2],
    ) -> Self {
        let mut lists = vec![Vec::new(); keys.len()];
        for &(a, b, w) in &edges {
            lists[a as usize].push((b, w));
            lists[b as usize].push((a, w));
        }
        for list in &mut lists {
            list.sort_unstable();
        }
        let adjacency = Adjacency::from_lists(&lists);
        Self {
            grid,
            keys,
            index,
            adjacency,
            edges,
            n_dropped_cells,
            n_unmapped_states,
            route_table: Arc::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use protocol::config::NodePosition;

    use super::*;

    fn build(window: u32, max_nodes: usize, trajectories: &[&[LatentPoint]]) -> LatentGraph {
        let mut builder =
            GraphBuilder::new(Grid::new(1.0, NodePosition::Corner), max_nodes, window);
        for t in trajectories {
            builder.add_trajectory(t);
        }
        builder.finish()
    }

    /// Cell (x, y) of a unit grid, as a point inside it.
    fn at(x: i32, y: i32) -> LatentPoint {
        [x as f32 + 0.5, y as f32 + 0.5]
    }

    fn weight(g: &LatentGraph, a: (i32, i32), b: (i32, i32)) -> Option<EdgeWeight> {
        let u = g.node_of_key(CellKey([a.0, a.1]))?;
        let v = g.node_of_key(CellKey([b.0, b.1]))?;
        g.edge_weight(u, v)
    }

    #[test]
    fn nodes_are_numbered_in_first_seen_order() {
        let g = build(
            1,
            10,
            &[&[at(5, 5), at(1, 1), at(5, 5)], &[at(-3, 0), at(1, 1)]],
        );
        assert_eq!(
            g.keys(),
            &[CellKey([5, 5]), CellKey([1, 1]), CellKey([-3, 0])]
        );
    }

    #[test]
    fn window_one_links_consecutive_cells_with_weight_one_and_ignores_self_pairs() {
        // cells: A A B C A, where A=(0,0), B=(1,0), C=(2,0)
        let t = [at(0, 0), at(0, 0), at(1, 0), at(2, 0), at(0, 0)];
        let g = build(1, 10, &[&t]);
        assert_eq!(weight(&g, (0, 0), (1, 0)), Some(1));
        assert_eq!(weight(&g, (1, 0), (2, 0)), Some(1));
        assert_eq!(weight(&g, (2, 0), (0, 0)), Some(1));
        assert_eq!(g.n_edges(), 3);
        let a = g.node_of_key(CellKey([0, 0])).unwrap();
        assert_eq!(g.edge_weight(a, a), None, "self pairs give no edge");
    }

    #[test]
    fn window_three_keeps_the_minimum_temporal_distance_per_pair() {
        // t:      0      1      2      3      4      5       6
        // cell:   A      B      B      C      D      A       C
        // Hand-computed minima over |p − q| ≤ 3:
        //   A–B: (0,1) → 1          A–C: (0,3)=3, (5,6)=1, (3,5)=2 → 1
        //   A–D: (4,5) → 1, (0,4) > 3      B–C: (2,3) → 1
        //   B–D: (2,4) → 2, (1,4)=3 → 2    C–D: (3,4) → 1, (4,6)=2 → 1
        //   B–A again at (2,5) = 3 → stays 1
        let (a, b, c, d) = ((-1, -1), (0, -1), (-2, 3), (7, 7));
        let t = [
            at(a.0, a.1),
            at(b.0, b.1),
            at(b.0, b.1),
            at(c.0, c.1),
            at(d.0, d.1),
            at(a.0, a.1),
            at(c.0, c.1),
        ];
        let g = build(3, 10, &[&t]);
        assert_eq!(weight(&g, a, b), Some(1));
        assert_eq!(weight(&g, a, c), Some(1));
        assert_eq!(weight(&g, a, d), Some(1));
        assert_eq!(weight(&g, b, c), Some(1));
        assert_eq!(weight(&g, b, d), Some(2));
        assert_eq!(weight(&g, c, d), Some(1));
        assert_eq!(g.n_edges(), 6);
    }

    #[test]
    fn window_three_weights_gaps_and_never_exceeds_the_window() {
        // cells: A A A A B on negative coordinates: A–B only via (3,4)=1 within window 3.
        // A second trajectory A x x x B: (0,4) = 4 > 3 → no edge from it; D is in between.
        let (a, b, d) = ((-5, -5), (-4, -5), (-10, 2));
        let first = [at(a.0, a.1), at(d.0, d.1), at(d.0, d.1), at(b.0, b.1)];
        let g = build(3, 10, &[&first]);
        assert_eq!(weight(&g, a, b), Some(3));
        assert_eq!(weight(&g, a, d), Some(1));
        assert_eq!(weight(&g, d, b), Some(1));
        let second = [
            at(a.0, a.1),
            at(d.0, d.1),
            at(d.0, d.1),
            at(d.0, d.1),
            at(b.0, b.1),
        ];
        let g = build(3, 10, &[&second]);
        assert_eq!(
            weight(&g, a, b),
            None,
            "4 steps apart is outside the window"
        );
        assert_eq!(weight(&g, a, d), Some(1));
    }

    #[test]
    fn edges_do_not_cross_trajectories() {
        let g = build(3, 10, &[&[at(0, 0)], &[at(1, 0)]]);
        assert_eq!(g.n_nodes(), 2);
        assert_eq!(g.n_edges(), 0);
    }

    #[test]
    fn the_node_cap_drops_new_cells_and_counts_each_once() {
        let t = [at(0, 0), at(1, 0), at(2, 0), at(3, 0), at(2, 0), at(1, 0)];
        let g = build(1, 2, &[&t]);
        assert_eq!(g.n_nodes(), 2);
        assert_eq!(g.n_dropped_cells(), 2);
        assert_eq!(g.n_edges(), 1);
    }

    /// The parts of `g` through [`LatentGraph::from_parts`].
    fn rebuilt(g: &LatentGraph) -> Result<LatentGraph, String> {
        LatentGraph::from_parts(
            g.grid,
            g.keys().to_vec(),
            g.edges().to_vec(),
            g.n_dropped_cells(),
            g.n_unmapped_states(),
        )
    }

    #[test]
    fn a_graph_from_its_parts_is_the_same_graph() {
        let t = [
            at(0, 0),
            at(1, 0),
            at(1, 1),
            at(0, 0),
            at(5, 5),
            at(2, 0),
            at(2, 1),
        ];
        let g = build(3, 5, &[&t, &[at(1, 1), at(2, 1)]]);
        assert!(g.n_dropped_cells() > 0 && g.n_edges() > 4, "{g:?}");
        let h = rebuilt(&g).unwrap();
        assert_eq!(h.keys(), g.keys());
        assert_eq!(h.edges(), g.edges());
        assert_eq!(h.adjacency(), g.adjacency());
        assert_eq!(
            (h.n_dropped_cells(), h.n_unmapped_states()),
            (g.n_dropped_cells(), g.n_unmapped_states())
        );
        for (node, &key) in g.keys().iter().enumerate() {
            assert_eq!(h.node_of_key(key), Some(node as NodeId));
        }
    }

    #[test]
    fn parts_no_built_graph_could_have_are_refused() {
        let g = build(1, 10, &[&[at(0, 0), at(1, 0), at(2, 0)]]);
        assert_eq!(g.edges(), &[(0, 1, 1), (1, 2, 1)]);
        let keys = g.keys().to_vec();
        let with_edges = |edges: Vec<(NodeId, NodeId, EdgeWeight)>| {
            LatentGraph::from_parts(g.grid, keys.clone(), edges, 0, 0)
        };
        for (edges, problem) in [
            (vec![(1, 1, 1)], "a < b"),
            (vec![(1, 0, 1)], "a < b"),
            (vec![(0, 3, 1)], "< 3 nodes"),
            (vec![(0, 1, 0)], "weight of at least 1"),
            (vec![(1, 2, 1), (0, 1, 1)], "out of order"),
            (vec![(0, 1, 1), (0, 1, 1)], "repeated"),
        ] {
            let err = with_edges(edges.clone()).unwrap_err();
            assert!(err.contains(problem), "{edges:?}: {err}");
        }
        let twice = vec![keys[0], keys[1], keys[0]];
        let err = LatentGraph::from_parts(g.grid, twice, Vec::new(), 0, 0).unwrap_err();
        assert!(err.contains("node 2 and an earlier one"), "{err}");
    }
}
