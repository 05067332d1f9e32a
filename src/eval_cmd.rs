//! `asi eval --run-dir DIR`: evaluates the newest weights saved in a run folder
//! ([`crate::weights_file`]) on the task's test variant — deterministic policies, no
//! exploration, the evaluator's episodes — and prints the figures as `name: value` lines;
//! `--png` also draws every episode's trajectory on the maze. Reads files only: it works on a
//! finished run and beside a running one without touching it.

use std::path::PathBuf;

use actor::eval::Evaluator;
use anyhow::{bail, Context};
use clap::Args;
use protocol::config::RESOLVED_CONFIG_FILE;
use protocol::Config;

use crate::proc::evaluator::eval_seed;
use crate::weights_file;

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run folder of a training run (finished or running); its resolved config and
    /// `weights/latest.*` are read.
    #[arg(long)]
    pub run_dir: PathBuf,
    /// Evaluation episodes. Default: the run's `eval.n_episodes` (10).
    #[arg(long)]
    pub episodes: Option<u32>,
    /// Seed of the episodes' reset noise. Default: the seed the run's evaluator uses, so the
    /// episodes are those of the run's own evaluations.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Also draw the maze with every episode's trajectory and the goal into this PNG file
    /// (maze tasks only).
    #[arg(long)]
    pub png: Option<PathBuf>,
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let config_path = args.run_dir.join(RESOLVED_CONFIG_FILE);
    let text = std::fs::read_to_string(&config_path).with_context(|| {
        format!(
            "reading {} (is {} a run folder?)",
            config_path.display(),
            args.run_dir.display()
        )
    })?;
    let config = Config::from_toml_str(&text, &config_path.display().to_string())?;
    let (header, bytes) = load_weights(&args.run_dir)?;
    let n_episodes = args.episodes.unwrap_or(config.eval.n_episodes);
    if n_episodes == 0 {
        bail!("--episodes must be at least 1 (the run's eval.n_episodes is 0)");
    }
    let seed = args.seed.unwrap_or_else(|| eval_seed(&config));
    let mut evaluator = Evaluator::new(&config, seed).context("building the evaluator")?;
    evaluator
        .load_weights(&header, &bytes)
        .context("the saved weights do not fit this run's networks")?;
    eprintln!(
        "evaluating policy version {} (φ version {}, after {} training episodes): {n_episodes} episodes of {}",
        header.policy_version.0,
        header.phi_version.0,
        header.schedule.train_episodes,
        actor::eval::test_task_name(&config.env.task)
    );
    let report = evaluator.run(0, n_episodes)?;
    println!("task: {}", actor::eval::test_task_name(&config.env.task));
    println!("policy_version: {}", report.policy_version.0);
    println!("phi_version: {}", report.phi_version.0);
    println!("train_episodes: {}", header.schedule.train_episodes);
    println!("episodes: {}", report.n_episodes);
    println!("seed: {seed}");
    println!("success_rate: {:.4}", report.success_rate);
    println!("mean_final_distance: {:.4}", report.mean_final_distance);
    if let Some(along) = report.mean_final_path_distance {
        println!("mean_final_path_distance: {along:.4}");
    }
    println!("mean_length: {:.1}", report.mean_length);
    println!("mean_return: {:.4}", report.mean_return);
    if let Some(path) = &args.png {
        let Some(maze) = evaluator.maze() else {
            bail!("--png: task {} has no maze to draw", config.env.task);
        };
        let all: Vec<[f32; 2]> = report.trajectories.iter().flatten().copied().collect();
        let goal = report.goals.first().copied().unwrap_or([f32::NAN; 2]);
        envs::render::render_maze_png(maze, &all, goal, path)
            .with_context(|| format!("drawing {}", path.display()))?;
        println!("png: {}", path.display());
    }
    Ok(())
}

/// The saved weights; one retry when the evaluator replaced them while they were read.
fn load_weights(run_dir: &std::path::Path) -> anyhow::Result<(protocol::WeightsHeader, Vec<u8>)> {
    weights_file::load(run_dir).or_else(|first| {
        std::thread::sleep(std::time::Duration::from_millis(200));
        weights_file::load(run_dir).map_err(|_| first)
    })
}
