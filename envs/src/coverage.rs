//! State-space coverage of a maze: a cumulative xy occupancy grid (SPEC §4, digest §10).
//!
//! The grid has square cells of [`COVERAGE_CELL_M`] (0.6 m, the code's `grid_scale 3.0 × 0.2`)
//! laid over the maze's goal box (the interior), starting at its low corner. A coverage cell is
//! *free* when its centre lies in a free maze cell. Coverage is the "faithful" version of the
//! digest: visited free coverage cells / all free coverage cells, so it lies in [0, 1] for every
//! maze (the code's hard-coded U-maze factor 9/7 is not used).
//!
//! Invariants: counts only grow (the grid is never reset); a point outside the goal box or not
//! finite changes no cell and is counted in [`Coverage::n_outside`]; a point in a wall coverage
//! cell is counted in that cell but never raises the coverage.

use crate::api::EnvError;
use crate::maze::{Maze, Rect};

/// Side of a coverage cell, metres (digest §10: `grid_scale 3.0 × 0.2`; source: code).
pub const COVERAGE_CELL_M: f32 = 0.6;

/// Cumulative visit counts on an xy grid over a maze's free area.
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    area: Rect,
    cell_size_m: f32,
    n_x: usize,
    n_y: usize,
    /// Row-major (`iy * n_x + ix`) visit counts.
    counts: Vec<u64>,
    /// Row-major: whether the cell's centre is in a free maze cell.
    free: Vec<bool>,
    n_free_cells: usize,
    n_visited_free_cells: usize,
    n_visits: u64,
    n_outside: u64,
}

impl Coverage {
    /// A grid of [`COVERAGE_CELL_M`] cells over `maze`'s goal box.
    pub fn new(maze: &Maze) -> Coverage {
        Coverage::build(maze, COVERAGE_CELL_M)
    }

    /// A grid of `cell_size_m` cells over `maze`'s goal box. The last row and column may stick out
    /// of the box (the box is covered completely). `cell_size_m` must be finite and positive.
    pub fn with_cell_size(maze: &Maze, cell_size_m: f32) -> Result<Coverage, EnvError> {
        if !(cell_size_m.is_finite() && cell_size_m > 0.0) {
            return Err(EnvError::InvalidParam {
                field: "coverage.cell_size_m".to_string(),
                value: cell_size_m.to_string(),
                reason: "must be finite and positive".to_string(),
            });
        }
        Ok(Coverage::build(maze, cell_size_m))
    }

    fn build(maze: &Maze, cell_size_m: f32) -> Coverage {
        let area = maze.goal_box();
        let n_x = cells_along(area.width(), cell_size_m);
        let n_y = cells_along(area.height(), cell_size_m);
        let free: Vec<bool> = (0..n_y)
            .flat_map(|iy| (0..n_x).map(move |ix| (ix, iy)))
            .map(|(ix, iy)| maze.is_free_xy(cell_centre(area, cell_size_m, ix, iy)))
            .collect();
        let n_free_cells = free.iter().filter(|&&f| f).count();
        Coverage {
            area,
            cell_size_m,
            n_x,
            n_y,
            counts: vec![0; n_x * n_y],
            free,
            n_free_cells,
            n_visited_free_cells: 0,
            n_visits: 0,
            n_outside: 0,
        }
    }

    /// Records one visit at `xy`.
    pub fn visit(&mut self, xy: [f32; 2]) {
        let Some(index) = self.index_of(xy) else {
            self.n_outside += 1;
            return;
        };
        self.n_visits += 1;
        if self.counts[index] == 0 && self.free[index] {
            self.n_visited_free_cells += 1;
        }
        self.counts[index] += 1;
    }

    /// Records a visit at every point of `xys`.
    pub fn visit_all(&mut self, xys: &[[f32; 2]]) {
        for &xy in xys {
            self.visit(xy);
        }
    }

    /// Visited free cells / free cells, in [0, 1] (0 when the grid has no free cell).
    pub fn coverage(&self) -> f64 {
        if self.n_free_cells == 0 {
            return 0.0;
        }
        self.n_visited_free_cells as f64 / self.n_free_cells as f64
    }

    /// Number of free coverage cells (the denominator of [`Coverage::coverage`]).
    pub fn n_free_cells(&self) -> usize {
        self.n_free_cells
    }

    /// Number of free coverage cells visited at least once.
    pub fn n_visited_free_cells(&self) -> usize {
        self.n_visited_free_cells
    }

    /// Visits that landed in the grid.
    pub fn n_visits(&self) -> u64 {
        self.n_visits
    }

    /// Visits outside the grid or not finite (ignored).
    pub fn n_outside(&self) -> u64 {
        self.n_outside
    }

    /// Grid size `(n_x, n_y)`.
    pub fn shape(&self) -> (usize, usize) {
        (self.n_x, self.n_y)
    }

    pub fn cell_size_m(&self) -> f32 {
        self.cell_size_m
    }

    /// The region the grid starts from (the maze's goal box).
    pub fn area(&self) -> Rect {
        self.area
    }

    /// Visit count of cell `(ix, iy)`; `None` outside the grid.
    pub fn count(&self, ix: usize, iy: usize) -> Option<u64> {
        (ix < self.n_x && iy < self.n_y).then(|| self.counts[iy * self.n_x + ix])
    }

    /// Whether cell `(ix, iy)` is free; `None` outside the grid.
    pub fn is_free_cell(&self, ix: usize, iy: usize) -> Option<bool> {
        (ix < self.n_x && iy < self.n_y).then(|| self.free[iy * self.n_x + ix])
    }

    /// Row-major (`iy * n_x + ix`) visit counts of every cell (to save the grid).
    pub fn counts(&self) -> &[u64] {
        &self.counts
    }

    /// Sets the grid's counts to saved ones (`counts` as [`Coverage::counts`] gave them, and
    /// [`Coverage::n_outside`]); the derived totals are recounted. Refused, changing nothing,
    /// when `counts` does not have one entry per cell.
    pub fn restore_counts(&mut self, counts: &[u64], n_outside: u64) -> Result<(), EnvError> {
        if counts.len() != self.counts.len() {
            return Err(EnvError::InvalidParam {
                field: "coverage.counts".to_string(),
                value: format!("{} cells", counts.len()),
                reason: format!("the grid has {} cells", self.counts.len()),
            });
        }
        self.counts.copy_from_slice(counts);
        self.n_visits = counts.iter().sum();
        self.n_visited_free_cells = counts
            .iter()
            .zip(&self.free)
            .filter(|(&n, &free)| n > 0 && free)
            .count();
        self.n_outside = n_outside;
        Ok(())
    }

    /// The cell `(ix, iy)` holding `xy`; `None` outside the grid or not finite.
    pub fn cell_of(&self, xy: [f32; 2]) -> Option<(usize, usize)> {
        let ix = axis_cell(xy[0], self.area.low[0], self.cell_size_m, self.n_x)?;
        let iy = axis_cell(xy[1], self.area.low[1], self.cell_size_m, self.n_y)?;
        Some((ix, iy))
    }

    /// World xy of cell `(ix, iy)`'s centre.
    pub fn cell_centre(&self, ix: usize, iy: usize) -> [f32; 2] {
        cell_centre(self.area, self.cell_size_m, ix, iy)
    }

    fn index_of(&self, xy: [f32; 2]) -> Option<usize> {
        if !self.area.contains(xy) {
            return None;
        }
        self.cell_of(xy).map(|(ix, iy)| iy * self.n_x + ix)
    }
}

/// Cells needed to cover `length` (at least one).
fn cells_along(length: f32, cell_size_m: f32) -> usize {
    ((length / cell_size_m).ceil() as usize).max(1)
}

/// Index of `v` along one axis, clamping the far edge of the area into the last cell.
fn axis_cell(v: f32, low: f32, cell_size_m: f32, n: usize) -> Option<usize> {
    if !v.is_finite() || v < low {
        return None;
    }
    let index = ((v - low) / cell_size_m).floor() as usize;
    match index {
        i if i < n => Some(i),
        i if i == n && (v - low) <= n as f32 * cell_size_m => Some(n - 1),
        _ => None,
    }
}

fn cell_centre(area: Rect, cell_size_m: f32, ix: usize, iy: usize) -> [f32; 2] {
    [
        area.low[0] + (ix as f32 + 0.5) * cell_size_m,
        area.low[1] + (iy as f32 + 0.5) * cell_size_m,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maze::MazeLayout;

    #[test]
    fn restored_counts_give_back_the_same_grid_and_a_wrong_length_is_refused() {
        let maze = Maze::new(MazeLayout::U);
        let mut visited = Coverage::new(&maze);
        for xy in [
            [0.0, 0.0],
            [0.1, 0.1],
            [8.0, 8.0],
            [f32::NAN, 0.0],
            [-1e6, 0.0],
        ] {
            visited.visit(xy);
        }
        assert_eq!(visited.n_visited_free_cells(), 2);
        assert_eq!(visited.n_outside(), 2);
        let mut restored = Coverage::new(&maze);
        restored
            .restore_counts(visited.counts(), visited.n_outside())
            .unwrap();
        assert_eq!(restored, visited);
        assert!(restored.restore_counts(&visited.counts()[1..], 0).is_err());
        assert_eq!(restored, visited, "a refused restore changes nothing");
    }
}
