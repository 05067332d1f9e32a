//! Indices along an SI route (digest §8): the imitation target and the low level's references.
//!
//! A route `R = [R[0], …, R[L−1]]` runs from the start node (index 0, the node of φ(s_t)) to
//! the end node. With `k` drawn uniformly from `asi.si_k_range` (default [3, 5] = [c//6, c//4]
//! for c = 20):
//! - target index `idx = min(k, L − 1)`;
//! - reference indices `u_i = ⌊linspace(1, max(1, ⌊min(L − 1, idx) / 2⌋), |u|)_i⌋`,
//!   `|u| = asi.si_n_refs` (default 3): idx 3 → [1, 1, 1], idx 4 or 5 → [1, 1, 2].
//!
//! Too-short routes are dropped: the high level needs `L > 1` ([`MIN_HIGH_ROUTE_LEN`]), the low
//! level `L > 2` ([`MIN_LOW_ROUTE_LEN`]): the target is then never the start node, and the low
//! level's references (all ≥ 1) never lie beyond its target (for k ≥ 1).

/// Shortest route the high-level SI step uses (`L > 1`, reference code).
pub const MIN_HIGH_ROUTE_LEN: usize = 2;
/// Shortest route the low-level SI step uses (`L > 2`, reference code).
pub const MIN_LOW_ROUTE_LEN: usize = 3;

/// The target index `min(k, L − 1)` for a drawn `k` on a route of `route_len` nodes;
/// `None` for an empty route (no index exists).
pub fn target_index(k: u32, route_len: usize) -> Option<usize> {
    let last = route_len.checked_sub(1)?;
    Some((k as usize).min(last))
}

/// The `n_refs` reference indices for target index `idx` on a route of `route_len` nodes:
/// `⌊linspace(1, stop, n_refs)⌋` with `stop = max(1, ⌊min(L − 1, idx) / 2⌋)`, computed in exact
/// integer arithmetic (`1 + ⌊i·(stop − 1)/(n_refs − 1)⌋`), which is what numpy's float linspace
/// truncated with `int` gives for these small values. `n_refs = 1` gives `[1]` (numpy: the
/// start). Every index lies in `[1, max(1, idx/2)]`, so on a route with `L > 2` it is a node
/// after the start node and at or before the target.
pub fn reference_indices(idx: usize, route_len: usize, n_refs: u32) -> Vec<usize> {
    let clamped = idx.min(route_len.saturating_sub(1));
    let stop = (clamped / 2).max(1);
    let n = n_refs as usize;
    if n <= 1 {
        return vec![1; n];
    }
    (0..n).map(|i| 1 + i * (stop - 1) / (n - 1)).collect()
}
