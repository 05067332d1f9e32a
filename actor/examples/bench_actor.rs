//! Throughput of `Actor::next_chunk` (env step + φ + low policy every step, high policy every
//! c steps, record writing), in env steps per second, single thread of the caller.
//!
//! Run: `RAYON_NUM_THREADS=1 cargo run --release -p actor --example bench_actor [-- <steps-scale>]`.
//! candle parallelises every matmul over `RAYON_NUM_THREADS` threads (default: all cores); at
//! batch 1 that costs far more than it gains (measured 8× slower on 2 busy cores), so actor
//! processes should run with `RAYON_NUM_THREADS=1`. The value in effect is printed.
//! For each task and low-level variant it prints the median of 3 timed repeats after one
//! warm-up chunk. `random_episodes = 0`, so the high policy runs at every decision; there is no
//! graph-service ([`actor::NoGraph`]), so no decision explores.

use std::time::Instant;

use actor::{Actor, NoGraph};
use protocol::config::LowAlgo;
use protocol::{ActorId, Config};

/// Env steps timed per repeat, before scaling, for each task.
const CASES: [(&str, u64); 2] = [("pointmaze-u", 20_000), ("antmaze-u", 2_000)];
const REPEATS: usize = 3;

fn config(task: &str, algo: LowAlgo) -> Config {
    let mut config = Config::default();
    config.env.task = task.to_owned();
    config.learner.high.random_episodes = 0;
    config.learner.low.algo = algo;
    config
}

/// Steps per second of `next_chunk` over about `n_steps` steps.
fn measure(actor: &mut Actor, n_steps: u64) -> Result<f64, actor::ActorError> {
    let start_steps = actor.stats().env_steps;
    let start = Instant::now();
    while actor.stats().env_steps - start_steps < n_steps {
        actor.next_chunk(&mut NoGraph)?;
    }
    let steps = actor.stats().env_steps - start_steps;
    Ok(steps as f64 / start.elapsed().as_secs_f64())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scale: f64 = std::env::args()
        .nth(1)
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(1.0);
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset (all cores)".into());
    println!("RAYON_NUM_THREADS = {threads}");
    println!(
        "{:<14} {:<14} {:>12} {:>12}",
        "task", "low", "steps", "steps/s"
    );
    for (task, base_steps) in CASES {
        for algo in [LowAlgo::Sac, LowAlgo::Deterministic] {
            let mut actor = Actor::new(&config(task, algo), ActorId(0), 1)?;
            actor.next_chunk(&mut NoGraph)?;
            let n_steps = (base_steps as f64 * scale).max(1.0) as u64;
            let mut rates = (0..REPEATS)
                .map(|_| measure(&mut actor, n_steps))
                .collect::<Result<Vec<_>, _>>()?;
            rates.sort_by(f64::total_cmp);
            println!(
                "{task:<14} {:<14} {n_steps:>12} {:>12.0}",
                format!("{algo:?}"),
                rates[REPEATS / 2]
            );
        }
    }
    Ok(())
}
