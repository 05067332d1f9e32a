//! `asi train`: resolves the config once, spawns graph-service, learner and actors as separate
//! processes, supervises them (a crashed process comes back with back-off, up to the crash-loop
//! guard `run.max_restarts`; see [`children`]), shows progress,
//! writes metrics, and stops everything cleanly on Ctrl-C, SIGTERM or when the budget is spent.
//!
//! Shutdown order matters for "nothing lost": actors stop first (SIGTERM; they finish the chunk
//! in hand), then the learner and graph-service get a Stop message and drain what the actors
//! sent before they exit. A signal, failure or timeout while the services are still starting
//! stops them the same way (Stop, then SIGTERM) before the launcher exits; after a failure or
//! a timeout, a service that is not ready gets SIGTERM at once (it may hang, e.g. on a read
//! that never returns, and holds nothing yet), and the launcher exits non-zero with an error
//! naming the process, the reason and its log.

mod children;
mod metrics;
mod starts;

use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use iceoryx2::prelude::*;
use learner::learner::checkpoint::{
    config_fingerprint, latest_checkpoint, Manifest, FORMAT_VERSION, MANIFEST,
};
use protocol::{ControlCommand, ControlMessage};

use crate::channels::Channels;
use crate::proc::common::{catch_termination_signals, node, task_info};
use crate::run::{RunContext, RunLock};
use children::{ChildKind, Children};
use metrics::MetricsBook;

/// Supervisor tick: how often children and metrics are checked.
const TICK: Duration = Duration::from_millis(100);
/// How long learner and graph-service may take to drain, write their final checkpoint and exit
/// after a Stop message (a checkpoint with a 1 M-step replay buffer takes seconds; SIGTERM
/// during the write loses only that checkpoint, never an older one).
const SERVICE_STOP_WAIT: Duration = Duration::from_secs(120);
/// While the services drain after Stop: how often the Stop is handed to control ports opened
/// after it was sent.
const STOP_RECONNECT: Duration = Duration::from_millis(200);

/// How the wait for the services' readiness ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Startup {
    Ready,
    Signal,
}

/// Why the supervisor loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Ending {
    BudgetReached,
    Signal,
}

/// Process mode: starts the services, then the actors and the evaluator, and supervises them
/// until the budget is reached or a signal arrives; `Ok(true)` when stopped by a signal.
pub fn run(ctx: RunContext) -> anyhow::Result<bool> {
    let config = &ctx.config;
    let layout = task_info(config)?.layout;
    let node = node(&ctx, "launcher")?;
    if catch_termination_signals(&node) {
        tracing::info!("stopped by signal while starting; nothing was started");
        return Ok(true);
    }
    if let (Some(launch), Some(point)) = (ctx.launch, ctx.resumed_from) {
        // Recorded before the learner restores it: a process-mode resume is never exact.
        let detail = format!(
            "process mode: the learner restores checkpoint {}, the actors start new episodes \
             and the processes run concurrently, so the run is not bit-identical to an \
             uninterrupted one",
            point.sequence.unwrap_or(0)
        );
        crate::run::launches::resumed(&ctx.run_dir, launch, false, &detail)?;
    }
    clean_stale_resources(&node);
    let channels = Channels::new(config, &ctx.run_id, &layout);
    let metrics_in = channels.metrics_subscriber(&node)?;
    let control = channels.control_publisher(&node)?;
    let mut book = MetricsBook::create(&ctx, ctx.resume)?;
    let mut children = Children::new(&ctx)?;
    if ctx.resume {
        if let Ok(Some(manifest)) = resume_point(config, &ctx.run_dir) {
            // A checkpoint of a build before the count was recorded: taken as past the warm-up.
            let done = manifest.episodes_completed;
            children.note_run_episodes(done.unwrap_or(config.learner.high.random_episodes));
        }
    }
    children.spawn(ChildKind::GraphService)?;
    children.spawn(ChildKind::Learner)?;
    let started = wait_until_ready(&ctx, &node, &mut children);
    if !matches!(started, Ok(Startup::Ready)) {
        if started.is_err() {
            // A service not ready by now may never read a Stop (a hung restore): SIGTERM.
            children.stop_kind(|k| !k.stops_first() && !ctx.is_ready(&k.name()));
        }
        // Not left to notice on their own that the launcher is gone: stopped in order, and
        // their iceoryx2 resources cleaned.
        shutdown(&control, &mut children);
        clean_stale_resources(&node);
        started?;
        tracing::info!(
            "stopped by signal while starting; run folder {}",
            ctx.run_dir.display()
        );
        return Ok(true);
    }
    for id in 0..config.run.n_actors as u32 {
        children.spawn(ChildKind::Actor(id))?;
    }
    if config.eval.n_episodes > 0 {
        children.spawn(ChildKind::Evaluator)?;
    }
    tracing::info!(run_id = %ctx.run_id, run_dir = %ctx.run_dir.display(), actors = config.run.n_actors, "training started");
    let ending = supervise(&ctx, &node, &metrics_in, &mut children, &mut book);
    shutdown(&control, &mut children);
    let drained = metrics_in.drain().unwrap_or_default();
    book.record(&drained);
    book.flush(children.total_restarts())?;
    book.finish(children.total_restarts());
    clean_stale_resources(&node);
    let ending = ending?;
    match ending {
        Ending::BudgetReached => tracing::info!("training budget reached; run finished"),
        Ending::Signal => tracing::info!("stopped by signal; run folder {}", ctx.run_dir.display()),
    }
    Ok(ending == Ending::Signal)
}

/// Removes iceoryx2 resources of dead nodes (e.g. processes SIGKILLed in an earlier run).
fn clean_stale_resources(node: &Node<protocol::transport::Ipc>) {
    let state = node.try_cleanup_dead_nodes();
    tracing::debug!(?state, "cleaned iceoryx2 resources of dead nodes");
}

/// Waits until learner and graph-service report ready, or a signal arrives; `Err` when one of
/// them exits first or `run.startup_timeout_secs` passes (naming the processes not ready).
fn wait_until_ready(
    ctx: &RunContext,
    node: &Node<protocol::transport::Ipc>,
    children: &mut Children,
) -> anyhow::Result<Startup> {
    // Validated finite and > 0; a timeout too long for a Duration is as good as none.
    let timeout =
        Duration::try_from_secs_f64(ctx.config.run.startup_timeout_secs).unwrap_or(Duration::MAX);
    let services = [ChildKind::Learner, ChildKind::GraphService];
    let start = Instant::now();
    loop {
        let waiting: Vec<ChildKind> = services
            .into_iter()
            .filter(|k| !ctx.is_ready(&k.name()))
            .collect();
        if waiting.is_empty() {
            return Ok(Startup::Ready);
        }
        if node.wait(TICK).is_err() {
            return Ok(Startup::Signal);
        }
        if let Some(failure) = children.check_services()? {
            bail!(failure);
        }
        if start.elapsed() > timeout {
            let names: Vec<String> = waiting.iter().map(|k| k.name()).collect();
            let logs: Vec<String> = waiting
                .iter()
                .map(|&k| children.log_path(k).display().to_string())
                .collect();
            bail!(
                "{} not ready after {timeout:?} (run.startup_timeout_secs); see {}",
                names.join(" and "),
                logs.join(", ")
            );
        }
    }
}

fn supervise(
    ctx: &RunContext,
    node: &Node<protocol::transport::Ipc>,
    metrics_in: &protocol::transport::ValueSubscriber<protocol::MetricsSample>,
    children: &mut Children,
    book: &mut MetricsBook,
) -> anyhow::Result<Ending> {
    let interval = Duration::from_secs_f64(ctx.config.run.metrics_interval_secs);
    let mut last_flush = Instant::now();
    loop {
        if node.wait(TICK).is_err() {
            return Ok(Ending::Signal);
        }
        book.record(&metrics_in.drain()?);
        children.note_run_episodes(book.episodes_completed());
        let restarts = children.restart_crashed()?;
        if restarts.crashed > 0 {
            // The dead process's ports would otherwise stay registered with its services.
            clean_stale_resources(node);
        }
        for kind in restarts.restarted.iter().filter(|k| !k.stops_first()) {
            // The dead incarnation's values (all drained during the back-off) would stand in
            // for the restarted one's, e.g. a budget the restored learner has not reached yet.
            book.forget_process(&kind.name());
        }
        if restarts.restarted.contains(&ChildKind::Learner) {
            rewind_records(ctx, book);
        }
        book.set_restarts(children.restarts_per_family());
        book.show_progress(children.total_restarts());
        if last_flush.elapsed() >= interval {
            book.flush(children.total_restarts())?;
            last_flush = Instant::now();
        }
        if children.services_running() && book.budget_reached(&ctx.config) {
            return Ok(Ending::BudgetReached);
        }
    }
}

/// The restarted learner resumes from its newest checkpoint (or from nothing): the records
/// written past that point move aside ([`MetricsBook::rewind_learner`]). A failure is logged
/// and training goes on; the records then go back in env steps as they did before the cut.
fn rewind_records(ctx: &RunContext, book: &mut MetricsBook) {
    let point = match resume_point(&ctx.config, &ctx.run_dir) {
        Ok(Some(manifest)) => crate::run::ResumePoint {
            sequence: Some(manifest.sequence),
            env_steps: manifest.env_steps,
            episodes: manifest.episodes_completed,
        },
        Ok(None) => crate::run::ResumePoint::START,
        Err(err) => {
            tracing::error!(
                "restarted learner: its checkpoint is unreadable here, metrics not cut: {err:#}"
            );
            return;
        }
    };
    match book.rewind_learner(point) {
        Ok(moved) => {
            for m in moved {
                tracing::warn!(
                    "learner restarted from {} (env steps {}): {} {} of {} written after it moved to {}",
                    point.sequence.map_or("the start".to_owned(), |n| format!("checkpoint {n}")),
                    point.env_steps,
                    m.lines,
                    m.unit,
                    m.file.display(),
                    m.side_file.display()
                );
            }
        }
        Err(err) => tracing::error!("restarted learner: cutting the metrics files failed: {err:#}"),
    }
}

/// Actors first (so everything they sent can be drained), then the services: a Stop message,
/// and SIGTERM for any that has not exited after [`SERVICE_STOP_WAIT`]. A crashed service
/// still waiting out its restart back-off is not restarted (its newest checkpoint stands).
fn shutdown(
    control: &protocol::transport::ValuePublisher<ControlMessage>,
    children: &mut Children,
) {
    children.stop_kind(|k| k.stops_first());
    if let Err(err) = control.send(ControlMessage::new(1, ControlCommand::Stop)) {
        tracing::warn!("could not send Stop: {err:#}");
    }
    // A learner in a φ round finishes it first (50,000 steps: about a minute on two cores).
    tracing::info!(
        "stopping: the learner and graph-service write their final checkpoints (a running φ \
         round is finished first; up to {} s)",
        SERVICE_STOP_WAIT.as_secs()
    );
    if !wait_for_services(control, children) {
        tracing::warn!("services did not stop on the Stop message; sending SIGTERM");
    }
    children.stop_kind(|_| true);
}

/// Waits up to [`SERVICE_STOP_WAIT`] for the services to exit after the Stop; returns whether
/// they did. Meanwhile the Stop (the control channel keeps the last message) is handed to
/// control ports opened after it was sent: a learner restarted just before a SIGTERM is still
/// restoring its checkpoint then, and would otherwise only get SIGTERM at the end of the wait.
fn wait_for_services(
    control: &protocol::transport::ValuePublisher<ControlMessage>,
    children: &mut Children,
) -> bool {
    let deadline = Instant::now() + SERVICE_STOP_WAIT;
    loop {
        if let Err(err) = control.update_connections() {
            tracing::debug!("handing the Stop to new control ports: {err:#}");
        }
        if children.wait_for_exit(|_| true, STOP_RECONNECT) {
            return true;
        }
        if Instant::now() >= deadline {
            return false;
        }
    }
}

/// Serial mode's actor count when nothing sets one: the default `run.n_actors` (cores − 2)
/// depends on the machine, and serial mode, which steps its actors in turn in one thread,
/// would then give another run for the same config and seed on another machine.
const SERIAL_DEFAULT_ACTORS: &str = "run.n_actors=1";

/// Whether the config file or a `--set` gives `run.n_actors`. A file that does not parse
/// counts as not giving it (loading it reports the problem).
fn sets_n_actors(file: Option<&std::path::Path>, sets: &[String]) -> bool {
    let by_set = sets.iter().any(|s| {
        s.split_once('=')
            .is_some_and(|(key, _)| key.trim() == "run.n_actors")
    });
    let by_file = file
        .and_then(|path| std::fs::read_to_string(path).ok())
        .and_then(|text| text.parse::<toml::Table>().ok())
        .is_some_and(|table| {
            table
                .get("run")
                .and_then(toml::Value::as_table)
                .is_some_and(|run| run.contains_key("n_actors"))
        });
    by_set || by_file
}

/// Settings a serial run cannot honour and stay deterministic, refused before any folder is
/// touched.
fn serial_fits(config: &protocol::Config) -> anyhow::Result<()> {
    anyhow::ensure!(
        !config.encoder.background_rounds,
        "encoder.background_rounds = true runs φ rounds on a thread beside the SAC updates, \
         which a serial run cannot do and stay deterministic: drop --serial (process mode), or \
         set encoder.background_rounds = false"
    );
    Ok(())
}

/// Resolves `asi train`'s arguments into a run context (writes the resolved config). An
/// existing run folder with a checkpoint is resumed ("resuming from checkpoint N (env steps
/// S)"), after checking that the checkpoint fits this build and config, unless that checkpoint
/// already reaches the budget ([`Launch::Finished`]: nothing starts, so a finished run's
/// folder is not touched by a repeated command); with `--restart` the old folder is first
/// moved aside ([`move_aside`]) and the run starts over.
pub fn prepare(args: &crate::cli::TrainArgs) -> anyhow::Result<Launch> {
    let mut overrides = args.set.clone();
    if let Some(seed) = args.seed {
        overrides.push(format!("run.seed={seed}"));
    }
    if let Some(actors) = args.actors {
        overrides.push(format!("run.n_actors={actors}"));
    } else if args.serial && !sets_n_actors(args.config.as_deref(), &args.set) {
        overrides.push(SERIAL_DEFAULT_ACTORS.to_owned());
    }
    let config =
        protocol::Config::load(args.config.as_deref(), &overrides).with_context(|| match &args
            .config
        {
            Some(path) => format!("loading config {}", path.display()),
            None => "loading the default config (AntMaze-U)".to_owned(),
        })?;
    for note in config.notes() {
        eprintln!("note: {note}");
    }
    if args.serial {
        serial_fits(&config)?;
    }
    let run_dir = args.run_dir.clone().unwrap_or_else(|| config.run.run_dir());
    // Locked before anything in it is read or moved: a running launch keeps its folder.
    let mut lock = RunLock::acquire(&run_dir)?;
    if args.restart {
        if let Some(old) = move_aside(&run_dir)? {
            println!(
                "restarting: the previous run folder was moved to {}",
                old.display()
            );
            lock = RunLock::acquire(&run_dir)?;
        }
    }
    let resumed_from = match resume_point(&config, &run_dir)? {
        Some(manifest) => {
            if let Some(done) = finished(&config.run, &manifest) {
                println!(
                    "run in {} already finished: checkpoint {} holds {done}; nothing was \
                     started or changed. To train on, raise the budget (e.g. --set \
                     run.max_episodes=N); to start over, add --restart",
                    run_dir.display(),
                    manifest.sequence
                );
                return Ok(Launch::Finished);
            }
            println!(
                "resuming from checkpoint {} (env steps {})",
                manifest.sequence, manifest.env_steps
            );
            let point = crate::run::ResumePoint {
                sequence: Some(manifest.sequence),
                env_steps: manifest.env_steps,
                episodes: manifest.episodes_completed,
            };
            for moved in crate::run::move_lines_past(&run_dir, point)? {
                println!(
                    "{}: {} {} written after checkpoint {} (a run stopped without a final \
                     checkpoint) moved to {}; the resumed run writes that stretch again",
                    moved.file.display(),
                    moved.lines,
                    moved.unit,
                    manifest.sequence,
                    moved.side_file.display()
                );
            }
            Some(point)
        }
        None => {
            refuse_outputs_without_checkpoint(&run_dir)?;
            None
        }
    };
    Ok(Launch::Start(Box::new(RunContext::create(
        config,
        run_dir,
        resumed_from,
        lock,
    )?)))
}

/// What `asi train` does after [`prepare`].
pub enum Launch {
    /// Train, in this context.
    Start(Box<RunContext>),
    /// Nothing: the checkpoint to resume from already reaches the budget (the folder is
    /// left exactly as it was; the lock is released on return).
    Finished,
}

/// `Some(what the checkpoint holds)` when a run resumed from `manifest` would have nothing to
/// do: its episodes or env steps already reach `run.max_episodes` / `run.max_env_steps`.
/// Checkpoints of builds that did not record episodes are judged by env steps alone.
fn finished(run: &protocol::config::RunConfig, manifest: &Manifest) -> Option<String> {
    let by_steps = run
        .max_env_steps
        .is_some_and(|max| manifest.env_steps >= max);
    let by_episodes = manifest
        .episodes_completed
        .is_some_and(|episodes| episodes >= run.max_episodes);
    (by_steps || by_episodes).then(|| {
        let episodes = manifest
            .episodes_completed
            .map_or("?".to_owned(), |e| e.to_string());
        let steps_budget = run
            .max_env_steps
            .map_or(String::new(), |max| format!(", run.max_env_steps={max}"));
        format!(
            "{episodes} episodes and {} env steps (budget run.max_episodes={}{steps_budget})",
            manifest.env_steps, run.max_episodes
        )
    })
}

/// A folder with an earlier run's outputs but no learner checkpoint (that run stopped before
/// its first one) is not started over in place: that would truncate its metrics and mix a
/// new learner with the graph-service checkpoint it may have left. Nothing is changed.
fn refuse_outputs_without_checkpoint(run_dir: &std::path::Path) -> anyhow::Result<()> {
    let outputs = crate::run::earlier_outputs(run_dir)?;
    if outputs.is_empty() {
        return Ok(());
    }
    bail!(
        "run folder {} holds an earlier run's outputs ({}) but no learner checkpoint to resume \
         from (that run stopped before its first checkpoint, written every \
         run.checkpoint_interval_mins); nothing was changed. Start over with --restart (the old \
         folder is moved aside, nothing is deleted), or choose another --run-dir",
        run_dir.display(),
        outputs.join(", ")
    )
}

/// The manifest of the checkpoint a launch in `run_dir` resumes from, checked against this
/// build and `config` up front so an incompatible one stops the launch with a clear error.
fn resume_point(
    config: &protocol::Config,
    run_dir: &std::path::Path,
) -> anyhow::Result<Option<Manifest>> {
    let dir = run_dir.join(crate::run::CHECKPOINT_DIR);
    let Some(path) = latest_checkpoint(&dir)? else {
        return Ok(None);
    };
    let manifest_path = path.join(MANIFEST);
    let text = std::fs::read(&manifest_path)
        .with_context(|| format!("reading {}", manifest_path.display()))?;
    let manifest: Manifest = serde_json::from_slice(&text).with_context(|| {
        format!(
            "{} is unreadable; start over with --restart",
            manifest_path.display()
        )
    })?;
    let fingerprint = config_fingerprint(config);
    let versions = (manifest.format_version, manifest.protocol_version);
    let readable = ckpt::Checksum::of_format(manifest.format_version, FORMAT_VERSION).is_some();
    if !readable || manifest.protocol_version != protocol::PROTOCOL_VERSION {
        bail!(
            "checkpoint {} has format/protocol version {versions:?}, this build reads \
             (1 to {FORMAT_VERSION}, {}); start over with --restart",
            path.display(),
            protocol::PROTOCOL_VERSION
        );
    }
    if manifest.config_fingerprint != fingerprint {
        bail!(
            "checkpoint {} was written with another config (sections env, hierarchy, learner, replay, encoder \
             differ: fingerprint {} vs {fingerprint}); resume with the same config, or start over with --restart",
            path.display(),
            manifest.config_fingerprint
        );
    }
    Ok(Some(manifest))
}

/// `--restart`: renames an existing, non-empty `run_dir` to `<run_dir>.old-<unix seconds>`
/// (nothing is deleted) and returns the new name; `None` when there was nothing to move.
pub fn move_aside(run_dir: &std::path::Path) -> anyhow::Result<Option<std::path::PathBuf>> {
    let empty = match std::fs::read_dir(run_dir) {
        // The lock file alone is this launch's own (see `prepare`).
        Ok(entries) => entries
            .flatten()
            .all(|e| e.file_name() == crate::run::LOCK_FILE),
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(err) => return Err(err).with_context(|| format!("reading {}", run_dir.display())),
    };
    if empty {
        return Ok(None);
    }
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let mut name = run_dir.as_os_str().to_owned();
    name.push(format!(".old-{secs}"));
    let old = std::path::PathBuf::from(name);
    if old.exists() {
        bail!(
            "cannot move {} aside: {} already exists",
            run_dir.display(),
            old.display()
        );
    }
    std::fs::rename(run_dir, &old)
        .with_context(|| format!("moving {} to {}", run_dir.display(), old.display()))?;
    Ok(Some(old))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn manifest(env_steps: u64, episodes_completed: Option<u64>) -> Manifest {
        Manifest {
            format_version: FORMAT_VERSION,
            protocol_version: protocol::PROTOCOL_VERSION,
            layout_hash: 0,
            config_fingerprint: String::new(),
            sequence: 3,
            env_steps,
            updates_low: 0,
            updates_high: 0,
            episodes_completed,
            files: Vec::new(),
        }
    }

    #[test]
    fn serial_mode_takes_one_actor_unless_the_file_or_a_set_gives_a_count() {
        let config = |name: &str| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(name);
        let smoke = config("configs/smoke.toml"); // [run] n_actors = 2
        let ant = config("configs/antmaze-u.toml");
        assert!(sets_n_actors(Some(&smoke), &[]));
        assert!(!sets_n_actors(Some(&ant), &[]));
        assert!(!sets_n_actors(None, &["run.seed=3".to_owned()]));
        assert!(sets_n_actors(None, &[" run.n_actors = 3".to_owned()]));
        assert!(!sets_n_actors(None, &["run.n_actors_x=3".to_owned()]));
        assert!(!sets_n_actors(Some(&config("no-such.toml")), &[]));
    }

    #[test]
    fn a_serial_run_with_background_phi_rounds_is_refused_before_its_folder_exists() {
        let run_dir = std::env::temp_dir().join(format!("asi-serial-bg-{}", std::process::id()));
        let args = |serial: bool| crate::cli::TrainArgs {
            serial,
            set: vec!["encoder.background_rounds=true".to_owned()],
            run_dir: Some(run_dir.clone()),
            ..Default::default()
        };
        let err = prepare(&args(true)).err().expect("refused");
        assert!(
            format!("{err:#}").contains("encoder.background_rounds = true"),
            "{err:#}"
        );
        assert!(!run_dir.exists(), "nothing written for a refused launch");
        assert!(serial_fits(&protocol::Config::default()).is_ok());
    }

    #[test]
    fn a_checkpoint_at_either_budget_is_finished_and_one_below_both_is_not() {
        let mut run = protocol::config::RunConfig {
            max_episodes: 10,
            ..Default::default()
        };
        assert_eq!(finished(&run, &manifest(5_000, Some(9))), None);
        assert_eq!(
            finished(&run, &manifest(5_000, Some(10))).as_deref(),
            Some("10 episodes and 5000 env steps (budget run.max_episodes=10)")
        );
        // Old checkpoints without an episode count never count as finished by episodes.
        assert_eq!(finished(&run, &manifest(5_000, None)), None);
        run.max_env_steps = Some(5_000);
        assert_eq!(
            finished(&run, &manifest(5_000, None)).as_deref(),
            Some("? episodes and 5000 env steps (budget run.max_episodes=10, run.max_env_steps=5000)")
        );
        assert_eq!(finished(&run, &manifest(4_999, Some(9))), None);
    }
}
