//! Coverage grid (SPEC §4, digest §10 "faithful" version) on hand-placed visits.

use envs::coverage::{Coverage, COVERAGE_CELL_M};
use envs::maze::{Maze, MazeLayout};

/// U maze, goal box [−2, 10]²: 20 × 20 cells of 0.6 m. Along an axis the cell centres
/// −1.7, −1.1, …, 9.7 fall 7 into [−2, 2] (−1.7 … 1.9), 6 into (2, 6] (2.5 … 5.5) and 7 into
/// (6, 10] (6.1 … 9.7). Free maze cells (row band × column band): (1,1) 7·7, (1,2) 7·6,
/// (1,3) 7·7, (2,3) 6·7, (3,1) 7·7, (3,2) 7·6, (3,3) 7·7 = 4·49 + 3·42 = 322.
const U_FREE_COVERAGE_CELLS: usize = 322;

#[test]
fn the_u_grid_has_hand_counted_free_cells() {
    let coverage = Coverage::new(&Maze::new(MazeLayout::U));
    assert_eq!(COVERAGE_CELL_M, 0.6);
    assert_eq!(coverage.shape(), (20, 20));
    assert_eq!(coverage.n_free_cells(), U_FREE_COVERAGE_CELLS);
    assert_eq!(coverage.coverage(), 0.0);
}

#[test]
fn coverage_counts_visited_free_cells_once_each() {
    let mut coverage = Coverage::new(&Maze::new(MazeLayout::U));
    coverage.visit([0.0, 0.0]);
    coverage.visit([0.1, 0.1]); // same 0.6 m cell as (0, 0): [−0.2, 0.4)²
    assert_eq!(coverage.n_visited_free_cells(), 1);
    assert_eq!(coverage.n_visits(), 2);
    assert_eq!(
        coverage.count(3, 3),
        Some(2),
        "(0, 0) is in cell (⌊2/0.6⌋, ⌊2/0.6⌋) = (3, 3)"
    );
    coverage.visit([8.0, 8.0]);
    assert_eq!(coverage.n_visited_free_cells(), 2);
    assert!((coverage.coverage() - 2.0 / U_FREE_COVERAGE_CELLS as f64).abs() < 1e-12);
}

#[test]
fn visits_in_walls_are_counted_but_do_not_raise_coverage() {
    let mut coverage = Coverage::new(&Maze::new(MazeLayout::U));
    coverage.visit([0.0, 4.0]); // the wall between the arms of the U
    assert_eq!(coverage.n_visits(), 1);
    assert_eq!(coverage.n_visited_free_cells(), 0);
    assert_eq!(coverage.coverage(), 0.0);
}

#[test]
fn points_outside_the_goal_box_or_not_finite_are_ignored_and_counted() {
    let mut coverage = Coverage::new(&Maze::new(MazeLayout::U));
    for xy in [
        [50.0, 0.0],
        [-2.1, 0.0],
        [0.0, 10.1],
        [f32::NAN, 0.0],
        [0.0, f32::INFINITY],
    ] {
        coverage.visit(xy);
    }
    assert_eq!(coverage.n_outside(), 5);
    assert_eq!(coverage.n_visits(), 0);
    coverage.visit([10.0, 10.0]); // the far corner of the box belongs to the last cell
    assert_eq!(coverage.count(19, 19), Some(1));
}

#[test]
fn visiting_every_free_cell_gives_full_coverage_in_every_maze() {
    for layout in MazeLayout::ALL {
        let mut coverage = Coverage::new(&Maze::new(layout));
        let (n_x, n_y) = coverage.shape();
        let centres: Vec<[f32; 2]> = (0..n_y)
            .flat_map(|iy| (0..n_x).map(move |ix| (ix, iy)))
            .map(|(ix, iy)| coverage.cell_centre(ix, iy))
            .collect();
        coverage.visit_all(&centres);
        assert_eq!(coverage.coverage(), 1.0, "{layout:?}");
        assert_eq!(coverage.n_visited_free_cells(), coverage.n_free_cells());
    }
}

#[test]
fn coverage_is_cumulative() {
    let mut coverage = Coverage::new(&Maze::new(MazeLayout::S));
    coverage.visit([0.0, 0.0]);
    let first = coverage.coverage();
    coverage.visit([16.0, 16.0]);
    assert!(coverage.coverage() > first);
    coverage.visit([0.0, 0.0]);
    assert_eq!(coverage.n_visited_free_cells(), 2);
}

#[test]
fn a_non_positive_cell_size_is_an_error() {
    let maze = Maze::new(MazeLayout::U);
    assert!(Coverage::with_cell_size(&maze, 0.0).is_err());
    assert!(Coverage::with_cell_size(&maze, f32::NAN).is_err());
    assert_eq!(
        Coverage::with_cell_size(&maze, 4.0)
            .expect("valid")
            .n_free_cells(),
        7
    );
}
