//! What every child process shares: its node, the stop conditions, metrics publishing, the
//! task's dimensions, and the graph-service client (actors' questions, the learner's SI routes).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use actor::{GraphTransport, ServiceOracle};
use anyhow::Context;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use learner::{RouteSource, RoutesReply};
use nets::TaskDims;
use protocol::graph::{GraphRequestHeader, GraphResponseHeader, RouteQuery};
use protocol::transport::{open_node, Ipc, ValuePublisher};
use protocol::{
    Config, GraphRequest, GraphResponse, MetricsSample, PhiVersion, ProcessRole, StepLayout,
};

use crate::channels::GraphClient;
use crate::run::RunContext;

/// What the processes need to know about the run's task.
pub struct TaskInfo {
    pub dims: TaskDims,
    pub layout: StepLayout,
    /// Episode length in control steps (the task's own, or `env.episode_length`).
    pub episode_length: u32,
}

/// Builds the run's environment once to learn its dimensions (and to fail early, with the
/// registry's list of names, on an unknown task).
pub fn task_info(config: &Config) -> anyhow::Result<TaskInfo> {
    let options = envs::EnvOptions {
        max_steps: config.env.episode_length,
    };
    let env = envs::make_with(&config.env.task, options)
        .with_context(|| format!("building task `{}`", config.env.task))?;
    let spec = env.spec();
    let dims = learner::setup::task_dims(spec);
    let layout = StepLayout::new(
        spec.obs_dim,
        spec.action_dim,
        spec.goal_dim,
        config.encoder.out_dim,
    )?;
    Ok(TaskInfo {
        dims,
        layout,
        episode_length: spec.max_steps,
    })
}

/// The process's iceoryx2 node, named after run and role.
pub fn node(ctx: &RunContext, role: &str) -> anyhow::Result<Node<Ipc>> {
    Ok(open_node(&ctx.run_id.node_name(role))?)
}

/// The stop reason of a caught SIGINT/SIGTERM.
const SIGNALLED: &str = "termination signal";

/// Installs iceoryx2's SIGINT/SIGTERM handlers now and says whether a termination signal has
/// arrived since (the check consumes it). iceoryx2 installs its handlers lazily, on a process's
/// first termination check (`Node::wait`), not when the node is created; until then SIGTERM has
/// its default action and ends the process at once, so no signal can come before the handlers
/// and be lost. The launcher calls this before it spawns anything, so that a signal while the
/// services start is caught and stops them in order; each child through [`StopWatch::new`]. A
/// SIGTERM before that (process start, the services' restore) ends a child at once, which
/// loses nothing: it has published nothing yet.
pub fn catch_termination_signals(node: &Node<Ipc>) -> bool {
    node.wait(Duration::ZERO).is_err()
}

/// A wait set for a process loop: it sleeps until one of the listeners it is given in
/// [`wake_on`] is notified, or its timeout passes.
pub fn wait_set() -> anyhow::Result<WaitSet<Ipc>> {
    WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| anyhow::anyhow!("creating a wait set: {e:?}"))
}

/// Attaches `listeners` to `waitset`; each stays attached while its guard lives.
pub fn wake_on<'w>(
    waitset: &'w WaitSet<Ipc>,
    listeners: &[&'w Listener<Ipc>],
) -> anyhow::Result<Vec<WaitSetGuard<'w, 'w, Ipc>>> {
    listeners
        .iter()
        .map(|listener| {
            waitset
                .attach_notification(*listener)
                .map_err(|e| anyhow::anyhow!("attaching a listener to the wait set: {e:?}"))
        })
        .collect()
}

/// Why a child loop should stop, checked once per iteration without blocking.
pub struct StopWatch {
    parent: u32,
    /// A signal seen while the handlers were installed, reported by the first check.
    pending: Option<&'static str>,
}

impl StopWatch {
    /// Installs iceoryx2's signal handlers now ([`catch_termination_signals`]): from here on a
    /// SIGTERM is caught and reported by [`StopWatch::should_stop`] instead of ending the
    /// process. Actors and the evaluator create it right after their node, before building
    /// their env and networks; the services only after their restore (a restore that hangs
    /// must still end on the launcher's SIGTERM).
    pub fn new(node: &Node<Ipc>) -> Self {
        Self {
            parent: std::os::unix::process::parent_id(),
            pending: catch_termination_signals(node).then_some(SIGNALLED),
        }
    }

    /// A termination signal arrived (iceoryx2's handler), or the launcher died (we were
    /// re-parented), in which case nobody would ever stop us.
    pub fn should_stop(&mut self, node: &Node<Ipc>) -> Option<&'static str> {
        if let Some(reason) = self.pending.take() {
            return Some(reason);
        }
        if node.wait(Duration::ZERO).is_err() {
            return Some(SIGNALLED);
        }
        if std::os::unix::process::parent_id() != self.parent {
            return Some("launcher exited");
        }
        None
    }
}

/// Publishes named values at most once per interval.
pub struct MetricsOut {
    publisher: ValuePublisher<MetricsSample>,
    role: ProcessRole,
    source_id: u32,
    interval: Duration,
    last: Option<Instant>,
    started: Instant,
}

impl MetricsOut {
    pub fn new(
        publisher: ValuePublisher<MetricsSample>,
        role: ProcessRole,
        source_id: u32,
        config: &Config,
    ) -> Self {
        Self {
            publisher,
            role,
            source_id,
            interval: Duration::from_secs_f64(config.run.metrics_interval_secs.min(1.0)),
            last: None,
            started: Instant::now(),
        }
    }

    /// Whether an interval has passed since the last publish.
    pub fn due(&self) -> bool {
        self.last.is_none_or(|t| t.elapsed() >= self.interval)
    }

    /// Sends every `(name, value)` now; a bad name or a full launcher buffer is logged, not fatal.
    pub fn publish(&mut self, env_step: u64, values: &[(String, f64)]) {
        let wall_ms = self.started.elapsed().as_millis() as u64;
        for (name, value) in values {
            let sent =
                MetricsSample::new(self.role, self.source_id, name, *value, env_step, wall_ms)
                    .map_err(anyhow::Error::from)
                    .and_then(|sample| self.publisher.send(sample).map_err(anyhow::Error::from));
            if let Err(err) = sent {
                tracing::warn!("metric `{name}` not sent: {err:#}");
            }
        }
        self.last = Some(Instant::now());
    }
}

/// The newest weights message waiting on `weights`, if any (older ones are superseded).
/// A receive failure is logged; the caller simply keeps its current weights.
pub fn newest_weights(
    weights: &crate::channels::WeightsSubscriber,
) -> Option<(protocol::WeightsHeader, Vec<u8>)> {
    let mut newest = None;
    if let Err(err) = weights.drain(|header, bytes| newest = Some((*header, bytes.to_vec()))) {
        tracing::warn!("receiving weights failed: {err:#}");
    }
    newest
}

/// The xy coverage of the training data (SPEC §7, digest §10): every achieved position of every
/// stored step, on the maze's 0.6 m coverage grid (`envs::Coverage`, cumulative, visited free
/// cells / free cells). Tasks without a maze have no coverage.
pub struct CoverageTracker {
    coverage: Option<envs::Coverage>,
    layout: StepLayout,
}

impl CoverageTracker {
    pub fn new(config: &Config, layout: StepLayout) -> anyhow::Result<Self> {
        let options = envs::EnvOptions {
            max_steps: config.env.episode_length,
        };
        let env = envs::make_with(&config.env.task, options)
            .with_context(|| format!("building task `{}`", config.env.task))?;
        Ok(Self {
            coverage: env.maze().map(envs::Coverage::new),
            layout,
        })
    }

    /// Counts the achieved xy of every record of an accepted chunk payload (records that do not
    /// decode were refused by the learner already and are skipped here).
    pub fn observe(&mut self, payload: &[f32]) {
        let Some(coverage) = self.coverage.as_mut() else {
            return;
        };
        let len = self.layout.record_len();
        if len == 0 || self.layout.goal_dim < 2 {
            return;
        }
        for record in payload.chunks_exact(len) {
            if let Ok(view) = self.layout.view(record) {
                coverage.visit([view.achieved_goal[0], view.achieved_goal[1]]);
            }
        }
    }

    /// The grid, if the task has a maze (serial-mode checkpoints save and restore it).
    pub fn grid_mut(&mut self) -> Option<&mut envs::Coverage> {
        self.coverage.as_mut()
    }

    /// Process mode: writes the grid beside the learner checkpoint at `checkpoint`
    /// (`checkpoints/ckpt-N` → `checkpoints/coverage/ckpt-N.json`, atomically) and removes
    /// the files of checkpoints no longer on disk. Nothing for tasks without a maze.
    pub fn save_beside(&self, checkpoint: &Path) -> anyhow::Result<()> {
        let Some(grid) = &self.coverage else {
            return Ok(());
        };
        let path = coverage_file(checkpoint)?;
        let dir = path.parent().context("a coverage file has a folder")?;
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let saved = serde_json::json!({"counts": grid.counts(), "n_outside": grid.n_outside()});
        crate::run::write_atomically(&path, &saved.to_string())?;
        let checkpoints = dir.parent().context("the coverage folder has a parent")?;
        for entry in std::fs::read_dir(dir)?.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let gone = name
                .strip_suffix(".json")
                .is_some_and(|ckpt| !checkpoints.join(ckpt).exists());
            if gone {
                let _ = std::fs::remove_file(entry.path());
            }
        }
        Ok(())
    }

    /// Process mode: restores the grid saved beside the learner checkpoint at `checkpoint`;
    /// true when it did or the task has no maze. False, the grid left empty, when there is no
    /// file (a checkpoint of a build before the grid was saved, or a stop between the two
    /// writes); a file that does not parse or does not fit the grid is an error naming it.
    pub fn restore_beside(&mut self, checkpoint: &Path) -> anyhow::Result<bool> {
        let Some(grid) = self.coverage.as_mut() else {
            return Ok(true);
        };
        let path = coverage_file(checkpoint)?;
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(err) => return Err(err).with_context(|| format!("reading {}", path.display())),
        };
        let saved: SavedCoverage = serde_json::from_str(&text)
            .with_context(|| format!("parsing the coverage grid {}", path.display()))?;
        grid.restore_counts(&saved.counts, saved.n_outside)
            .with_context(|| format!("restoring the coverage grid {}", path.display()))?;
        Ok(true)
    }

    /// `charts/coverage` and `charts/coverage_free_cells_visited`, if the task has a maze.
    pub fn metrics(&self) -> Vec<(String, f64)> {
        match &self.coverage {
            Some(c) => vec![
                ("charts/coverage".to_owned(), c.coverage()),
                (
                    "charts/coverage_free_cells_visited".to_owned(),
                    c.n_visited_free_cells() as f64,
                ),
            ],
            None => Vec::new(),
        }
    }
}

/// The coverage grid as [`CoverageTracker::save_beside`] writes it.
#[derive(serde::Deserialize)]
struct SavedCoverage {
    counts: Vec<u64>,
    n_outside: u64,
}

/// `checkpoints/coverage/ckpt-N.json` for the learner checkpoint `checkpoints/ckpt-N`.
fn coverage_file(checkpoint: &Path) -> anyhow::Result<PathBuf> {
    let (Some(dir), Some(name)) = (checkpoint.parent(), checkpoint.file_name()) else {
        anyhow::bail!("{} is not a checkpoint folder", checkpoint.display());
    };
    let mut file = name.to_os_string();
    file.push(".json");
    Ok(dir.join(COVERAGE_DIR).join(file))
}

/// Folder beside the learner's checkpoints with the coverage grid of each (process mode).
const COVERAGE_DIR: &str = "coverage";

/// The graph-service over iceoryx2, with the configured timeout. After a call that got no
/// answer (timeout, transport failure) the service counts as unreachable for one more timeout
/// period: requests in that time are answered "no answer" at once, so a dead or busy
/// graph-service costs its client (an actor, or the learner asking for self-imitation routes) at
/// most one timeout per period instead of one per request.
pub struct IpcGraph {
    client: GraphClient,
    timeout: Duration,
    unreachable_until: Option<Instant>,
    /// Calls that got no answer in time or failed in transport.
    pub n_unreachable: u64,
}

impl IpcGraph {
    pub fn new(client: GraphClient, timeout: Duration) -> Self {
        Self {
            client,
            timeout,
            unreachable_until: None,
            n_unreachable: 0,
        }
    }
}

impl GraphTransport for IpcGraph {
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String> {
        if let Some(until) = self.unreachable_until {
            if Instant::now() < until {
                return Err(
                    "graph-service unreachable (cooling down after a failed request)".to_owned(),
                );
            }
            self.unreachable_until = None;
        }
        self.client
            .call(*header, body, self.timeout)
            .map_err(|err| {
                self.n_unreachable += 1;
                self.unreachable_until = Some(Instant::now() + self.timeout);
                tracing::warn!(
                    "graph request failed; no graph requests for {:?}: {err:#}",
                    self.timeout
                );
                err.to_string()
            })
    }
}

/// A graph transport that remembers the φ version named by the last response header.
pub struct PhiTracking<T> {
    inner: T,
    last_phi: Option<PhiVersion>,
}

impl<T: GraphTransport> GraphTransport for PhiTracking<T> {
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String> {
        self.last_phi = None;
        let reply = self.inner.call(header, body)?;
        self.last_phi = Some(reply.0.phi_version);
        Ok(reply)
    }
}

/// The learner's self-imitation routes (SPEC §6.7) from the graph-service over any transport:
/// one batched `Routes` request through [`ServiceOracle::ask`] (shared encoding and status
/// handling). No answer (not ready, refused, timed out, wrong kind) is
/// [`RoutesReply::NoAnswer`]; an answer from a graph built with another φ version than the
/// learner's is [`RoutesReply::PhiMismatch`] (the points would not match).
pub struct GraphRoutes<T> {
    oracle: ServiceOracle<PhiTracking<T>>,
}

impl<T: GraphTransport> GraphRoutes<T> {
    pub fn new(transport: T) -> Self {
        Self {
            oracle: ServiceOracle::new(PhiTracking {
                inner: transport,
                last_phi: None,
            }),
        }
    }
}

impl<T: GraphTransport> RouteSource for GraphRoutes<T> {
    fn routes(&mut self, queries: &[RouteQuery], phi_version: PhiVersion) -> RoutesReply {
        let request = GraphRequest::Routes {
            queries: queries.to_vec(),
        };
        let answer = self.oracle.ask(&request, phi_version);
        match (answer, self.oracle.transport().last_phi) {
            (Some(GraphResponse::Routes(_)), Some(graph)) if graph != phi_version => {
                RoutesReply::PhiMismatch { graph }
            }
            (Some(GraphResponse::Routes(answers)), _) => RoutesReply::Answered(answers),
            (Some(other), _) => {
                tracing::warn!(answer = ?other, "unusable answer to a routes request");
                RoutesReply::NoAnswer
            }
            (None, _) => RoutesReply::NoAnswer,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_coverage_grid_saved_beside_a_checkpoint_restores_and_stale_files_go() {
        let dir = std::env::temp_dir().join(format!("asi-coverage-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (old, kept) = (dir.join("ckpt-000001"), dir.join("ckpt-000002"));
        std::fs::create_dir_all(&kept).unwrap();
        std::fs::create_dir_all(dir.join(COVERAGE_DIR)).unwrap();
        std::fs::write(coverage_file(&old).unwrap(), "{}").unwrap();
        let config = Config::default();
        let layout = task_info(&config).unwrap().layout;
        let fresh = || CoverageTracker::new(&config, layout).unwrap();
        let mut saved = fresh();
        let grid = saved.grid_mut().expect("the default task has a maze");
        for xy in [
            [0.0, 0.0],
            [0.1, 0.0],
            [4.0, 0.0],
            [8.0, 8.0],
            [500.0, 500.0],
        ] {
            grid.visit(xy);
        }
        let visited = saved.metrics();
        assert_eq!(visited[1].1, 3.0, "three free cells: {visited:?}");
        saved.save_beside(&kept).unwrap();
        assert_eq!(
            std::fs::read_dir(dir.join(COVERAGE_DIR)).unwrap().count(),
            1,
            "only the kept checkpoint's grid is left"
        );
        assert!(coverage_file(&kept).unwrap().exists());

        let mut restored = fresh();
        assert!(restored.restore_beside(&kept).unwrap());
        assert_eq!(restored.metrics(), visited);
        let (a, b) = (saved.grid_mut().unwrap(), restored.grid_mut().unwrap());
        assert_eq!((a.counts(), a.n_outside()), (b.counts(), b.n_outside()));
        assert_eq!(b.n_outside(), 1);

        // No file: false, nothing restored. A damaged one: an error naming it, nothing changed.
        let mut empty = fresh();
        assert!(!empty.restore_beside(&dir.join("ckpt-000003")).unwrap());
        assert_eq!(empty.metrics()[1].1, 0.0);
        std::fs::write(
            coverage_file(&kept).unwrap(),
            r#"{"counts": [1, 2], "n_outside": 0}"#,
        )
        .unwrap();
        let err = empty.restore_beside(&kept).unwrap_err();
        assert!(format!("{err:#}").contains("ckpt-000002.json"), "{err:#}");
        assert_eq!(empty.metrics()[1].1, 0.0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Set in the child process of [`a_sigterm_after_the_early_check_is_caught_not_fatal`].
    const CHILD_ENV: &str = "ASI_TEST_SIGNAL_CHILD";

    /// Runs in its own process (the parent test re-executes the test binary with only this
    /// test selected), since a signal handler is process-wide: raises SIGTERM after the early
    /// check and expects the next check to see it, then the same through [`StopWatch`].
    /// Without the early check the default action ends the process with the signal, which the
    /// parent test reports.
    #[test]
    #[ignore = "run by a_sigterm_after_the_early_check_is_caught_not_fatal in a child process"]
    fn signal_child() {
        if std::env::var_os(CHILD_ENV).is_none() {
            return;
        }
        let name = format!("asi-test-signal-{}", std::process::id());
        let node = open_node(&name).expect("node");
        assert!(!catch_termination_signals(&node), "no signal yet");
        // SAFETY: raising a signal in the own process; the handler installed above runs.
        assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
        assert!(node.wait(Duration::ZERO).is_err(), "the SIGTERM was seen");

        // A stop watch reports a signal at its next check, once.
        let mut stop = StopWatch::new(&node);
        assert_eq!(stop.should_stop(&node), None);
        // SAFETY: as above.
        assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
        assert_eq!(stop.should_stop(&node), Some(SIGNALLED));
        assert_eq!(stop.should_stop(&node), None, "reported once");
        // A signal that the watch's own installation consumed is kept for its first check.
        // SAFETY: as above.
        assert_eq!(unsafe { libc::raise(libc::SIGTERM) }, 0);
        let mut late = StopWatch::new(&node);
        assert_eq!(late.should_stop(&node), Some(SIGNALLED));
        assert_eq!(late.should_stop(&node), None, "reported once");
    }

    #[test]
    fn a_sigterm_after_the_early_check_is_caught_not_fatal() {
        let exe = std::env::current_exe().expect("test binary");
        let out = std::process::Command::new(exe)
            .args([
                "--exact",
                "proc::common::tests::signal_child",
                "--ignored",
                "--nocapture",
            ])
            .env(CHILD_ENV, "1")
            .output()
            .expect("run the child test");
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "child: {}\n{text}", out.status);
        assert!(text.contains("1 passed"), "the child test ran:\n{text}");
    }
}
