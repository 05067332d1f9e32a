//! Top-down PNG pictures of a maze with a trajectory (plotters' bitmap backend, no fonts).
//!
//! Orientation: x grows to the right and y grows *downward*, so the picture reads like the ASCII
//! maps of the digest (row 0 at the top). Walls are dark grey, free cells white, the start a green
//! dot, the goal a red dot inside a ring of the default success radius, and the trajectory a
//! blue polyline ending in a blue dot. Non-finite trajectory points are skipped.

use std::path::Path;

use plotters::prelude::*;

use crate::maze::{Maze, Rect};

/// Longest side of the picture, pixels.
pub const IMAGE_SIDE_PX: u32 = 600;
/// Radius of the start and goal dots, metres.
const MARKER_RADIUS_M: f32 = 0.3;
/// Radius of the ring around the goal: the default success threshold, metres.
const GOAL_RING_M: f32 = 1.5;
/// Width of the trajectory line, pixels.
const TRAJECTORY_WIDTH_PX: u32 = 2;
/// Radius of the trajectory's end dot, pixels.
const END_DOT_PX: i32 = 4;

const WALL_COLOR: RGBColor = RGBColor(60, 60, 60);
const START_COLOR: RGBColor = RGBColor(30, 160, 60);
const GOAL_COLOR: RGBColor = RGBColor(210, 40, 40);
const TRAJECTORY_COLOR: RGBColor = RGBColor(40, 90, 220);

/// Errors of the maze renderer.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("drawing `{path}` failed: {message}")]
    Drawing { path: String, message: String },
}

/// Maps world xy (metres) to pixels, as [`render_maze_png`] draws them (public so other
/// pictures of the maze draw their layers on the same walls).
pub struct PixelMap {
    bounds: Rect,
    px_per_m: f32,
}

impl PixelMap {
    /// The map of `bounds` with its longest side [`IMAGE_SIDE_PX`] pixels.
    pub fn new(bounds: Rect) -> PixelMap {
        let longest_m = bounds.width().max(bounds.height());
        PixelMap {
            bounds,
            px_per_m: IMAGE_SIDE_PX as f32 / longest_m,
        }
    }

    /// Picture size, pixels.
    pub fn size(&self) -> (u32, u32) {
        let w = (self.bounds.width() * self.px_per_m).round() as u32;
        let h = (self.bounds.height() * self.px_per_m).round() as u32;
        (w.max(1), h.max(1))
    }

    /// Pixel of world point `xy`.
    pub fn px(&self, xy: [f32; 2]) -> (i32, i32) {
        let x = (xy[0] - self.bounds.low[0]) * self.px_per_m;
        let y = (xy[1] - self.bounds.low[1]) * self.px_per_m;
        (x.round() as i32, y.round() as i32)
    }

    /// A length in pixels.
    pub fn len(&self, metres: f32) -> i32 {
        (metres * self.px_per_m).round() as i32
    }
}

/// Draws `maze` (walls, start, goal) and `trajectory` (xy points, metres) into a PNG at `path`.
pub fn render_maze_png(
    maze: &Maze,
    trajectory: &[[f32; 2]],
    goal: [f32; 2],
    path: &Path,
) -> Result<(), RenderError> {
    let map = PixelMap::new(maze.world_bounds());
    let fail = |e: &dyn std::fmt::Display| RenderError::Drawing {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    let root = BitMapBackend::new(path, map.size()).into_drawing_area();
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    draw_walls(&root, &map, maze).map_err(|e| fail(&e))?;
    draw_markers(&root, &map, maze.cell_center(maze.robot_cell()), goal).map_err(|e| fail(&e))?;
    draw_trajectory(&root, &map, trajectory).map_err(|e| fail(&e))?;
    root.present().map_err(|e| fail(&e))
}

/// A drawing area of the bitmap backend.
pub type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
/// What drawing on an [`Area`] returns.
pub type DrawResult<'a> =
    Result<(), DrawingAreaErrorKind<<BitMapBackend<'a> as DrawingBackend>::ErrorType>>;

/// Draws the wall cells of `maze`, dark grey.
pub fn draw_walls<'a>(root: &Area<'a>, map: &PixelMap, maze: &Maze) -> DrawResult<'a> {
    let half = maze.cell_size_m() / 2.0;
    for cell in maze.wall_cells() {
        let [x, y] = maze.cell_center(cell);
        let corners = [map.px([x - half, y - half]), map.px([x + half, y + half])];
        root.draw(&Rectangle::new(corners, WALL_COLOR.filled()))?;
    }
    Ok(())
}

fn draw_markers<'a>(
    root: &Area<'a>,
    map: &PixelMap,
    start: [f32; 2],
    goal: [f32; 2],
) -> DrawResult<'a> {
    let marker = map.len(MARKER_RADIUS_M);
    root.draw(&Circle::new(map.px(start), marker, START_COLOR.filled()))?;
    if goal[0].is_finite() && goal[1].is_finite() {
        root.draw(&Circle::new(
            map.px(goal),
            map.len(GOAL_RING_M),
            GOAL_COLOR.stroke_width(2),
        ))?;
        root.draw(&Circle::new(map.px(goal), marker, GOAL_COLOR.filled()))?;
    }
    Ok(())
}

fn draw_trajectory<'a>(root: &Area<'a>, map: &PixelMap, trajectory: &[[f32; 2]]) -> DrawResult<'a> {
    let points: Vec<(i32, i32)> = trajectory
        .iter()
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .map(|&p| map.px(p))
        .collect();
    let Some(&end) = points.last() else {
        return Ok(());
    };
    root.draw(&PathElement::new(
        points,
        TRAJECTORY_COLOR.stroke_width(TRAJECTORY_WIDTH_PX),
    ))?;
    root.draw(&Circle::new(end, END_DOT_PX, TRAJECTORY_COLOR.filled()))
}
