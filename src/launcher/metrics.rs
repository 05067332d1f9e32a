//! The launcher's view of the run: the latest value of every metric from every process,
//! written to `metrics.jsonl` (one object per flush, all values), `metrics.csv` (headline
//! columns) and TensorBoard event files in `tensorboard/` (all values, x axis = env steps), and
//! shown as one progress line. Metric names are documented in `docs/METRICS.md`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::time::{Duration, Instant};

use protocol::{Config, MetricsSample, ProcessRole};

use crate::progress::{Figures, Progress, Rates};
use crate::run::RunContext;
use crate::tensorboard::EventWriter;

/// Headline columns of `metrics.csv`, each the key of a value in the book.
const CSV_COLUMNS: [&str; 9] = [
    "learner/ingest/env_steps",
    "learner/ingest/episodes_completed",
    "learner/charts/updates_low",
    "learner/charts/updates_high",
    "learner/charts/policy_version",
    "learner/ingest/lost_chunks",
    "graph-service/graph/stored_steps",
    "evaluator0/eval/success_rate",
    "evaluator0/eval/train_episodes",
];
/// `launcher/env_steps_per_sec` is the rate over this much of the recent past.
const RATE_SPAN: Duration = Duration::from_secs(10);
/// How often `plots/curves.png` is redrawn from `metrics.jsonl`.
const PLOT_INTERVAL: Duration = Duration::from_secs(60);
/// How often a plain progress line is logged when stderr is not a terminal.
const PLAIN_PROGRESS_INTERVAL: Duration = Duration::from_secs(10);

pub struct MetricsBook {
    values: BTreeMap<String, f64>,
    started: Instant,
    jsonl: BufWriter<File>,
    csv: BufWriter<File>,
    tensorboard: EventWriter,
    progress: Progress,
    /// The run's budget: `run.max_episodes` and `run.max_env_steps`.
    budget: (u64, Option<u64>),
    /// Over [`RATE_SPAN`], for `launcher/env_steps_per_sec`.
    rate: Rates,
    run_dir: std::path::PathBuf,
    last_plot: Instant,
}

impl MetricsBook {
    /// The book of a run; `resume`: append to the run's `metrics.jsonl` and `metrics.csv`
    /// (a resumed run continues its curves) instead of starting them anew.
    pub fn create(ctx: &RunContext, resume: bool) -> anyhow::Result<Self> {
        let open = |name: &str| -> anyhow::Result<(File, bool)> {
            let path = ctx.run_dir.join(name);
            let fresh = !resume || std::fs::metadata(&path).map_or(true, |m| m.len() == 0);
            let file = std::fs::OpenOptions::new()
                .create(true)
                .write(true)
                .append(!fresh)
                .truncate(fresh)
                .open(&path)?;
            Ok((file, fresh))
        };
        let jsonl = BufWriter::new(open("metrics.jsonl")?.0);
        let (csv_file, csv_fresh) = open("metrics.csv")?;
        let mut csv = BufWriter::new(csv_file);
        if csv_fresh {
            writeln!(
                csv,
                "wall_secs,env_steps_per_sec,actor_restarts,{}",
                CSV_COLUMNS.join(",")
            )?;
        }
        let tensorboard = EventWriter::create(&ctx.run_dir.join("tensorboard"))?;
        let mut book = Self {
            values: BTreeMap::new(),
            started: Instant::now(),
            jsonl,
            csv,
            tensorboard,
            progress: Progress::new(PLAIN_PROGRESS_INTERVAL),
            budget: (ctx.config.run.max_episodes, ctx.config.run.max_env_steps),
            rate: Rates::over(RATE_SPAN),
            run_dir: ctx.run_dir.clone(),
            last_plot: Instant::now(),
        };
        // A resumed launch stands at its checkpoint until the learner reports: its rates and
        // progress line start there, not at 0 (which made the first rates the whole run's
        // episodes over ten seconds).
        if let Some(point) = ctx.resumed_from {
            book.stand_at(point);
        }
        Ok(book)
    }

    /// The learner's counters at `point` (a checkpoint, or the start) until it reports.
    fn stand_at(&mut self, point: crate::run::ResumePoint) {
        self.values.insert(
            "learner/ingest/env_steps".to_owned(),
            point.env_steps as f64,
        );
        if let Some(episodes) = point.episodes {
            self.values.insert(
                "learner/ingest/episodes_completed".to_owned(),
                episodes as f64,
            );
        }
    }

    /// Keeps the latest value per `<process>/<name>`; malformed samples are logged and skipped.
    pub fn record(&mut self, samples: &[MetricsSample]) {
        for sample in samples {
            match key_of(sample) {
                Ok(key) => {
                    self.values.insert(key, sample.value);
                }
                Err(err) => tracing::warn!("skipped a metrics sample: {err:#}"),
            }
        }
        self.rate.observe(
            Instant::now(),
            self.get("learner/ingest/episodes_completed") as u64,
            self.get("learner/ingest/env_steps") as u64,
        );
    }

    /// Drops every value of `process` (`learner`, `graph-service`): a restarted process starts
    /// its own values afresh.
    pub fn forget_process(&mut self, process: &str) {
        let prefix = format!("{process}/");
        self.values.retain(|key, _| !key.starts_with(&prefix));
    }

    /// A learner restarted inside this launch went back to `point` (its newest checkpoint, or
    /// the start): the lines and events already written past it move to side files
    /// ([`crate::run::move_metrics_past`]), writing continues at the cut, and the learner's
    /// counters stand at the checkpoint's until it reports, so the curves never go back in
    /// env steps. Returns what was moved.
    pub fn rewind_learner(
        &mut self,
        point: crate::run::ResumePoint,
    ) -> anyhow::Result<Vec<crate::run::MovedTail>> {
        self.jsonl.flush()?;
        self.csv.flush()?;
        self.tensorboard.flush()?;
        let moved = crate::run::move_metrics_past(&self.run_dir, point)?;
        for file in [self.jsonl.get_mut(), self.csv.get_mut()] {
            file.seek(SeekFrom::End(0))?;
        }
        self.tensorboard.continue_at_end()?;
        self.forget_process("learner");
        self.stand_at(point);
        self.rate = Rates::over(RATE_SPAN);
        self.progress.reset_rates();
        Ok(moved)
    }

    /// `launcher/restarts_<family>`: restarts so far per process kind.
    pub fn set_restarts(&mut self, per_family: &BTreeMap<&'static str, u64>) {
        for (family, n) in per_family {
            self.values
                .insert(format!("launcher/restarts_{family}"), *n as f64);
        }
    }

    fn get(&self, key: &str) -> f64 {
        self.values.get(key).copied().unwrap_or(0.0)
    }

    /// Training episodes the learner last reported completed (0 before its first report).
    pub fn episodes_completed(&self) -> u64 {
        self.get("learner/ingest/episodes_completed") as u64
    }

    pub fn budget_reached(&self, config: &Config) -> bool {
        let steps = self.get("learner/ingest/env_steps") as u64;
        let episodes = self.get("learner/ingest/episodes_completed") as u64;
        config.run.max_env_steps.is_some_and(|max| steps >= max)
            || episodes >= config.run.max_episodes
    }

    /// Where the run stands, as the progress line shows it.
    fn figures(&self) -> Figures {
        let (max_episodes, max_env_steps) = self.budget;
        let success = self.values.get("evaluator0/eval/success_rate");
        Figures {
            episodes: self.episodes_completed(),
            max_episodes,
            env_steps: self.get("learner/ingest/env_steps") as u64,
            max_env_steps,
            coverage: self.values.get("learner/charts/coverage").copied(),
            eval: success.map(|&s| (s, self.get("evaluator0/eval/train_episodes") as u64)),
        }
    }

    /// What the process mode's line adds to the common one.
    fn tail(&self, restarts: u64) -> [String; 2] {
        [
            format!(
                "policy v{}",
                self.get("learner/charts/policy_version") as u64
            ),
            format!("restarts {restarts}"),
        ]
    }

    /// `launcher/env_steps_per_sec`: 0 until there is a rate.
    fn steps_per_sec(&self) -> f64 {
        self.rate.per_sec().map_or(0.0, |(_, steps)| steps)
    }

    pub fn show_progress(&mut self, restarts: u64) {
        let (figures, tail) = (self.figures(), self.tail(restarts));
        self.progress.show(&figures, &tail);
    }

    /// Appends one line to each metrics file.
    pub fn flush(&mut self, restarts: u64) -> anyhow::Result<()> {
        let wall = self.started.elapsed().as_secs_f64();
        let mut object = serde_json::Map::new();
        object.insert("wall_secs".to_owned(), serde_json::json!(wall));
        object.insert(
            "launcher/env_steps_per_sec".to_owned(),
            serde_json::json!(self.steps_per_sec()),
        );
        object.insert(
            "launcher/actor_restarts".to_owned(),
            serde_json::json!(restarts),
        );
        for (key, value) in &self.values {
            object.insert(key.clone(), serde_json::json!(value));
        }
        writeln!(self.jsonl, "{}", serde_json::Value::Object(object))?;
        let columns: Vec<String> = CSV_COLUMNS
            .iter()
            .map(|k| self.get(k).to_string())
            .collect();
        writeln!(
            self.csv,
            "{wall:.3},{:.1},{restarts},{}",
            self.steps_per_sec(),
            columns.join(",")
        )?;
        let mut scalars: Vec<(&str, f32)> = vec![
            ("launcher/env_steps_per_sec", self.steps_per_sec() as f32),
            ("launcher/actor_restarts", restarts as f32),
        ];
        scalars.extend(
            self.values
                .iter()
                .map(|(key, value)| (key.as_str(), *value as f32)),
        );
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        let step = self.get("learner/ingest/env_steps") as i64;
        self.tensorboard
            .add_scalars(step, unix.as_secs_f64(), &scalars)?;
        self.jsonl.flush()?;
        self.csv.flush()?;
        self.tensorboard.flush()?;
        if self.last_plot.elapsed() >= PLOT_INTERVAL {
            self.plot();
        }
        Ok(())
    }

    /// Redraws `plots/curves.png` (test success and coverage against env steps); a failure is
    /// logged, never fatal.
    pub fn plot(&mut self) {
        self.last_plot = Instant::now();
        crate::plot::redraw_run_curves(&self.run_dir);
    }

    pub fn finish(&mut self, restarts: u64) {
        self.plot();
        let (figures, tail) = (self.figures(), self.tail(restarts));
        self.progress.finish(&figures, &tail);
    }
}

/// `learner/<name>`, `graph-service/<name>`, `actor3/<name>`, …
fn key_of(sample: &MetricsSample) -> anyhow::Result<String> {
    let name = sample.name()?;
    let process = match sample.role()? {
        ProcessRole::Launcher => "launcher".to_owned(),
        ProcessRole::Learner => "learner".to_owned(),
        ProcessRole::GraphService => "graph-service".to_owned(),
        ProcessRole::Actor => format!("actor{}", sample.source_id),
        ProcessRole::Evaluator => format!("evaluator{}", sample.source_id),
    };
    Ok(format!("{process}/{name}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::ResumePoint;

    fn learner_sample(name: &str, value: f64) -> MetricsSample {
        MetricsSample::new(ProcessRole::Learner, 0, name, value, value as u64, 0).unwrap()
    }

    fn steps_of_jsonl(text: &str) -> Vec<f64> {
        text.lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                v["learner/ingest/env_steps"].as_f64().unwrap()
            })
            .collect()
    }

    #[test]
    fn a_resumed_launch_stands_at_its_checkpoint_until_the_learner_reports() {
        let dir = std::env::temp_dir().join(format!("asi-book-resume-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let point = ResumePoint {
            sequence: Some(4),
            env_steps: 1_750_000,
            episodes: Some(3_500),
        };
        let ctx = RunContext {
            config: Config::default(),
            run_dir: dir.clone(),
            run_id: protocol::RunId::new("t-2").unwrap(),
            resume: true,
            resumed_from: Some(point),
            launch: None,
            _lock: None,
        };
        let mut book = MetricsBook::create(&ctx, true).unwrap();
        let figures = book.figures();
        assert_eq!((figures.episodes, figures.env_steps), (3_500, 1_750_000));
        // Another process reports first: the rate's first sample is the checkpoint's position.
        book.record(&[
            MetricsSample::new(ProcessRole::GraphService, 0, "graph/nodes", 1.0, 0, 0).unwrap(),
        ]);
        book.flush(0).unwrap();
        std::thread::sleep(Duration::from_millis(5));
        book.record(&[
            learner_sample("ingest/env_steps", 1_753_200.0),
            learner_sample("ingest/episodes_completed", 3_506.0),
        ]);
        book.flush(0).unwrap();
        let (episodes_per_sec, steps_per_sec) = book.rate.per_sec().unwrap();
        // 3,200 steps in 6 episodes since the checkpoint (from 0 it would be 1,753,200 in 3,506).
        assert!((steps_per_sec / episodes_per_sec - 3_200.0 / 6.0).abs() < 1e-6);
        let jsonl = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap();
        assert_eq!(steps_of_jsonl(&jsonl), [1_750_000.0, 1_753_200.0]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_restarted_learner_cuts_the_records_at_its_checkpoint_and_writing_goes_on_after_the_cut() {
        let dir = std::env::temp_dir().join(format!("asi-book-rewind-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let ctx = RunContext {
            config: Config::default(),
            run_dir: dir.clone(),
            run_id: protocol::RunId::new("t-1").unwrap(),
            resume: false,
            resumed_from: None,
            launch: None,
            _lock: None,
        };
        // A fresh run: the files are opened without O_APPEND, so only the explicit move to
        // the end keeps the writes after the cut from leaving a hole.
        let mut book = MetricsBook::create(&ctx, false).unwrap();
        let write = |book: &mut MetricsBook, steps: f64| {
            book.record(&[
                learner_sample("ingest/env_steps", steps),
                learner_sample("ingest/episodes_completed", steps / 100.0),
            ]);
            book.flush(0).unwrap();
        };
        for steps in [100.0, 200.0, 300.0, 400.0, 500.0] {
            write(&mut book, steps);
        }
        let point = ResumePoint {
            sequence: Some(3),
            env_steps: 300,
            episodes: Some(3),
        };
        let moved = book.rewind_learner(point).unwrap();
        let files: Vec<(String, u64)> = moved
            .iter()
            .map(|m| {
                (
                    m.file.file_name().unwrap().to_string_lossy().into_owned(),
                    m.lines,
                )
            })
            .collect();
        assert_eq!(
            files[..2],
            [
                ("metrics.jsonl".to_owned(), 2),
                ("metrics.csv".to_owned(), 2)
            ]
        );
        assert_eq!(files[2].1, 2, "{files:?}");
        // Until the restarted learner reports, lines carry the checkpoint's counters.
        book.flush(0).unwrap();
        assert!(!book.budget_reached(&ctx.config));
        for steps in [320.0, 360.0] {
            write(&mut book, steps);
        }
        let jsonl = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap();
        assert_eq!(
            steps_of_jsonl(&jsonl),
            [100.0, 200.0, 300.0, 300.0, 320.0, 360.0]
        );
        let side = std::fs::read_to_string(&moved[0].side_file).unwrap();
        assert_eq!(steps_of_jsonl(&side), [400.0, 500.0]);
        let csv = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        let column = |line: &str| line.split(',').nth(3).unwrap().to_owned();
        let csv_steps: Vec<String> = csv.lines().skip(1).map(column).collect();
        assert_eq!(csv_steps, ["100", "200", "300", "300", "320", "360"]);
        let events = crate::tensorboard::read_events(book.tensorboard.path()).unwrap();
        let steps: Vec<i64> = events.iter().map(|e| e.step).collect();
        assert_eq!(steps, [0, 100, 200, 300, 300, 320, 360]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
