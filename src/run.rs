//! The run context every process shares: the resolved config, the run folder and the run id.
//!
//! The launcher resolves the config once (defaults < TOML < `--set`), writes it to
//! `run_dir/config.resolved.toml` together with the run id, and passes `--run-dir` and
//! `--run-id` to each child, which reads the same file back. A child started with another run's
//! id, or a resolved file of another protocol version, is refused.
//!
//! Checkpoints: the learner writes them to `run_dir/checkpoints/` ([`CHECKPOINT_DIR`]) every
//! `run.checkpoint_interval_mins` and at a clean stop ([`CheckpointTimer`]), and starts from the
//! newest one when there is one ([`open_learner`]); see `learner::learner::checkpoint`.
//!
//! One launch per folder: the launcher holds an exclusive lock on `run_dir/run.lock`
//! ([`RunLock`]) for as long as it runs, so a second `asi train` on the same folder stops with
//! an error instead of writing into the first one's files.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use learner::learner::checkpoint::{Checkpoint, CheckpointError};
use learner::{Learner, TaskDims};
use protocol::config::RESOLVED_CONFIG_FILE;
use protocol::{Config, RunId};

pub mod launches;
mod tail;

pub use tail::{move_lines_past, move_metrics_past, MovedTail, ResumePoint};

/// File in the run folder holding the current run id (read by `asi graph` and tests).
pub const RUN_ID_FILE: &str = "run_id";
/// Folder in the run folder where each process writes its final status at a clean exit.
pub const STATUS_DIR: &str = "status";
/// Folder in the run folder holding the learner's checkpoints (`ckpt-NNNNNN/`, newest two).
pub const CHECKPOINT_DIR: &str = "checkpoints";
/// File in the run folder the launcher locks ([`RunLock`]); it holds the launcher's pid.
pub const LOCK_FILE: &str = "run.lock";

#[derive(Debug, Clone)]
pub struct RunContext {
    pub config: Config,
    pub run_dir: PathBuf,
    pub run_id: RunId,
    /// Launcher side: this launch resumes from a checkpoint (outputs are appended to).
    pub resume: bool,
    /// Launcher side: the checkpoint it resumes from.
    pub resumed_from: Option<ResumePoint>,
    /// Launcher side: this launch's number in the folder's history
    /// ([`launches::LAUNCHES_FILE`]), once its `start` line is written.
    pub launch: Option<u64>,
    /// Launcher side: the folder's lock, held while any clone of the context lives.
    pub(crate) _lock: Option<std::sync::Arc<RunLock>>,
}

impl RunContext {
    /// Launcher side: creates the run folder, writes the resolved config and a fresh run id,
    /// and clears the status files of an earlier launch in the same folder; `resumed_from` is
    /// the checkpoint this launch continues from, if any; `lock` is the folder's, held from
    /// before the resume decision.
    pub fn create(
        config: Config,
        run_dir: PathBuf,
        resumed_from: Option<ResumePoint>,
        lock: RunLock,
    ) -> anyhow::Result<Self> {
        let status = run_dir.join(STATUS_DIR);
        if status.exists() {
            std::fs::remove_dir_all(&status)
                .with_context(|| format!("clearing {}", status.display()))?;
        }
        std::fs::create_dir_all(&status)
            .with_context(|| format!("creating run folder {}", run_dir.display()))?;
        let run_id = fresh_run_id(&config.run.name)?;
        write_atomically(
            &run_dir.join(RESOLVED_CONFIG_FILE),
            &config.to_resolved_toml()?,
        )?;
        write_atomically(&run_dir.join(RUN_ID_FILE), run_id.as_str())?;
        Ok(Self {
            config,
            run_dir,
            run_id,
            resume: resumed_from.is_some(),
            resumed_from,
            launch: None,
            _lock: Some(std::sync::Arc::new(lock)),
        })
    }

    /// Child side: reads the resolved config and checks that `run_id` is this folder's run.
    pub fn open(run_dir: &Path, run_id: &str) -> anyhow::Result<Self> {
        let current = read_run_id(run_dir)?;
        if current.as_str() != run_id {
            bail!(
                "run id mismatch: this process was started for run `{run_id}`, but {} belongs to run `{current}`",
                run_dir.display()
            );
        }
        let path = run_dir.join(RESOLVED_CONFIG_FILE);
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        let config = Config::from_toml_str(&text, &path.display().to_string())?;
        Ok(Self {
            config,
            run_dir: run_dir.to_owned(),
            run_id: current,
            resume: false,
            resumed_from: None,
            launch: None,
            _lock: None,
        })
    }

    /// The run's checkpoint folder.
    pub fn checkpoint_dir(&self) -> PathBuf {
        self.run_dir.join(CHECKPOINT_DIR)
    }

    /// Path of a process's final status file.
    pub fn status_path(&self, process: &str) -> PathBuf {
        self.run_dir
            .join(STATUS_DIR)
            .join(format!("{process}.json"))
    }

    /// Marks a service process as ready (its subscribers exist), so the launcher can start
    /// actors without losing their first chunks.
    pub fn mark_ready(&self, process: &str) -> anyhow::Result<()> {
        write_atomically(
            &self
                .run_dir
                .join(STATUS_DIR)
                .join(format!("{process}.ready")),
            "",
        )
    }

    /// Whether a service process has marked itself ready.
    pub fn is_ready(&self, process: &str) -> bool {
        self.run_dir
            .join(STATUS_DIR)
            .join(format!("{process}.ready"))
            .exists()
    }

    /// Writes a process's final status (JSON) atomically.
    pub fn write_status(&self, process: &str, status: &serde_json::Value) -> anyhow::Result<()> {
        write_atomically(
            &self.status_path(process),
            &serde_json::to_string_pretty(status)?,
        )
    }
}

/// An exclusive lock on a run folder's [`LOCK_FILE`], released when dropped (or when the
/// process dies: the kernel drops it with the file descriptor).
#[derive(Debug)]
pub struct RunLock {
    _file: std::fs::File,
}

impl RunLock {
    /// Creates `run_dir` if needed and locks it; an error names the pid of the launch that
    /// holds it.
    pub fn acquire(run_dir: &Path) -> anyhow::Result<Self> {
        use std::io::{Read, Seek, Write};
        std::fs::create_dir_all(run_dir)
            .with_context(|| format!("creating run folder {}", run_dir.display()))?;
        let path = run_dir.join(LOCK_FILE);
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let mut holder = String::new();
                let _ = file.read_to_string(&mut holder);
                bail!(
                    "run folder {} is in use by another `asi train` (pid {}, in {}); stop that \
                     run first, or choose another --run-dir",
                    run_dir.display(),
                    holder.trim(),
                    path.display()
                );
            }
            Err(std::fs::TryLockError::Error(err)) => {
                return Err(err).with_context(|| format!("locking {}", path.display()))
            }
        }
        file.set_len(0)
            .and_then(|()| file.rewind())
            .and_then(|()| writeln!(file, "{}", std::process::id()))
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(Self { _file: file })
    }
}

/// What an earlier launch left in `run_dir` besides the files every launch rewrites (resolved
/// config, run id, status, lock) and the launch history (appended to by every launch): the
/// names of non-empty files and folders, sorted. Empty when the folder does not exist.
pub fn earlier_outputs(run_dir: &Path) -> anyhow::Result<Vec<String>> {
    let entries = match std::fs::read_dir(run_dir) {
        Ok(entries) => entries,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(err) => return Err(err).with_context(|| format!("reading {}", run_dir.display())),
    };
    let rewritten = [
        RESOLVED_CONFIG_FILE,
        RUN_ID_FILE,
        STATUS_DIR,
        LOCK_FILE,
        launches::LAUNCHES_FILE,
    ];
    let mut found = Vec::new();
    for entry in entries {
        let entry = entry.with_context(|| format!("reading {}", run_dir.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if rewritten.contains(&name.as_str()) {
            continue;
        }
        let path = entry.path();
        let non_empty = if path.is_dir() {
            std::fs::read_dir(&path).is_ok_and(|mut d| d.next().is_some())
        } else {
            entry.metadata().is_ok_and(|m| m.len() > 0)
        };
        if non_empty {
            found.push(name);
        }
    }
    found.sort();
    Ok(found)
}

/// Reads the run id stored in a run folder.
pub fn read_run_id(run_dir: &Path) -> anyhow::Result<RunId> {
    let path = run_dir.join(RUN_ID_FILE);
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "reading {} (is this a run folder of `asi train`?)",
            path.display()
        )
    })?;
    Ok(RunId::new(text.trim())?)
}

/// `<name>-<8 hex digits>`: unique per launch, so two launches never share services.
fn fresh_run_id(name: &str) -> anyhow::Result<RunId> {
    let suffix: u32 = rand::random();
    let mut base = name.to_owned();
    base.truncate(protocol::services::MAX_RUN_ID_LEN - 9);
    Ok(RunId::new(&format!("{base}-{suffix:08x}"))?)
}

/// Writes `text` to a temporary file beside `path`, then renames it over `path`.
pub fn write_atomically(path: &Path, text: &str) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// The run's learner: restored from the newest checkpoint in `checkpoints/` when there is one
/// (an incompatible or damaged one is an error, never silently replaced), else a new one
/// seeded with `run.seed`; with the folder of the checkpoint it was restored from.
pub fn open_learner(
    ctx: &RunContext,
    dims: TaskDims,
    episode_length: u32,
) -> anyhow::Result<(Learner, Option<PathBuf>)> {
    let dir = ctx.checkpoint_dir();
    let start = Instant::now();
    let restored = Learner::restore_latest(&ctx.config, dims, &dir).with_context(|| {
        format!(
            "restoring the learner from {} (start over with `asi train --restart`)",
            dir.display()
        )
    })?;
    match restored {
        Some((learner, ckpt)) => {
            let m = &ckpt.manifest;
            tracing::info!(
                checkpoint = m.sequence,
                env_steps = m.env_steps,
                updates_low = m.updates_low,
                secs = start.elapsed().as_secs_f64(),
                "learner resumed from {}",
                ckpt.path.display()
            );
            Ok((learner, Some(ckpt.path)))
        }
        None => {
            Learner::with_episode_length(&ctx.config, dims, episode_length, ctx.config.run.seed)
                .context("building the learner")
                .map(|learner| (learner, None))
        }
    }
}

/// When the learner writes checkpoints: every `run.checkpoint_interval_mins`, retried at each
/// tick while a φ round defers it, and once more at a clean stop.
pub struct CheckpointTimer {
    interval: Duration,
    last: Instant,
}

impl CheckpointTimer {
    /// A timer for `config`'s interval, starting now.
    pub fn new(config: &Config) -> Self {
        Self {
            interval: Duration::from_secs_f64(config.run.checkpoint_interval_mins * 60.0),
            last: Instant::now(),
        }
    }

    /// Whether the interval has passed since the last checkpoint (or failed attempt).
    pub fn is_due(&self) -> bool {
        self.last.elapsed() >= self.interval
    }

    /// Writes a checkpoint if one is due and no φ round runs; a failed write is logged and
    /// retried at the next interval (training goes on). The checkpoint, when one was written.
    pub fn tick(&mut self, ctx: &RunContext, learner: &Learner) -> Option<Checkpoint> {
        if !self.is_due() {
            return None;
        }
        match save_checkpoint(ctx, learner) {
            Ok(Some(ckpt)) => {
                self.last = Instant::now();
                Some(ckpt)
            }
            Ok(None) => None,
            Err(err) => {
                tracing::error!("writing a checkpoint failed: {err:#}");
                self.last = Instant::now();
                None
            }
        }
    }
}

/// A checkpoint at a clean stop: a running φ round is first run to its end (its state is not
/// saved), then the checkpoint is written — unless the newest checkpoint on disk already holds
/// this state (nothing ingested, no update since it was written or restored: a launch stopped
/// before it trained, or a finished run launched again), which is logged and `None`: rewriting
/// it would only push an older, different checkpoint out of the two kept.
pub fn final_checkpoint(
    ctx: &RunContext,
    learner: &mut Learner,
) -> anyhow::Result<Option<Checkpoint>> {
    learner
        .finish_phi_round()
        .context("finishing the φ round before the final checkpoint")?;
    if let Some(sequence) = unchanged_since_newest(ctx, learner) {
        tracing::info!(
            checkpoint = sequence,
            "no final checkpoint: nothing was ingested or trained since checkpoint {sequence}"
        );
        return Ok(None);
    }
    save_checkpoint(ctx, learner)?
        .context("a φ round is still running after it was finished")
        .map(Some)
}

/// The sequence number of the newest checkpoint in the run folder when its counters (env steps
/// ingested, low and high updates) equal the learner's; `None` otherwise or when there is none
/// or it cannot be read (then a new one is written).
fn unchanged_since_newest(ctx: &RunContext, learner: &Learner) -> Option<u64> {
    let path = learner::learner::checkpoint::latest_checkpoint(&ctx.checkpoint_dir()).ok()??;
    let manifest: learner::learner::checkpoint::Manifest =
        ckpt::read_manifest(&path, learner::learner::checkpoint::MANIFEST).ok()?;
    let now = learner.progress();
    (manifest.env_steps == now.env_steps_ingested
        && manifest.updates_low == now.updates_low
        && manifest.updates_high == now.updates_high)
        .then_some(manifest.sequence)
}

/// Writes a checkpoint and logs its size and write time; `None` when a φ round defers it.
fn save_checkpoint(ctx: &RunContext, learner: &Learner) -> anyhow::Result<Option<Checkpoint>> {
    let start = Instant::now();
    match learner.save_checkpoint(&ctx.config, &ctx.checkpoint_dir()) {
        Ok(ckpt) => {
            let m = &ckpt.manifest;
            tracing::info!(
                checkpoint = m.sequence,
                env_steps = m.env_steps,
                mib = m.total_bytes() as f64 / (1 << 20) as f64,
                secs = start.elapsed().as_secs_f64(),
                "checkpoint written to {}",
                ckpt.path.display()
            );
            Ok(Some(ckpt))
        }
        Err(CheckpointError::RoundActive) => Ok(None),
        Err(err) => Err(err).context("writing a checkpoint"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("asi-run-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_locked_run_folder_refuses_a_second_lock_naming_the_holder_until_the_first_is_dropped() {
        let dir = temp_dir("lock");
        let first = RunLock::acquire(&dir).unwrap();
        let pid = std::process::id().to_string();
        assert_eq!(
            std::fs::read_to_string(dir.join(LOCK_FILE)).unwrap().trim(),
            pid
        );
        // flock locks belong to the open file, so a second open in this process conflicts too.
        let err = RunLock::acquire(&dir).unwrap_err().to_string();
        assert!(err.contains("in use by another `asi train`"), "{err}");
        assert!(err.contains(&format!("pid {pid}")), "{err}");
        drop(first);
        let _again = RunLock::acquire(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn earlier_outputs_are_the_non_empty_entries_besides_the_files_every_launch_rewrites() {
        let dir = temp_dir("outputs");
        assert!(earlier_outputs(&dir).unwrap().is_empty(), "no folder");
        std::fs::create_dir_all(dir.join(STATUS_DIR)).unwrap();
        std::fs::write(dir.join(STATUS_DIR).join("learner.json"), "{}").unwrap();
        std::fs::write(dir.join(RESOLVED_CONFIG_FILE), "[run]").unwrap();
        std::fs::write(dir.join(RUN_ID_FILE), "r-1").unwrap();
        std::fs::write(dir.join(LOCK_FILE), "1").unwrap();
        std::fs::write(dir.join(launches::LAUNCHES_FILE), "{}\n").unwrap();
        std::fs::write(dir.join("metrics.jsonl"), "").unwrap();
        std::fs::create_dir_all(dir.join("plots")).unwrap();
        assert!(
            earlier_outputs(&dir).unwrap().is_empty(),
            "only rewritten files, the history, an empty file and an empty folder"
        );
        std::fs::write(dir.join("metrics.jsonl"), "{}\n").unwrap();
        std::fs::create_dir_all(dir.join("checkpoints/graph-service")).unwrap();
        assert_eq!(
            earlier_outputs(&dir).unwrap(),
            ["checkpoints", "metrics.jsonl"]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
