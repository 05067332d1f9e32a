//! The grid over φ-space (SPEC §6.5, digest §6): a point p falls in the cell with integer key
//! `(⌊p_x/d⌋, ⌊p_y/d⌋)` — floor division, so −0.5 with d = 2 is in cell −1, not 0 — and a
//! cell's node sits at its lower-left corner `key·d` (released code) or its centre
//! `(key + ½)·d` (`graph.node_position`).
//!
//! Invariant: keys are computed in f64 and must fit in `i32` (the wire type of a key); a point
//! whose key does not fit is "out of range" and has no cell ([`Grid::key`] returns `None`).

use protocol::config::NodePosition;
use protocol::LatentPoint;

/// Integer key of a grid cell, `(⌊x/d⌋, ⌊y/d⌋)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CellKey(pub [i32; 2]);

/// Cells of side `d` in φ-space and where their nodes sit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    cell_size: f64,
    node_position: NodePosition,
}

impl Grid {
    /// A grid of side `cell_size` (finite, > 0: checked by the config validation).
    pub fn new(cell_size: f64, node_position: NodePosition) -> Self {
        Self {
            cell_size,
            node_position,
        }
    }

    /// Cell side d.
    pub fn cell_size(&self) -> f64 {
        self.cell_size
    }

    /// The cell of `point`, or `None` if a coordinate is non-finite or its key overflows `i32`.
    pub fn key(&self, point: LatentPoint) -> Option<CellKey> {
        let x = axis_key(point[0], self.cell_size)?;
        let y = axis_key(point[1], self.cell_size)?;
        Some(CellKey([x, y]))
    }

    /// Where the node of cell `key` sits in φ-space.
    pub fn position(&self, key: CellKey) -> LatentPoint {
        let offset = match self.node_position {
            NodePosition::Corner => 0.0,
            NodePosition::Centre => 0.5,
        };
        key.0
            .map(|k| ((f64::from(k) + offset) * self.cell_size) as f32)
    }
}

/// `⌊value/d⌋` as an `i32`, if it is finite and fits.
fn axis_key(value: f32, cell_size: f64) -> Option<i32> {
    let key = (f64::from(value) / cell_size).floor();
    let fits = key.is_finite() && key >= f64::from(i32::MIN) && key <= f64::from(i32::MAX);
    // Truncation is exact: `key` is an integral value inside the i32 range.
    fits.then_some(key as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_use_floor_division_for_negative_coordinates() {
        let grid = Grid::new(2.0, NodePosition::Corner);
        assert_eq!(grid.key([0.0, 1.99]), Some(CellKey([0, 0])));
        assert_eq!(grid.key([-0.5, -2.0]), Some(CellKey([-1, -1])));
        assert_eq!(grid.key([-2.01, 3.0]), Some(CellKey([-2, 1])));
    }

    #[test]
    fn node_positions_are_corners_or_centres() {
        let corner = Grid::new(4.0, NodePosition::Corner);
        let centre = Grid::new(4.0, NodePosition::Centre);
        assert_eq!(corner.position(CellKey([-1, 2])), [-4.0, 8.0]);
        assert_eq!(centre.position(CellKey([-1, 2])), [-2.0, 10.0]);
    }

    #[test]
    fn out_of_range_and_non_finite_points_have_no_cell() {
        let grid = Grid::new(2.0, NodePosition::Corner);
        assert_eq!(grid.key([1e30, 0.0]), None);
        assert_eq!(grid.key([0.0, f32::NAN]), None);
        assert_eq!(grid.key([f32::NEG_INFINITY, 0.0]), None);
    }
}
