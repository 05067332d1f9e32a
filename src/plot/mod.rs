//! `asi plot`: learning curves of several runs on one figure, as the paper reports them — runs
//! grouped into arms (seeds of one setting), each arm's mean over seeds with a 95 % confidence
//! band (Student t over seeds), x axis env steps — one panel per metric, as a PNG.
//!
//! Data: each run directory's `metrics.jsonl` (one object per launcher flush). A curve is the
//! metric against the x key (default `learner/ingest/env_steps`), lines missing either key
//! skipped. Arms: a run directory's name with a trailing seed tag removed (`…_seed-3`,
//! `…-seed3`, `…_s3`), so `u-asi_seed-0` and `u-asi_seed-1` form the arm `u-asi`.
//! Aggregation: every seed's curve is linearly interpolated onto a common grid (no
//! extrapolation), then mean and `t(0.975, n−1) · sd / √n` per grid point over the seeds whose
//! curve reaches it; the drawn band is clipped to [0, 1] when every value lies in it (rates and
//! fractions cannot leave it), and at 0 from below when every value is ≥ 0 (distances, counts).
//! The grid runs at one spacing from the latest first x to the smallest final x (every seed
//! there: solid line) and on to the largest final x when the seeds' lengths differ; that tail
//! holds only the seeds that got so far, so it is drawn dashed, and the legend and the printed
//! summary say how many seeds each part holds. Each panel's legend goes in the corner of the plot
//! area where it hides the least of the curves and bands ([`legend_origin`]).
//!
//! Also used by the launcher to keep `run_dir/plots/curves.png` current during a run.

pub mod font;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use plotters::prelude::*;

/// Default x axis: env steps ingested by the learner.
pub const DEFAULT_X: &str = "learner/ingest/env_steps";
/// Default metrics: test-goal success rate and xy coverage.
pub const DEFAULT_METRICS: [&str; 2] = ["evaluator0/eval/success_rate", "learner/charts/coverage"];
/// Points of the common grid between an arm's latest first x and its smallest final x.
const GRID_POINTS: usize = 200;
/// At most this many more points in the tail past the smallest final x (the spacing widens
/// beyond it, so one seed much longer than the others does not make a huge grid).
const TAIL_POINTS_MAX: usize = 4 * GRID_POINTS;

/// One run's curve of one metric.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
}

/// An arm's aggregate on a grid: mean and confidence half-width (0 with one seed).
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    pub x: Vec<f64>,
    pub mean: Vec<f64>,
    pub half_width: Vec<f64>,
    pub n_seeds: usize,
    /// Seeds whose curve reaches each grid point: `n_seeds` up to the shortest seed's end, fewer
    /// in the tail past it.
    pub n_at: Vec<usize>,
    /// `(0, 1)` when every value of every seed lies in [0, 1] (a rate or fraction: success,
    /// coverage): the drawn band is clipped to it, since the metric cannot leave it.
    pub clip: Option<(f64, f64)>,
}

impl Band {
    /// Grid points every seed reaches (the solid part; the points after it are the tail).
    pub fn common_len(&self) -> usize {
        self.n_at.iter().take_while(|&&k| k == self.n_seeds).count()
    }

    /// Lower edge of the band at each grid point (clipped to [`Band::clip`]).
    pub fn lower(&self) -> Vec<f64> {
        let lo = self.clip.map_or(f64::NEG_INFINITY, |c| c.0);
        self.mean
            .iter()
            .zip(&self.half_width)
            .map(|(m, h)| (m - h).max(lo))
            .collect()
    }

    /// Upper edge of the band at each grid point (clipped to [`Band::clip`]).
    pub fn upper(&self) -> Vec<f64> {
        let hi = self.clip.map_or(f64::INFINITY, |c| c.1);
        self.mean
            .iter()
            .zip(&self.half_width)
            .map(|(m, h)| (m + h).min(hi))
            .collect()
    }
}

/// Reads `metric` against `x_key` from `run_dir/metrics.jsonl` ([`read_series_of`] for one
/// metric).
#[cfg(test)]
pub fn read_series(run_dir: &Path, x_key: &str, metric: &str) -> anyhow::Result<Series> {
    let mut one = read_series_of(run_dir, x_key, &[metric.to_owned()])?;
    Ok(one.pop().expect("one series per metric"))
}

/// `run_dir/metrics.jsonl`, or when only that exists its packed form `metrics.jsonl.gz` (a run
/// folder archived by scripts/run_archive.py), with the path opened.
fn open_metrics(run_dir: &Path) -> anyhow::Result<(PathBuf, Box<dyn std::io::Read>)> {
    let path = run_dir.join("metrics.jsonl");
    let packed = run_dir.join("metrics.jsonl.gz");
    if !path.exists() && packed.exists() {
        let file = std::fs::File::open(&packed)
            .with_context(|| format!("reading {}", packed.display()))?;
        return Ok((packed, Box::new(flate2::read::MultiGzDecoder::new(file))));
    }
    let file = std::fs::File::open(&path).with_context(|| format!("reading {}", path.display()))?;
    Ok((path, Box::new(file)))
}

/// Reads each of `metrics` against `x_key` from `run_dir/metrics.jsonl` (or its packed form,
/// [`open_metrics`]), in one streamed pass
/// that keeps only the wanted keys of each line (a week-long process-mode run writes hundreds
/// of MB, and the launcher redraws its curves every minute). Points are kept in file order
/// with x non-decreasing (a point whose x goes back is dropped) and the last value kept for
/// repeated x; non-finite and non-numeric values are skipped, as are lines that are not JSON
/// objects. A last line without its newline that is not JSON is one a running writer has not
/// finished: it is skipped, any other bad line is an error.
pub fn read_series_of(
    run_dir: &Path,
    x_key: &str,
    metrics: &[String],
) -> anyhow::Result<Vec<Series>> {
    use std::io::BufRead;
    let (path, file) = open_metrics(run_dir)?;
    let mut reader = std::io::BufReader::with_capacity(1 << 16, file);
    let mut series = vec![
        Series {
            x: Vec::new(),
            y: Vec::new(),
        };
        metrics.len()
    ];
    let mut wanted = WantedKeys::new(x_key, metrics);
    let mut line = String::new();
    let mut number = 0usize;
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            break;
        }
        number += 1;
        if line.trim().is_empty() {
            continue;
        }
        wanted.clear();
        let parsed = if line.trim_start().starts_with('{') {
            let mut de = serde_json::Deserializer::from_str(&line);
            serde::de::DeserializeSeed::deserialize(&mut wanted, &mut de).and_then(|()| de.end())
        } else {
            // Other JSON values hold no keys; they are checked, not read.
            serde_json::from_str::<serde::de::IgnoredAny>(&line).map(|_| ())
        };
        match parsed {
            Ok(()) => {}
            Err(_) if !line.ends_with('\n') => break,
            Err(err) => {
                return Err(err)
                    .with_context(|| format!("{}: line {number} is not JSON", path.display()))
            }
        }
        let Some(x) = wanted.values[0].filter(|x| x.is_finite()) else {
            continue;
        };
        for (series, y) in series.iter_mut().zip(&wanted.values[1..]) {
            let Some(y) = y.filter(|y| y.is_finite()) else {
                continue;
            };
            match series.x.last() {
                Some(&last) if x < last => {}
                Some(&last) if x == last => *series.y.last_mut().expect("same length") = y,
                _ => {
                    series.x.push(x);
                    series.y.push(y);
                }
            }
        }
    }
    Ok(series)
}

/// The keys [`read_series_of`] wants from a line (`keys[0]` the x key) and their values in
/// the line just read: a serde seed that walks one JSON object, reads the wanted keys' values
/// as numbers (`None` when absent or not a number; the last one of a repeated key counts)
/// and skips everything else without building it.
struct WantedKeys {
    keys: Vec<String>,
    values: Vec<Option<f64>>,
}

impl WantedKeys {
    fn new(x_key: &str, metrics: &[String]) -> Self {
        let keys: Vec<String> = std::iter::once(x_key.to_owned())
            .chain(metrics.iter().cloned())
            .collect();
        let values = vec![None; keys.len()];
        Self { keys, values }
    }

    fn clear(&mut self) {
        self.values.iter_mut().for_each(|v| *v = None);
    }
}

impl<'de> serde::de::DeserializeSeed<'de> for &mut WantedKeys {
    type Value = ();

    fn deserialize<D: serde::Deserializer<'de>>(self, deserializer: D) -> Result<(), D::Error> {
        deserializer.deserialize_map(self)
    }
}

impl<'de> serde::de::Visitor<'de> for &mut WantedKeys {
    type Value = ();

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a JSON object of metrics")
    }

    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
            match self.keys.iter().position(|k| *k == key) {
                Some(i) => {
                    let value: serde_json::Value = map.next_value()?;
                    self.values[i] = value.as_f64();
                }
                None => {
                    map.next_value::<serde::de::IgnoredAny>()?;
                }
            }
        }
        Ok(())
    }
}

/// The arm of a run directory: its name without a trailing seed tag.
pub fn arm_name(run_dir: &Path) -> String {
    let name = run_dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| run_dir.display().to_string());
    let digits = name.len() - name.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    if digits == 0 {
        return name;
    }
    let stem = &name[..name.len() - digits];
    for tag in ["_seed-", "-seed-", "_seed", "-seed", "_s", "-s"] {
        if let Some(arm) = stem.strip_suffix(tag) {
            if !arm.is_empty() {
                return arm.to_owned();
            }
        }
    }
    name
}

/// Linear interpolation of `s` at `x` (`None` outside its range).
fn interpolate(s: &Series, x: f64) -> Option<f64> {
    let (first, last) = (*s.x.first()?, *s.x.last()?);
    if x < first || x > last {
        return None;
    }
    let i = s.x.partition_point(|&v| v < x);
    if s.x[i] == x {
        return Some(s.y[i]);
    }
    let (x0, x1, y0, y1) = (s.x[i - 1], s.x[i], s.y[i - 1], s.y[i]);
    Some(y0 + (y1 - y0) * (x - x0) / (x1 - x0))
}

/// Two-sided 95 % Student t quantile for `df` degrees of freedom.
pub fn t_975(df: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
        2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
        2.052, 2.048, 2.045, 2.042,
    ];
    match df {
        0 => f64::NAN,
        1..=30 => TABLE[df - 1],
        _ => 1.96,
    }
}

/// The range an arm's band is clipped to: [0, 1] when every value of every seed lies in it,
/// [0, ∞) when every value is ≥ 0, none otherwise.
fn value_range(seeds: &[&Series]) -> Option<(f64, f64)> {
    let all = |keep: &dyn Fn(f64) -> bool| seeds.iter().all(|s| s.y.iter().all(|&y| keep(y)));
    if all(&|y| (0.0..=1.0).contains(&y)) {
        Some((0.0, 1.0))
    } else if all(&|y| y >= 0.0) {
        Some((0.0, f64::INFINITY))
    } else {
        None
    }
}

/// Mean and 95 % band of the seeds' curves on a common grid (see the module doc).
pub fn aggregate(seeds: &[Series]) -> Option<Band> {
    let seeds: Vec<&Series> = seeds.iter().filter(|s| !s.x.is_empty()).collect();
    // Invariant: every series left has a point (the filter above), so `last` is `Some`.
    let ends = || {
        seeds
            .iter()
            .map(|s| *s.x.last().expect("empty series filtered out"))
    };
    let start = seeds
        .iter()
        .map(|s| s.x[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let common_end = ends().fold(f64::INFINITY, f64::min);
    let longest_end = ends().fold(f64::NEG_INFINITY, f64::max);
    if seeds.is_empty() || common_end < start {
        return None;
    }
    let mut grid: Vec<f64> = if common_end > start {
        // The ends exactly, so that every seed reaches the last point of the common part.
        let last = GRID_POINTS - 1;
        (0..GRID_POINTS)
            .map(|k| match k {
                _ if k == last => common_end,
                _ => start + (common_end - start) * k as f64 / last as f64,
            })
            .collect()
    } else {
        vec![start]
    };
    if longest_end > common_end {
        // The tail at the common part's spacing (the whole range's when that part is a point),
        // widened to at most TAIL_POINTS_MAX points; its last point is the longest seed's end.
        let spacing = if common_end > start {
            (common_end - start) / (GRID_POINTS - 1) as f64
        } else {
            (longest_end - start) / (GRID_POINTS - 1) as f64
        };
        let tail =
            (((longest_end - common_end) / spacing).ceil() as usize).clamp(1, TAIL_POINTS_MAX);
        grid.extend((1..=tail).map(|k| match k {
            _ if k == tail => longest_end,
            _ => common_end + (longest_end - common_end) * k as f64 / tail as f64,
        }));
    }
    let mut band = Band {
        x: Vec::with_capacity(grid.len()),
        mean: Vec::with_capacity(grid.len()),
        half_width: Vec::with_capacity(grid.len()),
        n_seeds: seeds.len(),
        n_at: Vec::with_capacity(grid.len()),
        clip: value_range(&seeds),
    };
    for x in grid {
        let ys: Vec<f64> = seeds.iter().filter_map(|s| interpolate(s, x)).collect();
        let mean = ys.iter().sum::<f64>() / ys.len() as f64;
        let half = if ys.len() > 1 {
            let var = ys.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (ys.len() - 1) as f64;
            t_975(ys.len() - 1) * (var / ys.len() as f64).sqrt()
        } else {
            0.0
        };
        band.x.push(x);
        band.mean.push(mean);
        band.half_width.push(half);
        band.n_at.push(ys.len());
    }
    Some(band)
}

/// Arms in order of first appearance, each with its bands per metric.
pub struct Figure {
    pub metrics: Vec<String>,
    pub x_key: String,
    /// `(arm, bands per metric (None when no seed has the metric))`.
    pub arms: Vec<(String, Vec<Option<Band>>)>,
}

/// Redraws `run_dir/plots/curves.png` (the default metrics against env steps) from the run's
/// `metrics.jsonl`; a failure is logged, never fatal (used during a run).
pub fn redraw_run_curves(run_dir: &Path) {
    let metrics: Vec<String> = DEFAULT_METRICS.iter().map(|m| (*m).to_owned()).collect();
    let plots = run_dir.join("plots");
    let drawn = std::fs::create_dir_all(&plots)
        .map_err(anyhow::Error::from)
        .and_then(|()| build_figure(&[run_dir.to_path_buf()], DEFAULT_X, &metrics))
        .and_then(|figure| render_png(&figure, &plots.join("curves.png")));
    if let Err(err) = drawn {
        tracing::warn!("plots/curves.png not drawn: {err:#}");
    }
}

/// Reads every run and aggregates it per arm and metric.
pub fn build_figure(
    run_dirs: &[PathBuf],
    x_key: &str,
    metrics: &[String],
) -> anyhow::Result<Figure> {
    if run_dirs.is_empty() {
        bail!("no run directories given");
    }
    let mut order: Vec<String> = Vec::new();
    let mut by_arm: BTreeMap<String, Vec<&PathBuf>> = BTreeMap::new();
    for dir in run_dirs {
        let arm = arm_name(dir);
        if !by_arm.contains_key(&arm) {
            order.push(arm.clone());
        }
        by_arm.entry(arm).or_default().push(dir);
    }
    let mut arms = Vec::new();
    for arm in order {
        // Each run's file is read once, for every metric.
        let mut per_run = by_arm[&arm]
            .iter()
            .map(|d| read_series_of(d, x_key, metrics).map(Vec::into_iter))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let mut bands = Vec::new();
        for _ in metrics {
            let series: Vec<Series> = per_run
                .iter_mut()
                .map(|run| run.next().expect("one series per metric"))
                .collect();
            bands.push(aggregate(&series));
        }
        arms.push((arm, bands));
    }
    Ok(Figure {
        metrics: metrics.to_vec(),
        x_key: x_key.to_owned(),
        arms,
    })
}

const PANEL_W: u32 = 900;
const PANEL_H: u32 = 380;
const MARGIN_L: i32 = 80;
const MARGIN_R: i32 = 20;
const MARGIN_T: i32 = 40;
const MARGIN_B: i32 = 60;
const TEXT: RGBColor = RGBColor(30, 30, 30);
const GRID: RGBColor = RGBColor(225, 225, 225);
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// "Nice" tick values covering `[lo, hi]` (1, 2, 5 × 10^k steps, about `n` of them).
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// A short label: 1500000 → "1.5M", 0.25 → "0.25".
pub fn format_tick(v: f64) -> String {
    let a = v.abs();
    let (scaled, suffix) = if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e3 {
        (v / 1e3, "K")
    } else {
        (v, "")
    };
    let text = format!("{scaled:.2}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    format!("{}{suffix}", if text == "-0" { "0" } else { text })
}

/// Draws `figure` as a PNG at `out`.
pub fn render_png(figure: &Figure, out: &Path) -> anyhow::Result<()> {
    let n_panels = figure.metrics.len().max(1) as u32;
    let root = BitMapBackend::new(out, (PANEL_W, PANEL_H * n_panels)).into_drawing_area();
    let fail = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing {}: {e}", out.display());
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    for (p, metric) in figure.metrics.iter().enumerate() {
        let top = (p as u32 * PANEL_H) as i32;
        draw_panel(&root, figure, p, metric, top).map_err(|e| fail(&e))?;
    }
    root.present().map_err(|e| fail(&e))
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;
type DrawResult<'a> =
    Result<(), DrawingAreaErrorKind<<BitMapBackend<'a> as DrawingBackend>::ErrorType>>;

fn text<'a>(
    root: &Area<'a>,
    s: &str,
    x: i32,
    y: i32,
    scale: u32,
    color: &RGBColor,
) -> DrawResult<'a> {
    let mut result = Ok(());
    font::for_each_pixel(s, x, y, scale, |px, py| {
        if result.is_ok() {
            result = root.draw_pixel((px, py), color);
        }
    });
    result
}

fn draw_panel<'a>(
    root: &Area<'a>,
    figure: &Figure,
    p: usize,
    metric: &str,
    top: i32,
) -> DrawResult<'a> {
    let bands: Vec<(usize, &Band)> = figure
        .arms
        .iter()
        .enumerate()
        .filter_map(|(i, (_, bands))| bands[p].as_ref().map(|b| (i, b)))
        .collect();
    let (left, right) = (MARGIN_L, PANEL_W as i32 - MARGIN_R);
    let (upper, lower) = (top + MARGIN_T, top + PANEL_H as i32 - MARGIN_B);
    text(root, metric, left, top + 12, 2, &TEXT)?;
    if bands.is_empty() {
        return text(root, "no data", left + 20, upper + 40, 2, &TEXT);
    }
    let x_max = bands
        .iter()
        .map(|(_, b)| *b.x.last().expect("non-empty"))
        .fold(0.0f64, f64::max)
        .max(1.0);
    let x_min = bands
        .iter()
        .map(|(_, b)| b.x[0])
        .fold(f64::INFINITY, f64::min)
        .min(0.0);
    let lows = bands.iter().flat_map(|(_, b)| b.lower());
    let highs = bands.iter().flat_map(|(_, b)| b.upper());
    let (mut y_min, mut y_max) = (
        lows.fold(f64::INFINITY, f64::min).min(0.0),
        highs.fold(f64::NEG_INFINITY, f64::max),
    );
    if y_max <= y_min {
        y_max = y_min + 1.0;
    }
    let pad = 0.05 * (y_max - y_min);
    y_max += pad;
    if y_min < 0.0 {
        y_min -= pad;
    }
    let px =
        |x: f64| left + ((x - x_min) / (x_max - x_min) * f64::from(right - left)).round() as i32;
    let py =
        |y: f64| lower - ((y - y_min) / (y_max - y_min) * f64::from(lower - upper)).round() as i32;
    for t in ticks(y_min, y_max, 5) {
        root.draw(&PathElement::new(vec![(left, py(t)), (right, py(t))], GRID))?;
        let label = format_tick(t);
        text(
            root,
            &label,
            left - 8 - 2 * font::text_width(&label) as i32,
            py(t) - font::GLYPH_H as i32,
            2,
            &TEXT,
        )?;
    }
    for t in ticks(x_min, x_max, 6) {
        root.draw(&PathElement::new(
            vec![(px(t), upper), (px(t), lower)],
            GRID,
        ))?;
        let label = format_tick(t);
        text(
            root,
            &label,
            px(t) - font::text_width(&label) as i32,
            lower + 8,
            2,
            &TEXT,
        )?;
    }
    root.draw(&Rectangle::new([(left, upper), (right, lower)], TEXT))?;
    let x_label = format!("{} ->", figure.x_key);
    text(
        root,
        &x_label,
        right - 2 * font::text_width(&x_label) as i32,
        lower + 32,
        2,
        &TEXT,
    )?;
    let mut columns = Vec::new();
    for &(i, band) in &bands {
        let color = PALETTE[i % PALETTE.len()];
        // The part every seed reaches, then the tail (fewer seeds) from its last point on.
        // Both parts share the tail's first point, so the line has no gap (common ≥ 1: every
        // seed reaches the first grid point).
        let (common, len) = (band.common_len(), band.x.len());
        let mut parts = vec![(0, common)];
        if common < len {
            parts.push((common - 1, len));
        }
        let (band_upper, band_lower) = (band.upper(), band.lower());
        // Where this arm is drawn, for the legend's placement.
        columns.extend((0..len).map(|j| {
            let line = py(band.mean[j]);
            Column {
                x: px(band.x[j]),
                line,
                band: if band.n_at[j] > 1 {
                    (py(band_upper[j]), py(band_lower[j]))
                } else {
                    (line, line)
                },
            }
        }));
        for (part, &(from, to)) in parts.iter().enumerate() {
            let (xs, upper, lower) = (
                &band.x[from..to],
                &band_upper[from..to],
                &band_lower[from..to],
            );
            if band.n_at[from..to].iter().any(|&k| k > 1) {
                let mut polygon: Vec<(i32, i32)> = xs
                    .iter()
                    .zip(upper)
                    .map(|(x, y)| (px(*x), py(*y)))
                    .collect();
                polygon.extend(xs.iter().zip(lower).rev().map(|(x, y)| (px(*x), py(*y))));
                let alpha = if part == 0 { 0.2 } else { 0.1 };
                root.draw(&Polygon::new(polygon, color.mix(alpha).filled()))?;
            }
            let line: Vec<(i32, i32)> = xs
                .iter()
                .zip(&band.mean[from..to])
                .map(|(x, m)| (px(*x), py(*m)))
                .collect();
            if part == 0 {
                root.draw(&PathElement::new(line, color.stroke_width(2)))?;
            } else {
                root.draw(&plotters::element::DashedPathElement::new(
                    line,
                    8,
                    6,
                    color.stroke_width(2),
                ))?;
            }
        }
    }
    // Legend: in the corner of the plot area where it hides the least of the curves, on a
    // light background so what it still covers stays visible.
    let labels: Vec<String> = bands
        .iter()
        .map(|&(i, band)| match band.n_at.last() {
            Some(&k) if k < band.n_seeds => format!(
                "{} (n={}, dashed: {k} at the end)",
                figure.arms[i].0, band.n_seeds
            ),
            _ => format!("{} (n={})", figure.arms[i].0, band.n_seeds),
        })
        .collect();
    let text_w = labels.iter().map(|l| 2 * font::text_width(l) as i32).max();
    let size = (
        LEGEND_TEXT_X + text_w.unwrap_or(0) + LEGEND_PAD,
        2 * LEGEND_PAD - 6 + LEGEND_ROW * labels.len() as i32,
    );
    let (x0, y0) = legend_origin([left, upper, right, lower], size, &columns);
    root.draw(&Rectangle::new(
        [(x0, y0), (x0 + size.0, y0 + size.1)],
        WHITE.mix(0.85).filled(),
    ))?;
    root.draw(&Rectangle::new(
        [(x0, y0), (x0 + size.0, y0 + size.1)],
        GRID,
    ))?;
    for (row, (&(i, _), label)) in bands.iter().zip(&labels).enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let y = y0 + LEGEND_PAD + row as i32 * LEGEND_ROW;
        root.draw(&Rectangle::new(
            [(x0 + LEGEND_PAD, y), (x0 + LEGEND_PAD + 20, y + 12)],
            color.filled(),
        ))?;
        text(root, label, x0 + LEGEND_TEXT_X, y, 2, &TEXT)?;
    }
    Ok(())
}

/// Legend box layout (device pixels): padding inside the box, height of one row, the label's
/// offset from the box's left edge (after the colour swatch), and the gap to the plot frame.
const LEGEND_PAD: i32 = 8;
const LEGEND_ROW: i32 = 20;
const LEGEND_TEXT_X: i32 = LEGEND_PAD + 28;
const LEGEND_INSET: i32 = 4;
/// What hiding one grid point of a mean line costs, in pixels of band height hidden.
const LEGEND_LINE_WEIGHT: i32 = 20;

/// One grid point of an arm as drawn: its column, the mean line's row and the band's rows
/// (top, bottom; both the line's row where the arm has no band).
#[derive(Debug, Clone, Copy)]
struct Column {
    x: i32,
    line: i32,
    band: (i32, i32),
}

/// The legend box's top-left corner: of the four corners of the plot area `[left, upper,
/// right, lower]` (the box `LEGEND_INSET` inside the frame), the one where a box of `size`
/// hides the least of the curves: each mean-line point inside it costs
/// `LEGEND_LINE_WEIGHT`, each band the height of its part inside it, the box counted
/// `LEGEND_INSET` larger on every side so that it does not end flush against a curve. Ties go
/// to the first of top left, top right, bottom right, bottom left.
fn legend_origin(area: [i32; 4], size: (i32, i32), columns: &[Column]) -> (i32, i32) {
    let [left, upper, right, lower] = area;
    let (w, h) = size;
    let corners = [
        (left + LEGEND_INSET, upper + LEGEND_INSET),
        (right - LEGEND_INSET - w, upper + LEGEND_INSET),
        (right - LEGEND_INSET - w, lower - LEGEND_INSET - h),
        (left + LEGEND_INSET, lower - LEGEND_INSET - h),
    ];
    let m = LEGEND_INSET;
    let cost = |(x0, y0): (i32, i32)| -> i64 {
        let (top, bottom) = (y0 - m, y0 + h + m);
        columns
            .iter()
            .filter(|c| (x0 - m..=x0 + w + m).contains(&c.x))
            .map(|c| {
                let line = if (top..=bottom).contains(&c.line) {
                    LEGEND_LINE_WEIGHT
                } else {
                    0
                };
                let band = (c.band.1.min(bottom) - c.band.0.max(top)).max(0);
                i64::from(line + band)
            })
            .sum()
    };
    let mut best = (corners[0], cost(corners[0]));
    for &corner in &corners[1..] {
        let c = cost(corner);
        if c < best.1 {
            best = (corner, c);
        }
    }
    best.0
}

/// `asi plot`: reads the runs, aggregates, draws `out`; prints what it plotted.
pub fn run(args: &crate::cli::PlotArgs) -> anyhow::Result<()> {
    let metrics: Vec<String> = if args.metric.is_empty() {
        DEFAULT_METRICS.iter().map(|m| (*m).to_owned()).collect()
    } else {
        args.metric.clone()
    };
    let figure = build_figure(&args.run_dirs, &args.x, &metrics)?;
    for (arm, bands) in &figure.arms {
        for (metric, band) in metrics.iter().zip(bands) {
            let Some(b) = band else {
                println!("{arm}: {metric}: no data");
                continue;
            };
            // The common part's end: the last point every seed reaches.
            let c = b.common_len().max(1) - 1;
            print!(
                "{arm}: {metric}: {} seed(s), mean {:.4} ± {:.4} at x = {}",
                b.n_seeds,
                b.mean[c],
                b.half_width[c],
                format_tick(b.x[c]),
            );
            let last = b.x.len() - 1;
            if last > c {
                print!(
                    " (the shortest seed's end); {} seed(s) on to x = {}, mean there {:.4}",
                    b.n_at[last],
                    format_tick(b.x[last]),
                    b.mean[last],
                );
            }
            println!();
        }
    }
    render_png(&figure, &args.out)?;
    println!("wrote {}", args.out.display());
    Ok(())
}

/// (tests) Width, height and RGB bytes (rows, no alpha) of a PNG the plotters bitmap encoder
/// wrote.
#[cfg(test)]
pub(crate) fn read_rgb_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).expect("open the PNG");
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .expect("a PNG header");
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).expect("a PNG frame");
    (info.width, info.height, pixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(points: &[(f64, f64)]) -> Series {
        Series {
            x: points.iter().map(|p| p.0).collect(),
            y: points.iter().map(|p| p.1).collect(),
        }
    }

    #[test]
    fn arms_drop_seed_tags_only() {
        for (dir, arm) in [
            ("runs/u-asi_seed-0", "u-asi"),
            ("u-asi-seed12", "u-asi"),
            ("hess_s3", "hess"),
            ("antmaze-u", "antmaze-u"),
            ("run42", "run42"),
            ("_seed-1", "_seed-1"),
        ] {
            assert_eq!(arm_name(Path::new(dir)), arm, "{dir}");
        }
    }

    #[test]
    fn one_pass_reads_every_metric_as_a_full_parse_would() {
        let dir = std::env::temp_dir().join(format!("asi-plot-one-pass-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // Nested values, strings, escaped keys, a repeated key (the last counts), null, a
        // non-object line, x going back, a missing metric, and keys in any order.
        let text = concat!(
            "{\"x\": 1, \"a\": 0.5, \"nested\": {\"a\": 9, \"x\": 9}, \"s\": \"x\"}\n",
            "{\"b\": 7, \"x\": 2, \"a\": 0.25, \"a\": 0.75, \"list\": [1, {\"b\": 3}]}\n",
            "[1, 2, 3]\n",
            "{\"x\": 3, \"a\": null, \"b\": \"8\", \"\\u0062\": 8}\n",
            "{\"x\": 2.5, \"a\": 1, \"b\": 1}\n",
            "{\"x\": 4, \"b\": true}\n",
            "\n",
            "{\"a\": 3}\n",
            "{\"x\": 5, \"a\": 2, \"b\": 10}\n",
        );
        std::fs::write(dir.join("metrics.jsonl"), text).unwrap();
        let metrics = ["a".to_owned(), "b".to_owned(), "c".to_owned()];
        let got = read_series_of(&dir, "x", &metrics).unwrap();
        // What a full parse of every line into a serde_json::Value gives.
        let expected: Vec<Series> = metrics
            .iter()
            .map(|m| {
                let mut s = Series {
                    x: Vec::new(),
                    y: Vec::new(),
                };
                for line in text.lines().filter(|l| !l.trim().is_empty()) {
                    let v: serde_json::Value = serde_json::from_str(line).unwrap();
                    let (Some(x), Some(y)) = (
                        v.get("x").and_then(|v| v.as_f64()),
                        v.get(m.as_str()).and_then(|v| v.as_f64()),
                    ) else {
                        continue;
                    };
                    if !(x.is_finite() && y.is_finite()) || s.x.last().is_some_and(|&l| x < l) {
                        continue;
                    }
                    if s.x.last() == Some(&x) {
                        *s.y.last_mut().unwrap() = y;
                    } else {
                        s.x.push(x);
                        s.y.push(y);
                    }
                }
                s
            })
            .collect();
        assert_eq!(got, expected);
        assert_eq!(
            (got[0].x.clone(), got[0].y.clone()),
            (vec![1.0, 2.0, 2.5, 5.0], vec![0.5, 0.75, 1.0, 2.0])
        );
        assert_eq!(
            (got[1].x.clone(), got[1].y.clone()),
            (vec![2.0, 3.0, 5.0], vec![7.0, 8.0, 10.0])
        );
        assert!(got[2].x.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_packed_run_folder_reads_as_its_plain_one() {
        use std::io::Write;
        let root = std::env::temp_dir().join(format!("asi-plot-packed-{}", std::process::id()));
        let (plain, packed) = (root.join("plain"), root.join("packed"));
        std::fs::create_dir_all(&plain).unwrap();
        std::fs::create_dir_all(&packed).unwrap();
        let text = "{\"x\": 1, \"y\": 0.5}\n{\"x\": 2, \"y\": 0.75}\n{\"x\": 3, \"y\": 0.25}\n";
        std::fs::write(plain.join("metrics.jsonl"), text).unwrap();
        // Two gzip members, as a file appended to after packing would have: both are read.
        let (first, second) = text.split_at(text.find("{\"x\": 3").unwrap());
        let mut gz = Vec::new();
        for part in [first, second] {
            let mut encoder =
                flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
            encoder.write_all(part.as_bytes()).unwrap();
            gz.extend(encoder.finish().unwrap());
        }
        std::fs::write(packed.join("metrics.jsonl.gz"), &gz).unwrap();
        let want = read_series(&plain, "x", "y").unwrap();
        assert_eq!(
            (want.x.clone(), want.y.clone()),
            (vec![1.0, 2.0, 3.0], vec![0.5, 0.75, 0.25])
        );
        assert_eq!(read_series(&packed, "x", "y").unwrap(), want);
        // A plain metrics.jsonl beside a packed one is the one read (a run going on).
        std::fs::write(packed.join("metrics.jsonl"), "{\"x\": 9, \"y\": 9}\n").unwrap();
        let read = read_series(&packed, "x", "y").unwrap();
        assert_eq!((read.x, read.y), (vec![9.0], vec![9.0]));
        // A broken archive is an error naming it, not an empty curve.
        std::fs::remove_file(packed.join("metrics.jsonl")).unwrap();
        std::fs::write(packed.join("metrics.jsonl.gz"), &gz[..gz.len() / 2]).unwrap();
        let err = read_series(&packed, "x", "y").unwrap_err();
        assert!(format!("{err:#}").contains("metrics.jsonl.gz"), "{err:#}");
        std::fs::remove_dir_all(&root).unwrap();
    }

    #[test]
    fn a_last_line_being_written_is_skipped_and_a_bad_line_before_it_is_an_error() {
        let dir = std::env::temp_dir().join(format!("asi-plot-partial-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("metrics.jsonl");
        let whole = "{\"x\": 1, \"y\": 0.5}\n{\"x\": 2, \"y\": 0.75}\n";
        // A writer in the middle of its third line: the two whole lines are read.
        std::fs::write(&path, format!("{whole}{{\"x\": 3, \"y\"")).unwrap();
        let read = read_series(&dir, "x", "y").unwrap();
        assert_eq!((read.x, read.y), (vec![1.0, 2.0], vec![0.5, 0.75]));
        // The same bad line ended by a newline is a broken file, not a partial write.
        std::fs::write(&path, format!("{whole}{{\"x\": 3, \"y\"\n")).unwrap();
        let err = read_series(&dir, "x", "y").unwrap_err();
        assert!(format!("{err:#}").contains("line 3 is not JSON"), "{err:#}");
        // And so is a bad line followed by good ones.
        std::fs::write(&path, format!("{{\"x\"\n{whole}")).unwrap();
        assert!(read_series(&dir, "x", "y").is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn aggregate_matches_a_hand_computation() {
        // Three seeds, linear curves y = a·x on [0, 10] (one sampled coarsely): at x = 10 the
        // values are 1, 2, 3 → mean 2, sd 1, half-width t(2)·1/√3 = 4.303/√3.
        let seeds = [
            series(&[(0.0, 0.0), (10.0, 1.0)]),
            series(&[(0.0, 0.0), (5.0, 1.0), (10.0, 2.0), (20.0, 4.0)]),
            series(&[(0.0, 0.0), (10.0, 3.0)]),
        ];
        let band = aggregate(&seeds).unwrap();
        assert_eq!(band.n_seeds, 3);
        let c = band.common_len();
        assert_eq!(c, GRID_POINTS, "the common part has the full grid");
        assert_eq!(band.x[c - 1], 10.0, "every seed to the shortest run's end");
        assert!((band.mean[c - 1] - 2.0).abs() < 1e-12);
        assert!((band.half_width[c - 1] - 4.303 / 3f64.sqrt()).abs() < 1e-9);
        // The tail to x = 20 holds the one longer seed (y = 0.2·x): its values, no band.
        assert_eq!(*band.x.last().unwrap(), 20.0);
        assert!(band.n_at[c..].iter().all(|&k| k == 1));
        assert!(band.half_width[c..].iter().all(|&h| h == 0.0));
        for (x, m) in band.x[c..].iter().zip(&band.mean[c..]) {
            assert!((m - 0.2 * x).abs() < 1e-9, "{x}: {m}");
        }
        // Midpoint x = 5 (grid point 100 of 200 is not exactly 5; interpolate by hand instead).
        let k = band.x.iter().position(|x| *x > 4.9).unwrap();
        let x = band.x[k];
        assert!((band.mean[k] - (0.1 * x + 0.2 * x + 0.3 * x) / 3.0).abs() < 1e-9);
        assert_eq!(band.half_width[0], 0.0, "all seeds agree at x = 0");
    }

    #[test]
    fn seeds_of_different_lengths_give_a_tail_with_the_seeds_that_reach_it() {
        // Three seeds to x = 10 (values 1, 3, 5 there: mean 3, sd 2), two of them on to 20
        // (values 2 and 6: mean 4, sd 2√2, half-width t(1) · 2√2 / √2 = 2 · 12.706).
        let seeds = [
            series(&[(0.0, 0.0), (10.0, 1.0), (20.0, 2.0)]),
            series(&[(0.0, 0.0), (10.0, 3.0), (20.0, 6.0)]),
            series(&[(0.0, 0.0), (10.0, 5.0)]),
        ];
        let band = aggregate(&seeds).unwrap();
        let c = band.common_len();
        assert_eq!((band.n_seeds, c), (3, GRID_POINTS));
        assert_eq!(band.x[c - 1], 10.0);
        assert!((band.mean[c - 1] - 3.0).abs() < 1e-12);
        assert!((band.half_width[c - 1] - 4.303 * 2.0 / 3f64.sqrt()).abs() < 1e-9);
        let last = band.x.len() - 1;
        assert_eq!((band.x[last], band.n_at[last]), (20.0, 2));
        assert!((band.mean[last] - 4.0).abs() < 1e-12);
        assert!((band.half_width[last] - 2.0 * 12.706).abs() < 1e-9);
        // The tail keeps the common part's spacing and rises strictly.
        let spacing = 10.0 / (GRID_POINTS - 1) as f64;
        for w in band.x[c - 1..].windows(2) {
            assert!(
                w[1] > w[0] && w[1] - w[0] <= spacing * (1.0 + 1e-9),
                "{w:?}"
            );
        }
        // A seed far longer than the others: the tail's points are capped.
        let wide = aggregate(&[
            series(&[(0.0, 0.0), (1.0, 1.0)]),
            series(&[(0.0, 0.0), (1000.0, 1.0)]),
        ])
        .unwrap();
        assert_eq!(wide.x.len(), GRID_POINTS + TAIL_POINTS_MAX);
        assert_eq!(
            (*wide.x.last().unwrap(), wide.common_len()),
            (1000.0, GRID_POINTS)
        );
    }

    #[test]
    fn a_band_of_rates_is_clipped_to_zero_and_one_of_distances_at_zero_and_others_not_at_all() {
        // Success rates 1, 1, 0.7 at the end: mean 0.9, sd √0.03, half-width
        // 4.303 · √0.03 / √3 = 0.4303, so the upper edge 1.33 is clipped to 1 and the lower
        // edge 0.4697 is not. At x = 5 (0.5, 0.5, 0.35) the band lies inside [0, 1].
        let seeds = [
            series(&[(0.0, 0.0), (10.0, 1.0)]),
            series(&[(0.0, 0.0), (10.0, 1.0)]),
            series(&[(0.0, 0.0), (10.0, 0.7)]),
        ];
        let band = aggregate(&seeds).unwrap();
        assert_eq!(band.clip, Some((0.0, 1.0)));
        let h = *band.half_width.last().unwrap();
        assert!((h - 0.4303).abs() < 1e-4, "{h}");
        assert_eq!(*band.upper().last().unwrap(), 1.0, "0.9 + 0.43 clipped");
        assert!((band.lower().last().unwrap() - (0.9 - h)).abs() < 1e-12);
        let k = band.x.iter().position(|x| *x >= 5.0).unwrap();
        let (m, hk) = (band.mean[k], band.half_width[k]);
        assert!(m - hk > 0.0 && m + hk < 1.0, "mid-run band inside [0, 1]");
        assert_eq!((band.lower()[k], band.upper()[k]), (m - hk, m + hk));
        // A metric that leaves [0, 1] (a Q value) keeps its band as computed.
        let q = aggregate(&[
            series(&[(0.0, -5.0), (10.0, 2.0)]),
            series(&[(0.0, -3.0), (10.0, 0.5)]),
        ])
        .unwrap();
        assert_eq!(q.clip, None);
        let m = *q.mean.last().unwrap();
        assert!((q.upper().last().unwrap() - (m + q.half_width.last().unwrap())).abs() < 1e-12);
        // A distance (≥ 0, beyond 1): final values 1, 2, 15 → mean 6, sd 7.81, half-width
        // 4.303 · 7.81 / √3 = 19.4, so the lower edge −13.4 is clipped to 0, the upper is not.
        let d = aggregate(&[
            series(&[(0.0, 20.0), (10.0, 1.0)]),
            series(&[(0.0, 18.0), (10.0, 2.0)]),
            series(&[(0.0, 16.0), (10.0, 15.0)]),
        ])
        .unwrap();
        assert_eq!(d.clip, Some((0.0, f64::INFINITY)));
        let (m, h) = (*d.mean.last().unwrap(), *d.half_width.last().unwrap());
        assert!((m - 6.0).abs() < 1e-12 && (h - 4.303 * 61f64.sqrt() / 3f64.sqrt()).abs() < 1e-3);
        assert_eq!(*d.lower().last().unwrap(), 0.0);
        assert_eq!(*d.upper().last().unwrap(), m + h);
    }

    #[test]
    fn one_seed_has_no_band_and_empty_input_none() {
        let band = aggregate(&[series(&[(0.0, 1.0), (4.0, 3.0)])]).unwrap();
        assert!(band.half_width.iter().all(|h| *h == 0.0));
        assert!(
            (interpolate(&series(&[(0.0, 1.0), (4.0, 3.0)]), 1.0).unwrap() - 1.5).abs() < 1e-12
        );
        assert!(aggregate(&[]).is_none());
        assert!(aggregate(&[series(&[])]).is_none());
    }

    #[test]
    fn ticks_are_nice_and_labels_short() {
        assert_eq!(
            ticks(0.0, 1.0, 5),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
        assert_eq!(
            ticks(0.0, 1_000_000.0, 4),
            vec![0.0, 500_000.0, 1_000_000.0]
        );
        assert_eq!(format_tick(1_500_000.0), "1.5M");
        assert_eq!(format_tick(20_000.0), "20K");
        assert_eq!(format_tick(0.25), "0.25");
        assert_eq!(format_tick(0.0), "0");
        assert_eq!(t_975(1), 12.706);
        assert_eq!(t_975(100), 1.96);
    }

    #[test]
    fn series_are_read_monotone_with_last_value_per_x() {
        let dir = std::env::temp_dir().join(format!("asi-plot-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("metrics.jsonl"),
            "{\"x\":0,\"m\":0.5}\n{\"x\":10,\"m\":0.1}\n{\"x\":10,\"m\":0.2}\n{\"x\":5,\"m\":9}\n{\"x\":20}\n\n{\"x\":30,\"m\":0.4}\n",
        )
        .unwrap();
        let s = read_series(&dir, "x", "m").unwrap();
        assert_eq!(s, series(&[(0.0, 0.5), (10.0, 0.2), (30.0, 0.4)]));
        std::fs::write(dir.join("metrics.jsonl"), "not json\n").unwrap();
        assert!(read_series(&dir, "x", "m").is_err());
        let figure = build_figure(std::slice::from_ref(&dir), "x", &["m".to_owned()]);
        assert!(figure.is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Two seeds of one arm (`arm_seed-0`, `arm_seed-1`) in a fresh folder named after `tag`:
    /// seed s has metric `m` = `value(s, k)` at x = 100 k for k < `points(s)`. Returns the
    /// folder (the caller removes it) and the run directories.
    fn two_seed_runs(
        tag: &str,
        points: impl Fn(usize) -> usize,
        value: impl Fn(usize, usize) -> f64,
    ) -> (PathBuf, Vec<PathBuf>) {
        let dir = std::env::temp_dir().join(format!("asi-plot-{tag}-{}", std::process::id()));
        let runs: Vec<PathBuf> = (0..2).map(|s| dir.join(format!("arm_seed-{s}"))).collect();
        for (s, run) in runs.iter().enumerate() {
            std::fs::create_dir_all(run).unwrap();
            let lines: String = (0..points(s))
                .map(|k| format!("{{\"x\":{},\"m\":{}}}\n", k * 100, value(s, k)))
                .collect();
            std::fs::write(run.join("metrics.jsonl"), lines).unwrap();
        }
        (dir, runs)
    }

    #[test]
    fn a_figure_renders_to_a_png_file() {
        // Seed 1 runs on past seed 0's end (x = 1,900) to x = 2,300: a dashed tail.
        let (dir, runs) = two_seed_runs(
            "png",
            |s| 20 + 4 * s,
            |s, k| k as f64 * 0.05 * (1.0 + s as f64 * 0.1),
        );
        let figure = build_figure(&runs, "x", &["m".to_owned(), "absent".to_owned()]).unwrap();
        assert_eq!(figure.arms.len(), 1);
        assert_eq!(figure.arms[0].1[0].as_ref().unwrap().n_seeds, 2);
        assert!(figure.arms[0].1[1].is_none());
        let out = dir.join("plot.png");
        render_png(&figure, &out).unwrap();
        let (width, _, pixels) = read_rgb_png(&out);
        std::fs::remove_dir_all(&dir).unwrap();
        // The arm's line colour in the first panel's plot area, per column: present both left
        // and right of the common end (x = 1,900 of 0–2,300), and with gaps right of it (dashed).
        let width = width as usize;
        let arm = [PALETTE[0].0, PALETTE[0].1, PALETTE[0].2];
        let rows = (MARGIN_T + 1) as usize..(PANEL_H as i32 - MARGIN_B) as usize;
        let drawn = |col: usize| {
            rows.clone()
                .any(|r| pixels[3 * (r * width + col)..][..3] == arm)
        };
        let plot_w = f64::from(PANEL_W as i32 - MARGIN_R - MARGIN_L);
        let end_col = MARGIN_L as usize + (1900.0 / 2300.0 * plot_w) as usize;
        let right = (PANEL_W as i32 - MARGIN_R) as usize;
        assert!(
            (MARGIN_L as usize + 5..end_col - 5).all(drawn),
            "solid part"
        );
        let tail: Vec<bool> = (end_col + 5..right - 2).map(drawn).collect();
        assert!(
            tail.iter().filter(|&&d| d).count() > tail.len() / 3,
            "tail drawn"
        );
        assert!(tail.iter().any(|&d| !d), "tail dashed");
    }

    #[test]
    fn the_legend_takes_the_corner_that_hides_the_least() {
        let column = |x, line, band| Column { x, line, band };
        let (area, size) = ([0, 0, 400, 300], (100, 50));
        // The four boxes: x 4..104 or 296..396, y 4..54 or 246..296; counted 4 px larger
        // (x 0..108 or 292..400, y 0..58 or 242..300).
        assert_eq!(
            legend_origin(area, size, &[]),
            (4, 4),
            "ties go to the top left"
        );
        // Top left: three band columns with 28 px inside the counted box (cost 84); top right:
        // five line points (5 · 20 = 100); each bottom corner ten line points (200).
        let mut columns: Vec<Column> = (1..4).map(|k| column(10 * k, 200, (30, 154))).collect();
        columns.extend((0..5).map(|k| column(300 + 10 * k, 10, (10, 10))));
        for x0 in [10, 300] {
            columns.extend((0..10).map(|k| column(x0 + 5 * k, 270, (270, 270))));
        }
        assert_eq!(legend_origin(area, size, &columns), (4, 4));
        // One more band column at the top left (112) tips it to the top right.
        columns.push(column(40, 200, (30, 154)));
        assert_eq!(legend_origin(area, size, &columns), (296, 4));
        // So does a line point outside the box but within its margin (84 + 20 > 100).
        columns.pop();
        columns.push(column(106, 56, (56, 56)));
        assert_eq!(legend_origin(area, size, &columns), (296, 4));
        // A falling line leaves the top right and the bottom left free: the top right first.
        let falling: Vec<Column> = (0..=40)
            .map(|k| column(10 * k, 300 - 300 * (40 - k) / 40, (0, 0)))
            .map(|c| Column {
                band: (c.line, c.line),
                ..c
            })
            .collect();
        assert_eq!(legend_origin(area, size, &falling), (296, 4));
        // A line along the top: the bottom right.
        let high: Vec<Column> = (0..=40).map(|k| column(10 * k, 20, (20, 20))).collect();
        assert_eq!(legend_origin(area, size, &high), (296, 246));
    }

    #[test]
    fn a_falling_curve_puts_the_legend_top_right() {
        let (dir, runs) = two_seed_runs(
            "legend",
            |_| 20,
            |s, k| (1.0 - k as f64 * 0.05) * (1.0 - s as f64 * 0.05),
        );
        let figure = build_figure(&runs, "x", &["m".to_owned()]).unwrap();
        let out = dir.join("plot.png");
        render_png(&figure, &out).unwrap();
        let (width, _, pixels) = read_rgb_png(&out);
        std::fs::remove_dir_all(&dir).unwrap();
        // Label text pixels in the legend's first row, left and right in the plot area.
        let width = width as usize;
        let first_row = MARGIN_T + LEGEND_INSET + LEGEND_PAD;
        let text_pixels = |cols: std::ops::Range<i32>| {
            (first_row..first_row + 14)
                .flat_map(|r| cols.clone().map(move |c| (r as usize, c as usize)))
                .filter(|&(r, c)| pixels[3 * (r * width + c)..][..3] == [TEXT.0, TEXT.1, TEXT.2])
                .count()
        };
        let right = PANEL_W as i32 - MARGIN_R;
        assert!(
            text_pixels(right - 150..right - 10) > 20,
            "legend at the top right"
        );
        assert_eq!(
            text_pixels(MARGIN_L + LEGEND_TEXT_X..MARGIN_L + 150),
            0,
            "nothing at the top left, where the curve starts"
        );
    }
}
