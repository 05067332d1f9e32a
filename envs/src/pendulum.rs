//! `Pendulum`: a port of Gymnasium's `Pendulum-v1` (classic control), used as the flat SAC
//! sanity check of the learner (a task with a published SAC result: Stable-Baselines3's SAC
//! reaches a mean return of about −150 to −200 within 20,000 env steps).
//!
//! Model (Gymnasium `envs/classic_control/pendulum.py`, `PendulumEnv.step`; every constant is a
//! field of [`PendulumParams`] with Gymnasium's value as default). State `(θ, θ̇)`, θ = 0 upright,
//! counter-clockwise positive. One step with torque `u`:
//! 1. `u ← clip(u, −max_torque, max_torque)`;
//! 2. `cost = norm(θ)² + 0.1·θ̇² + 0.001·u²` on the state *before* the step, with
//!    `norm(x) = ((x + π) mod 2π) − π` (floor modulo, so `norm(x) ∈ [−π, π)`);
//! 3. `θ̇' = clip(θ̇ + (3g/(2l)·sin θ + 3/(m l²)·u)·dt, −max_speed, max_speed)`;
//! 4. `θ' = θ + θ̇'·dt` (semi-implicit Euler; θ itself is never wrapped, only the cost is);
//! 5. reward `−cost`, observation `[cos θ', sin θ', θ̇']` (`f32`), `terminated = false`.
//!
//! Reset: `θ ~ U(−π, π)`, `θ̇ ~ U(−1, 1)`. Episodes are truncated after 200 steps (Gymnasium's
//! registration `max_episode_steps=200`, applied by its `TimeLimit` wrapper).
//!
//! Invariants: the state is kept in `f64` as Gymnasium's NumPy state; `reset(seed)` fully
//! re-seeds (same seed → same episode); a bad action (wrong length, NaN/inf) is an [`EnvError`]
//! and changes nothing; after `truncated`, `step` is [`EnvError::NotReady`] until `reset`.

use std::f64::consts::PI;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::api::EnvError;

/// Observation length: `[cos θ, sin θ, θ̇]`.
pub const PENDULUM_OBS_DIM: usize = 3;
/// Action length: the torque.
pub const PENDULUM_ACTION_DIM: usize = 1;
/// Task name used in errors.
const TASK: &str = "pendulum";

/// Constants of `Pendulum-v1`. Every default is Gymnasium's (`PendulumEnv.__init__`, `reset`,
/// and the `Pendulum-v1` registration).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PendulumParams {
    /// Gravity g, m/s². Default 10.0 (Gymnasium's `g` argument).
    pub gravity: f64,
    /// Mass m, kg. Default 1.0.
    pub mass_kg: f64,
    /// Length l, m. Default 1.0.
    pub length_m: f64,
    /// Time step dt, s. Default 0.05.
    pub dt_secs: f64,
    /// Angular speed clip, rad/s. Default 8.0 (`max_speed`).
    pub max_speed: f64,
    /// Torque clip, N·m; also the action bound. Default 2.0 (`max_torque`).
    pub max_torque: f64,
    /// Half-width of the uniform reset angle, rad. Default π (`DEFAULT_X`).
    pub reset_theta_high: f64,
    /// Half-width of the uniform reset angular speed, rad/s. Default 1.0 (`DEFAULT_Y`).
    pub reset_theta_dot_high: f64,
    /// Episode length in steps; `truncated` is set on the last one. Default 200.
    pub max_steps: u32,
}

impl Default for PendulumParams {
    fn default() -> Self {
        Self {
            gravity: 10.0,
            mass_kg: 1.0,
            length_m: 1.0,
            dt_secs: 0.05,
            max_speed: 8.0,
            max_torque: 2.0,
            reset_theta_high: PI,
            reset_theta_dot_high: 1.0,
            max_steps: 200,
        }
    }
}

impl PendulumParams {
    /// Checks that every constant is finite and positive (the reset widths may be 0).
    pub fn validate(&self) -> Result<(), EnvError> {
        let positive = [
            ("gravity", self.gravity),
            ("mass_kg", self.mass_kg),
            ("length_m", self.length_m),
            ("dt_secs", self.dt_secs),
            ("max_speed", self.max_speed),
            ("max_torque", self.max_torque),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(field, value, "must be finite and positive"));
            }
        }
        for (field, value) in [
            ("reset_theta_high", self.reset_theta_high),
            ("reset_theta_dot_high", self.reset_theta_dot_high),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(invalid(field, value, "must be finite and non-negative"));
            }
        }
        if self.max_steps == 0 {
            return Err(invalid("max_steps", 0.0, "must be at least 1"));
        }
        Ok(())
    }
}

fn invalid(field: &str, value: f64, reason: &str) -> EnvError {
    EnvError::InvalidParam {
        field: field.to_owned(),
        value: value.to_string(),
        reason: reason.to_owned(),
    }
}

/// What [`Pendulum::step`] hands back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PendulumStep {
    /// `[cos θ', sin θ', θ̇']`.
    pub obs: [f32; PENDULUM_OBS_DIM],
    /// `−cost` of the state before the step and the clipped torque.
    pub reward: f32,
    /// Always false: the task has no terminal state.
    pub terminated: bool,
    /// True on step `max_steps` of the episode.
    pub truncated: bool,
}

/// `((x + π) mod 2π) − π` with a floor modulo (as NumPy's `%`): the angle in `[−π, π)`.
pub fn angle_normalize(x: f64) -> f64 {
    (x + PI).rem_euclid(2.0 * PI) - PI
}

/// The pendulum swing-up task. Build with [`Pendulum::new`], then [`Pendulum::reset`].
#[derive(Debug, Clone)]
pub struct Pendulum {
    params: PendulumParams,
    theta: f64,
    theta_dot: f64,
    n_steps: u32,
    ready: bool,
    rng: Pcg64Mcg,
}

impl Pendulum {
    /// A pendulum with validated `params`; `step` needs a `reset` first.
    pub fn new(params: PendulumParams) -> Result<Self, EnvError> {
        params.validate()?;
        Ok(Self {
            params,
            theta: 0.0,
            theta_dot: 0.0,
            n_steps: 0,
            ready: false,
            rng: Pcg64Mcg::seed_from_u64(0),
        })
    }

    /// The constants.
    pub fn params(&self) -> &PendulumParams {
        &self.params
    }

    /// Starts an episode: re-seeds from `seed`, draws `θ ~ U(−x, x)`, `θ̇ ~ U(−y, y)`.
    pub fn reset(&mut self, seed: u64) -> [f32; PENDULUM_OBS_DIM] {
        self.rng = Pcg64Mcg::seed_from_u64(seed);
        let (x, y) = (
            self.params.reset_theta_high,
            self.params.reset_theta_dot_high,
        );
        let theta = uniform(&mut self.rng, x);
        let theta_dot = uniform(&mut self.rng, y);
        self.start(theta, theta_dot)
    }

    /// Starts an episode from a given state (for tests and hand-made starts); errors if a value
    /// is not finite.
    pub fn reset_to(
        &mut self,
        theta: f64,
        theta_dot: f64,
    ) -> Result<[f32; PENDULUM_OBS_DIM], EnvError> {
        if !theta.is_finite() {
            return Err(invalid("theta", theta, "must be finite"));
        }
        if !theta_dot.is_finite() {
            return Err(invalid("theta_dot", theta_dot, "must be finite"));
        }
        Ok(self.start(theta, theta_dot))
    }

    fn start(&mut self, theta: f64, theta_dot: f64) -> [f32; PENDULUM_OBS_DIM] {
        self.theta = theta;
        self.theta_dot = theta_dot;
        self.n_steps = 0;
        self.ready = true;
        self.obs()
    }

    /// One step with `action = [torque]`; the torque is clipped to `±max_torque`.
    pub fn step(&mut self, action: &[f32]) -> Result<PendulumStep, EnvError> {
        let torque = self.validate_action(action)?;
        let p = &self.params;
        let u = torque.clamp(-p.max_torque, p.max_torque);
        let cost =
            angle_normalize(self.theta).powi(2) + 0.1 * self.theta_dot.powi(2) + 0.001 * u.powi(2);
        let gravity_term = 3.0 * p.gravity / (2.0 * p.length_m) * self.theta.sin();
        let torque_term = 3.0 / (p.mass_kg * p.length_m.powi(2)) * u;
        let theta_dot = (self.theta_dot + (gravity_term + torque_term) * p.dt_secs)
            .clamp(-p.max_speed, p.max_speed);
        self.theta += theta_dot * p.dt_secs;
        self.theta_dot = theta_dot;
        self.n_steps += 1;
        let truncated = self.n_steps >= p.max_steps;
        self.ready = !truncated;
        Ok(PendulumStep {
            obs: self.obs(),
            reward: -cost as f32,
            terminated: false,
            truncated,
        })
    }

    fn validate_action(&self, action: &[f32]) -> Result<f64, EnvError> {
        if !self.ready {
            return Err(EnvError::NotReady {
                task: TASK.to_owned(),
            });
        }
        match action {
            [torque] if torque.is_finite() => Ok(f64::from(*torque)),
            [torque] => Err(EnvError::NonFiniteAction {
                index: 0,
                value: *torque,
            }),
            _ => Err(EnvError::ActionLength {
                task: TASK.to_owned(),
                expected: PENDULUM_ACTION_DIM,
                got: action.len(),
            }),
        }
    }

    /// `[cos θ, sin θ, θ̇]` of the current state.
    pub fn obs(&self) -> [f32; PENDULUM_OBS_DIM] {
        [
            self.theta.cos() as f32,
            self.theta.sin() as f32,
            self.theta_dot as f32,
        ]
    }

    /// The raw state `(θ, θ̇)`; θ is not wrapped.
    pub fn state(&self) -> (f64, f64) {
        (self.theta, self.theta_dot)
    }

    /// Steps taken in the current episode.
    pub fn n_steps(&self) -> u32 {
        self.n_steps
    }
}

/// `U(−high, high)`; exactly 0 when `high` is 0.
fn uniform(rng: &mut Pcg64Mcg, high: f64) -> f64 {
    if high > 0.0 {
        rng.random_range(-high..high)
    } else {
        0.0
    }
}
