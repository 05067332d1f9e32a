//! `asi bench …`: throughput measurements printed as `name: value` lines, the last one the
//! headline figure, so scripts can `tail -n 1`.

use anyhow::Context;

use crate::cli::{BenchCommand, BenchEnvArgs};

pub fn run(command: BenchCommand) -> anyhow::Result<()> {
    match command {
        BenchCommand::Env(args) => bench_env(&args),
        BenchCommand::Graph(args) => crate::bench_graph::run(&args),
    }
}

fn bench_env(args: &BenchEnvArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.steps > 0 && args.repeats > 0, "--steps and --repeats must be positive");
    let report = envs::bench::run(&args.task, args.steps, args.repeats, args.seed)
        .with_context(|| format!("benchmarking task `{}`", args.task))?;
    println!("task: {}", report.task);
    println!("steps_per_repeat: {}", report.steps);
    for (i, rate) in report.per_repeat.iter().enumerate() {
        println!("repeat_{i}_steps_per_sec: {rate:.0}");
    }
    println!("physics_failures: {}", report.n_physics_failures);
    println!("env_steps_per_sec: {:.0}", report.median);
    Ok(())
}
