//! Control steps per second of HalfCheetahHurdle under uniform random actions.
//!
//! `cargo run --release -p envs --example bench_cheetah -- [n_steps] [substeps] [pgs_iterations]`
//! prints steps/s, physics failures and the worst joint-limit violation seen.

use std::time::Instant;

use envs::cheetah::{CheetahHurdle, CheetahParams, N_ACTION};
use envs::Env;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn arg(index: usize, default: usize) -> usize {
    std::env::args()
        .nth(index)
        .and_then(|a| a.parse().ok())
        .unwrap_or(default)
}

fn main() -> Result<(), envs::EnvError> {
    let n_steps = arg(1, 20_000);
    let mut params = CheetahParams::default();
    params.solver.substeps = arg(2, params.solver.substeps);
    params.solver.pgs_iterations = arg(3, params.solver.pgs_iterations);
    let ranges: Vec<[f32; 2]> = params.legs().iter().map(|leg| leg.range_rad).collect();
    let mut env = CheetahHurdle::new(params, false)?;
    let mut rng = Pcg64Mcg::seed_from_u64(0);
    env.reset(0);
    let mut worst_violation: f32 = 0.0;
    let start = Instant::now();
    for _ in 0..n_steps {
        let action: Vec<f32> = (0..N_ACTION).map(|_| rng.random_range(-1.0..1.0)).collect();
        let step = env.step(&action)?;
        for (j, [low, high]) in ranges.iter().enumerate() {
            let q = step.obs[3 + j];
            worst_violation = worst_violation.max(low - q).max(q - high);
        }
        if step.terminated || step.truncated {
            env.reset(rng.random());
        }
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{n_steps} control steps in {secs:.2} s: {:.0} steps/s; physics failures {}; worst limit violation {worst_violation:.4} rad",
        n_steps as f64 / secs,
        env.n_physics_failures()
    );
    Ok(())
}
