//! Side-by-side speed of Ant parameter variants in an Ant maze task, interleaved so that a
//! busy machine slows every variant alike.
//!
//! `cargo run --release -p envs --example bench_ant_variants -- [--steps N] [--rounds R]
//! [--layout u|s|w|fourrooms] base "frame_skip=4 timestep_secs=0.05" ...`
//!
//! Each positional argument is one variant: space-separated `key=value` overrides of
//! [`AntParams`] (keys in `common/ant_overrides.rs`), or `base` for the defaults. In every
//! round each variant steps its own training task `--steps` control steps with the same
//! uniform random actions (resetting at episode ends with the same seeds), the order of the
//! variants rotating from round to round. Printed per variant: the median over rounds of
//! control steps per wall-clock second and per second of this thread's CPU time (from
//! `/proc/thread-self/schedstat`, so time spent waiting for a core on a shared machine does
//! not count), and the ratio of each to the first variant.

use std::process::ExitCode;
use std::time::Instant;

use envs::ant::AntParams;
use envs::maze::MazeLayout;
use envs::maze_env::{MazeEnv, MazeTaskParams};
use envs::registry::make_ant_maze;
use envs::{Env, EnvError, Variant};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

#[path = "common/ant_overrides.rs"]
mod ant_overrides;
use ant_overrides::{apply_override, bad_arg};

const DEFAULT_STEPS: usize = 2000;
const DEFAULT_ROUNDS: usize = 5;
const ACTION_SEED: u64 = 0;

struct AntVariant {
    label: String,
    params: AntParams,
}

struct Args {
    steps: usize,
    rounds: usize,
    layout: MazeLayout,
    variants: Vec<AntVariant>,
}

fn parse_layout(value: &str) -> Result<MazeLayout, EnvError> {
    match value {
        "u" => Ok(MazeLayout::U),
        "s" => Ok(MazeLayout::S),
        "w" => Ok(MazeLayout::W),
        "fourrooms" => Ok(MazeLayout::FourRooms),
        _ => Err(bad_arg("--layout", value)),
    }
}

fn parse_variant(text: &str) -> Result<AntVariant, EnvError> {
    let mut params = AntParams::default();
    for item in text.split_whitespace().filter(|item| *item != "base") {
        let (key, value) = item.split_once('=').ok_or_else(|| bad_arg(item, ""))?;
        apply_override(&mut params, key, value)?;
    }
    params.validate()?;
    Ok(AntVariant {
        label: text.to_string(),
        params,
    })
}

fn parse_args() -> Result<Args, EnvError> {
    let mut parsed = Args {
        steps: DEFAULT_STEPS,
        rounds: DEFAULT_ROUNDS,
        layout: MazeLayout::U,
        variants: Vec::new(),
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().unwrap_or_default();
        match arg.as_str() {
            "--steps" => {
                let v = value();
                parsed.steps = v.parse().map_err(|_| bad_arg("--steps", &v))?;
            }
            "--rounds" => {
                let v = value();
                parsed.rounds = v.parse().map_err(|_| bad_arg("--rounds", &v))?;
            }
            "--layout" => parsed.layout = parse_layout(&value())?,
            _ => parsed.variants.push(parse_variant(&arg)?),
        }
    }
    if parsed.variants.is_empty() {
        parsed.variants.push(parse_variant("base")?);
    }
    if parsed.steps == 0 || parsed.rounds == 0 {
        return Err(bad_arg("--steps/--rounds", "0"));
    }
    Ok(parsed)
}

/// CPU time this thread has run, in seconds (Linux schedstat; 0 where unavailable).
fn thread_cpu_secs() -> f64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|text| text.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(0.0, |ns| ns as f64 * 1e-9)
}

/// Steps `env` through `actions`; returns (wall steps/s, CPU steps/s).
fn time_run(
    env: &mut MazeEnv<envs::ant::Ant>,
    actions: &[[f32; 8]],
    round: usize,
) -> Result<(f64, f64), EnvError> {
    let mut seed = (round as u64) << 32;
    env.reset(seed);
    let cpu_start = thread_cpu_secs();
    let start = Instant::now();
    for action in actions {
        let step = env.step(action)?;
        if step.terminated || step.truncated {
            seed += 1;
            env.reset(seed);
        }
    }
    let wall = start.elapsed().as_secs_f64();
    let cpu = thread_cpu_secs() - cpu_start;
    let n = actions.len() as f64;
    Ok((n / wall, if cpu > 0.0 { n / cpu } else { 0.0 }))
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn run(args: &Args) -> Result<(), EnvError> {
    let mut envs = Vec::with_capacity(args.variants.len());
    for variant in &args.variants {
        let env = make_ant_maze(
            args.layout,
            Variant::Train,
            variant.params.clone(),
            MazeTaskParams::default(),
        )?;
        envs.push(env);
    }
    let mut rng = Pcg64Mcg::seed_from_u64(ACTION_SEED);
    let bound = args.variants[0].params.ctrl_range;
    let actions: Vec<[f32; 8]> = (0..args.steps)
        .map(|_| std::array::from_fn(|_| rng.random_range(-bound..=bound)))
        .collect();
    let n = envs.len();
    let mut wall = vec![Vec::new(); n];
    let mut cpu = vec![Vec::new(); n];
    for round in 0..args.rounds {
        for k in 0..n {
            let index = (round + k) % n;
            let (w, c) = time_run(&mut envs[index], &actions, round)?;
            wall[index].push(w);
            cpu[index].push(c);
        }
    }
    let (wall0, cpu0) = (median(&mut wall[0].clone()), median(&mut cpu[0].clone()));
    for (index, variant) in args.variants.iter().enumerate() {
        let w = median(&mut wall[index]);
        let c = median(&mut cpu[index]);
        println!(
            "variant [{}]: wall {w:.0} steps/s ({:.3}x), cpu {c:.0} steps/s ({:.3}x)",
            variant.label,
            w / wall0,
            c / cpu0
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    match parse_args().and_then(|args| run(&args)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("bench_ant_variants: {error}");
            ExitCode::FAILURE
        }
    }
}
