//! Visit counts n(v) per grid cell (paper Eq. 10), for FR count mode (SPEC §6.6).
//!
//! n(v) = the number of stored states whose latent point under the current φ lies in cell v
//! (the graph's grid, side d). Counts go up as chunks are ingested, down as states are evicted,
//! and are recounted from the store when φ changes, so they always describe the store. Cells
//! are counted whether or not they are graph nodes (a cell left out by the node cap still has
//! visits); a cell never seen has n = 0. States whose key is out of range are not counted.

use std::collections::HashMap;

use protocol::LatentPoint;

use crate::grid::{CellKey, Grid};

/// A candidate point whose cell key does not fit (see [`Grid::key`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutOfRange {
    /// Index of the candidate.
    pub index: usize,
    /// The candidate.
    pub point: LatentPoint,
}

/// Visit counts per cell.
#[derive(Debug, Clone, PartialEq)]
pub struct VisitCounts {
    grid: Grid,
    counts: HashMap<CellKey, u64>,
}

impl VisitCounts {
    /// Empty counts on `grid`.
    pub fn new(grid: Grid) -> Self {
        Self {
            grid,
            counts: HashMap::new(),
        }
    }

    /// Counts one more state at each of `points`.
    pub fn add(&mut self, points: &[LatentPoint]) {
        for key in points.iter().filter_map(|&p| self.grid.key(p)) {
            *self.counts.entry(key).or_insert(0) += 1;
        }
    }

    /// Forgets one state at each of `points` (evicted states).
    pub fn remove(&mut self, points: &[LatentPoint]) {
        for key in points.iter().filter_map(|&p| self.grid.key(p)) {
            if let Some(n) = self.counts.get_mut(&key) {
                *n = n.saturating_sub(1);
                if *n == 0 {
                    self.counts.remove(&key);
                }
            }
        }
    }

    /// Every counted cell and its n(v), sorted by key (checkpoints).
    pub fn entries(&self) -> Vec<(CellKey, u64)> {
        let mut entries: Vec<_> = self.counts.iter().map(|(&k, &n)| (k, n)).collect();
        entries.sort_unstable();
        entries
    }

    /// Clears every count.
    pub fn clear(&mut self) {
        self.counts.clear();
    }

    /// n(v) of cell `key`.
    pub fn of_key(&self, key: CellKey) -> u64 {
        self.counts.get(&key).copied().unwrap_or(0)
    }

    /// n(v) of the cell holding `point`, `None` if its key is out of range.
    pub fn at(&self, point: LatentPoint) -> Option<u64> {
        self.grid.key(point).map(|key| self.of_key(key))
    }

    /// The candidate with the fewest visits (first on ties) and its count; `Ok(None)` for no
    /// candidates, `Err` at the first candidate whose cell is out of range.
    pub fn least_visited(
        &self,
        candidates: &[LatentPoint],
    ) -> Result<Option<(usize, u64)>, OutOfRange> {
        let mut best: Option<(usize, u64)> = None;
        for (index, &point) in candidates.iter().enumerate() {
            let visits = self.at(point).ok_or(OutOfRange { index, point })?;
            if best.is_none_or(|(_, fewest)| visits < fewest) {
                best = Some((index, visits));
            }
        }
        Ok(best)
    }
}

#[cfg(test)]
mod tests {
    use protocol::config::NodePosition;

    use super::*;

    fn counts() -> VisitCounts {
        VisitCounts::new(Grid::new(2.0, NodePosition::Corner))
    }

    #[test]
    fn counts_follow_adds_and_removals_per_cell() {
        let mut c = counts();
        c.add(&[[0.5, 0.5], [1.5, 1.9], [-0.1, 0.0]]);
        assert_eq!(c.at([0.0, 0.0]), Some(2));
        assert_eq!(c.at([-2.0, 1.0]), Some(1));
        c.remove(&[[0.1, 0.1]]);
        assert_eq!(c.at([0.0, 0.0]), Some(1));
        assert_eq!(c.at([9.0, 9.0]), Some(0));
    }

    #[test]
    fn least_visited_picks_the_first_of_the_fewest() {
        let mut c = counts();
        c.add(&[[0.0, 0.0], [0.0, 0.0], [2.0, 0.0], [4.0, 0.0]]);
        let candidates = [[0.5, 0.5], [2.5, 0.5], [4.5, 0.5], [0.0, 0.0]];
        assert_eq!(c.least_visited(&candidates), Ok(Some((1, 1))));
        assert_eq!(
            c.least_visited(&[[0.0, 0.0], [50.0, 50.0]]),
            Ok(Some((1, 0)))
        );
        assert_eq!(c.least_visited(&[]), Ok(None));
    }

    #[test]
    fn least_visited_refuses_out_of_range_candidates() {
        let c = counts();
        let err = c.least_visited(&[[0.0, 0.0], [1e30, 0.0]]).unwrap_err();
        assert_eq!(err.index, 1);
    }
}
