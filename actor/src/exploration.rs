//! Turning policy heads into actions: tanh-Gaussian sampling, the reference deterministic
//! level's Gaussian + ε-random noise, the noise-free low action of FR navigation, uniform random
//! high actions, and clipping.
//!
//! Invariants: every random number comes from the caller's generator (the actor's seeded
//! `Pcg64Mcg`), drawn in a fixed order, so a seed fixes the actions; outputs are written into
//! caller-provided slices of the action's length.

use rand::Rng;
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;

use crate::networks::{GaussianHead, LowHead};

/// Exploration noise of the deterministic low-level variant (`learner.low.deterministic`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DeterministicNoise {
    /// Gaussian noise std as a fraction of the action bound (`noise_scale`).
    pub noise_scale: f32,
    /// Probability of replacing the whole action by a uniform random one (`random_eps`).
    pub random_eps: f64,
}

/// SAC sample `a = scale · tanh(μ + σ·ε)`, ε ~ N(0, I) from `rng` (the same map as
/// `nets::GaussianPolicy::sample`, without the log-probability).
pub(crate) fn sample_gaussian(head: &GaussianHead, rng: &mut Pcg64Mcg, out: &mut [f32]) {
    for ((a, mean), log_std) in out.iter_mut().zip(&head.mean).zip(&head.log_std) {
        let eps: f32 = rng.sample(StandardNormal);
        *a = head.scale * (mean + log_std.exp() * eps).tanh();
    }
}

/// Uniform sample in `[−bound, bound]` per dimension.
pub(crate) fn sample_uniform(bound: f32, rng: &mut Pcg64Mcg, out: &mut [f32]) {
    for a in out.iter_mut() {
        *a = rng.random_range(-bound..=bound);
    }
}

/// The reference code's behaviour action: `clip(μ(x) + noise_scale·scale·N(0, I), ±scale)`, then
/// with probability `random_eps` the whole action replaced by a uniform one (digest §3.2).
fn deterministic_with_noise(
    action: &[f32],
    scale: f32,
    noise: DeterministicNoise,
    rng: &mut Pcg64Mcg,
    out: &mut [f32],
) {
    let std = noise.noise_scale * scale;
    for (a, mean) in out.iter_mut().zip(action) {
        let eps: f32 = rng.sample(StandardNormal);
        *a = (mean + std * eps).clamp(-scale, scale);
    }
    if rng.random_bool(noise.random_eps.clamp(0.0, 1.0)) {
        sample_uniform(scale, rng, out);
    }
}

/// The low level's exploratory action for `head`.
pub(crate) fn low_action(
    head: &LowHead,
    noise: DeterministicNoise,
    rng: &mut Pcg64Mcg,
    out: &mut [f32],
) {
    match head {
        LowHead::Gaussian(head) => sample_gaussian(head, rng, out),
        LowHead::Deterministic { action, scale } => {
            deterministic_with_noise(action, *scale, noise, rng, out)
        }
    }
}

/// The low level's noise-free action for `head` (FR navigation, SPEC §6.6): the deterministic
/// actor's action, or `scale · tanh(μ)` for a SAC head.
pub(crate) fn noise_free_low_action(head: &LowHead, out: &mut [f32]) {
    match head {
        LowHead::Gaussian(head) => {
            for (a, mean) in out.iter_mut().zip(&head.mean) {
                *a = head.scale * mean.tanh();
            }
        }
        LowHead::Deterministic { action, .. } => {
            for (a, mean) in out.iter_mut().zip(action) {
                *a = *mean;
            }
        }
    }
}

/// Clips `action` into the env's per-dimension bounds.
pub(crate) fn clip(action: &mut [f32], low: &[f32], high: &[f32]) {
    for ((a, lo), hi) in action.iter_mut().zip(low).zip(high) {
        *a = a.clamp(*lo, *hi);
    }
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;

    use super::*;

    #[test]
    fn deterministic_noise_stays_in_bounds_and_sometimes_goes_uniform() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let noise = DeterministicNoise {
            noise_scale: 0.2,
            random_eps: 0.5,
        };
        let mut out = [0.0; 4];
        let mut far = 0;
        for _ in 0..200 {
            deterministic_with_noise(&[0.9, -0.9, 0.0, 0.5], 1.0, noise, &mut rng, &mut out);
            assert!(out.iter().all(|a| a.abs() <= 1.0));
            far += usize::from((out[2]).abs() > 0.8);
        }
        assert!(
            far > 5,
            "uniform replacement should sometimes move a zero mean far: {far}"
        );
    }

    #[test]
    fn the_noise_free_low_action_is_the_mean_action_and_draws_nothing() {
        let gaussian = LowHead::Gaussian(GaussianHead {
            mean: vec![0.5, -2.0],
            log_std: vec![3.0, 3.0],
            scale: 2.0,
        });
        let mut out = [0.0; 2];
        noise_free_low_action(&gaussian, &mut out);
        assert_eq!(out, [2.0 * 0.5f32.tanh(), 2.0 * (-2.0f32).tanh()]);
        let deterministic = LowHead::Deterministic {
            action: vec![0.25, -0.75],
            scale: 1.0,
        };
        noise_free_low_action(&deterministic, &mut out);
        assert_eq!(out, [0.25, -0.75]);
    }

    #[test]
    fn clip_uses_per_dimension_bounds() {
        let mut action = [2.0, -3.0, 0.5];
        clip(&mut action, &[-1.0, -2.0, -1.0], &[1.0, 2.0, 1.0]);
        assert_eq!(action, [1.0, -2.0, 0.5]);
    }
}
