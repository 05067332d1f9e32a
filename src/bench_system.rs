//! `asi bench system`: how many actors the machine can feed. For each actor count, a real
//! `asi train` (separate processes, iceoryx2) runs on a copy of the smoke config in a temporary
//! run folder; after a warm-up, the run's own `metrics.jsonl` gives env steps/s, learner
//! updates/s and policy lag over `--seconds` of steady state, and `/proc` gives the CPU time
//! its processes used. Each run is stopped with SIGTERM (the launcher's clean shutdown) and
//! must leave no iceoryx2 service behind.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use serde_json::Value;

use super::{services_containing, Table};
use crate::cli::BenchSystemArgs;

/// The default config of the runs (PointMaze-U with tiny networks and frequent metrics).
const SMOKE_CONFIG: &str = include_str!("../configs/smoke.toml");
/// Largest actor count accepted on the command line.
pub const MAX_ACTORS: usize = 64;
/// Longest accepted `--seconds` or `--warmup-secs`.
const MAX_SECONDS: f64 = 3600.0;
/// How long a run may take until its learner has ingested data (a loaded 2-core machine).
const STARTUP_TIMEOUT: Duration = Duration::from_secs(300);
/// How long the launcher may take to stop everything after SIGTERM.
const STOP_TIMEOUT: Duration = Duration::from_secs(120);
/// How often the bench looks at the run while waiting.
const POLL: Duration = Duration::from_millis(200);
/// Episode budget that no measured run reaches (the bench stops runs itself).
const UNREACHED_EPISODES: u64 = 1_000_000_000;

/// The actor counts to measure, in the order given.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ActorCounts(pub Vec<usize>);

/// Parses `--actors`: comma-separated counts in 1–[`MAX_ACTORS`], no repeats, e.g. `1,2,4`.
pub fn parse_actor_counts(text: &str) -> Result<ActorCounts, String> {
    let mut counts = Vec::new();
    for part in text.split(',') {
        let part = part.trim();
        let n: usize = part.parse().map_err(|_| {
            format!("`{part}` is not a whole number of actors (expected e.g. 1,2,4)")
        })?;
        if !(1..=MAX_ACTORS).contains(&n) {
            return Err(format!("{n} actors is outside 1–{MAX_ACTORS}"));
        }
        if counts.contains(&n) {
            return Err(format!("{n} actors is listed twice"));
        }
        counts.push(n);
    }
    Ok(ActorCounts(counts))
}

/// What one run measured over its steady-state window.
#[derive(Debug, Clone, PartialEq)]
pub struct SystemRow {
    /// Actor processes.
    pub actors: usize,
    /// Env steps ingested by the learner per second.
    pub env_steps_per_sec: f64,
    /// Low + high gradient updates per second.
    pub updates_per_sec: f64,
    /// Mean of `learner/charts/policy_lag` over the window's metrics lines (versions).
    pub policy_lag_mean: f64,
    /// `learner/charts/policy_lag_max` at the end of the window.
    pub policy_lag_max: f64,
    /// CPU seconds used by the launcher and its children per wall second.
    pub cpu_cores: f64,
}

/// The result table, one row per actor count.
pub fn table(rows: &[SystemRow]) -> Table {
    let mut table = Table::new(&[
        "actors",
        "env steps/s",
        "updates/s",
        "policy lag (mean)",
        "policy lag (max)",
        "CPU cores",
    ]);
    for r in rows {
        table.push(&[
            r.actors.to_string(),
            format!("{:.0}", r.env_steps_per_sec),
            format!("{:.1}", r.updates_per_sec),
            format!("{:.2}", r.policy_lag_mean),
            format!("{:.0}", r.policy_lag_max),
            format!("{:.2}", r.cpu_cores),
        ]);
    }
    table
}

pub fn run(args: &BenchSystemArgs) -> anyhow::Result<()> {
    for (flag, value) in [
        ("--seconds", args.seconds),
        ("--warmup-secs", args.warmup_secs),
    ] {
        ensure!(
            value.is_finite() && (0.0..=MAX_SECONDS).contains(&value),
            "{flag} must be in [0, {MAX_SECONDS}], got {value}"
        );
    }
    ensure!(args.seconds > 0.0, "--seconds must be positive");
    let config_text = match &args.config {
        Some(path) => {
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?
        }
        None => SMOKE_CONFIG.to_owned(),
    };
    let origin = args
        .config
        .as_ref()
        .map_or("the embedded configs/smoke.toml".to_owned(), |p| {
            p.display().to_string()
        });
    protocol::Config::from_toml_str(&config_text, &origin)?;
    let mut rows = Vec::new();
    for (i, &actors) in args.actors.0.iter().enumerate() {
        eprintln!(
            "[{}/{}] asi train with {actors} actor(s) ({origin}) …",
            i + 1,
            args.actors.0.len()
        );
        let row = measure(args, &config_text, actors)
            .with_context(|| format!("the run with {actors} actor(s)"))?;
        eprintln!(
            "      {:.0} env steps/s, {:.1} updates/s",
            row.env_steps_per_sec, row.updates_per_sec
        );
        rows.push(row);
    }
    println!("config: {origin}");
    println!("seconds_per_run: {}", args.seconds);
    print!("{}", table(&rows).render());
    for r in &rows {
        let a = r.actors;
        println!("actors_{a}_env_steps_per_sec: {:.0}", r.env_steps_per_sec);
        println!("actors_{a}_updates_per_sec: {:.1}", r.updates_per_sec);
        println!("actors_{a}_policy_lag_mean: {:.2}", r.policy_lag_mean);
        println!("actors_{a}_cpu_cores: {:.2}", r.cpu_cores);
    }
    Ok(())
}

/// One run: start, warm up, measure, stop cleanly, check for leftovers.
fn measure(args: &BenchSystemArgs, config_text: &str, actors: usize) -> anyhow::Result<SystemRow> {
    let mut run = TrainRun::start(config_text, actors)?;
    run.wait_for(
        "steady state (data ingested, and no more of it than the throttle's budget)",
        STARTUP_TIMEOUT,
        |dir| latest_metrics(dir).is_some_and(|m| in_steady_state(&m)),
    )?;
    run.sleep(Duration::from_secs_f64(args.warmup_secs))?;
    let start = Snapshot::take(&run)?;
    run.sleep(Duration::from_secs_f64(args.seconds))?;
    let end = Snapshot::take(&run)?;
    run.stop()?;
    let leftovers = services_containing(&run.run_id()?);
    ensure!(
        leftovers.is_empty(),
        "iceoryx2 services left behind: {}",
        leftovers.join(", ")
    );
    let row = summarise(
        actors,
        &start,
        &end,
        &window_lines(&run.run_dir(), start.wall_secs, end.wall_secs),
    );
    run.remove();
    Ok(row)
}

const ENV_STEPS: &str = "learner/ingest/env_steps";
const UPDATES_LOW: &str = "learner/charts/updates_low";
const UPDATES_HIGH: &str = "learner/charts/updates_high";
const ENV_STEP_BUDGET: &str = "learner/charts/env_step_budget";
const POLICY_LAG: &str = "learner/charts/policy_lag";
const POLICY_LAG_MAX: &str = "learner/charts/policy_lag_max";

/// Whether the run is past its start-up: the learner has data, and has trained enough that
/// the throttle lets actors send (ingested env steps within the budget, SPEC §6.8). Before
/// that, actors that all started at once may have sent several times the slack and then wait
/// (tens of seconds with 4 actors on the smoke config), which is not the steady state.
fn in_steady_state(metrics: &Value) -> bool {
    let steps = number(metrics, ENV_STEPS);
    steps > 0.0 && steps <= number(metrics, ENV_STEP_BUDGET)
}

/// The rates between two snapshots; policy lag averaged over the metrics lines between them.
fn summarise(actors: usize, start: &Snapshot, end: &Snapshot, window: &[Value]) -> SystemRow {
    let dt = (end.wall_secs - start.wall_secs).max(f64::MIN_POSITIVE);
    let updates = |m: &Value| number(m, UPDATES_LOW) + number(m, UPDATES_HIGH);
    let lags: Vec<f64> = window.iter().map(|m| number(m, POLICY_LAG)).collect();
    SystemRow {
        actors,
        env_steps_per_sec: (number(&end.metrics, ENV_STEPS) - number(&start.metrics, ENV_STEPS))
            / dt,
        updates_per_sec: (updates(&end.metrics) - updates(&start.metrics)) / dt,
        policy_lag_mean: lags.iter().sum::<f64>() / lags.len().max(1) as f64,
        policy_lag_max: number(&end.metrics, POLICY_LAG_MAX),
        cpu_cores: (end.cpu_secs - start.cpu_secs)
            / end
                .taken
                .duration_since(start.taken)
                .as_secs_f64()
                .max(f64::MIN_POSITIVE),
    }
}

fn number(metrics: &Value, key: &str) -> f64 {
    metrics.get(key).and_then(Value::as_f64).unwrap_or(0.0)
}

/// The run's metrics and CPU time at one moment.
struct Snapshot {
    metrics: Value,
    wall_secs: f64,
    cpu_secs: f64,
    taken: Instant,
}

impl Snapshot {
    fn take(run: &TrainRun) -> anyhow::Result<Self> {
        let metrics = latest_metrics(&run.run_dir()).context("metrics.jsonl has no line yet")?;
        let wall_secs = number(&metrics, "wall_secs");
        Ok(Self {
            metrics,
            wall_secs,
            cpu_secs: run.cpu_secs(),
            taken: Instant::now(),
        })
    }
}

/// The last complete line of `metrics.jsonl`.
fn latest_metrics(run_dir: &Path) -> Option<Value> {
    let text = std::fs::read_to_string(run_dir.join("metrics.jsonl")).ok()?;
    text.lines()
        .rev()
        .find_map(|line| serde_json::from_str(line).ok())
}

/// Metrics lines with `from < wall_secs <= to`.
fn window_lines(run_dir: &Path, from: f64, to: f64) -> Vec<Value> {
    let text = std::fs::read_to_string(run_dir.join("metrics.jsonl")).unwrap_or_default();
    text.lines()
        .filter_map(|line| serde_json::from_str::<Value>(line).ok())
        .filter(|m| (from..=to).contains(&number(m, "wall_secs")) && number(m, "wall_secs") > from)
        .collect()
}

/// A running `asi train` in its own temporary folder; killed (with its children) and removed
/// if dropped before a clean stop.
struct TrainRun {
    dir: PathBuf,
    child: Child,
    stopped: bool,
}

impl TrainRun {
    fn start(config_text: &str, actors: usize) -> anyhow::Result<Self> {
        let tag = format!(
            "{}-{actors}-{:06x}",
            std::process::id(),
            rand::random::<u32>() & 0xff_ffff
        );
        let dir = std::env::temp_dir().join(format!("asi-bench-system-{tag}"));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let config = dir.join("config.toml");
        std::fs::write(&config, config_text)
            .with_context(|| format!("writing {}", config.display()))?;
        let log = std::fs::File::create(dir.join("launcher.log"))?;
        let exe = std::env::current_exe().context("locating the asi executable")?;
        let child = Command::new(exe)
            .arg("train")
            .arg("--config")
            .arg(&config)
            .args(["--actors", &actors.to_string(), "--run-dir"])
            .arg(dir.join("run"))
            .args(["--set", &format!("run.name=bench-system-{tag}")])
            .args(["--set", &format!("run.max_episodes={UNREACHED_EPISODES}")])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .context("starting asi train")?;
        Ok(Self {
            dir,
            child,
            stopped: false,
        })
    }

    fn run_dir(&self) -> PathBuf {
        self.dir.join("run")
    }

    fn run_id(&self) -> anyhow::Result<String> {
        Ok(crate::run::read_run_id(&self.run_dir())?.to_string())
    }

    /// An error naming the launcher's log if the run has ended.
    fn check_alive(&mut self) -> anyhow::Result<()> {
        if let Some(status) = self.child.try_wait()? {
            bail!(
                "asi train exited early ({status}); see {}",
                self.dir.join("launcher.log").display()
            );
        }
        Ok(())
    }

    fn wait_for(
        &mut self,
        what: &str,
        timeout: Duration,
        done: impl Fn(&Path) -> bool,
    ) -> anyhow::Result<()> {
        let deadline = Instant::now() + timeout;
        while !done(&self.run_dir()) {
            self.check_alive()?;
            ensure!(
                Instant::now() < deadline,
                "never saw: {what} within {timeout:?}; see {}",
                self.dir.display()
            );
            std::thread::sleep(POLL);
        }
        Ok(())
    }

    fn sleep(&mut self, duration: Duration) -> anyhow::Result<()> {
        let end = Instant::now() + duration;
        while Instant::now() < end {
            self.check_alive()?;
            std::thread::sleep(POLL.min(end.saturating_duration_since(Instant::now())));
        }
        Ok(())
    }

    /// The launcher and the children it wrote pid files for.
    fn pids(&self) -> Vec<u32> {
        let mut pids = vec![self.child.id()];
        let status = self.run_dir().join(crate::run::STATUS_DIR);
        for entry in std::fs::read_dir(status).into_iter().flatten().flatten() {
            if entry.path().extension().is_some_and(|e| e == "pid") {
                if let Some(pid) = std::fs::read_to_string(entry.path())
                    .ok()
                    .and_then(|t| t.trim().parse().ok())
                {
                    pids.push(pid);
                }
            }
        }
        pids
    }

    /// CPU seconds (user + system) used so far by the run's live processes.
    fn cpu_secs(&self) -> f64 {
        // SAFETY: sysconf only reads a system constant.
        let ticks_per_sec = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
        self.pids().into_iter().filter_map(cpu_ticks).sum::<u64>() as f64 / ticks_per_sec
    }

    /// SIGTERM to the launcher, which stops actors, then learner and graph-service.
    fn stop(&mut self) -> anyhow::Result<()> {
        // SAFETY: plain syscall on the pid of our own child.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let deadline = Instant::now() + STOP_TIMEOUT;
        loop {
            if let Some(status) = self.child.try_wait()? {
                self.stopped = true;
                ensure!(
                    status.success(),
                    "asi train exited with {status} after SIGTERM; see {}",
                    self.dir.join("launcher.log").display()
                );
                return Ok(());
            }
            ensure!(
                Instant::now() < deadline,
                "asi train did not stop within {STOP_TIMEOUT:?} of SIGTERM"
            );
            std::thread::sleep(POLL);
        }
    }

    /// Deletes the run folder (after a successful measurement).
    fn remove(self) {
        if let Err(err) = std::fs::remove_dir_all(&self.dir) {
            tracing::warn!("could not remove {}: {err}", self.dir.display());
        }
    }
}

impl Drop for TrainRun {
    /// A run not stopped cleanly (an error above) is killed, children included; its folder is
    /// kept for the logs.
    fn drop(&mut self) {
        if !self.stopped {
            for pid in self.pids().into_iter().skip(1) {
                // SAFETY: plain syscall on pids this run's launcher wrote.
                unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
            }
            let _ = self.child.kill();
            let _ = self.child.wait();
            eprintln!(
                "the run's folder is kept for its logs: {}",
                self.dir.display()
            );
        }
    }
}

/// utime + stime of a live process, in clock ticks (`/proc/<pid>/stat` fields 14 and 15).
fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) may contain spaces; the fields after its ')' are plain.
    let after = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = after.split_whitespace().collect();
    // `after` starts at field 3, so fields 14 and 15 are at indices 11 and 12.
    Some(fields.get(11)?.parse::<u64>().ok()? + fields.get(12)?.parse::<u64>().ok()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actor_counts_parse_in_order_with_spaces_allowed() {
        assert_eq!(parse_actor_counts("1,2,4"), Ok(ActorCounts(vec![1, 2, 4])));
        assert_eq!(parse_actor_counts(" 4 , 1"), Ok(ActorCounts(vec![4, 1])));
        assert_eq!(parse_actor_counts("3"), Ok(ActorCounts(vec![3])));
    }

    #[test]
    fn bad_actor_counts_are_refused_with_the_offending_part() {
        for (text, needle) in [
            ("", "``"),
            ("1,,2", "``"),
            ("two", "`two`"),
            ("1,-2", "`-2`"),
            ("0", "0 actors"),
            ("65", "65 actors"),
            ("2,2", "listed twice"),
            ("1.5", "`1.5`"),
        ] {
            let err = parse_actor_counts(text).expect_err(text);
            assert!(err.contains(needle), "{text:?} gave {err:?}");
        }
    }

    #[test]
    fn clap_applies_the_actor_list_parser() {
        use clap::Parser;
        let cli = crate::cli::Cli::try_parse_from([
            "asi",
            "bench",
            "system",
            "--actors",
            "2,8",
            "--seconds",
            "5",
        ])
        .unwrap();
        let Some(crate::cli::Command::Bench(crate::cli::BenchCommand::System(args))) = cli.command
        else {
            panic!("not bench system")
        };
        assert_eq!(args.actors, ActorCounts(vec![2, 8]));
        assert_eq!(args.seconds, 5.0);
        let default = crate::cli::Cli::try_parse_from(["asi", "bench", "system"]).unwrap();
        let Some(crate::cli::Command::Bench(crate::cli::BenchCommand::System(args))) =
            default.command
        else {
            panic!()
        };
        assert_eq!(args.actors, ActorCounts(vec![1, 2, 4]));
        assert!(
            crate::cli::Cli::try_parse_from(["asi", "bench", "system", "--actors", "1,x"]).is_err()
        );
    }

    fn metrics(wall: f64, steps: f64, low: f64, high: f64, lag: f64, lag_max: f64) -> Value {
        serde_json::json!({
            "wall_secs": wall, ENV_STEPS: steps, UPDATES_LOW: low, UPDATES_HIGH: high,
            POLICY_LAG: lag, POLICY_LAG_MAX: lag_max,
        })
    }

    #[test]
    fn rates_are_the_metric_deltas_over_the_wall_clock_delta() {
        let t0 = Instant::now();
        let start = Snapshot {
            metrics: metrics(10.0, 1000.0, 50.0, 5.0, 1.0, 2.0),
            wall_secs: 10.0,
            cpu_secs: 3.0,
            taken: t0,
        };
        let end = Snapshot {
            metrics: metrics(30.0, 9000.0, 450.0, 45.0, 3.0, 4.0),
            wall_secs: 30.0,
            cpu_secs: 43.0,
            taken: t0 + Duration::from_secs(20),
        };
        let window = [
            metrics(20.0, 0.0, 0.0, 0.0, 1.0, 0.0),
            metrics(30.0, 0.0, 0.0, 0.0, 2.0, 0.0),
        ];
        let row = summarise(2, &start, &end, &window);
        assert_eq!(
            row,
            SystemRow {
                actors: 2,
                env_steps_per_sec: 400.0,
                updates_per_sec: 22.0,
                policy_lag_mean: 1.5,
                policy_lag_max: 4.0,
                cpu_cores: 2.0
            }
        );
    }

    #[test]
    fn the_table_has_one_row_per_actor_count() {
        let row = |actors| SystemRow {
            actors,
            env_steps_per_sec: 1234.4,
            updates_per_sec: 56.78,
            policy_lag_mean: 0.5,
            policy_lag_max: 3.0,
            cpu_cores: 1.955,
        };
        let text = table(&[row(1), row(4)]).render();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        assert!(
            lines[0].starts_with("actors  env steps/s  updates/s"),
            "{text}"
        );
        assert_eq!(
            lines[2].split_whitespace().collect::<Vec<_>>(),
            ["1", "1234", "56.8", "0.50", "3", "1.96"]
        );
        assert_eq!(lines[3].split_whitespace().next(), Some("4"));
    }

    #[test]
    fn steady_state_starts_when_the_throttle_budget_covers_what_was_ingested() {
        let m = |steps: f64, budget: f64| serde_json::json!({ ENV_STEPS: steps, ENV_STEP_BUDGET: budget });
        assert!(!in_steady_state(&m(0.0, 2000.0)), "nothing ingested yet");
        assert!(
            !in_steady_state(&m(7600.0, 5127.0)),
            "actors overshot and wait for the learner"
        );
        assert!(in_steady_state(&m(7600.0, 7600.0)));
        assert!(in_steady_state(&m(8000.0, 9500.0)));
        assert!(!in_steady_state(&serde_json::json!({})), "no metrics yet");
    }

    #[test]
    fn cpu_ticks_of_this_process_are_readable() {
        assert!(cpu_ticks(std::process::id()).is_some());
        assert_eq!(cpu_ticks(u32::MAX), None);
    }
}
