//! Maze layouts of the ant-maze family (U, S, W, FourRooms) as data, with their geometry.
//!
//! Conventions (reference digest §9.1–9.2):
//! - Cell (row `i`, column `j`); the robot cell `(i_r, j_r)` is the start and sits at the world
//!   origin. The centre of cell `(i, j)` is `((j − j_r)·s, (i − i_r)·s)` with `s` the cell size,
//!   so `y` grows with the row index (downward in the ASCII maps below, as in the digest).
//! - Every wall cell is a [`StaticBox`] centred at `(x_c, y_c, s/4)` with half extents
//!   `(s/2, s/2, s/4)`: walls are `s/2` tall.
//! - The goal box spans the maze interior (everything but the border ring); training goals are
//!   uniform in it, rejection-sampled until the goal's cell (by the code's lookup
//!   `j = j_r + ceil(x/s − 0.5)`, `i = i_r + ceil(y/s − 0.5)`) is free.
//!
//! Invariants of a [`Maze`]: the grid is rectangular with a wall border, the robot and goal cells
//! are free interior cells, and every free cell is reachable from the robot cell (checked when
//! the maze is built), so goal sampling always terminates and path distances are defined.

use std::collections::VecDeque;

use rand::Rng;

use crate::api::{EnvError, StaticBox};

/// Which maze layout a task uses (digest §9.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MazeLayout {
    /// `AntMaze1-v1`: U shape, 4 m cells, 500 steps, test goal (0, 8).
    U,
    /// `AntMazeS-v1`: S shape, 4 m cells, 1000 steps, test goal (16, 16).
    S,
    /// `AntMazeW-v1`: W shape, 4 m cells, 1000 steps, test goal (0, 8).
    W,
    /// `AntMaze-v2`: four rooms, 2 m cells, 1000 steps, test goal (14, 14).
    FourRooms,
}

impl MazeLayout {
    /// All layouts, in the order of the digest.
    pub const ALL: [MazeLayout; 4] = [
        MazeLayout::U,
        MazeLayout::S,
        MazeLayout::W,
        MazeLayout::FourRooms,
    ];
}

/// Character of a wall cell in the layout maps.
const WALL_CHAR: char = '#';
/// Character of an ordinary free cell.
const FREE_CHAR: char = '.';
/// Character of the robot (start) cell; it is free.
const START_CHAR: char = 'S';
/// Character of the evaluation-goal cell; it is free.
const GOAL_CHAR: char = 'G';

/// The layout data of one maze: map rows, cell size and episode length.
struct LayoutData {
    rows: &'static [&'static str],
    cell_size_m: f32,
    max_steps: u32,
}

/// U shape (digest §9.2, `AntMaze1-v1`): s = 4, robot (1, 1), goal (3, 1), T = 500.
const U_LAYOUT: LayoutData = LayoutData {
    rows: &["#####", "#S..#", "###.#", "#G..#", "#####"],
    cell_size_m: 4.0,
    max_steps: 500,
};

/// S shape (digest §9.2, `AntMazeS-v1`): s = 4, robot (1, 1), goal (5, 5), T = 1000.
const S_LAYOUT: LayoutData = LayoutData {
    rows: &[
        "#######", "#S....#", "#####.#", "#.....#", "#.#####", "#....G#", "#######",
    ],
    cell_size_m: 4.0,
    max_steps: 1000,
};

/// W shape (digest §9.2, `AntMazeW-v1`): s = 4, robot (2, 1), goal (4, 1), T = 1000.
const W_LAYOUT: LayoutData = LayoutData {
    rows: &[
        "#######", "#.....#", "#S###.#", "###...#", "#G###.#", "#.....#", "#######",
    ],
    cell_size_m: 4.0,
    max_steps: 1000,
};

/// Four rooms (digest §9.2, `AntMaze-v2`): s = 2, robot (2, 2), goal (9, 9), T = 1000.
const FOUR_ROOMS_LAYOUT: LayoutData = LayoutData {
    rows: &[
        "###########",
        "#....#....#",
        "#.S..#....#",
        "#.........#",
        "#....#....#",
        "##.#####.##",
        "#....#....#",
        "#....#....#",
        "#.........#",
        "#....#...G#",
        "###########",
    ],
    cell_size_m: 2.0,
    max_steps: 1000,
};

fn layout_data(layout: MazeLayout) -> &'static LayoutData {
    match layout {
        MazeLayout::U => &U_LAYOUT,
        MazeLayout::S => &S_LAYOUT,
        MazeLayout::W => &W_LAYOUT,
        MazeLayout::FourRooms => &FOUR_ROOMS_LAYOUT,
    }
}

/// Fraction of the maximum start-to-cell path distance a "far goal" must reach (SPEC §6.4).
pub const FAR_GOAL_FRACTION: f64 = 2.0 / 3.0;

/// Tolerance of the far-goal comparison, so that e.g. 4 ≥ (2/3)·6 holds despite rounding.
const FAR_GOAL_TOLERANCE: f64 = 1e-9;

/// A grid cell: row `i`, column `j`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Cell {
    pub i: usize,
    pub j: usize,
}

impl Cell {
    pub const fn new(i: usize, j: usize) -> Cell {
        Cell { i, j }
    }
}

/// An axis-aligned rectangle in the plane (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rect {
    pub low: [f32; 2],
    pub high: [f32; 2],
}

impl Rect {
    /// Whether `xy` lies in the closed rectangle.
    pub fn contains(&self, xy: [f32; 2]) -> bool {
        (0..2).all(|d| xy[d] >= self.low[d] && xy[d] <= self.high[d])
    }

    pub fn width(&self) -> f32 {
        self.high[0] - self.low[0]
    }

    pub fn height(&self) -> f32 {
        self.high[1] - self.low[1]
    }
}

/// A maze: its wall grid, cell size, robot and goal cells, and episode length.
#[derive(Debug, Clone, PartialEq)]
pub struct Maze {
    layout: Option<MazeLayout>,
    n_rows: usize,
    n_cols: usize,
    /// Row-major, `true` where the cell is a wall.
    walls: Vec<bool>,
    cell_size_m: f32,
    robot_cell: Cell,
    goal_cell: Cell,
    max_steps: u32,
    /// Row-major BFS distance (in cells) from the robot cell; `None` on walls.
    start_distance: Vec<Option<u32>>,
}

impl Maze {
    /// One of the built-in layouts.
    pub fn new(layout: MazeLayout) -> Maze {
        let data = layout_data(layout);
        let maze = Maze::from_rows(data.rows, data.cell_size_m, data.max_steps)
            .expect("built-in layouts are valid mazes (checked by tests/maze.rs)");
        Maze {
            layout: Some(layout),
            ..maze
        }
    }

    /// A custom maze from map rows (`#` wall, `.` free, `S` robot cell, `G` goal cell).
    ///
    /// Fails unless the rows are rectangular, bordered by walls, have exactly one `S` and one
    /// `G`, every free cell is reachable from `S`, and `cell_size_m` is finite and positive.
    pub fn from_rows(rows: &[&str], cell_size_m: f32, max_steps: u32) -> Result<Maze, EnvError> {
        if !(cell_size_m.is_finite() && cell_size_m > 0.0) {
            return Err(invalid(
                "cell_size_m",
                cell_size_m,
                "must be finite and positive",
            ));
        }
        if max_steps == 0 {
            return Err(invalid("max_steps", max_steps, "must be positive"));
        }
        let grid = parse_rows(rows)?;
        check_border(&grid)?;
        let mut maze = Maze {
            layout: None,
            n_rows: grid.n_rows,
            n_cols: grid.n_cols,
            walls: grid.walls,
            cell_size_m,
            robot_cell: grid.start,
            goal_cell: grid.goal,
            max_steps,
            start_distance: Vec::new(),
        };
        maze.start_distance = maze.bfs_from(maze.robot_cell);
        maze.check_connected()?;
        Ok(maze)
    }

    /// The built-in layout this maze was made from (`None` for a custom maze).
    pub fn layout(&self) -> Option<MazeLayout> {
        self.layout
    }

    pub fn n_rows(&self) -> usize {
        self.n_rows
    }

    pub fn n_cols(&self) -> usize {
        self.n_cols
    }

    /// Side of a cell, metres (4 for U/S/W, 2 for FourRooms).
    pub fn cell_size_m(&self) -> f32 {
        self.cell_size_m
    }

    /// The robot (start) cell; its centre is the world origin.
    pub fn robot_cell(&self) -> Cell {
        self.robot_cell
    }

    /// The cell of the fixed evaluation goal.
    pub fn goal_cell(&self) -> Cell {
        self.goal_cell
    }

    /// Episode length in control steps (500 for U, 1000 otherwise).
    pub fn max_steps(&self) -> u32 {
        self.max_steps
    }

    /// Whether `cell` is inside the grid and not a wall.
    pub fn is_free(&self, cell: Cell) -> bool {
        cell.i < self.n_rows && cell.j < self.n_cols && !self.walls[self.index(cell)]
    }

    /// Whether `cell` is inside the grid and a wall.
    pub fn is_wall(&self, cell: Cell) -> bool {
        cell.i < self.n_rows && cell.j < self.n_cols && self.walls[self.index(cell)]
    }

    /// All free cells, row by row.
    pub fn free_cells(&self) -> impl Iterator<Item = Cell> + '_ {
        self.cells().filter(|&c| self.is_free(c))
    }

    /// All wall cells, row by row.
    pub fn wall_cells(&self) -> impl Iterator<Item = Cell> + '_ {
        self.cells().filter(|&c| self.is_wall(c))
    }

    /// The map as rows in the layout notation (`#` wall, `.` free, `S` robot cell, `G` goal
    /// cell); [`Maze::from_rows`] of them builds this maze again.
    pub fn rows(&self) -> Vec<String> {
        (0..self.n_rows)
            .map(|i| {
                (0..self.n_cols)
                    .map(|j| match Cell::new(i, j) {
                        c if c == self.robot_cell => START_CHAR,
                        c if c == self.goal_cell => GOAL_CHAR,
                        c if self.is_wall(c) => WALL_CHAR,
                        _ => FREE_CHAR,
                    })
                    .collect()
            })
            .collect()
    }

    /// The free-cell map, row-major (`true` = free), `n_rows × n_cols`.
    pub fn free_map(&self) -> Vec<Vec<bool>> {
        (0..self.n_rows)
            .map(|i| {
                (0..self.n_cols)
                    .map(|j| self.is_free(Cell::new(i, j)))
                    .collect()
            })
            .collect()
    }

    /// World xy of a cell's centre: `((j − j_r)·s, (i − i_r)·s)`.
    pub fn cell_center(&self, cell: Cell) -> [f32; 2] {
        let dj = cell.j as f32 - self.robot_cell.j as f32;
        let di = cell.i as f32 - self.robot_cell.i as f32;
        [dj * self.cell_size_m, di * self.cell_size_m]
    }

    /// The cell containing `xy` by the code's lookup (`j = j_r + ceil(x/s − 0.5)`, same for `i`
    /// with `y`); `None` when outside the grid or not finite. Boundaries belong to the lower cell.
    pub fn cell_of(&self, xy: [f32; 2]) -> Option<Cell> {
        let j = axis_index(xy[0], self.cell_size_m, self.robot_cell.j, self.n_cols)?;
        let i = axis_index(xy[1], self.cell_size_m, self.robot_cell.i, self.n_rows)?;
        Some(Cell::new(i, j))
    }

    /// Whether `xy` lies in a free cell (by [`Maze::cell_of`]).
    pub fn is_free_xy(&self, xy: [f32; 2]) -> bool {
        self.cell_of(xy).is_some_and(|c| self.is_free(c))
    }

    /// The box training goals are drawn from: the interior,
    /// `x ∈ [(0.5 − j_r)s, (n_cols − 1.5 − j_r)s]`, `y ∈ [(0.5 − i_r)s, (n_rows − 1.5 − i_r)s]`.
    pub fn goal_box(&self) -> Rect {
        let s = self.cell_size_m;
        let (ir, jr) = (self.robot_cell.i as f32, self.robot_cell.j as f32);
        Rect {
            low: [(0.5 - jr) * s, (0.5 - ir) * s],
            high: [
                (self.n_cols as f32 - 1.5 - jr) * s,
                (self.n_rows as f32 - 1.5 - ir) * s,
            ],
        }
    }

    /// The whole grid, border walls included.
    pub fn world_bounds(&self) -> Rect {
        let s = self.cell_size_m;
        let (ir, jr) = (self.robot_cell.i as f32, self.robot_cell.j as f32);
        Rect {
            low: [(-0.5 - jr) * s, (-0.5 - ir) * s],
            high: [
                (self.n_cols as f32 - 0.5 - jr) * s,
                (self.n_rows as f32 - 0.5 - ir) * s,
            ],
        }
    }

    /// The fixed evaluation goal: the centre of the goal cell.
    pub fn test_goal(&self) -> [f32; 2] {
        self.cell_center(self.goal_cell)
    }

    /// A training goal: uniform over [`Maze::goal_box`], rejection-sampled to free cells.
    ///
    /// Terminates with probability 1: the robot cell is a free interior cell, so it covers a
    /// positive share of the goal box.
    pub fn sample_goal<G: Rng + ?Sized>(&self, rng: &mut G) -> [f32; 2] {
        let goal_box = self.goal_box();
        loop {
            let xy = [
                rng.random_range(goal_box.low[0]..=goal_box.high[0]),
                rng.random_range(goal_box.low[1]..=goal_box.high[1]),
            ];
            if self.is_free_xy(xy) {
                return xy;
            }
        }
    }

    /// Walls as static boxes: centre `(x_c, y_c, s/4)`, half extents `(s/2, s/2, s/4)`.
    pub fn walls(&self) -> Vec<StaticBox> {
        let s = self.cell_size_m;
        self.wall_cells()
            .map(|c| {
                let [x, y] = self.cell_center(c);
                StaticBox {
                    center: [x, y, s / 4.0],
                    half_extents: [s / 2.0, s / 2.0, s / 4.0],
                }
            })
            .collect()
    }

    /// Maze path distance in cells (BFS over free cells, 4-neighbour); `None` if either cell is
    /// a wall or outside the grid.
    pub fn path_distance(&self, from: Cell, to: Cell) -> Option<u32> {
        if !self.is_free(from) || !self.is_free(to) {
            return None;
        }
        if from == self.robot_cell {
            return self.start_distance[self.index(to)];
        }
        self.bfs_from(from)[self.index(to)]
    }

    /// Distance along the maze from `from` to `to` in metres, at the resolution of its cells:
    /// [`Maze::path_distance`] between their cells × the cell size (0 within one cell). On U,
    /// start to test goal is 6 cells, 24 m, where the straight line is 8 m, so this says how
    /// far along the maze a final position is where the xy distance cannot. `None` when either
    /// point is not in a free cell (outside the grid, in a wall, not finite).
    pub fn path_distance_m(&self, from: [f32; 2], to: [f32; 2]) -> Option<f32> {
        let (from, to) = (self.cell_of(from)?, self.cell_of(to)?);
        self.path_distance(from, to)
            .map(|cells| cells as f32 * self.cell_size_m)
    }

    /// Path distance from the robot cell to `cell`; `None` on walls or outside the grid.
    pub fn start_distance(&self, cell: Cell) -> Option<u32> {
        if !self.is_free(cell) {
            return None;
        }
        self.start_distance[self.index(cell)]
    }

    /// The largest path distance from the robot cell to any free cell.
    pub fn max_start_distance(&self) -> u32 {
        self.start_distance
            .iter()
            .flatten()
            .copied()
            .max()
            .unwrap_or(0)
    }

    /// Whether `goal` is a "far goal" (SPEC §6.4): its cell's path distance from the start is at
    /// least [`FAR_GOAL_FRACTION`] of the maximum. On U this is the bottom row (y > 6), the cell
    /// version of the code's `g_y ≥ 8` rule.
    pub fn is_far_goal(&self, goal: [f32; 2]) -> bool {
        self.is_far_goal_with_fraction(goal, FAR_GOAL_FRACTION)
    }

    /// [`Maze::is_far_goal`] with a chosen fraction of the maximum path distance.
    pub fn is_far_goal_with_fraction(&self, goal: [f32; 2], fraction: f64) -> bool {
        let threshold = fraction * f64::from(self.max_start_distance()) - FAR_GOAL_TOLERANCE;
        self.cell_of(goal)
            .and_then(|c| self.start_distance(c))
            .is_some_and(|d| f64::from(d) >= threshold)
    }

    fn cells(&self) -> impl Iterator<Item = Cell> + '_ {
        (0..self.n_rows).flat_map(move |i| (0..self.n_cols).map(move |j| Cell::new(i, j)))
    }

    fn index(&self, cell: Cell) -> usize {
        cell.i * self.n_cols + cell.j
    }

    /// The free 4-neighbours of a cell.
    fn neighbours(&self, cell: Cell) -> impl Iterator<Item = Cell> + '_ {
        let up = cell.i.checked_sub(1).map(|i| Cell::new(i, cell.j));
        let left = cell.j.checked_sub(1).map(|j| Cell::new(cell.i, j));
        let down = Some(Cell::new(cell.i + 1, cell.j));
        let right = Some(Cell::new(cell.i, cell.j + 1));
        [up, down, left, right]
            .into_iter()
            .flatten()
            .filter(|&c| self.is_free(c))
    }

    /// Breadth-first distances (in cells) from a free cell to every cell, row-major.
    fn bfs_from(&self, from: Cell) -> Vec<Option<u32>> {
        let mut dist = vec![None; self.walls.len()];
        dist[self.index(from)] = Some(0);
        let mut queue = VecDeque::from([(from, 0u32)]);
        while let Some((cell, d)) = queue.pop_front() {
            for next in self.neighbours(cell) {
                let slot = &mut dist[self.index(next)];
                if slot.is_none() {
                    *slot = Some(d + 1);
                    queue.push_back((next, d + 1));
                }
            }
        }
        dist
    }

    fn check_connected(&self) -> Result<(), EnvError> {
        match self
            .free_cells()
            .find(|&c| self.start_distance[self.index(c)].is_none())
        {
            Some(c) => Err(invalid(
                "rows",
                format!("cell ({}, {})", c.i, c.j),
                "free cell unreachable from S",
            )),
            None => Ok(()),
        }
    }
}

/// One axis of the code's cell lookup: `start + ceil(v/s − 0.5)`, if inside `0..n`.
fn axis_index(v: f32, cell_size_m: f32, start: usize, n: usize) -> Option<usize> {
    if !v.is_finite() {
        return None;
    }
    let index = start as f64 + (f64::from(v) / f64::from(cell_size_m) - 0.5).ceil();
    (index >= 0.0 && index < n as f64).then_some(index as usize)
}

/// A parsed map: wall flags and the two marked cells.
struct ParsedGrid {
    n_rows: usize,
    n_cols: usize,
    walls: Vec<bool>,
    start: Cell,
    goal: Cell,
}

fn parse_rows(rows: &[&str]) -> Result<ParsedGrid, EnvError> {
    let n_cols = rows.first().map_or(0, |r| r.chars().count());
    if rows.len() < 3 || n_cols < 3 {
        return Err(invalid(
            "rows",
            rows.len(),
            "a maze needs at least 3 × 3 cells",
        ));
    }
    let mut walls = Vec::with_capacity(rows.len() * n_cols);
    let (mut starts, mut goals) = (Vec::new(), Vec::new());
    for (i, row) in rows.iter().enumerate() {
        if row.chars().count() != n_cols {
            return Err(invalid(
                "rows",
                format!("row {i}"),
                "rows must all have the same length",
            ));
        }
        for (j, ch) in row.chars().enumerate() {
            match ch {
                WALL_CHAR => walls.push(true),
                FREE_CHAR => walls.push(false),
                START_CHAR => {
                    walls.push(false);
                    starts.push(Cell::new(i, j));
                }
                GOAL_CHAR => {
                    walls.push(false);
                    goals.push(Cell::new(i, j));
                }
                other => {
                    return Err(invalid(
                        "rows",
                        format!("'{other}' at ({i}, {j})"),
                        "use # . S G",
                    ))
                }
            }
        }
    }
    let start = single_mark(&starts, START_CHAR)?;
    let goal = single_mark(&goals, GOAL_CHAR)?;
    Ok(ParsedGrid {
        n_rows: rows.len(),
        n_cols,
        walls,
        start,
        goal,
    })
}

fn single_mark(marks: &[Cell], ch: char) -> Result<Cell, EnvError> {
    match marks {
        [cell] => Ok(*cell),
        _ => Err(invalid(
            "rows",
            format!("{} '{ch}' cells", marks.len()),
            "exactly one is needed",
        )),
    }
}

fn check_border(grid: &ParsedGrid) -> Result<(), EnvError> {
    let (n_rows, n_cols) = (grid.n_rows, grid.n_cols);
    let on_border = |i: usize, j: usize| i == 0 || j == 0 || i + 1 == n_rows || j + 1 == n_cols;
    for i in 0..n_rows {
        for j in 0..n_cols {
            if on_border(i, j) && !grid.walls[i * n_cols + j] {
                return Err(invalid(
                    "rows",
                    format!("cell ({i}, {j})"),
                    "the border must be walls",
                ));
            }
        }
    }
    Ok(())
}

fn invalid(field: &str, value: impl std::fmt::Display, reason: &str) -> EnvError {
    EnvError::InvalidParam {
        field: field.to_string(),
        value: value.to_string(),
        reason: reason.to_string(),
    }
}
