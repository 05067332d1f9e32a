//! The run context every process shares: the resolved config, the run folder and the run id.
//!
//! The launcher resolves the config once (defaults < TOML < `--set`), writes it to
//! `run_dir/config.resolved.toml` together with the run id, and passes `--run-dir` and
//! `--run-id` to each child, which reads the same file back. A child started with another run's
//! id, or a resolved file of another protocol version, is refused.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use protocol::config::RESOLVED_CONFIG_FILE;
use protocol::{Config, RunId};

/// File in the run folder holding the current run id (read by `asi graph` and tests).
pub const RUN_ID_FILE: &str = "run_id";
/// Folder in the run folder where each process writes its final status at a clean exit.
pub const STATUS_DIR: &str = "status";

#[derive(Debug, Clone)]
pub struct RunContext {
    pub config: Config,
    pub run_dir: PathBuf,
    pub run_id: RunId,
}

impl RunContext {
    /// Launcher side: creates the run folder, writes the resolved config and a fresh run id.
    pub fn create(config: Config, run_dir: PathBuf) -> anyhow::Result<Self> {
        std::fs::create_dir_all(run_dir.join(STATUS_DIR))
            .with_context(|| format!("creating run folder {}", run_dir.display()))?;
        let run_id = fresh_run_id(&config.run.name)?;
        write_atomically(&run_dir.join(RESOLVED_CONFIG_FILE), &config.to_resolved_toml()?)?;
        write_atomically(&run_dir.join(RUN_ID_FILE), run_id.as_str())?;
        Ok(Self { config, run_dir, run_id })
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
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let config = Config::from_toml_str(&text, &path.display().to_string())?;
        Ok(Self { config, run_dir: run_dir.to_owned(), run_id: current })
    }

    /// Path of a process's final status file.
    pub fn status_path(&self, process: &str) -> PathBuf {
        self.run_dir.join(STATUS_DIR).join(format!("{process}.json"))
    }

    /// Marks a service process as ready (its subscribers exist), so the launcher can start
    /// actors without losing their first chunks.
    pub fn mark_ready(&self, process: &str) -> anyhow::Result<()> {
        write_atomically(&self.run_dir.join(STATUS_DIR).join(format!("{process}.ready")), "")
    }

    /// Whether a service process has marked itself ready.
    pub fn is_ready(&self, process: &str) -> bool {
        self.run_dir.join(STATUS_DIR).join(format!("{process}.ready")).exists()
    }

    /// Writes a process's final status (JSON) atomically.
    pub fn write_status(&self, process: &str, status: &serde_json::Value) -> anyhow::Result<()> {
        write_atomically(&self.status_path(process), &serde_json::to_string_pretty(status)?)
    }
}

/// Reads the run id stored in a run folder.
pub fn read_run_id(run_dir: &Path) -> anyhow::Result<RunId> {
    let path = run_dir.join(RUN_ID_FILE);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {} (is this a run folder of `asi train`?)", path.display()))?;
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
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}
