//! `asi graph-service`: stores every trajectory chunk, follows φ as the learner publishes it,
//! and answers graph requests. Sleeps on its channels' events. Draws the graph in the maze
//! (`plots/graph_latest.png`, [`crate::maze_graph_png`]) after rebuilds, at most once a minute.
//!
//! Checkpoints (`graph_service::checkpoint`): at start the service is restored from the newest
//! usable checkpoint in `run_dir/checkpoints/graph-service/`, and it writes one every
//! `run.checkpoint_interval_mins` and at a clean stop. Decision: a checkpoint that is refused
//! (corrupt, truncated, incompatible) is logged with its error and the next older one is
//! tried; when none is usable the service starts empty instead of failing. Unlike the
//! learner's, its state is exploration data that new chunks rebuild, and a refusal to start
//! would turn one bad file into a crash loop that stops the whole run. The status file says
//! which checkpoint it started from and which were refused.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use graph_service::checkpoint::{CheckpointError, Resumed, SUBDIR};
use graph_service::GraphService;
use iceoryx2::prelude::*;
use protocol::{ControlCommand, ProcessRole};

use super::common::{newest_weights, node, task_info, wait_set, wake_on, MetricsOut, StopWatch};
use crate::channels::{Channels, TrajectorySubscriber, WeightsSubscriber};
use crate::maze_graph_png::{MazeGraphPlot, REDRAW_INTERVAL};
use crate::run::RunContext;

/// Sleep when idle; chunks, weights, requests and control messages wake the service earlier.
const IDLE_WAIT: Duration = Duration::from_millis(100);

pub fn run(ctx: &RunContext) -> anyhow::Result<()> {
    let started = Instant::now();
    let config = &ctx.config;
    let task = task_info(config)?;
    let (dims, layout) = (task.dims, task.layout);
    let dir = ctx.checkpoint_dir().join(SUBDIR);
    let (mut service, start) = open_service(ctx, &dir, dims)?;
    let mut checkpoints = Checkpoints::new(dir, config.run.checkpoint_interval_mins);
    if start.restored_from.is_some() {
        checkpoints.mark_saved(&service);
    }
    let node = node(ctx, "graph-service")?;
    let channels = Channels::new(config, &ctx.run_id, &layout);
    let trajectories = channels.trajectory_subscriber(&node)?;
    let weights = channels.weights_subscriber(&node)?;
    let control = channels.control_subscriber(&node)?;
    let server = channels.graph_server(&node)?;
    let mut metrics = MetricsOut::new(
        channels.metrics_publisher(&node)?,
        ProcessRole::GraphService,
        0,
        config,
    );
    let waitset = wait_set()?;
    let _wake = wake_on(
        &waitset,
        &[
            trajectories.listener(),
            weights.listener(),
            control.listener(),
            server.listener(),
        ],
    )?;
    let mut stop = StopWatch::new(&node);
    let mut picture = GraphPicture::new(ctx)?;
    ctx.mark_ready("graph-service")?;
    let mut first_chunk = FirstChunk::new(&service, started);
    let reason = loop {
        let _ = waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, IDLE_WAIT);
        if let Some(reason) = stop.should_stop(&node) {
            break reason;
        }
        if control
            .drain()?
            .iter()
            .any(|m| m.command() == Ok(ControlCommand::Stop))
        {
            break "stop requested";
        }
        ingest_all(&mut service, &trajectories);
        first_chunk.check(&service);
        load_new_weights(&mut service, &weights);
        server.serve(|header, body| service.handle(header, body))?;
        if metrics.due() {
            let stats = service.stats();
            metrics.publish(stats.stored_steps, &graph_metrics(&stats));
        }
        checkpoints.tick(&service);
        picture.tick(&service);
    };
    ingest_all(&mut service, &trajectories);
    tracing::info!(reason, "graph-service stopping");
    checkpoints.write(&service);
    picture.draw_if_behind(&service);
    write_final_status(ctx, &service, &start, &checkpoints, reason)
}

/// `status/graph-service.json`: the service's final counts, how it started and its checkpoints.
fn write_final_status(
    ctx: &RunContext,
    service: &GraphService,
    start: &Start,
    checkpoints: &Checkpoints,
    reason: &str,
) -> anyhow::Result<()> {
    let stats = service.stats();
    let per_actor: serde_json::Map<String, serde_json::Value> = stats
        .per_actor_steps
        .iter()
        .map(|(k, v)| (k.to_string(), serde_json::json!(v)))
        .collect();
    ctx.write_status(
        "graph-service",
        &serde_json::json!({
            "role": "graph-service", "env_steps": stats.per_actor_steps.values().sum::<u64>(),
            "stored_steps": stats.stored_steps, "chunks": stats.chunks,
            "rejected_chunks": stats.rejected_chunks, "per_actor_steps": per_actor,
            "nodes": stats.n_nodes, "graph_version": stats.graph_version, "stop_reason": reason,
            "restored_from": start.restored_from, "restored_stored_steps": start.restored_stored_steps,
            "refused_checkpoints": start.refused, "checkpoints_written": checkpoints.written,
            "last_checkpoint": checkpoints.last_path, "checkpoint_errors": checkpoints.errors,
        }),
    )
}

/// Logs when the first trajectory chunk of this incarnation arrives, seconds after the process
/// started and after it was ready (a crash restart's data gap, see docs/ARCHITECTURE.md).
struct FirstChunk {
    started: Instant,
    ready: Instant,
    chunks_at_ready: Option<u64>,
}

impl FirstChunk {
    fn new(service: &GraphService, started: Instant) -> Self {
        let chunks_at_ready = Some(service.stats().chunks);
        Self {
            started,
            ready: Instant::now(),
            chunks_at_ready,
        }
    }

    fn check(&mut self, service: &GraphService) {
        let Some(before) = self.chunks_at_ready else {
            return;
        };
        if service.stats().chunks > before {
            tracing::info!(
                secs_since_start = self.started.elapsed().as_secs_f64(),
                secs_since_ready = self.ready.elapsed().as_secs_f64(),
                "first trajectory chunk of this graph-service"
            );
            self.chunks_at_ready = None;
        }
    }
}

/// Where the service started from, for the log and the status file.
pub(crate) struct Start {
    /// The checkpoint restored, if any.
    pub(crate) restored_from: Option<PathBuf>,
    /// Stored states after the restore (0 when started empty).
    pub(crate) restored_stored_steps: u64,
    /// Refused checkpoints, newest first, as `path: error`.
    pub(crate) refused: Vec<String>,
}

/// The service restored from the newest usable checkpoint in `dir`, else a new one (see the
/// module doc for why a refused checkpoint does not stop the process). Serial mode opens its
/// graph-service the same way.
pub(crate) fn open_service(
    ctx: &RunContext,
    dir: &Path,
    dims: nets::TaskDims,
) -> anyhow::Result<(GraphService, Start)> {
    let config = &ctx.config;
    let clock = Instant::now();
    let resumed = GraphService::restore_newest_valid(dir, config, dims).unwrap_or_else(
        |err: CheckpointError| Resumed {
            restored: None,
            refused: vec![(dir.to_path_buf(), err)],
        },
    );
    let refused: Vec<String> = resumed
        .refused
        .iter()
        .map(|(path, err)| format!("{}: {err}", path.display()))
        .collect();
    for problem in &refused {
        tracing::error!(
            "graph-service checkpoint refused, trying an older one or starting empty: {problem}"
        );
    }
    let Some((service, ckpt)) = resumed.restored else {
        if !refused.is_empty() {
            tracing::warn!(
                "graph-service starting empty: no usable checkpoint in {}",
                dir.display()
            );
        }
        let service = GraphService::new(config, dims, config.run.seed)
            .context("building the graph-service")?;
        return Ok((
            service,
            Start {
                restored_from: None,
                restored_stored_steps: 0,
                refused,
            },
        ));
    };
    let m = &ckpt.manifest;
    tracing::info!(
        checkpoint = m.sequence,
        stored_steps = m.stored_steps,
        phi_version = m.phi_version,
        secs = clock.elapsed().as_secs_f64(),
        "graph-service restored from {}",
        ckpt.path.display()
    );
    let start = Start {
        restored_from: Some(ckpt.path),
        restored_stored_steps: m.stored_steps,
        refused,
    };
    Ok((service, start))
}

/// When the graph-service writes checkpoints: every `run.checkpoint_interval_mins` and at a
/// clean stop, unless nothing changed since the last one written or restored (same counters:
/// no chunk, weights, request or report since), which would only push an older, different
/// checkpoint out of the ones kept. A failed write is logged, counted in the status and
/// retried at the next interval; serving goes on.
pub(crate) struct Checkpoints {
    dir: PathBuf,
    interval: Duration,
    last: Instant,
    written: u64,
    last_path: Option<PathBuf>,
    errors: Vec<String>,
    /// The service's counters at the last checkpoint written or restored.
    saved: Option<graph_service::GraphStats>,
}

impl Checkpoints {
    pub(crate) fn new(dir: PathBuf, interval_mins: f64) -> Self {
        Self {
            dir,
            interval: Duration::from_secs_f64(interval_mins * 60.0),
            last: Instant::now(),
            written: 0,
            last_path: None,
            errors: Vec::new(),
            saved: None,
        }
    }

    /// Records `service` as the state of the newest checkpoint (a restored one).
    fn mark_saved(&mut self, service: &GraphService) {
        self.saved = Some(service.stats());
    }

    /// Writes a checkpoint if the interval has passed since the last attempt.
    fn tick(&mut self, service: &GraphService) {
        if self.last.elapsed() >= self.interval {
            self.write(service);
        }
    }

    /// Writes a checkpoint now and logs its size and write time (or the error).
    pub(crate) fn write(&mut self, service: &GraphService) {
        let clock = Instant::now();
        let stats = service.stats();
        if self.saved.as_ref() == Some(&stats) {
            tracing::info!("no graph-service checkpoint: nothing changed since the last one");
            self.last = Instant::now();
            return;
        }
        match service.save(&self.dir) {
            Ok(ckpt) => {
                let m = &ckpt.manifest;
                tracing::info!(
                    checkpoint = m.sequence,
                    stored_steps = m.stored_steps,
                    mib = m.total_bytes() as f64 / (1 << 20) as f64,
                    secs = clock.elapsed().as_secs_f64(),
                    "graph-service checkpoint written to {}",
                    ckpt.path.display()
                );
                self.written += 1;
                self.last_path = Some(ckpt.path);
                self.saved = Some(stats);
            }
            Err(err) => {
                tracing::error!("writing a graph-service checkpoint failed: {err:#}");
                self.errors.push(err.to_string());
            }
        }
        self.last = Instant::now();
    }
}

/// `plots/graph_latest.png` ([`MazeGraphPlot`]): redrawn when the graph changed, at most once
/// per [`REDRAW_INTERVAL`], and at a clean stop.
struct GraphPicture {
    plot: Option<MazeGraphPlot>,
    last: Option<Instant>,
}

impl GraphPicture {
    fn new(ctx: &RunContext) -> anyhow::Result<Self> {
        Ok(Self {
            plot: MazeGraphPlot::new(&ctx.config, &ctx.run_dir)?,
            last: None,
        })
    }

    fn tick(&mut self, service: &GraphService) {
        if self
            .last
            .is_none_or(|last| last.elapsed() >= REDRAW_INTERVAL)
        {
            self.draw_if_behind(service);
        }
    }

    fn draw_if_behind(&mut self, service: &GraphService) {
        let Some(plot) = self.plot.as_mut().filter(|p| p.behind(service)) else {
            return;
        };
        let clock = Instant::now();
        plot.draw(service);
        tracing::debug!(secs = clock.elapsed().as_secs_f64(), "graph picture drawn");
        self.last = Some(Instant::now());
    }
}

fn ingest_all(service: &mut GraphService, trajectories: &TrajectorySubscriber) {
    let drained = trajectories.drain(|header, payload| {
        if let Err(err) = service.ingest(header, payload) {
            tracing::warn!("rejected a trajectory chunk: {err:#}");
        }
    });
    if let Err(err) = drained {
        tracing::warn!("receiving trajectories failed: {err:#}");
    }
}

fn load_new_weights(service: &mut GraphService, weights: &WeightsSubscriber) {
    if let Some((header, bytes)) = newest_weights(weights) {
        if let Err(err) = service.load_weights(&header, &bytes) {
            tracing::error!("refused weights: {err:#}");
        }
    }
}

/// The graph-service's counters as metrics (names documented in `docs/METRICS.md`); serial
/// mode writes the same names but `graph/version`.
pub fn graph_metrics(stats: &graph_service::GraphStats) -> Vec<(String, f64)> {
    vec![
        ("graph/stored_steps".to_owned(), stats.stored_steps as f64),
        ("graph/chunks".to_owned(), stats.chunks as f64),
        (
            "graph/rejected_chunks".to_owned(),
            stats.rejected_chunks as f64,
        ),
        ("graph/nodes".to_owned(), stats.n_nodes as f64),
        ("graph/edges".to_owned(), stats.n_edges as f64),
        ("graph/version".to_owned(), stats.graph_version as f64),
        ("graph/requests".to_owned(), stats.requests as f64),
        (
            "graph/invalid_requests".to_owned(),
            stats.invalid_requests as f64,
        ),
        (
            "graph/frontier_not_found".to_owned(),
            stats.frontier_not_found as f64,
        ),
        (
            "graph/routes_not_found".to_owned(),
            stats.routes_not_found as f64,
        ),
        (
            "graph/explore_answers".to_owned(),
            stats.explore_answers as f64,
        ),
        (
            "graph/hess_visited_cells".to_owned(),
            stats.hess_visited_cells as f64,
        ),
        (
            "graph/future_count_recomputes".to_owned(),
            stats.future_count_recomputes as f64,
        ),
        ("graph/reach_samples".to_owned(), stats.reach_samples as f64),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_graph_metric_is_documented() {
        let doc = std::fs::read_to_string("docs/METRICS.md").unwrap();
        let start = doc.find("## Graph-service").unwrap();
        let section = &doc[start..start + doc[start..].find("\n## Launcher").unwrap()];
        for (name, _) in graph_metrics(&graph_service::GraphStats::default()) {
            assert!(
                section.contains(&format!("`{name}`")),
                "{name} is not in the graph-service table of docs/METRICS.md"
            );
        }
    }

    fn sequences(dir: &Path) -> Vec<u64> {
        let listed = ckpt::list(dir, "ckpt-").unwrap();
        listed.into_iter().map(|(sequence, _)| sequence).collect()
    }

    #[test]
    fn a_checkpoint_is_written_only_when_the_service_changed_since_the_last() {
        let config = protocol::Config::load(Some(Path::new("configs/smoke.toml")), &[]).unwrap();
        let task = task_info(&config).unwrap();
        let mut service = GraphService::new(&config, task.dims, 1).unwrap();
        let dir = std::env::temp_dir().join(format!("asi-gs-ckpts-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut checkpoints = Checkpoints::new(dir.clone(), 30.0);
        checkpoints.write(&service);
        assert_eq!(sequences(&dir), [1]);
        checkpoints.write(&service);
        assert_eq!(sequences(&dir), [1], "nothing changed");
        assert_eq!(checkpoints.written, 1);
        // A request (here a malformed one) changes the counters: written again.
        let header = protocol::graph::GraphRequestHeader::new(
            1,
            protocol::graph::GraphRequestKind::FrontierRoute,
            protocol::PhiVersion(0),
        );
        let _ = service.handle(&header, b"not postcard");
        checkpoints.write(&service);
        assert_eq!(sequences(&dir), [1, 2]);
        // A restored service counts as saved: stopping it at once writes nothing.
        let resumed = GraphService::restore_newest_valid(&dir, &config, task.dims).unwrap();
        let (restored, _) = resumed.restored.expect("the newest checkpoint restores");
        let mut after_restore = Checkpoints::new(dir.clone(), 30.0);
        after_restore.mark_saved(&restored);
        after_restore.write(&restored);
        assert_eq!(sequences(&dir), [1, 2]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
