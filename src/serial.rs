//! `asi train --serial`: the same components as the process mode (actors, learner,
//! graph-service) driven by one loop in one process, with no transport and no clock in what the
//! loop computes, so a run is deterministic for its seed: two runs with the same config produce
//! identical `metrics.jsonl` files. Meant for debugging and for tests. Actors ask the
//! graph-service (HESS exploration, reaching reports) by calling its request handler directly,
//! with the same encoded messages as in process mode, and so does the learner for its
//! self-imitation routes. Evaluations run inline when they fall due (same schedule and outputs
//! as the evaluator process). One metrics line is written after each round of actor chunks in
//! which episodes completed (and a last one at the end if anything changed since).
//!
//! Progress goes to the terminal ([`crate::progress`]: episodes against the budget, rates, time left,
//! coverage, the latest evaluation), or to the log once a minute when stderr is not one.
//!
//! Checkpoints and resume (issue #7). A checkpoint has three parts: the learner's
//! (`checkpoints/ckpt-N/`), the graph-service's (`checkpoints/graph-service/`) and the serial
//! loop's own ([`checkpoint`], `checkpoints/serial/`: every actor's generator, episode counter
//! and counters, the last weights broadcast, the evaluator's schedule and latest metrics, the
//! coverage grid, and the graph-service's inputs since its checkpoint). The learner's and the
//! serial part are written every `run.checkpoint_interval_mins` and at the end, always at a
//! round boundary where no actor has an open episode, so no environment or rollout state needs
//! saving: when the interval has passed, or SIGINT/SIGTERM arrives, the loop lets the open
//! episodes finish first (logged), then writes the checkpoint (a signal: the last metrics line
//! and the checkpoint, exit 0). Checkpoints only read state, so a run's metrics do not depend
//! on when they fall.
//!
//! The graph-service's checkpoint is written only at start and in every round whose broadcast
//! re-mapped φ (its *base*), and serial mode logs every chunk and request the service gets
//! after that ([`LoggedGraph`]); a resume restores the base the serial checkpoint names (kept
//! when later bases rotate the graph-service's checkpoints, so a run killed after more re-maps
//! still resumes exactly) and replays the log. (Graph-service checkpoints of builds before
//! 2026-12-06 did not hold the graph, and a restore rebuilt it from the whole store, while a
//! running service keeps the graph of its last φ re-map: the bases sit where the two agree,
//! so those checkpoints resume exactly too.)
//!
//! A resumed serial run (same folder; `run.max_episodes` or `run.max_env_steps` may grow)
//! continues bit-identically to an uninterrupted run with the same seed — same `metrics.jsonl`
//! and `eval.jsonl` lines (`tests/serial_resume.rs`). Not exact, and logged as such: a
//! checkpoint written with open episodes (a run ended by its env-step budget mid-episode: they
//! are lost), or after a failed base write (until the next φ re-map). The graph-service's
//! `graph/version` is one higher after a restore of an older build's checkpoint (its
//! rebuild), so it is not in the serial metrics lines.

use std::io::{BufWriter, Write};
use std::sync::atomic::{AtomicBool, Ordering};

use actor::eval::Evaluator;
use actor::{Actor, GraphTransport, ServiceOracle};
use anyhow::{bail, Context};
use graph_service::GraphService;
use learner::Learner;
use protocol::graph::{GraphRequestHeader, GraphResponseHeader};
use protocol::{ActorId, TrajectoryHeader};

use crate::maze_graph_png::{MazeGraphPlot, REDRAW_EPISODES};
use crate::proc::actor::{actor_metrics, ReachMeans};
use crate::proc::common::{task_info, CoverageTracker, GraphRoutes};
use crate::proc::evaluator::{eval_metrics, record_report, EvalSchedule};
use crate::proc::graph_service::open_service;
use crate::progress::{Figures, Progress};
use crate::run::RunContext;
use crate::weights_file::WeightsSaver;

mod checkpoint;

use checkpoint::GraphInput;

/// How often the progress line is logged when stderr is not a terminal.
const PLAIN_PROGRESS_INTERVAL: std::time::Duration = std::time::Duration::from_secs(60);

/// Updates per `train` call while catching up with the replay ratio.
const UPDATE_BURST: usize = 64;

/// Set by SIGINT or SIGTERM: the loop stops at the first round boundary with no open episode,
/// writes its last metrics line and a checkpoint, and exits 0 (as process mode does on a
/// signal).
static STOP_REQUESTED: AtomicBool = AtomicBool::new(false);

extern "C" fn request_stop(_signal: libc::c_int) {
    STOP_REQUESTED.store(true, Ordering::Relaxed);
}

fn install_stop_handlers() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        let previous =
            unsafe { libc::signal(signal, request_stop as *const () as libc::sighandler_t) };
        if previous == libc::SIG_ERR {
            tracing::warn!(signal, "could not install a stop handler; the signal will kill the run without a checkpoint");
        }
    }
}

/// Trains `ctx`'s run in this process until its budget is reached or a signal arrives;
/// `Ok(true)` when stopped by a signal.
pub fn run(ctx: RunContext) -> anyhow::Result<bool> {
    let mut serial = Serial::open(ctx)?;
    let mut checkpoints = crate::run::CheckpointTimer::new(&serial.ctx.config);
    install_stop_handlers();
    let mut progress = Progress::new(PLAIN_PROGRESS_INTERVAL);
    let mut waiting_logged = false;
    let mut stopped = false;
    while !budget_reached(&serial.ctx.config, &serial.learner) {
        serial.round()?;
        if serial.line_if_episodes_ended()? {
            progress.show(&serial.figures(), &[]);
        }
        // Checkpoints and stops wait for a round boundary with no open episode, so that no
        // environment state needs saving; they read state only, so the run's metrics do not
        // depend on when they fall.
        let stop = STOP_REQUESTED.load(Ordering::Relaxed);
        if stop || checkpoints.is_due() {
            if serial.actors.iter().any(Actor::has_open_episode) {
                if !waiting_logged {
                    let why = if stop {
                        "stop requested"
                    } else {
                        "checkpoint due"
                    };
                    tracing::info!("{why}: letting the open episodes finish first");
                    waiting_logged = true;
                }
            } else if stop {
                stopped = true;
                break;
            } else {
                waiting_logged = false;
                if checkpoints.tick(&serial.ctx, &serial.learner).is_some() {
                    if let Err(err) = serial.save() {
                        tracing::error!("writing the serial checkpoint failed: {err:#}");
                    }
                }
            }
        }
        let episodes = serial.learner.ingest_stats().episodes_completed;
        // The curves are read back from metrics.jsonl: it must hold whole lines (a no-op
        // when nothing was written since the last flush).
        if let Err(err) = serial.metrics.flush() {
            tracing::warn!("flushing metrics.jsonl failed: {err}");
        }
        serial.picture.tick(episodes, &serial.graph.service);
    }
    progress.finish(&serial.figures(), &[]);
    serial.finish(stopped)?;
    Ok(stopped)
}

/// Everything the serial loop drives and keeps.
struct Serial {
    ctx: RunContext,
    /// `checkpoints/serial/`.
    serial_dir: std::path::PathBuf,
    learner: Learner,
    graph: LoggedGraph,
    actors: Vec<Actor>,
    lines: Vec<ActorLine>,
    eval: SerialEval,
    coverage: CoverageTracker,
    metrics: BufWriter<std::fs::File>,
    picture: SerialPicture,
    /// Episodes completed at the last metrics line.
    last_episodes: u64,
    /// Env steps at the last metrics line of this launch (an exact resume had just written
    /// one).
    line_at: Option<u64>,
}

impl Serial {
    /// Builds (or restores, on a resume) every component, and broadcasts the first weights
    /// unless the resume is exact.
    fn open(ctx: RunContext) -> anyhow::Result<Self> {
        let config = &ctx.config;
        let task = task_info(config)?;
        let serial_dir = ctx.checkpoint_dir().join(checkpoint::SUBDIR);
        // Read and checked first: an incompatible serial checkpoint stops the run before
        // anything is written.
        let saved = match ctx.resume {
            true => checkpoint::read_latest(&serial_dir, config).with_context(|| {
                format!(
                    "restoring the serial state from {} (start over with `asi train --restart`)",
                    serial_dir.display()
                )
            })?,
            false => None,
        };
        let (learner, _) = crate::run::open_learner(&ctx, task.dims, task.episode_length)?;
        let base = saved
            .as_ref()
            .and_then(|s| s.manifest.graph_base.as_deref());
        let graph = open_graph(&ctx, task.dims, base)?;
        let actors = (0..config.run.n_actors as u32)
            .map(|id| Actor::new(config, ActorId(id), config.run.seed))
            .collect::<Result<Vec<_>, _>>()
            .context("building the actors")?;
        // A resumed run continues its metrics file.
        let metrics_file = std::fs::OpenOptions::new()
            .create(true)
            .write(true)
            .append(ctx.resume)
            .truncate(!ctx.resume)
            .open(ctx.run_dir.join("metrics.jsonl"))?;
        let mut serial = Serial {
            lines: actors.iter().map(|_| ActorLine::default()).collect(),
            eval: SerialEval::new(config, &ctx.run_dir)?,
            coverage: CoverageTracker::new(config, task.layout)?,
            picture: SerialPicture::new(&ctx)?,
            metrics: BufWriter::new(metrics_file),
            last_episodes: learner.ingest_stats().episodes_completed,
            line_at: None,
            serial_dir,
            learner,
            graph,
            actors,
            ctx,
        };
        serial.start(saved)?;
        Ok(serial)
    }

    /// Restores the serial state if there is one; an exact resume continues right after the
    /// round at which the checkpoint was written, whose broadcast the actors already hold
    /// (publishing here would add a broadcast).
    fn start(&mut self, saved: Option<checkpoint::Restored>) -> anyhow::Result<()> {
        let (exact, detail) = match saved {
            Some(saved) => self.restore(saved)?,
            None => {
                let detail = format!(
                    "no serial checkpoint in {}: the actors start new episodes and the resumed \
                     run is not bit-identical to an uninterrupted one",
                    self.serial_dir.display()
                );
                if self.ctx.resume {
                    tracing::warn!("{detail}");
                }
                (false, detail)
            }
        };
        if let (true, Some(launch)) = (self.ctx.resume, self.ctx.launch) {
            crate::run::launches::resumed(&self.ctx.run_dir, launch, exact, &detail)?;
        }
        if exact {
            self.line_at = Some(self.learner.progress().env_steps_ingested);
            return Ok(());
        }
        let published =
            broadcast_weights(&mut self.learner, &mut self.actors, &mut self.graph.service)?;
        self.eval.on_weights(&self.ctx, published)?;
        // This graph-service (fresh or restored) is what a restore of its checkpoint gives
        // back: a base for the input log. After a replay that did not match, the graph is
        // rebuilt first, so that a base holds the graph of every stored state as after a φ
        // re-map (what an older build's restore of it would rebuild).
        if !self.graph.log.is_empty() {
            self.graph.service.rebuild();
        }
        self.graph.write_base();
        Ok(())
    }

    /// One chunk from every actor, the updates the replay ratio allows, the weights broadcast
    /// (and any evaluation due), and the self-imitation rounds due.
    fn round(&mut self) -> anyhow::Result<()> {
        let learner = &mut self.learner;
        for (actor, line) in self.actors.iter_mut().zip(&mut self.lines) {
            catch_up(learner)?;
            let chunk =
                actor.next_chunk(&mut ServiceOracle::new(InProcessGraph(&mut self.graph)))?;
            line.published_steps += u64::from(chunk.header.n_steps);
            learner.ingest(&chunk.header, &chunk.records)?;
            self.coverage.observe(&chunk.records);
            self.graph.ingest(&chunk.header, &chunk.records)?;
        }
        catch_up(learner)?;
        let version_before = self.graph.service.stats().graph_version;
        let published = broadcast_weights(learner, &mut self.actors, &mut self.graph.service)?;
        self.eval.on_weights(&self.ctx, published)?;
        // A φ re-map rebuilt the graph from every stored state: a restore of a checkpoint
        // written now gives this graph back, so the input log can start over from it.
        if self.graph.service.stats().graph_version != version_before {
            self.graph.write_base();
        }
        self_imitate(learner, &mut self.graph)
    }

    /// A metrics line if episodes completed since the last one; whether one was written.
    fn line_if_episodes_ended(&mut self) -> anyhow::Result<bool> {
        let episodes = self.learner.ingest_stats().episodes_completed;
        if episodes == self.last_episodes {
            return Ok(false);
        }
        self.write_line()?;
        self.last_episodes = episodes;
        Ok(true)
    }

    /// What the progress line shows.
    fn figures(&self) -> Figures {
        let config = &self.ctx.config;
        let value = |values: &[(String, f64)], key: &str| {
            values.iter().find(|(k, _)| k == key).map(|&(_, v)| v)
        };
        let eval = &self.eval.latest;
        Figures {
            episodes: self.learner.ingest_stats().episodes_completed,
            max_episodes: config.run.max_episodes,
            env_steps: self.learner.progress().env_steps_ingested,
            max_env_steps: config.run.max_env_steps,
            coverage: value(&self.coverage.metrics(), "charts/coverage"),
            eval: value(eval, "eval/success_rate")
                .zip(value(eval, "eval/train_episodes").map(|e| e as u64)),
        }
    }

    fn write_line(&mut self) -> anyhow::Result<()> {
        write_line(
            &mut self.metrics,
            &self.learner,
            &self.graph.service,
            &self.actors,
            &mut self.lines,
            &self.eval.latest,
            &self.coverage,
        )?;
        self.line_at = Some(self.learner.progress().env_steps_ingested);
        Ok(())
    }

    /// The last metrics line (if anything changed since the previous one) and checkpoint.
    fn finish(mut self, stopped: bool) -> anyhow::Result<()> {
        if self.line_at != Some(self.learner.progress().env_steps_ingested) {
            self.write_line()?;
        }
        self.metrics.flush()?;
        self.eval.finish();
        // Nothing new since the newest checkpoint: its serial part stays the one beside it.
        if crate::run::final_checkpoint(&self.ctx, &mut self.learner)?.is_some() {
            if self.actors.iter().any(Actor::has_open_episode) {
                tracing::warn!(
                    "the run ended with open episodes: they are not saved, and a resume \
                     continues with new episodes (not bit-identical to an uninterrupted run)"
                );
            }
            self.save().context("writing the final serial checkpoint")?;
        }
        self.picture.draw_if_behind(&self.graph.service);
        crate::plot::redraw_run_curves(&self.picture.run_dir);
        let env_steps = self.learner.progress().env_steps_ingested;
        if stopped {
            tracing::info!(
                env_steps,
                "stopped by signal; checkpoint written, run folder {}",
                self.ctx.run_dir.display()
            );
        } else {
            tracing::info!(env_steps, "serial run finished");
        }
        Ok(())
    }

    /// Writes the serial checkpoint beside the learner's just written.
    fn save(&mut self) -> anyhow::Result<()> {
        let clock = std::time::Instant::now();
        let Some((header, bytes)) = &self.eval.last_weights else {
            bail!("no weights were broadcast yet");
        };
        let state = checkpoint::SerialState {
            actors: self.actors.iter().map(Actor::save_state).collect(),
            published_steps: self.lines.iter().map(|l| l.published_steps).collect(),
            eval_schedule: self.eval.schedule,
            eval_latest: self.eval.latest.clone(),
            coverage: self
                .coverage
                .grid_mut()
                .map(|grid| (grid.counts().to_vec(), grid.n_outside())),
            weights: checkpoint::SavedHeader::of(header),
        };
        let graph = &self.graph;
        let moment = checkpoint::Moment {
            learner_env_steps: self.learner.progress().env_steps_ingested,
            graph_stored_steps: graph.service.stats().stored_steps,
            graph_base: graph.base.clone(),
            graph_log: graph.complete.then_some(&graph.log[..]),
        };
        let (path, manifest) =
            checkpoint::write(&self.serial_dir, &self.ctx.config, &state, bytes, moment)?;
        self.graph.protected = manifest.graph_base.clone();
        tracing::info!(
            secs = clock.elapsed().as_secs_f64(),
            "serial checkpoint written to {} ({})",
            path.display(),
            manifest.exactness()
        );
        Ok(())
    }

    /// Restores a serial checkpoint into the fresh components; true when the resume is exact
    /// (see [`checkpoint::Manifest::exact`], and of the same moment as the restored learner
    /// and graph-service), with what makes it so or not.
    fn restore(&mut self, saved: checkpoint::Restored) -> anyhow::Result<(bool, String)> {
        let checkpoint::Restored {
            state,
            weights: (header, bytes),
            manifest,
            path,
            graph_log,
        } = saved;
        let replayed = self.graph.replay(&manifest, graph_log)?;
        let saved_lines = state.actors.into_iter().zip(state.published_steps);
        for ((actor, line), (saved, steps)) in self
            .actors
            .iter_mut()
            .zip(self.lines.iter_mut())
            .zip(saved_lines)
        {
            actor.restore_state(saved)?;
            actor.load_weights(&header, &bytes)?;
            line.published_steps = steps;
            // The metrics line written with the checkpoint consumed the reaching tallies.
            line.reach_means.since_last(&actor.stats());
        }
        if let (Some(grid), Some((counts, n_outside))) = (self.coverage.grid_mut(), &state.coverage)
        {
            grid.restore_counts(counts, *n_outside)?;
        }
        self.eval.schedule = state.eval_schedule;
        self.eval.latest = state.eval_latest;
        self.eval.last_weights = Some((header, bytes));
        let now = (
            self.learner.progress().env_steps_ingested,
            self.graph.service.stats().stored_steps,
        );
        let matched = replayed && now == (manifest.learner_env_steps, manifest.graph_stored_steps);
        let detail = if !matched {
            let detail = format!(
                "serial checkpoint {} is of another moment (learner env steps, graph stored \
                 steps) = ({}, {}) than the restored learner and graph-service {now:?}{}: the \
                 resume is not bit-exact",
                path.display(),
                manifest.learner_env_steps,
                manifest.graph_stored_steps,
                if replayed {
                    ""
                } else {
                    ", and the graph-service's inputs were not replayed"
                }
            );
            tracing::warn!("{detail}");
            detail
        } else {
            let detail = format!(
                "serial checkpoint {}: {}",
                path.display(),
                manifest.exactness()
            );
            if !manifest.exact() {
                tracing::warn!("{detail}");
            }
            detail
        };
        let exact = matched && manifest.exact();
        let how = if exact {
            "bit-exact resume"
        } else {
            "resume not bit-exact"
        };
        tracing::info!("serial state restored from {}: {how}", path.display());
        Ok((exact, detail))
    }
}

/// The graph-service, restored from its newest checkpoint (the input log's base) if any.
/// The serial graph-service: on a resume restored from `base`, the graph-service checkpoint the
/// serial checkpoint's input log starts from (not necessarily the newest: a run killed after
/// later φ re-maps wrote newer ones, with states the resumed run collects again); the newest
/// valid one when there is no base or it does not restore (then the log is not replayed and
/// the resume is not exact, as logged).
fn open_graph(
    ctx: &RunContext,
    dims: nets::TaskDims,
    base: Option<&str>,
) -> anyhow::Result<LoggedGraph> {
    let dir = ctx.checkpoint_dir().join(graph_service::checkpoint::SUBDIR);
    if let Some(name) = base {
        let path = dir.join(name);
        match GraphService::restore(&path, &ctx.config, dims) {
            Ok((service, ckpt)) => {
                tracing::info!(
                    restored_stored_steps = ckpt.manifest.stored_steps,
                    "serial graph-service restored from {}, the serial checkpoint's base",
                    path.display()
                );
                return Ok(LoggedGraph::new(
                    service,
                    dir,
                    Some(name.to_owned()),
                    ctx.config.graph.max_stored_steps,
                ));
            }
            Err(err) => tracing::warn!(
                "the serial checkpoint's graph-service base {} does not restore ({err}); \
                 trying the newest graph-service checkpoint instead",
                path.display()
            ),
        }
    }
    let (service, start) = open_service(ctx, &dir, dims)?;
    let from = start.restored_from.as_ref();
    tracing::info!(
        restored_stored_steps = start.restored_stored_steps,
        "serial graph-service {}",
        from.map_or("started empty".to_owned(), |p| format!(
            "restored from {}",
            p.display()
        ))
    );
    let base = from
        .and_then(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned());
    Ok(LoggedGraph::new(
        service,
        dir,
        base,
        ctx.config.graph.max_stored_steps,
    ))
}

fn budget_reached(config: &protocol::Config, learner: &Learner) -> bool {
    let steps = learner.progress().env_steps_ingested;
    let episodes = learner.ingest_stats().episodes_completed;
    config.run.max_env_steps.is_some_and(|max| steps >= max) || episodes >= config.run.max_episodes
}

/// Runs every update the replay ratio allows, until the throttle lets actors continue.
fn catch_up(learner: &mut Learner) -> anyhow::Result<()> {
    while learner.train(UPDATE_BURST)? > 0 {}
    let p = learner.progress();
    if p.env_steps_ingested >= p.env_step_budget {
        bail!(
            "the throttle blocks the actors ({} env steps ingested, budget {}) but no update is allowed: \
             check learner.*.updates_* and replay.replay_slack_steps",
            p.env_steps_ingested,
            p.env_step_budget
        );
    }
    Ok(())
}

/// Runs every due self-imitation round with routes from the in-process graph-service. Called
/// after the weights broadcast, so the graph already uses the learner's φ version.
fn self_imitate(learner: &mut Learner, graph: &mut LoggedGraph) -> anyhow::Result<()> {
    while learner.si_pending() > 0 && !learner.phi_round_active() {
        learner.train_self_imitation(&mut GraphRoutes::new(InProcessGraph(graph)))?;
    }
    Ok(())
}

/// Publishes due weights to every component; returns them for the evaluator.
fn broadcast_weights(
    learner: &mut Learner,
    actors: &mut [Actor],
    graph: &mut GraphService,
) -> anyhow::Result<Option<(protocol::WeightsHeader, Vec<u8>)>> {
    let published = learner.publish_due()?;
    if let Some((header, bytes)) = &published {
        for actor in actors.iter_mut() {
            actor.load_weights(header, bytes)?;
        }
        graph.load_weights(header, bytes)?;
    }
    Ok(published)
}

/// The evaluator of serial mode: the process mode's schedule and outputs, run inline on the
/// weights of the broadcast at which an evaluation falls due. Like the evaluator process, it
/// keeps the newest weights in `run_dir/weights/` for `asi eval`.
struct SerialEval {
    evaluator: Option<Evaluator>,
    schedule: EvalSchedule,
    n_episodes: u32,
    /// The latest evaluation's metrics, repeated on every line (as the launcher keeps them).
    latest: Vec<(String, f64)>,
    saver: WeightsSaver,
    /// The newest broadcast, saved at the end of the run.
    last_weights: Option<(protocol::WeightsHeader, Vec<u8>)>,
}

impl SerialEval {
    fn new(config: &protocol::Config, run_dir: &std::path::Path) -> anyhow::Result<Self> {
        let evaluator = if config.eval.n_episodes > 0 {
            Some(
                Evaluator::new(config, crate::proc::evaluator::eval_seed(config))
                    .context("building the evaluator")?,
            )
        } else {
            None
        };
        Ok(Self {
            evaluator,
            schedule: EvalSchedule::new(config.eval.interval_episodes),
            n_episodes: config.eval.n_episodes,
            latest: Vec::new(),
            saver: WeightsSaver::new(run_dir),
            last_weights: None,
        })
    }

    fn on_weights(
        &mut self,
        ctx: &RunContext,
        published: Option<(protocol::WeightsHeader, Vec<u8>)>,
    ) -> anyhow::Result<()> {
        let Some((header, bytes)) = published else {
            return Ok(());
        };
        let due = match self.evaluator {
            Some(_) => self.schedule.due(header.schedule.train_episodes),
            None => None,
        };
        self.saver.offer(&header, &bytes, due.is_some());
        if let (Some(evaluator), Some(index)) = (self.evaluator.as_mut(), due) {
            evaluator.load_weights(&header, &bytes)?;
            let report = evaluator.run(index, self.n_episodes)?;
            record_report(ctx, evaluator, &report, &header)?;
            self.latest = eval_metrics(&report, &header, self.schedule.skipped(), 0);
        }
        self.last_weights = Some((header, bytes));
        Ok(())
    }

    /// Saves the newest weights whatever the interval (end of the run).
    fn finish(&mut self) {
        if let Some((header, bytes)) = &self.last_weights {
            self.saver.offer(header, bytes, true);
        }
    }
}

/// `plots/graph_latest.png` in serial mode: redrawn when the graph changed, at most once per
/// [`REDRAW_EPISODES`] completed episodes (no clock in the loop), and at the end; beside it
/// `plots/curves.png` (success and coverage curves) on the same schedule.
struct SerialPicture {
    plot: Option<MazeGraphPlot>,
    last_episodes: Option<u64>,
    run_dir: std::path::PathBuf,
    last_curves: u64,
}

impl SerialPicture {
    fn new(ctx: &RunContext) -> anyhow::Result<Self> {
        Ok(Self {
            plot: MazeGraphPlot::new(&ctx.config, &ctx.run_dir)?,
            last_episodes: None,
            run_dir: ctx.run_dir.clone(),
            last_curves: 0,
        })
    }

    fn tick(&mut self, episodes: u64, graph: &GraphService) {
        if episodes >= self.last_curves + REDRAW_EPISODES {
            self.last_curves = episodes;
            crate::plot::redraw_run_curves(&self.run_dir);
        }
        if self
            .last_episodes
            .is_none_or(|last| episodes >= last + REDRAW_EPISODES)
            && self.draw_if_behind(graph)
        {
            self.last_episodes = Some(episodes);
        }
    }

    /// Draws if the graph changed since the last picture; true when it drew.
    fn draw_if_behind(&mut self, graph: &GraphService) -> bool {
        match self.plot.as_mut().filter(|p| p.behind(graph)) {
            Some(plot) => {
                plot.draw(graph);
                true
            }
            None => false,
        }
    }
}

/// The in-process graph-service as the actors' transport: its request handler, called directly
/// (and the request logged).
struct InProcessGraph<'a>(&'a mut LoggedGraph);

impl GraphTransport for InProcessGraph<'_> {
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String> {
        self.0
            .record(|| GraphInput::Request(*header, body.to_vec()));
        Ok(self.0.service.handle(header, body))
    }
}

/// Serial mode's graph-service with the log of its inputs (chunks and requests) since its
/// *base*: the newest graph-service checkpoint, written whenever its graph holds every stored
/// state (at start and after each φ re-map). Restoring the base and replaying the log gives
/// back the service exactly (also from bases of builds before 2026-12-06, whose checkpoints
/// did not hold the graph: their restore rebuilds it from the whole store, which at a base is
/// the same graph). Weights messages are not logged: between re-maps they change nothing.
struct LoggedGraph {
    service: GraphService,
    /// `checkpoints/graph-service/`.
    dir: std::path::PathBuf,
    /// Folder name of the base checkpoint.
    base: Option<String>,
    log: Vec<GraphInput>,
    /// Env steps of the chunks in the log.
    logged_steps: u64,
    /// Past this many logged env steps (`graph.max_stored_steps`: the log would outgrow the
    /// store) the log is dropped until the next base, e.g. when φ rounds are skipped for long.
    max_logged_steps: u64,
    /// The log holds every input since `base` (false after a failed base write or a dropped
    /// log, until the next base; nothing is logged meanwhile).
    complete: bool,
    /// The base the newest serial checkpoint replays from (written or restored): kept when
    /// later bases rotate the graph-service's checkpoints, so a run killed after more φ
    /// re-maps still resumes exactly from that checkpoint.
    protected: Option<String>,
}

impl LoggedGraph {
    fn new(
        service: GraphService,
        dir: std::path::PathBuf,
        base: Option<String>,
        max_logged_steps: u64,
    ) -> Self {
        Self {
            service,
            dir,
            complete: base.is_some(),
            protected: base.clone(),
            base,
            log: Vec::new(),
            logged_steps: 0,
            max_logged_steps,
        }
    }

    fn record(&mut self, input: impl FnOnce() -> GraphInput) {
        if !self.complete {
            return;
        }
        let input = input();
        if let GraphInput::Chunk(header, _) = &input {
            self.logged_steps += u64::from(header.n_steps);
        }
        if self.logged_steps > self.max_logged_steps {
            tracing::warn!(
                logged_steps = self.logged_steps,
                "the graph-service's input log outgrew graph.max_stored_steps without a φ \
                 re-map: dropped; serial checkpoints are not bit-exact until the next re-map"
            );
            self.log = Vec::new();
            self.complete = false;
            return;
        }
        self.log.push(input);
    }

    fn ingest(&mut self, header: &TrajectoryHeader, records: &[f32]) -> anyhow::Result<()> {
        self.record(|| GraphInput::Chunk(*header, records.to_vec()));
        Ok(self.service.ingest(header, records)?)
    }

    /// Writes a graph-service checkpoint as the new base and empties the log.
    fn write_base(&mut self) {
        let clock = std::time::Instant::now();
        self.log.clear();
        self.logged_steps = 0;
        let protected = self
            .protected
            .as_deref()
            .and_then(graph_service::checkpoint::sequence_of);
        match self.service.save_protecting(&self.dir, protected) {
            Ok(ckpt) => {
                tracing::info!(
                    stored_steps = ckpt.manifest.stored_steps,
                    secs = clock.elapsed().as_secs_f64(),
                    "graph-service checkpoint written to {}",
                    ckpt.path.display()
                );
                self.base = ckpt
                    .path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned());
                self.complete = true;
            }
            Err(err) => {
                tracing::error!(
                    "writing a graph-service checkpoint failed ({err}); serial checkpoints are \
                     not bit-exact until the next φ re-map"
                );
                self.complete = false;
            }
        }
    }

    /// Replays a saved log onto the restored base; false (nothing replayed) when the restored
    /// checkpoint is not the log's base or the log is incomplete.
    fn replay(
        &mut self,
        manifest: &checkpoint::Manifest,
        log: Vec<GraphInput>,
    ) -> anyhow::Result<bool> {
        if !manifest.graph_log_complete || manifest.graph_base != self.base {
            tracing::warn!(
                "the graph-service was restored from {:?}, the serial checkpoint's input log \
                 starts from {:?} (complete: {}): not replayed",
                self.base,
                manifest.graph_base,
                manifest.graph_log_complete
            );
            return Ok(false);
        }
        for input in &log {
            match input {
                GraphInput::Chunk(header, records) => self
                    .service
                    .ingest(header, records)
                    .context("replaying a logged chunk into the graph-service")?,
                GraphInput::Request(header, body) => {
                    self.service.handle(header, body);
                }
            }
        }
        tracing::info!(
            n_inputs = log.len(),
            "graph-service inputs since its checkpoint replayed"
        );
        self.logged_steps = log
            .iter()
            .map(|input| match input {
                GraphInput::Chunk(header, _) => u64::from(header.n_steps),
                GraphInput::Request(..) => 0,
            })
            .sum();
        self.log = log;
        Ok(true)
    }
}

/// What serial mode tracks per actor for its metric lines.
#[derive(Default)]
struct ActorLine {
    published_steps: u64,
    reach_means: ReachMeans,
}

/// One JSON object per completed episode; only values that depend on the seed, no clock.
/// Actor values use the process mode's names (`actor<i>/actor/…`).
fn write_line(
    out: &mut impl Write,
    learner: &Learner,
    graph: &GraphService,
    actors: &[Actor],
    lines: &mut [ActorLine],
    eval: &[(String, f64)],
    coverage: &CoverageTracker,
) -> anyhow::Result<()> {
    let mut object = serde_json::Map::new();
    for (name, value) in learner.metrics() {
        if !name.contains("per_sec") {
            object.insert(format!("learner/{name}"), serde_json::json!(value));
        }
    }
    for (name, value) in coverage.metrics() {
        object.insert(format!("learner/{name}"), serde_json::json!(value));
    }
    for (i, (actor, line)) in actors.iter().zip(lines.iter_mut()).enumerate() {
        let stats = actor.stats();
        let mut values = actor_metrics(&stats, line.published_steps);
        values.extend(line.reach_means.since_last(&stats));
        for (name, value) in values {
            object.insert(format!("actor{i}/{name}"), serde_json::json!(value));
        }
    }
    // Not `graph/version`: a graph-service restored from an older build's checkpoint counts
    // its rebuild as one more version.
    // All are counts, exact in f64; serial lines have always written them as integers.
    for (name, value) in crate::proc::graph_service::graph_metrics(&graph.stats()) {
        if name != "graph/version" {
            object.insert(
                format!("graph-service/{name}"),
                serde_json::json!(value as u64),
            );
        }
    }
    for (name, value) in eval {
        object.insert(format!("evaluator0/{name}"), serde_json::json!(value));
    }
    writeln!(out, "{}", serde_json::Value::Object(object))?;
    Ok(())
}
