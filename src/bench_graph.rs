//! `asi bench graph`: graph-service speed on synthetic trajectories ([`graph_service::bench`]).
//!
//! Prints, as `name: value` lines: the rebuild time for each store size (φ re-mapping with the
//! fused forward on `--remap-threads` threads and its FLOP rate, graph construction,
//! visit/future-count recount — timed separately; `--candle` adds the former candle re-map),
//! the graph-service checkpoint of stores up to 2 M steps (`checkpoint_*`: size, write,
//! restore),
//! route query latency p50/p99 (wall time, and the querying thread's CPU time, which leaves out
//! preemption on a loaded machine) on the graph of the first size (capped at
//! `graph.max_nodes` = 5,000 nodes) — first searched per query (`route_dijkstra_*`), then
//! looked up in the route table the service builds after each rebuild (`route_*`, with the
//! table's build time and size, and a check that both give the same distances) — the time of
//! all-pairs shortest paths (Dijkstra from every node, one thread) on that graph, and the same measurements by scipy (`scripts/bench_graph_scipy.py`,
//! which installs scipy into its own venv) on the same graph and queries, with ratios. Without
//! `python3` (or with `--no-python`) the scipy side is skipped with a message.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Args;
use graph_service::bench::{
    largest_component_fraction, quantile, random_phi, synthetic_store, time_candle_map,
    time_checkpoint, time_rebuild, time_routes, RouteSample,
};
use graph_service::dijkstra::shortest_paths;
use graph_service::LatentGraph;
use protocol::Config;

/// Observation size of the synthetic states (the Ant's).
const OBS_DIM: usize = 29;
/// Largest store whose graph-service checkpoint is timed (`checkpoint_*` lines: size, write,
/// restore with the graph rebuild); writing holds a second copy of the store in memory.
const CHECKPOINT_MAX_STEPS: u64 = 2_000_000;
/// Script of the scipy side, relative to the repository root.
const SCIPY_SCRIPT: &str = "scripts/bench_graph_scipy.py";

#[derive(Debug, Args)]
pub struct BenchGraphArgs {
    /// Store sizes to rebuild, in stored steps, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1000000,10000000")]
    pub sizes: Vec<u64>,
    /// Env steps per synthetic episode (each stores one more state).
    #[arg(long, default_value_t = 500)]
    pub episode_len: usize,
    /// Route queries timed (random node pairs).
    #[arg(long, default_value_t = 2000)]
    pub queries: usize,
    /// Seed of the synthetic walks, φ's initialisation and the query pairs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Skip the scipy comparison.
    #[arg(long)]
    pub no_python: bool,
    /// Threads of the φ re-map (`graph.remap_threads`; default: the config's, 2).
    #[arg(long)]
    pub remap_threads: Option<usize>,
    /// Also time the former candle re-map (single thread, 4096-row batches) on the first size.
    #[arg(long)]
    pub candle: bool,
}

pub fn run(args: &BenchGraphArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        !args.sizes.is_empty() && args.sizes.iter().all(|&s| s > 0),
        "--sizes must list positive step counts"
    );
    anyhow::ensure!(
        args.episode_len > 0 && args.queries > 0,
        "--episode-len and --queries must be positive"
    );
    let mut config = Config::default();
    if let Some(threads) = args.remap_threads {
        anyhow::ensure!(
            (1..=256).contains(&threads),
            "--remap-threads must be in [1, 256], got {threads}"
        );
        config.graph.remap_threads = threads;
    }
    println!("obs_dim: {OBS_DIM}");
    println!("max_nodes: {}", config.graph.max_nodes);
    println!("remap_threads: {}", config.graph.remap_threads);
    let mut route_graph = None;
    for (i, &size) in args.sizes.iter().enumerate() {
        let graph = rebuild(&config, size, args, args.candle && i == 0)?;
        route_graph.get_or_insert(graph);
    }
    let graph = route_graph.context("no store size measured")?;
    let searched = time_routes(&graph, args.queries, args.seed, Some(thread_cpu_secs));
    report_latency("route_dijkstra", &searched)?;
    let start = Instant::now();
    let built = graph.build_route_table(config.graph.remap_threads);
    let table_secs = start.elapsed().as_secs_f64();
    anyhow::ensure!(built, "no route table for {} nodes", graph.n_nodes());
    println!("route_table_build_secs: {table_secs:.3}");
    if let Some(table) = graph.route_table() {
        println!(
            "route_table_mib: {:.1}",
            table.bytes() as f64 / (1 << 20) as f64
        );
    }
    let samples = time_routes(&graph, args.queries, args.seed, Some(thread_cpu_secs));
    let agree = searched
        .iter()
        .zip(&samples)
        .all(|(a, b)| (a.from, a.to, a.distance) == (b.from, b.to, b.distance));
    println!("route_table_agrees_with_dijkstra: {agree}");
    anyhow::ensure!(agree, "route table and Dijkstra disagree on a query");
    let ours = report_routes(&graph, &samples)?;
    if args.no_python {
        println!("scipy: skipped (--no-python)");
        return Ok(());
    }
    compare_with_scipy(&graph, &samples, &ours)
}

/// Builds a store of `size` steps, times its rebuild (and the candle re-map if `candle`),
/// prints the figures; returns the graph.
fn rebuild(
    config: &Config,
    size: u64,
    args: &BenchGraphArgs,
    candle: bool,
) -> anyhow::Result<LatentGraph> {
    let label = size_label(size);
    let start = Instant::now();
    let store = synthetic_store(config, OBS_DIM, size, args.episode_len, args.seed);
    println!(
        "rebuild_{label}_generate_secs: {:.3}",
        start.elapsed().as_secs_f64()
    );
    let phi = random_phi(config, OBS_DIM, args.seed)?;
    let (timing, graph) = time_rebuild(config, &store, &phi)?;
    println!("rebuild_{label}_stored_steps: {}", timing.n_steps);
    println!("rebuild_{label}_nodes: {}", timing.n_nodes);
    println!("rebuild_{label}_edges: {}", timing.n_edges);
    // 2 FLOP per multiply-add; the bias adds and ReLUs are not counted.
    let flop = 2.0 * phi.fused().macs_per_row() as f64 * timing.n_steps as f64;
    println!("rebuild_{label}_phi_kernel: {:?}", phi.fused().isa());
    println!("rebuild_{label}_phi_map_secs: {:.3}", timing.map_secs);
    println!(
        "rebuild_{label}_phi_map_gflop_per_sec: {:.1}",
        flop / timing.map_secs / 1e9
    );
    if candle {
        let candle_secs = time_candle_map(&store, &phi)?;
        println!("rebuild_{label}_phi_map_candle_secs: {candle_secs:.3}");
        println!(
            "rebuild_{label}_phi_map_candle_gflop_per_sec: {:.1}",
            flop / candle_secs / 1e9
        );
    }
    println!("rebuild_{label}_graph_build_secs: {:.3}", timing.build_secs);
    println!("rebuild_{label}_counts_secs: {:.3}", timing.counts_secs);
    println!(
        "rebuild_{label}_total_secs: {:.3}",
        timing.map_secs + timing.build_secs + timing.counts_secs
    );
    if size <= CHECKPOINT_MAX_STEPS {
        let dir = temp_dir()?;
        let ckpt = time_checkpoint(config, store, &dir);
        std::fs::remove_dir_all(&dir).with_context(|| format!("removing {}", dir.display()))?;
        let ckpt = ckpt.context("graph-service checkpoint")?;
        println!(
            "checkpoint_{label}_mib: {:.1}",
            ckpt.bytes as f64 / (1 << 20) as f64
        );
        println!("checkpoint_{label}_write_secs: {:.3}", ckpt.write_secs);
        println!("checkpoint_{label}_restore_secs: {:.3}", ckpt.restore_secs);
    }
    Ok(graph)
}

/// CPU time of the calling thread, seconds (`CLOCK_THREAD_CPUTIME_ID`; NaN if unreadable,
/// which the quantiles skip).
fn thread_cpu_secs() -> f64 {
    let mut now = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `now` is a valid, writable timespec for the duration of the call.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut now) };
    if rc == 0 {
        now.tv_sec as f64 + now.tv_nsec as f64 * 1e-9
    } else {
        f64::NAN
    }
}

/// `1M`, `10M`, `250k`, or the plain number.
fn size_label(size: u64) -> String {
    match size {
        s if s % 1_000_000 == 0 => format!("{}M", s / 1_000_000),
        s if s % 1_000 == 0 => format!("{}k", s / 1_000),
        s => s.to_string(),
    }
}

/// Our route and all-pairs figures.
struct Ours {
    p50_us: f64,
    p99_us: f64,
    all_pairs_secs: f64,
}

/// Prints `<prefix>_p50_us`, `_p99_us` (wall) and `_cpu_p50_us`, `_cpu_p99_us` (thread CPU
/// time) of `samples`; returns the wall p50 and p99.
fn report_latency(prefix: &str, samples: &[RouteSample]) -> anyhow::Result<(f64, f64)> {
    let micros: Vec<f64> = samples.iter().map(|s| s.secs * 1e6).collect();
    let (Some(p50_us), Some(p99_us)) = (quantile(&micros, 0.5), quantile(&micros, 0.99)) else {
        bail!("no route query was timed (empty graph?)");
    };
    println!("{prefix}_p50_us: {p50_us:.1}");
    println!("{prefix}_p99_us: {p99_us:.1}");
    let cpu_micros: Vec<f64> = samples
        .iter()
        .filter_map(|s| s.cpu_secs)
        .map(|s| s * 1e6)
        .collect();
    if let (Some(p50), Some(p99)) = (quantile(&cpu_micros, 0.5), quantile(&cpu_micros, 0.99)) {
        println!("{prefix}_cpu_p50_us: {p50:.1}");
        println!("{prefix}_cpu_p99_us: {p99:.1}");
    }
    Ok((p50_us, p99_us))
}

fn report_routes(graph: &LatentGraph, samples: &[RouteSample]) -> anyhow::Result<Ours> {
    let start = Instant::now();
    let mut reachable_pairs = 0usize;
    for source in 0..graph.n_nodes() as u32 {
        reachable_pairs += shortest_paths(graph.adjacency(), source)
            .distances()
            .iter()
            .flatten()
            .count();
    }
    let all_pairs_secs = start.elapsed().as_secs_f64();
    println!("route_nodes: {}", graph.n_nodes());
    println!("route_edges: {}", graph.n_edges());
    println!("route_queries: {}", samples.len());
    let reachable = samples.iter().filter(|s| s.distance.is_some()).count();
    println!(
        "route_largest_component_fraction: {:.4}",
        largest_component_fraction(graph)
    );
    println!("route_reachable_queries: {reachable}");
    println!(
        "route_reachable_fraction: {:.4}",
        reachable as f64 / samples.len() as f64
    );
    let (p50_us, p99_us) = report_latency("route", samples)?;
    println!("all_pairs_reachable_pairs: {reachable_pairs}");
    println!("all_pairs_secs: {all_pairs_secs:.3}");
    Ok(Ours {
        p50_us,
        p99_us,
        all_pairs_secs,
    })
}

/// Runs the scipy script on the same graph and queries and prints its figures and the ratios.
fn compare_with_scipy(
    graph: &LatentGraph,
    samples: &[RouteSample],
    ours: &Ours,
) -> anyhow::Result<()> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join(SCIPY_SCRIPT);
    if Command::new("python3").arg("--version").output().is_err() {
        println!(
            "scipy: skipped (python3 not found on PATH; install Python 3 to compare with scipy)"
        );
        return Ok(());
    }
    let dir = temp_dir()?;
    let result = write_inputs(&dir, graph, samples).and_then(|()| run_script(&script, &dir));
    let _ = std::fs::remove_dir_all(&dir);
    let scipy = match result {
        Ok(scipy) => scipy,
        Err(err) => {
            println!("scipy: skipped ({err:#})");
            return Ok(());
        }
    };
    let field = |key: &str| {
        scipy
            .get(key)
            .and_then(serde_json::Value::as_f64)
            .with_context(|| format!("`{key}` missing in {scipy}"))
    };
    let (p50, p99, all_pairs) = (field("p50_us")?, field("p99_us")?, field("all_pairs_secs")?);
    println!(
        "scipy_version: {}",
        scipy
            .get("scipy_version")
            .and_then(serde_json::Value::as_str)
            .unwrap_or("?")
    );
    println!(
        "scipy_distances_agree: {}",
        scipy
            .get("distances_agree")
            .and_then(serde_json::Value::as_bool)
            .unwrap_or(false)
    );
    println!("scipy_route_p50_us: {p50:.1}");
    println!("scipy_route_p99_us: {p99:.1}");
    println!("scipy_all_pairs_secs: {all_pairs:.3}");
    println!("route_p50_ratio_scipy_over_ours: {:.2}", p50 / ours.p50_us);
    println!("route_p99_ratio_scipy_over_ours: {:.2}", p99 / ours.p99_us);
    println!(
        "all_pairs_ratio_scipy_over_ours: {:.2}",
        all_pairs / ours.all_pairs_secs
    );
    Ok(())
}

fn temp_dir() -> anyhow::Result<PathBuf> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)?
        .as_nanos();
    let dir = std::env::temp_dir().join(format!("asi-bench-graph-{}-{nanos}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}

/// `edges.txt`: `n_nodes` then `a b weight` lines; `queries.txt`: `from to distance` lines
/// (distance −1 when unreachable), our answers, which the script checks.
fn write_inputs(dir: &Path, graph: &LatentGraph, samples: &[RouteSample]) -> anyhow::Result<()> {
    let mut edges = format!("{}\n", graph.n_nodes());
    for &(a, b, w) in graph.edges() {
        edges.push_str(&format!("{a} {b} {w}\n"));
    }
    std::fs::write(dir.join("edges.txt"), edges)?;
    let queries: String = samples
        .iter()
        .map(|s| {
            format!(
                "{} {} {}\n",
                s.from,
                s.to,
                s.distance.map_or(-1, |d| d as i64)
            )
        })
        .collect();
    std::fs::write(dir.join("queries.txt"), queries)?;
    Ok(())
}

/// Runs the script; its last stdout line is a JSON object of figures.
fn run_script(script: &Path, dir: &Path) -> anyhow::Result<serde_json::Value> {
    let out = Command::new("python3")
        .arg(script)
        .arg(dir)
        .output()
        .with_context(|| format!("running {}", script.display()))?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = stderr.lines().rev().take(5).collect();
        bail!(
            "{} failed ({}): {}",
            script.display(),
            out.status,
            tail.into_iter().rev().collect::<Vec<_>>().join(" | ")
        );
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout
        .lines()
        .last()
        .context("the scipy script printed nothing")?;
    serde_json::from_str(last)
        .with_context(|| format!("parsing the scipy script's output {last:?}"))
}
