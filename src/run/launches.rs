//! The run folder's launch history, `run_dir/launches.jsonl`: every `asi train` on the folder
//! appends a `start` line before it trains (when, which build, on which machine, with which
//! command and resolved config, and the checkpoint it resumes from), a `resume` line once it
//! has restored that checkpoint (whether the resume is bit-exact, and why not), and an `end`
//! line when it ends (budget reached, stopped by a signal, or failed, with the newest
//! checkpoint). A launch without an `end` line was killed.
//!
//! Metrics say what a run did; this file says which launches, builds and resumes made them, so
//! that two runs of one seed that part can be told apart from the folder alone (a resume that
//! was not exact, another build, another CPU). A fork copied with `cp -a` keeps its prefix's
//! history, which is also its own. `--restart` moves the folder, history included, aside.
//!
//! The history is appended to, never rewritten. A line that cannot be parsed (a launch killed
//! while writing one) is skipped with a warning when launches are counted; [`read`] refuses it.

use std::io::Write;
use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::{ResumePoint, RunContext};

/// The history's file in the run folder.
pub const LAUNCHES_FILE: &str = "launches.jsonl";

/// One line of the history.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Record {
    Start(Box<Start>),
    Resume(Resume),
    End(End),
}

/// A launch begins (written before anything trains).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Start {
    /// 0 for the folder's first recorded launch, then one more per launch.
    pub launch: u64,
    /// UTC, to the second (`2026-12-05T05:14:04Z`).
    pub at: String,
    pub run_id: String,
    /// `serial` or `processes`.
    pub mode: String,
    /// The command line, program name first, and the folder it ran in.
    pub command: Vec<String>,
    pub cwd: String,
    /// The crate version of the binary.
    pub version: String,
    /// Checksum of the executable file (16 hex digits): equal for launches of the same build.
    pub binary: String,
    pub host: Host,
    pub seed: u64,
    /// Checksum of `config.resolved.toml` as this launch wrote it.
    pub config: String,
    /// The checkpoint this launch resumes from; `None`: it starts fresh.
    pub resumed_from: Option<Point>,
    /// A resume in a folder whose earlier launches are not recorded (they predate the
    /// history, or the file was removed).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub earlier_launches_unrecorded: bool,
}

/// The machine a launch ran on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Host {
    /// The CPU's model name (`/proc/cpuinfo`), `unknown` where there is none.
    pub cpu: String,
    /// Logical cores available to the process.
    pub logical_cores: usize,
    /// `RAYON_NUM_THREADS` as the launch ran (candle's matmul threads).
    pub rayon_threads: String,
}

/// A learner checkpoint: its sequence number and counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Point {
    /// N of `checkpoints/ckpt-N`.
    pub checkpoint: u64,
    pub env_steps: u64,
    /// Training episodes completed; `None` for checkpoints that do not record them.
    pub episodes: Option<u64>,
}

/// A resumed launch has restored its checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Resume {
    pub launch: u64,
    pub at: String,
    /// The run continues bit-identically to an uninterrupted one (serial mode only).
    pub exact: bool,
    /// Why it is or is not exact.
    pub detail: String,
}

/// A launch ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct End {
    pub launch: u64,
    pub at: String,
    pub outcome: Outcome,
    /// The error chain, when the launch failed.
    pub error: Option<String>,
    /// The newest learner checkpoint in the folder after the launch (where the next resumes).
    pub checkpoint: Option<Point>,
}

/// How a launch ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// `run.max_episodes` or `run.max_env_steps` reached.
    BudgetReached,
    /// SIGINT or SIGTERM: stopped with a checkpoint.
    Stopped,
    /// An error ended it (`error` says which).
    Failed,
}

/// How a launch trains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    Serial,
    Processes,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Serial => "serial",
            Mode::Processes => "processes",
        }
    }
}

/// Appends the `start` line of a new launch of `ctx`'s folder and returns its number.
pub fn begin(ctx: &RunContext, mode: Mode) -> anyhow::Result<u64> {
    let launch = count_starts(&ctx.run_dir)?;
    let resumed_from = ctx.resumed_from.map(point_of);
    let config_path = ctx.run_dir.join(protocol::config::RESOLVED_CONFIG_FILE);
    let config = std::fs::read(&config_path)
        .with_context(|| format!("reading {}", config_path.display()))?;
    let start = Start {
        launch,
        at: utc_now(),
        run_id: ctx.run_id.as_str().to_owned(),
        mode: mode.name().to_owned(),
        command: std::env::args().collect(),
        cwd: std::env::current_dir().map_or_else(|_| "unknown".into(), |d| d.display().to_string()),
        version: env!("CARGO_PKG_VERSION").to_owned(),
        binary: binary_checksum(),
        host: Host::this(),
        seed: ctx.config.run.seed,
        config: format!("{:016x}", ckpt::fingerprint(&config)),
        earlier_launches_unrecorded: launch == 0 && resumed_from.is_some(),
        resumed_from,
    };
    append(&ctx.run_dir, &Record::Start(Box::new(start)))?;
    Ok(launch)
}

/// Appends launch `launch`'s `resume` line: whether its resume is bit-exact, and why (not).
pub fn resumed(run_dir: &Path, launch: u64, exact: bool, detail: &str) -> anyhow::Result<()> {
    append(
        run_dir,
        &Record::Resume(Resume {
            launch,
            at: utc_now(),
            exact,
            detail: detail.to_owned(),
        }),
    )
}

/// Appends launch `launch`'s `end` line for how it ended (`Ok(true)`: stopped by a signal,
/// `Ok(false)`: budget reached), with the newest learner checkpoint in the folder.
pub fn end(run_dir: &Path, launch: u64, ending: &anyhow::Result<bool>) -> anyhow::Result<()> {
    let (outcome, error) = match ending {
        Ok(false) => (Outcome::BudgetReached, None),
        Ok(true) => (Outcome::Stopped, None),
        Err(err) => (Outcome::Failed, Some(format!("{err:#}"))),
    };
    let checkpoint = newest_checkpoint(run_dir);
    append(
        run_dir,
        &Record::End(End {
            launch,
            at: utc_now(),
            outcome,
            error,
            checkpoint,
        }),
    )
}

/// Every line of the folder's history, oldest first; an empty history when there is none.
/// A line that does not parse is an error naming it.
#[cfg(test)]
pub fn read(run_dir: &Path) -> anyhow::Result<Vec<Record>> {
    let path = run_dir.join(LAUNCHES_FILE);
    let file = match std::fs::File::open(&path) {
        Ok(file) => file,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(err) => return Err(err).with_context(|| format!("reading {}", path.display())),
    };
    use std::io::BufRead;
    let mut records = Vec::new();
    for (i, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.with_context(|| format!("reading {}", path.display()))?;
        let record = serde_json::from_str(&line)
            .with_context(|| format!("{} line {} is not a launch record", path.display(), i + 1))?;
        records.push(record);
    }
    Ok(records)
}

/// The number of `start` lines in the folder's history (unparsable lines are skipped, with a
/// warning: a launch killed mid-line must not stop the next).
fn count_starts(run_dir: &Path) -> anyhow::Result<u64> {
    let path = run_dir.join(LAUNCHES_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(err) => return Err(err).with_context(|| format!("reading {}", path.display())),
    };
    let mut starts = 0;
    for (i, line) in text.lines().enumerate() {
        match serde_json::from_str::<Record>(line) {
            Ok(Record::Start(_)) => starts += 1,
            Ok(_) => {}
            Err(err) => tracing::warn!(
                "{} line {} is not a launch record ({err}); skipped",
                path.display(),
                i + 1
            ),
        }
    }
    Ok(starts)
}

fn append(run_dir: &Path, record: &Record) -> anyhow::Result<()> {
    let path = run_dir.join(LAUNCHES_FILE);
    let mut line = serde_json::to_string(record)?;
    line.push('\n');
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    file.write_all(line.as_bytes())
        .and_then(|()| file.sync_data())
        .with_context(|| format!("writing {}", path.display()))
}

fn point_of(resume: ResumePoint) -> Point {
    Point {
        checkpoint: resume.sequence.unwrap_or(0),
        env_steps: resume.env_steps,
        episodes: resume.episodes,
    }
}

/// The newest learner checkpoint's counters; `None` when there is none or it does not read.
fn newest_checkpoint(run_dir: &Path) -> Option<Point> {
    use learner::learner::checkpoint::{latest_checkpoint, Manifest, MANIFEST};
    let path = latest_checkpoint(&run_dir.join(super::CHECKPOINT_DIR)).ok()??;
    let text = std::fs::read(path.join(MANIFEST)).ok()?;
    let manifest: Manifest = serde_json::from_slice(&text).ok()?;
    Some(Point {
        checkpoint: manifest.sequence,
        env_steps: manifest.env_steps,
        episodes: manifest.episodes_completed,
    })
}

impl Host {
    fn this() -> Host {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|text| cpu_model(&text))
            .unwrap_or_else(|| "unknown".to_owned());
        Host {
            cpu,
            logical_cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            rayon_threads: std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into()),
        }
    }
}

/// The first `model name` of a `/proc/cpuinfo` text.
fn cpu_model(cpuinfo: &str) -> Option<String> {
    cpuinfo.lines().find_map(|line| {
        let (key, value) = line.split_once(':')?;
        (key.trim() == "model name").then(|| value.trim().to_owned())
    })
}

/// Checksum of this executable's file, 16 hex digits; `unknown` when it cannot be read.
fn binary_checksum() -> String {
    std::env::current_exe().and_then(std::fs::read).map_or_else(
        |_| "unknown".to_owned(),
        |bytes| format!("{:016x}", ckpt::fingerprint(&bytes)),
    )
}

fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    utc(secs)
}

/// `YYYY-MM-DDThh:mm:ssZ` of a Unix time (proleptic Gregorian calendar, from the day count by
/// 400-year eras of 146,097 days, each year taken to start on 1 March so that the leap day
/// ends it).
fn utc(unix_secs: u64) -> String {
    let days = unix_secs / 86_400;
    let secs = unix_secs % 86_400;
    // Days since 0000-03-01; 1970-01-01 is day 719,468.
    let z = days + 719_468;
    let era = z / 146_097;
    let day_of_era = z % 146_097;
    let year_of_era =
        (day_of_era - day_of_era / 1_460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let month_from_march = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * month_from_march + 2) / 5 + 1;
    let month = if month_from_march < 10 {
        month_from_march + 3
    } else {
        month_from_march - 9
    };
    let year = year_of_era + era * 400 + u64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        secs / 3_600,
        secs % 3_600 / 60,
        secs % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_matches_dates_computed_by_python_datetime() {
        // datetime.fromtimestamp(s, timezone.utc) for each s.
        let cases = [
            (0, "1970-01-01T00:00:00Z"),
            (951_782_399, "2000-02-28T23:59:59Z"),
            (951_782_400, "2000-02-29T00:00:00Z"),
            (951_868_800, "2000-03-01T00:00:00Z"),
            (4_107_542_400, "2100-03-01T00:00:00Z"),
            (4_107_456_000, "2100-02-28T00:00:00Z"),
            (1_796_447_644, "2026-12-05T05:14:04Z"),
            (1_798_761_599, "2026-12-31T23:59:59Z"),
        ];
        for (secs, expected) in cases {
            assert_eq!(utc(secs), expected, "{secs}");
        }
    }

    #[test]
    fn the_cpu_model_is_the_first_model_name_line() {
        let cpuinfo = "processor\t: 0\nvendor_id\t: GenuineIntel\nmodel\t\t: 143\n\
                       model name\t: Intel(R) Xeon(R) Platinum 8480C\nflags\t: fpu\n\n\
                       processor\t: 1\nmodel name\t: Other\n";
        assert_eq!(
            cpu_model(cpuinfo).as_deref(),
            Some("Intel(R) Xeon(R) Platinum 8480C")
        );
        assert_eq!(cpu_model("processor : 0\n"), None);
    }

    #[test]
    fn records_round_trip_and_read_refuses_a_broken_line_that_counting_skips() {
        let dir = std::env::temp_dir().join(format!(
            "asi-launches-{}-{}",
            std::process::id(),
            rand::random::<u32>()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(read(&dir).unwrap().is_empty());
        assert_eq!(count_starts(&dir).unwrap(), 0);
        let start = Start {
            launch: 0,
            at: utc(1_796_447_644),
            run_id: "r-1".into(),
            mode: "serial".into(),
            command: vec!["asi".into(), "train".into()],
            cwd: "/work".into(),
            version: "0.1.0".into(),
            binary: "00ff".into(),
            host: Host {
                cpu: "cpu".into(),
                logical_cores: 2,
                rayon_threads: "1".into(),
            },
            seed: 3,
            config: "abcd".into(),
            resumed_from: Some(Point {
                checkpoint: 4,
                env_steps: 100,
                episodes: None,
            }),
            earlier_launches_unrecorded: true,
        };
        let records = vec![
            Record::Start(Box::new(start.clone())),
            Record::Resume(Resume {
                launch: 0,
                at: utc(1),
                exact: false,
                detail: "2 open episodes are lost".into(),
            }),
            Record::End(End {
                launch: 0,
                at: utc(2),
                outcome: Outcome::Stopped,
                error: None,
                checkpoint: None,
            }),
            Record::Start(Box::new(Start {
                launch: 1,
                resumed_from: None,
                earlier_launches_unrecorded: false,
                ..start
            })),
        ];
        for record in &records {
            append(&dir, record).unwrap();
        }
        assert_eq!(read(&dir).unwrap(), records);
        let text = std::fs::read_to_string(dir.join(LAUNCHES_FILE)).unwrap();
        assert!(text
            .lines()
            .next()
            .unwrap()
            .starts_with(r#"{"event":"start","launch":0,"#));
        assert!(
            text.lines()
                .nth(2)
                .unwrap()
                .contains(r#""outcome":"stopped""#),
            "{text}"
        );
        assert!(
            !text
                .lines()
                .nth(3)
                .unwrap()
                .contains("earlier_launches_unrecorded"),
            "left out when false: {text}"
        );
        assert_eq!(count_starts(&dir).unwrap(), 2);
        // A launch killed mid-line.
        std::fs::write(dir.join(LAUNCHES_FILE), format!("{text}{{\"event\":\"sta")).unwrap();
        assert_eq!(count_starts(&dir).unwrap(), 2);
        let err = read(&dir).unwrap_err();
        assert!(
            format!("{err:#}").contains("line 5 is not a launch record"),
            "{err:#}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
