//! A picture of a graph dump (plotters' bitmap backend, no fonts): φ-space with y up, edges
//! as thin grey lines, each node a square of its cell coloured by visit count (log scale, dark
//! blue = fewest, yellow = most), the route to the frontier as a thick red line, the start as a
//! green dot and the frontier as a red ring.

use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;
use protocol::graph::{FrontierRoute, GraphDump};
use protocol::LatentPoint;

/// Longest side of the picture, pixels.
const IMAGE_SIDE_PX: u32 = 800;
/// Empty border around the drawn φ region, pixels.
const MARGIN_PX: f64 = 20.0;
const EDGE_COLOR: RGBColor = RGBColor(170, 170, 170);
const ROUTE_COLOR: RGBColor = RGBColor(215, 30, 30);
const START_COLOR: RGBColor = RGBColor(30, 160, 60);
/// Colour of the fewest and of the most visits.
const FEW_VISITS: [f64; 3] = [30.0, 40.0, 120.0];
const MANY_VISITS: [f64; 3] = [250.0, 220.0, 40.0];

/// Maps φ-space to pixels (y up).
struct PixelMap {
    low: [f64; 2],
    high: [f64; 2],
    px_per_unit: f64,
}

impl PixelMap {
    /// The bounding box of `points` (at least one cell wide), scaled to the picture.
    fn covering(points: &[LatentPoint], cell: f64) -> Self {
        let mut low = [f64::INFINITY; 2];
        let mut high = [f64::NEG_INFINITY; 2];
        for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
            for axis in 0..2 {
                low[axis] = low[axis].min(f64::from(p[axis]));
                high[axis] = high[axis].max(f64::from(p[axis]) + cell);
            }
        }
        if !low[0].is_finite() {
            (low, high) = ([0.0, 0.0], [cell, cell]);
        }
        let longest = (high[0] - low[0]).max(high[1] - low[1]).max(cell);
        let px_per_unit = (f64::from(IMAGE_SIDE_PX) - 2.0 * MARGIN_PX) / longest;
        Self {
            low,
            high,
            px_per_unit,
        }
    }

    fn size(&self) -> (u32, u32) {
        let side = |axis: usize| {
            ((self.high[axis] - self.low[axis]) * self.px_per_unit + 2.0 * MARGIN_PX).round() as u32
        };
        (side(0).max(1), side(1).max(1))
    }

    fn px(&self, p: [f64; 2]) -> (i32, i32) {
        let x = MARGIN_PX + (p[0] - self.low[0]) * self.px_per_unit;
        let y = MARGIN_PX + (self.high[1] - p[1]) * self.px_per_unit;
        (x.round() as i32, y.round() as i32)
    }

    fn px_of(&self, p: LatentPoint) -> (i32, i32) {
        self.px(p.map(f64::from))
    }
}

/// Draws `dump` (with the frontier route from `start`, if any) into a PNG at `path`.
pub fn render(
    dump: &GraphDump,
    start: Option<LatentPoint>,
    found: Option<&FrontierRoute>,
    path: &Path,
) -> anyhow::Result<()> {
    let cell = f64::from(dump.cell_size);
    let mut points: Vec<LatentPoint> = dump.nodes.iter().map(|n| corner(n.key, cell)).collect();
    points.extend(start);
    let map = PixelMap::covering(&points, cell);
    let root = BitMapBackend::new(path, map.size()).into_drawing_area();
    let fail = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing {}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    draw_graph(&root, &map, dump).map_err(|e| fail(&e))?;
    draw_route(&root, &map, cell, start, found).map_err(|e| fail(&e))?;
    root.present()
        .map_err(|e| fail(&e))
        .with_context(|| format!("writing {}", path.display()))
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type DrawResult<'a> =
    Result<(), DrawingAreaErrorKind<<BitMapBackend<'a> as DrawingBackend>::ErrorType>>;

fn draw_graph<'a>(root: &Area<'a>, map: &PixelMap, dump: &GraphDump) -> DrawResult<'a> {
    let cell = f64::from(dump.cell_size);
    for &(a, b, _) in &dump.edges {
        if let (Some(a), Some(b)) = (dump.nodes.get(a as usize), dump.nodes.get(b as usize)) {
            let line = vec![map.px(centre(a.key, cell)), map.px(centre(b.key, cell))];
            root.draw(&PathElement::new(line, EDGE_COLOR.stroke_width(1)))?;
        }
    }
    let most = dump.nodes.iter().map(|n| n.visits).max().unwrap_or(0);
    for node in &dump.nodes {
        let [x, y] = corner(node.key, cell).map(f64::from);
        // Inset by a tenth so neighbouring cells stay apart.
        let corners = [
            map.px([x + 0.1 * cell, y + 0.9 * cell]),
            map.px([x + 0.9 * cell, y + 0.1 * cell]),
        ];
        root.draw(&Rectangle::new(
            corners,
            visit_color(node.visits, most).filled(),
        ))?;
    }
    Ok(())
}

/// Route nodes are drawn at their cell's centre, like the edges, whatever `graph.node_position`.
fn draw_route<'a>(
    root: &Area<'a>,
    map: &PixelMap,
    cell: f64,
    start: Option<LatentPoint>,
    found: Option<&FrontierRoute>,
) -> DrawResult<'a> {
    let at_centre = |p: LatentPoint| map.px(centre(key_of(p, cell), cell));
    if let Some(found) = found {
        let line: Vec<(i32, i32)> = found.route.iter().map(|&p| at_centre(p)).collect();
        root.draw(&PathElement::new(line, ROUTE_COLOR.stroke_width(3)))?;
        root.draw(&Circle::new(
            at_centre(found.frontier),
            8,
            ROUTE_COLOR.stroke_width(3),
        ))?;
    }
    if let Some(start) = start {
        root.draw(&Circle::new(map.px_of(start), 6, START_COLOR.filled()))?;
    }
    Ok(())
}

/// Lower-left corner of cell `key`.
fn corner(key: [i32; 2], cell: f64) -> LatentPoint {
    key.map(|k| (f64::from(k) * cell) as f32)
}

/// Centre of cell `key`.
fn centre(key: [i32; 2], cell: f64) -> [f64; 2] {
    key.map(|k| (f64::from(k) + 0.5) * cell)
}

/// Cell key of a node position (corner or centre: both floor to the key).
fn key_of(p: LatentPoint, cell: f64) -> [i32; 2] {
    p.map(|v| (f64::from(v) / cell).floor() as i32)
}

/// Colour of a node with `visits`, on a log scale up to `most`.
pub(crate) fn visit_color(visits: u64, most: u64) -> RGBColor {
    let t = if most == 0 {
        0.0
    } else {
        (1.0 + visits as f64).ln() / (1.0 + most as f64).ln()
    };
    let mix =
        |axis: usize| (FEW_VISITS[axis] + t * (MANY_VISITS[axis] - FEW_VISITS[axis])).round() as u8;
    RGBColor(mix(0), mix(1), mix(2))
}
