//! The `Pendulum-v1` port against numbers from Gymnasium's equations (NumPy, float64), the
//! 200-step truncation, angle normalisation, seeding and bad input.
//!
//! Reference (Gymnasium `PendulumEnv.step` transcribed; run with python3 + numpy):
//! ```python
//! import numpy as np
//! def norm(x): return ((x + np.pi) % (2 * np.pi)) - np.pi
//! def step(th, thdot, u):
//!     u = np.clip(np.float32(u), -2.0, 2.0)
//!     costs = norm(th) ** 2 + 0.1 * thdot ** 2 + 0.001 * u ** 2
//!     nd = np.clip(thdot + (3 * 10.0 / 2 * np.sin(th) + 3.0 * u) * 0.05, -8, 8)
//!     nt = th + nd * 0.05
//!     return -costs, nt, nd
//! print(step(0.5, -0.3, 1.0))    # -0.26, 0.5104784576976577, 0.2095691539531523
//! print(step(7.0, 7.5, 3.0))     # -6.1428237, 7.4, 8.0
//! print(step(-4.0, -1.0, -0.5))  # -5.313185, -4.0253699064259525, -0.5073981285190539
//! for x in [0.0, np.pi, 7.0, -7.0, 3 * np.pi + 0.1, 100.0]: print(norm(x))
//! ```

use std::f64::consts::PI;

use envs::pendulum::{angle_normalize, Pendulum, PendulumParams};
use envs::EnvError;

fn pendulum() -> Pendulum {
    Pendulum::new(PendulumParams::default()).unwrap()
}

/// One step from `(theta, theta_dot)` with `torque`, checked against the reference.
fn check_step(theta: f64, theta_dot: f64, torque: f32, reward: f32, next: (f64, f64)) {
    let mut env = pendulum();
    env.reset_to(theta, theta_dot).unwrap();
    let step = env.step(&[torque]).unwrap();
    assert!(
        (step.reward - reward).abs() < 1e-5,
        "reward {} != {reward}",
        step.reward
    );
    let (next_theta, next_theta_dot) = env.state();
    assert!(
        (next_theta - next.0).abs() < 1e-12,
        "θ' {next_theta} != {}",
        next.0
    );
    assert!(
        (next_theta_dot - next.1).abs() < 1e-12,
        "θ̇' {next_theta_dot} != {}",
        next.1
    );
    let expected_obs = [next.0.cos() as f32, next.0.sin() as f32, next.1 as f32];
    assert_eq!(step.obs, expected_obs);
    assert!(!step.terminated && !step.truncated);
}

#[test]
fn a_step_inside_the_limits_matches_gymnasium() {
    check_step(
        0.5,
        -0.3,
        1.0,
        -0.26,
        (0.5104784576976577, 0.2095691539531523),
    );
}

#[test]
fn torque_and_speed_are_clipped_and_the_cost_uses_the_normalised_angle() {
    // θ = 7 normalises to 0.7168…; u = 3 is clipped to 2; θ̇' = 8.29… is clipped to 8.
    check_step(7.0, 7.5, 3.0, -6.1428237, (7.4, 8.0));
}

#[test]
fn a_negative_angle_below_minus_pi_matches_gymnasium() {
    check_step(
        -4.0,
        -1.0,
        -0.5,
        -5.313185,
        (-4.0253699064259525, -0.5073981285190539),
    );
}

#[test]
fn angles_normalise_into_minus_pi_to_pi_with_a_floor_modulo() {
    let cases = [
        (0.0, 0.0),
        (PI, -PI),
        (-PI, -PI),
        (7.0, 0.7168146928204138),
        (-7.0, -0.7168146928204138),
        (3.0 * PI + 0.1, -3.0415926535897935),
        (100.0, -0.5309649148733762),
    ];
    for (x, expected) in cases {
        let got = angle_normalize(x);
        assert!(
            (got - expected).abs() < 1e-12,
            "norm({x}) = {got}, expected {expected}"
        );
    }
}

#[test]
fn episodes_truncate_after_200_steps_and_then_refuse_to_step() {
    let mut env = pendulum();
    env.reset(3);
    for i in 1..=200 {
        let step = env.step(&[0.5]).unwrap();
        assert!(!step.terminated);
        assert_eq!(step.truncated, i == 200, "step {i}");
        assert!(step.reward <= 0.0 && step.reward >= -16.273_605);
    }
    assert!(matches!(env.step(&[0.0]), Err(EnvError::NotReady { .. })));
    env.reset(4);
    assert!(env.step(&[0.0]).is_ok());
}

#[test]
fn reset_draws_the_state_uniformly_from_the_gymnasium_box_and_is_seeded() {
    let mut env = pendulum();
    let mut thetas = Vec::new();
    for seed in 0..2000 {
        let obs = env.reset(seed);
        let (theta, theta_dot) = env.state();
        assert!((-PI..PI).contains(&theta) && (-1.0..1.0).contains(&theta_dot));
        assert_eq!(
            obs,
            [theta.cos() as f32, theta.sin() as f32, theta_dot as f32]
        );
        thetas.push(theta);
    }
    // Uniform over (−π, π): mean ≈ 0 and a quarter of the draws in each quadrant.
    let mean = thetas.iter().sum::<f64>() / thetas.len() as f64;
    assert!(mean.abs() < 0.15, "mean θ {mean}");
    let upper_right = thetas
        .iter()
        .filter(|t| (0.0..PI / 2.0).contains(*t))
        .count();
    assert!(
        (400..600).contains(&upper_right),
        "{upper_right} of 2000 in [0, π/2)"
    );
    let a = env.reset(17);
    let mut other = pendulum();
    other.reset(99);
    assert_eq!(other.reset(17), a);
    assert_ne!(env.reset(18), a);
}

#[test]
fn bad_actions_are_errors_and_change_nothing() {
    let mut env = pendulum();
    assert!(matches!(env.step(&[0.0]), Err(EnvError::NotReady { .. })));
    env.reset_to(1.0, 0.5).unwrap();
    let wrong_length = env.step(&[0.0, 1.0]);
    assert!(matches!(
        wrong_length,
        Err(EnvError::ActionLength {
            expected: 1,
            got: 2,
            ..
        })
    ));
    assert!(matches!(
        env.step(&[]),
        Err(EnvError::ActionLength { got: 0, .. })
    ));
    assert!(matches!(
        env.step(&[f32::NAN]),
        Err(EnvError::NonFiniteAction { index: 0, .. })
    ));
    assert!(matches!(
        env.step(&[f32::INFINITY]),
        Err(EnvError::NonFiniteAction { .. })
    ));
    assert_eq!(env.state(), (1.0, 0.5));
    assert_eq!(env.n_steps(), 0);
    assert!(env.reset_to(f64::NAN, 0.0).is_err());
}

#[test]
fn invalid_parameters_are_rejected_with_the_field_name() {
    let params = PendulumParams {
        dt_secs: -0.05,
        ..PendulumParams::default()
    };
    match Pendulum::new(params) {
        Err(EnvError::InvalidParam { field, .. }) => assert_eq!(field, "dt_secs"),
        other => panic!("expected InvalidParam, got {other:?}"),
    }
    let params = PendulumParams {
        max_steps: 0,
        ..PendulumParams::default()
    };
    assert!(Pendulum::new(params).is_err());
}
