//! Digest of a task's trajectory under fixed random actions, to check that a change meant to
//! be speed-only leaves the physics bit-identical.
//!
//! `cargo run --release -p envs --example trajectory_digest -- --task antmaze-u --steps 5000`
//!
//! Steps the training task with uniform random actions (action seed 0, reset seeds 0, 1, 2, …
//! at episode ends) and prints one line: task, steps, episodes, the FNV-1a hash of the bits of
//! every observation and reward, and the sum of rewards. Two builds that print the same line
//! produced the same trajectory to the last bit.

use std::process::ExitCode;

use envs::registry::make;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const ACTION_SEED: u64 = 0;
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// FNV-1a over the bytes of `value`.
fn fnv(hash: u64, value: f32) -> u64 {
    value
        .to_bits()
        .to_le_bytes()
        .iter()
        .fold(hash, |h, b| (h ^ u64::from(*b)).wrapping_mul(FNV_PRIME))
}

fn run(task: &str, n_steps: u64) -> Result<String, String> {
    let mut env = make(task).map_err(|e| e.to_string())?;
    let (low, high) = (
        env.spec().action_low.clone(),
        env.spec().action_high.clone(),
    );
    let mut rng = Pcg64Mcg::seed_from_u64(ACTION_SEED);
    let mut episode = 0u64;
    let reset = env.reset(episode);
    let mut hash = reset.obs.iter().fold(FNV_OFFSET, |h, v| fnv(h, *v));
    let mut reward_sum = 0.0f64;
    let mut action = vec![0.0f32; low.len()];
    for _ in 0..n_steps {
        for (d, a) in action.iter_mut().enumerate() {
            *a = rng.random_range(low[d]..=high[d]);
        }
        let step = env.step(&action).map_err(|e| e.to_string())?;
        hash = step
            .obs
            .iter()
            .fold(fnv(hash, step.reward), |h, v| fnv(h, *v));
        reward_sum += f64::from(step.reward);
        if step.terminated || step.truncated {
            episode += 1;
            let reset = env.reset(episode);
            hash = reset.obs.iter().fold(hash, |h, v| fnv(h, *v));
        }
    }
    Ok(format!(
        "{task} steps {n_steps} episodes {episode} digest {hash:016x} reward_sum {reward_sum}"
    ))
}

fn main() -> ExitCode {
    let mut task = "antmaze-u".to_string();
    let mut n_steps = 5000u64;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let value = args.next().unwrap_or_default();
        match flag.as_str() {
            "--task" => task = value,
            "--steps" => match value.parse() {
                Ok(n) => n_steps = n,
                Err(e) => {
                    eprintln!("--steps {value}: {e}");
                    return ExitCode::FAILURE;
                }
            },
            other => {
                eprintln!("unknown flag {other}; use --task NAME --steps N");
                return ExitCode::FAILURE;
            }
        }
    }
    match run(&task, n_steps) {
        Ok(line) => {
            println!("{line}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("{e}");
            ExitCode::FAILURE
        }
    }
}
