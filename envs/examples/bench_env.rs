//! Environment step throughput: steps a task with uniform random actions on one thread.
//!
//! `cargo run --release -p envs --example bench_env -- --task pointmaze-u --steps 200000`
//!
//! Runs 5 repeats of `--steps` control steps each (resetting whenever an episode ends), prints
//! each repeat's steps/s, then a final line `env_steps_per_sec: <median of the 5>`.

use std::process::ExitCode;
use std::time::Instant;

use envs::registry::make;
use envs::Env;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const N_REPEATS: usize = 5;
const DEFAULT_TASK: &str = "pointmaze-u";
const DEFAULT_STEPS: u64 = 100_000;
const ACTION_SEED: u64 = 0;

struct Args {
    task: String,
    steps: u64,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        task: DEFAULT_TASK.to_string(),
        steps: DEFAULT_STEPS,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--task" => args.task = value,
            "--steps" => args.steps = value.parse().map_err(|e| format!("--steps {value}: {e}"))?,
            other => return Err(format!("unknown flag {other}; use --task NAME --steps N")),
        }
    }
    if args.steps == 0 {
        return Err("--steps must be positive".to_string());
    }
    Ok(args)
}

/// Steps `env` for `n_steps` with random actions; returns steps per second.
fn run_repeat(
    env: &mut dyn Env,
    n_steps: u64,
    rng: &mut Pcg64Mcg,
    seed: &mut u64,
) -> Result<f64, String> {
    let (low, high) = (
        env.spec().action_low.clone(),
        env.spec().action_high.clone(),
    );
    let mut action = vec![0.0f32; low.len()];
    env.reset(*seed);
    let start = Instant::now();
    for _ in 0..n_steps {
        for (a, (&lo, &hi)) in action.iter_mut().zip(low.iter().zip(&high)) {
            *a = rng.random_range(lo..=hi);
        }
        let step = env.step(&action).map_err(|e| e.to_string())?;
        if step.terminated || step.truncated {
            *seed += 1;
            env.reset(*seed);
        }
    }
    Ok(n_steps as f64 / start.elapsed().as_secs_f64())
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn run(args: &Args) -> Result<f64, String> {
    let mut env = make(&args.task).map_err(|e| e.to_string())?;
    let mut rng = Pcg64Mcg::seed_from_u64(ACTION_SEED);
    let mut seed = 0;
    let mut rates = Vec::with_capacity(N_REPEATS);
    for repeat in 0..N_REPEATS {
        let rate = run_repeat(env.as_mut(), args.steps, &mut rng, &mut seed)?;
        println!(
            "repeat {repeat}: {} steps in task {}: {rate:.0} steps/s",
            args.steps, args.task
        );
        rates.push(rate);
    }
    Ok(median(rates))
}

fn main() -> ExitCode {
    let result = parse_args().and_then(|args| run(&args));
    match result {
        Ok(rate) => {
            println!("env_steps_per_sec: {rate:.0}");
            ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("bench_env: {message}");
            ExitCode::FAILURE
        }
    }
}
