//! Environment stepping throughput, shared by `asi bench env` and the `bench_env` example.
//!
//! Steps one task with uniform random actions inside its action bounds (resetting when an
//! episode ends) on the calling thread, `repeats` times, and reports each repeat's control steps
//! per second and their median. Timing covers `step` and the resets it triggers; the action
//! draws are made before the clock starts.

use std::time::Instant;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::api::EnvError;
use crate::registry;

/// Result of [`run`].
#[derive(Debug, Clone, PartialEq)]
pub struct BenchReport {
    pub task: String,
    pub steps: usize,
    /// Control steps per second of each repeat.
    pub per_repeat: Vec<f64>,
    /// Median of `per_repeat`.
    pub median: f64,
    /// Steps that ended in a physics failure, over all repeats.
    pub n_physics_failures: u64,
}

/// Times `steps` random control steps of `task`, `repeats` times.
pub fn run(task: &str, steps: usize, repeats: usize, seed: u64) -> Result<BenchReport, EnvError> {
    let mut env = registry::make(task)?;
    let (low, high) = (
        env.spec().action_low.clone(),
        env.spec().action_high.clone(),
    );
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let actions: Vec<f32> = (0..steps * low.len())
        .map(|i| {
            let d = i % low.len();
            rng.random_range(low[d]..=high[d])
        })
        .collect();
    let mut per_repeat = Vec::with_capacity(repeats);
    for repeat in 0..repeats {
        env.reset(seed.wrapping_add(repeat as u64));
        let start = Instant::now();
        let mut episode = 0u64;
        for action in actions.chunks_exact(low.len()) {
            let step = env.step(action)?;
            if step.terminated || step.truncated {
                episode += 1;
                env.reset(seed.wrapping_add(repeat as u64).wrapping_add(episode << 32));
            }
        }
        per_repeat.push(steps as f64 / start.elapsed().as_secs_f64().max(f64::MIN_POSITIVE));
    }
    let median = median(&per_repeat);
    Ok(BenchReport {
        task: task.to_owned(),
        steps,
        per_repeat,
        median,
        n_physics_failures: env.n_physics_failures(),
    })
}

/// Median of a non-empty slice (mean of the two middle values for even lengths); 0 if empty.
pub fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even_lengths() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&[]), 0.0);
    }

    #[test]
    fn a_short_pointmaze_bench_reports_every_repeat() {
        let report = run("pointmaze-u", 200, 3, 7).unwrap();
        assert_eq!(report.per_repeat.len(), 3);
        assert!(report.per_repeat.iter().all(|s| s.is_finite() && *s > 0.0));
        assert_eq!(report.n_physics_failures, 0);
    }

    #[test]
    fn an_unknown_task_is_an_error() {
        assert!(matches!(
            run("no-such-task", 10, 1, 0),
            Err(EnvError::UnknownTask { .. })
        ));
    }
}
