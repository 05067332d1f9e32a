//! `asi evaluator`: the evaluation process (SPEC §7). It listens to the weights broadcast and,
//! each time the learner's count of completed training episodes (`WeightsHeader.schedule`)
//! passes the next multiple of `eval.interval_episodes`, evaluates the weights of that message:
//! `eval.n_episodes` deterministic episodes on the task's test goal. Each result is published as
//! metrics (`evaluator0/eval/*`, see docs/METRICS.md), appended to `run_dir/eval.jsonl`, and
//! drawn as `run_dir/plots/eval_latest.png` (the maze with every evaluation trajectory). The
//! newest weights it has seen are saved in `run_dir/weights/` for `asi eval`
//! ([`crate::weights_file`]).
//!
//! An evaluation is done on the newest weights at the moment it falls due; when the learner
//! crosses several multiples at once (a slow evaluator), the skipped ones are counted, not
//! queued, so evaluation never holds training back.
//!
//! A restarted evaluator (after its own crash, or in a resumed run) goes on after the last
//! evaluation in `eval.jsonl` ([`evaluations_done`]): it does not evaluate the restored weights
//! at once under an index that is already there, nor count the earlier ones as skipped. On a
//! resume the launch has already moved the evaluations past the checkpoint out of the file
//! (`crate::run::tail`), so those are run again as the resumed learner passes them.

use std::fs::OpenOptions;
use std::io::Write;
use std::time::Duration;

use actor::eval::{EvalReport, Evaluator};
use anyhow::Context;
use protocol::{ProcessRole, WeightsHeader};

use super::common::{newest_weights, node, task_info, MetricsOut, StopWatch};
use crate::channels::Channels;
use crate::run::RunContext;
use crate::weights_file::WeightsSaver;

/// How long one wait for weights lasts before the stop conditions are re-checked.
const WEIGHTS_WAIT: Duration = Duration::from_millis(200);

/// Which evaluations are due: evaluation `k` (1, 2, …) falls due once the learner has
/// completed `k × interval` training episodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct EvalSchedule {
    interval: u64,
    done: u64,
    skipped: u64,
}

impl EvalSchedule {
    pub fn new(interval: u64) -> Self {
        Self {
            interval: interval.max(1),
            done: 0,
            skipped: 0,
        }
    }

    /// A schedule whose evaluations `1..=done` have already been run.
    pub fn after(interval: u64, done: u64) -> Self {
        Self {
            done,
            ..Self::new(interval)
        }
    }

    /// The index of the evaluation to run now for `train_episodes`, if one is due; marks it
    /// done and counts any multiples crossed in between as skipped.
    pub fn due(&mut self, train_episodes: u64) -> Option<u64> {
        let reached = train_episodes / self.interval;
        if reached <= self.done {
            return None;
        }
        self.skipped += reached - self.done - 1;
        self.done = reached;
        Some(reached)
    }

    pub fn skipped(&self) -> u64 {
        self.skipped
    }
}

/// Seed of the evaluation episodes: derived from `run.seed`, apart from the actors' seeds.
pub fn eval_seed(config: &protocol::Config) -> u64 {
    config.run.seed ^ 0xE7A1
}

pub fn run(ctx: &RunContext) -> anyhow::Result<()> {
    let config = &ctx.config;
    let info = task_info(config)?;
    // Signals are caught from here on (see the actor).
    let node = node(ctx, "evaluator")?;
    let mut stop = StopWatch::new(&node);
    let mut evaluator =
        Evaluator::new(config, eval_seed(config)).context("building the evaluator")?;
    let mut saver = WeightsSaver::new(&ctx.run_dir);
    let mut last_weights = None;
    let channels = Channels::new(config, &ctx.run_id, &info.layout);
    let weights = channels.weights_subscriber(&node)?;
    let mut metrics = MetricsOut::new(
        channels.metrics_publisher(&node)?,
        ProcessRole::Evaluator,
        0,
        config,
    );
    let eval_file = ctx.run_dir.join(EVAL_FILE);
    let done = evaluations_done(&eval_file)?;
    if done > 0 {
        tracing::info!(
            "evaluations continue after evaluation {done} in {}",
            eval_file.display()
        );
    }
    let mut schedule = EvalSchedule::after(config.eval.interval_episodes, done);
    let mut n_rejected = 0u64;
    let reason = loop {
        if let Some(reason) = stop.should_stop(&node) {
            break reason;
        }
        let Some((header, bytes)) = newest_weights(&weights) else {
            // Interrupted waits (termination signal) are caught by the stop check.
            let _ = weights.listener().timed_wait(|_| {}, WEIGHTS_WAIT);
            continue;
        };
        let due = schedule.due(header.schedule.train_episodes);
        saver.offer(&header, &bytes, due.is_some());
        let Some(index) = due else {
            last_weights = Some((header, bytes));
            continue;
        };
        if let Err(err) = evaluator.load_weights(&header, &bytes) {
            n_rejected += 1;
            tracing::error!("evaluator refused weights: {err:#}");
            continue;
        }
        let report = evaluator.run(index, config.eval.n_episodes)?;
        tracing::info!(
            index,
            train_episodes = header.schedule.train_episodes,
            success_rate = report.success_rate,
            policy_version = report.policy_version.0,
            "evaluation"
        );
        metrics.publish(
            0,
            &eval_metrics(&report, &header, schedule.skipped(), n_rejected),
        );
        record_report(ctx, &evaluator, &report, &header)?;
        last_weights = Some((header, bytes));
    };
    if let Some((header, bytes)) = &last_weights {
        saver.offer(header, bytes, true);
    }
    tracing::info!(
        reason,
        evaluations = schedule.done,
        skipped = schedule.skipped(),
        "evaluator stopping"
    );
    ctx.write_status(
        "evaluator",
        &serde_json::json!({
            "role": "evaluator", "evaluations": schedule.done, "skipped": schedule.skipped(),
            "weights_rejected": n_rejected, "stop_reason": reason,
        }),
    )
}

pub fn eval_metrics(
    report: &EvalReport,
    header: &WeightsHeader,
    skipped: u64,
    rejected: u64,
) -> Vec<(String, f64)> {
    let mut values = vec![
        ("eval/success_rate".to_owned(), report.success_rate),
        (
            "eval/mean_final_distance".to_owned(),
            report.mean_final_distance,
        ),
        ("eval/mean_length".to_owned(), report.mean_length),
        ("eval/mean_return".to_owned(), report.mean_return),
        ("eval/index".to_owned(), report.index as f64),
        (
            "eval/train_episodes".to_owned(),
            header.schedule.train_episodes as f64,
        ),
        (
            "eval/policy_version".to_owned(),
            report.policy_version.0 as f64,
        ),
        ("eval/skipped".to_owned(), skipped as f64),
        ("eval/weights_rejected".to_owned(), rejected as f64),
    ];
    if let Some(along) = report.mean_final_path_distance {
        values.push(("eval/mean_final_path_distance".to_owned(), along));
    }
    values
}

/// One JSON line per evaluation in `run_dir/eval.jsonl`.
/// The evaluation record of a run, in its folder.
pub const EVAL_FILE: &str = "eval.jsonl";

/// The highest evaluation `index` in `path` (an `eval.jsonl`), 0 when the file is missing or
/// holds none. Lines that do not parse (a last line cut short by a crash) are skipped.
pub fn evaluations_done(path: &std::path::Path) -> anyhow::Result<u64> {
    use std::io::BufRead;
    let file = match std::fs::File::open(path) {
        Ok(file) => file,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(err) => return Err(err).with_context(|| format!("opening {}", path.display())),
    };
    let mut done = 0;
    for line in std::io::BufReader::new(file).lines() {
        let line = line.with_context(|| format!("reading {}", path.display()))?;
        let index = serde_json::from_str::<serde_json::Value>(&line)
            .ok()
            .and_then(|v| v.get("index")?.as_u64());
        done = done.max(index.unwrap_or(0));
    }
    Ok(done)
}

/// What an evaluation leaves in the run folder, in process and serial mode alike: its line in
/// `eval.jsonl` and, on a maze task, `plots/eval_latest.png` (the maze with every evaluation
/// trajectory and the goal; a picture that cannot be drawn is a warning, not an error).
pub fn record_report(
    ctx: &RunContext,
    evaluator: &Evaluator,
    report: &EvalReport,
    header: &WeightsHeader,
) -> anyhow::Result<()> {
    append_report(ctx, report, header)?;
    if let Some(maze) = evaluator.maze() {
        let plots = ctx.run_dir.join("plots");
        let all: Vec<[f32; 2]> = report.trajectories.iter().flatten().copied().collect();
        let goal = report.goals.first().copied().unwrap_or([f32::NAN; 2]);
        let draw = || -> anyhow::Result<()> {
            std::fs::create_dir_all(&plots)?;
            envs::render::render_maze_png(maze, &all, goal, &plots.join("eval_latest.png"))?;
            Ok(())
        };
        if let Err(err) = draw() {
            tracing::warn!("evaluation picture not drawn: {err:#}");
        }
    }
    Ok(())
}

fn append_report(
    ctx: &RunContext,
    report: &EvalReport,
    header: &WeightsHeader,
) -> anyhow::Result<()> {
    let path = ctx.run_dir.join(EVAL_FILE);
    let mut file = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    let line = serde_json::json!({
        "index": report.index,
        "train_episodes": header.schedule.train_episodes,
        "policy_version": report.policy_version.0,
        "phi_version": report.phi_version.0,
        "n_episodes": report.n_episodes,
        "success_rate": report.success_rate,
        "mean_final_distance": report.mean_final_distance,
        "mean_final_path_distance": report.mean_final_path_distance,
        "mean_length": report.mean_length,
        "mean_return": report.mean_return,
    });
    writeln!(file, "{line}").with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluations_fall_due_at_multiples_and_count_skips() {
        let mut s = EvalSchedule::new(50);
        assert_eq!(s.due(0), None);
        assert_eq!(s.due(49), None);
        assert_eq!(s.due(50), Some(1));
        assert_eq!(s.due(50), None);
        assert_eq!(s.due(99), None);
        assert_eq!(s.due(100), Some(2));
        assert_eq!(s.due(260), Some(5));
        assert_eq!(s.skipped(), 2);
        assert_eq!(s.due(260), None);
    }

    #[test]
    fn a_restarted_evaluator_goes_on_after_the_last_evaluation_in_its_file() {
        let dir = std::env::temp_dir().join(format!("asi-eval-done-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(EVAL_FILE);
        assert_eq!(evaluations_done(&path).unwrap(), 0, "no file yet");
        std::fs::write(
            &path,
            "{\"index\":1,\"train_episodes\":50}\n{\"index\":4,\"train_episodes\":200}\n\
             {\"index\":3,\"train_episodes\":150}\n{\"index\":5,\"train",
        )
        .unwrap();
        let done = evaluations_done(&path).unwrap();
        assert_eq!(
            done, 4,
            "the highest whole line's index; the cut-off line is skipped"
        );
        // Restored weights at 244 episodes: evaluation 4 is in the file already.
        let mut s = EvalSchedule::after(50, done);
        assert_eq!(s.due(244), None);
        assert_eq!(s.due(250), Some(5));
        assert_eq!(s.skipped(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
