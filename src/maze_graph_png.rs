//! `run_dir/plots/graph_latest.png`: the latent graph drawn in the maze (plotters' bitmap
//! backend, no fonts), on the walls of [`envs::render`] (same orientation: y grows downward).
//! Layers, bottom to top: visited 0.6 m coverage cells of the stored states (light blue),
//! walls, edges between node positions (grey), nodes at the mean xy of their stored states
//! ([`graph_service::xy`]) coloured by visit count (log scale, as `asi graph dump --png`), and
//! the last frontier the service answered with its route (red line, red ring).
//!
//! Drawn by the graph-service process (at most once per [`REDRAW_INTERVAL`], after a rebuild)
//! and by serial mode; tasks without a maze draw nothing.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use envs::render::{draw_walls, Area, DrawResult, PixelMap};
use envs::{Coverage, Env, Maze};
use graph_service::xy::XyGraph;
use graph_service::GraphService;
use plotters::prelude::*;

use crate::graph_png::visit_color;

/// Shortest time between two redraws in process mode (a 5,000-node picture takes tens of
/// milliseconds; once a minute keeps it off the service's time budget).
pub const REDRAW_INTERVAL: Duration = Duration::from_secs(60);
/// Serial mode has no clock in its loop: it redraws at most once per this many completed
/// episodes.
pub const REDRAW_EPISODES: u64 = 50;
/// File name inside `run_dir/plots/`.
pub const FILE_NAME: &str = "graph_latest.png";

const COVERED_COLOR: RGBColor = RGBColor(200, 225, 245);
const EDGE_COLOR: RGBColor = RGBColor(150, 150, 150);
const ROUTE_COLOR: RGBColor = RGBColor(215, 30, 30);
/// Radius of a node dot and of the frontier ring, pixels.
const NODE_PX: i32 = 3;
const FRONTIER_PX: i32 = 9;

/// Draws `graph` in `maze` with the visited cells of `coverage` into a PNG at `path`.
pub fn render(
    maze: &Maze,
    coverage: &Coverage,
    graph: &XyGraph,
    path: &Path,
) -> anyhow::Result<()> {
    let map = PixelMap::new(maze.world_bounds());
    let root = BitMapBackend::new(path, map.size()).into_drawing_area();
    let fail = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing {}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    draw_coverage(&root, &map, coverage).map_err(|e| fail(&e))?;
    draw_walls(&root, &map, maze).map_err(|e| fail(&e))?;
    draw_graph(&root, &map, graph).map_err(|e| fail(&e))?;
    root.present()
        .map_err(|e| fail(&e))
        .with_context(|| format!("writing {}", path.display()))
}

fn draw_coverage<'a>(root: &Area<'a>, map: &PixelMap, coverage: &Coverage) -> DrawResult<'a> {
    let (n_x, n_y) = coverage.shape();
    let half = coverage.cell_size_m() / 2.0;
    for (ix, iy) in (0..n_y).flat_map(|iy| (0..n_x).map(move |ix| (ix, iy))) {
        if coverage.count(ix, iy).unwrap_or(0) > 0 {
            let [x, y] = coverage.cell_centre(ix, iy);
            let corners = [map.px([x - half, y - half]), map.px([x + half, y + half])];
            root.draw(&Rectangle::new(corners, COVERED_COLOR.filled()))?;
        }
    }
    Ok(())
}

fn draw_graph<'a>(root: &Area<'a>, map: &PixelMap, graph: &XyGraph) -> DrawResult<'a> {
    let xy = |node: u32| graph.nodes.get(node as usize).and_then(|n| n.xy);
    for &(a, b) in &graph.edges {
        if let (Some(a), Some(b)) = (xy(a), xy(b)) {
            root.draw(&PathElement::new(
                vec![map.px(a), map.px(b)],
                EDGE_COLOR.stroke_width(1),
            ))?;
        }
    }
    let most = graph.nodes.iter().map(|n| n.visits).max().unwrap_or(0);
    for node in &graph.nodes {
        if let Some(at) = node.xy {
            root.draw(&Circle::new(
                map.px(at),
                NODE_PX,
                visit_color(node.visits, most).filled(),
            ))?;
        }
    }
    if let Some(frontier) = &graph.frontier {
        let line: Vec<(i32, i32)> = frontier.route.iter().map(|&p| map.px(p)).collect();
        root.draw(&PathElement::new(line, ROUTE_COLOR.stroke_width(3)))?;
        if let Some(at) = frontier.frontier {
            root.draw(&Circle::new(
                map.px(at),
                FRONTIER_PX,
                ROUTE_COLOR.stroke_width(3),
            ))?;
        }
    }
    Ok(())
}

/// The run's maze picture of the graph: knows the maze and how to read a state's xy, and
/// which graph version it drew last.
pub struct MazeGraphPlot {
    env: Box<dyn Env>,
    path: PathBuf,
    drawn_version: u64,
}

impl MazeGraphPlot {
    /// The plot of `run_dir/plots/graph_latest.png`; `None` for a task without a maze.
    pub fn new(config: &protocol::Config, run_dir: &Path) -> anyhow::Result<Option<Self>> {
        let options = envs::EnvOptions {
            max_steps: config.env.episode_length,
        };
        let env = envs::make_with(&config.env.task, options)
            .with_context(|| format!("building task `{}`", config.env.task))?;
        if env.maze().is_none() {
            return Ok(None);
        }
        let plots = run_dir.join("plots");
        std::fs::create_dir_all(&plots).with_context(|| format!("creating {}", plots.display()))?;
        Ok(Some(Self {
            env,
            path: plots.join(FILE_NAME),
            drawn_version: 0,
        }))
    }

    /// Whether the service holds a graph this plot has not drawn yet.
    pub fn behind(&self, service: &GraphService) -> bool {
        service.stats().graph_version != self.drawn_version
    }

    /// Draws the service's current graph (nothing before the first); a failure is logged, not
    /// returned: a picture never stops the run.
    pub fn draw(&mut self, service: &GraphService) {
        let Some(maze) = self.env.maze() else { return };
        let env = &self.env;
        let Some(graph) = service.xy_graph(|obs| env.achieved_goal(obs)) else {
            return;
        };
        let mut coverage = Coverage::new(maze);
        let store = service.store();
        for trajectory in store.trajectories() {
            for obs in trajectory.obs().chunks_exact(store.obs_dim().max(1)) {
                coverage.visit(env.achieved_goal(obs));
            }
        }
        match render(maze, &coverage, &graph, &self.path) {
            Ok(()) => self.drawn_version = graph.graph_version,
            Err(err) => tracing::warn!("{FILE_NAME} not drawn: {err:#}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use graph_service::xy::{XyFrontier, XyNode};

    use super::*;

    /// A lattice of `side × side` nodes over `maze`'s goal box, each joined to its right and
    /// upper neighbour, with a frontier route along the first row.
    fn lattice(maze: &Maze, side: u32) -> XyGraph {
        let area = maze.goal_box();
        let at = |i: u32, j: u32| {
            let t = |k: u32| (k as f32 + 0.5) / side as f32;
            [
                area.low[0] + t(i) * area.width(),
                area.low[1] + t(j) * area.height(),
            ]
        };
        let id = |i: u32, j: u32| j * side + i;
        let nodes = (0..side * side)
            .map(|n| XyNode {
                xy: Some(at(n % side, n / side)),
                n_states: 1,
                visits: u64::from(n),
            })
            .collect();
        let mut edges = Vec::new();
        for (i, j) in (0..side).flat_map(|j| (0..side).map(move |i| (i, j))) {
            if i + 1 < side {
                edges.push((id(i, j), id(i + 1, j)));
            }
            if j + 1 < side {
                edges.push((id(i, j), id(i, j + 1)));
            }
        }
        let route: Vec<[f32; 2]> = (0..side).map(|i| at(i, 0)).collect();
        let frontier = Some(XyFrontier {
            frontier: route.last().copied(),
            route,
        });
        XyGraph {
            graph_version: 1,
            nodes,
            edges,
            frontier,
        }
    }

    #[test]
    fn a_five_thousand_node_graph_is_drawn_into_a_png_that_decodes() {
        let maze = Maze::new(envs::MazeLayout::U);
        let mut coverage = Coverage::new(&maze);
        coverage.visit(maze.cell_center(maze.robot_cell()));
        let graph = lattice(&maze, 71);
        assert!(graph.nodes.len() > 5_000);
        let path = std::env::temp_dir().join(format!("asi-maze-graph-{}.png", std::process::id()));
        let clock = std::time::Instant::now();
        render(&maze, &coverage, &graph, &path).unwrap();
        eprintln!(
            "{} nodes drawn in {:.3} s",
            graph.nodes.len(),
            clock.elapsed().as_secs_f64()
        );
        let (width, height, pixels) = crate::plot::read_rgb_png(&path);
        std::fs::remove_file(&path).unwrap();
        assert_eq!((width, height), PixelMap::new(maze.world_bounds()).size());
        // The route colour is in the picture (RGB rows, no alpha).
        let red = [ROUTE_COLOR.0, ROUTE_COLOR.1, ROUTE_COLOR.2];
        assert!(
            pixels.chunks_exact(3).any(|p| p == red),
            "the frontier route is drawn"
        );
    }
}
