//! `PointMass`: a force-controlled ball on the maze floor (ours, not in the paper; SPEC §4).
//!
//! Model. A planar point mass of radius `r` with linear damping:
//! `m·dv/dt = F_max·a − c·v`, `dx/dt = v`, where `a ∈ [−1, 1]²` is the action. Each control step
//! is `n_substeps` semi-implicit Euler sub-steps (velocity first, then position), after which the
//! speed is capped at `max_speed` and the ball is pushed out of every wall it overlaps: along the
//! minimum-penetration direction, with the velocity component into the wall cancelled (a
//! perfectly inelastic, frictionless contact). Walls are the maze's [`StaticBox`]es seen from
//! above (their height is ignored: every wall reaches the floor and is taller than the ball).
//!
//! Why not a rapier world: the point maze exists for fast tests and quick experiments and must
//! run ≥ 50,000 control steps/s on one thread. A rapier world pays broad phase, contact graph and
//! solver set-up on every sub-step; this closed-form integrator costs a few hundred flops per
//! control step and is exact enough for a ball among axis-aligned boxes. Rapier is kept for the
//! articulated robots (Ant, half-cheetah), whose dynamics need it.
//!
//! Observation (4-D, `f32`): `[x, y, vx, vy]` — position (m) and velocity (m/s) in the world
//! frame; `obs[0..2]` is the achieved goal. Action (2-D, bound 1): force as a fraction of
//! `max_force_n` along x and y.
//!
//! Invariants: with valid [`PointParams`] (checked by [`PointMass::new`]) the ball moves at most
//! `max_speed · dt_sub < radius` per sub-step, so it cannot tunnel through a wall; the state stays
//! finite for finite actions (forces and speed are bounded).

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::api::{EnvError, Robot, StaticBox};

/// Observation length: `[x, y, vx, vy]`.
pub const POINT_OBS_DIM: usize = 4;
/// Action length: force along x and y.
pub const POINT_ACTION_DIM: usize = 2;
/// Action bound: actions are fractions of the maximum force.
pub const POINT_ACTION_BOUND: f32 = 1.0;

/// Physical constants of the point mass. All sources are "ours": chosen so that the ball crosses
/// a 4 m cell in about 8 control steps from rest (terminal speed 3 m/s at 0.2 s per step),
/// comparable to the Ant's reach per high-level segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PointParams {
    /// Ball radius, metres. Default 0.5 (fits the 2 m corridors of FourRooms). Source: ours.
    pub radius_m: f32,
    /// Mass, kilograms. Default 1.0. Source: ours.
    pub mass_kg: f32,
    /// Force at action magnitude 1 along an axis, newtons. Default 12.0 (terminal speed
    /// `max_force_n / damping` = 3 m/s). Source: ours.
    pub max_force_n: f32,
    /// Linear damping coefficient `c`, N·s/m. Default 4.0 (velocity time constant m/c = 0.25 s).
    /// Source: ours.
    pub damping_n_s_per_m: f32,
    /// Speed cap, m/s. Default 4.0 (above the 3 m/s axis terminal speed; a diagonal full-force
    /// push reaches 4.24 m/s without the cap). Source: ours.
    pub max_speed_m_per_s: f32,
    /// Simulated seconds per control step. Default 0.2 (as the Ant). Source: ours.
    pub control_dt_secs: f64,
    /// Integration sub-steps per control step. Default 10 (0.02 s each, as the Ant's timestep).
    /// Source: ours.
    pub n_substeps: u32,
    /// Half-width of the uniform reset noise on x and y, metres. Default 0.1 (as the Ant's
    /// U(±0.1) position noise). Velocity starts at 0. Source: ours.
    pub reset_noise_m: f32,
}

impl Default for PointParams {
    fn default() -> Self {
        PointParams {
            radius_m: 0.5,
            mass_kg: 1.0,
            max_force_n: 12.0,
            damping_n_s_per_m: 4.0,
            max_speed_m_per_s: 4.0,
            control_dt_secs: 0.2,
            n_substeps: 10,
            reset_noise_m: 0.1,
        }
    }
}

impl PointParams {
    /// Seconds per integration sub-step.
    pub fn substep_secs(&self) -> f32 {
        (self.control_dt_secs / f64::from(self.n_substeps.max(1))) as f32
    }

    /// Checks every field; lists the first problem found.
    pub fn validate(&self) -> Result<(), EnvError> {
        let positive = [
            ("radius_m", self.radius_m),
            ("mass_kg", self.mass_kg),
            ("max_force_n", self.max_force_n),
            ("max_speed_m_per_s", self.max_speed_m_per_s),
            ("control_dt_secs", self.control_dt_secs as f32),
        ];
        for (field, value) in positive {
            if !(value.is_finite() && value > 0.0) {
                return Err(invalid(field, value, "must be finite and positive"));
            }
        }
        self.validate_rest()
    }

    fn validate_rest(&self) -> Result<(), EnvError> {
        if !(self.damping_n_s_per_m.is_finite() && self.damping_n_s_per_m >= 0.0) {
            return Err(invalid(
                "damping_n_s_per_m",
                self.damping_n_s_per_m,
                "must be finite and ≥ 0",
            ));
        }
        if !(self.reset_noise_m.is_finite() && self.reset_noise_m >= 0.0) {
            return Err(invalid(
                "reset_noise_m",
                self.reset_noise_m,
                "must be finite and ≥ 0",
            ));
        }
        if self.n_substeps == 0 {
            return Err(invalid("n_substeps", self.n_substeps, "must be at least 1"));
        }
        let dt = self.substep_secs();
        if self.damping_n_s_per_m * dt / self.mass_kg >= 1.0 {
            return Err(invalid(
                "damping_n_s_per_m",
                self.damping_n_s_per_m,
                "c·dt_sub/m must be < 1 (stability)",
            ));
        }
        if self.max_speed_m_per_s * dt >= self.radius_m {
            return Err(invalid(
                "max_speed_m_per_s",
                self.max_speed_m_per_s,
                "max_speed·dt_sub must be < radius (no tunnelling)",
            ));
        }
        Ok(())
    }
}

/// A wall seen from above: centre and half extents in the plane.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Wall2 {
    center: [f32; 2],
    half: [f32; 2],
}

/// The force-controlled ball. See the module docs for the model and the observation layout.
#[derive(Debug, Clone)]
pub struct PointMass {
    params: PointParams,
    walls: Vec<Wall2>,
    pos: [f32; 2],
    vel: [f32; 2],
    /// `1 − c·dt_sub/m`, the per-sub-step velocity decay.
    decay: f32,
    /// `dt_sub / m`, velocity change per newton per sub-step.
    dt_over_mass: f32,
    dt_sub: f32,
}

impl PointMass {
    /// A ball at the origin among `walls`. Fails on invalid parameters.
    pub fn new(params: PointParams, walls: &[StaticBox]) -> Result<PointMass, EnvError> {
        params.validate()?;
        let dt_sub = params.substep_secs();
        let walls = walls
            .iter()
            .map(|b| Wall2 {
                center: [b.center[0], b.center[1]],
                half: [b.half_extents[0], b.half_extents[1]],
            })
            .collect();
        Ok(PointMass {
            params,
            walls,
            pos: [0.0; 2],
            vel: [0.0; 2],
            decay: 1.0 - params.damping_n_s_per_m * dt_sub / params.mass_kg,
            dt_over_mass: dt_sub / params.mass_kg,
            dt_sub,
        })
    }

    pub fn params(&self) -> &PointParams {
        &self.params
    }

    /// Position, metres.
    pub fn position(&self) -> [f32; 2] {
        self.pos
    }

    /// Velocity, m/s.
    pub fn velocity(&self) -> [f32; 2] {
        self.vel
    }

    /// Places the ball exactly (for tests and scripted starts); walls are resolved at the next
    /// sub-step.
    pub fn set_state(&mut self, pos: [f32; 2], vel: [f32; 2]) {
        self.pos = pos;
        self.vel = vel;
    }

    /// One semi-implicit Euler sub-step under `force` (newtons), then the speed cap and contacts.
    fn substep(&mut self, force: [f32; 2]) {
        let (decay, dt_over_mass) = (self.decay, self.dt_over_mass);
        self.vel = [0, 1].map(|d| self.vel[d] * decay + force[d] * dt_over_mass);
        self.cap_speed();
        self.pos = [0, 1].map(|d| self.pos[d] + self.vel[d] * self.dt_sub);
        self.resolve_contacts();
    }

    fn cap_speed(&mut self) {
        let speed_sq = self.vel[0] * self.vel[0] + self.vel[1] * self.vel[1];
        let max = self.params.max_speed_m_per_s;
        if speed_sq > max * max {
            let scale = max / speed_sq.sqrt();
            self.vel = [self.vel[0] * scale, self.vel[1] * scale];
        }
    }

    fn resolve_contacts(&mut self) {
        let radius = self.params.radius_m;
        for i in 0..self.walls.len() {
            if let Some((normal, depth)) = penetration(self.pos, radius, &self.walls[i]) {
                self.pos = [
                    self.pos[0] + normal[0] * depth,
                    self.pos[1] + normal[1] * depth,
                ];
                let inward = self.vel[0] * normal[0] + self.vel[1] * normal[1];
                if inward < 0.0 {
                    self.vel = [
                        self.vel[0] - inward * normal[0],
                        self.vel[1] - inward * normal[1],
                    ];
                }
            }
        }
    }
}

/// Outward unit normal and depth by which a ball at `pos` overlaps `wall`; `None` if apart.
fn penetration(pos: [f32; 2], radius: f32, wall: &Wall2) -> Option<([f32; 2], f32)> {
    let d = [pos[0] - wall.center[0], pos[1] - wall.center[1]];
    if d[0].abs() >= wall.half[0] + radius || d[1].abs() >= wall.half[1] + radius {
        return None;
    }
    let inside = d[0].abs() <= wall.half[0] && d[1].abs() <= wall.half[1];
    if inside {
        return Some(centre_inside_push(d, radius, wall));
    }
    let closest = [
        d[0].clamp(-wall.half[0], wall.half[0]),
        d[1].clamp(-wall.half[1], wall.half[1]),
    ];
    let delta = [d[0] - closest[0], d[1] - closest[1]];
    let dist_sq = delta[0] * delta[0] + delta[1] * delta[1];
    if dist_sq >= radius * radius {
        return None;
    }
    let dist = dist_sq.sqrt();
    Some(([delta[0] / dist, delta[1] / dist], radius - dist))
}

/// Push for a centre inside the box: out through the nearest face, to touching distance.
fn centre_inside_push(d: [f32; 2], radius: f32, wall: &Wall2) -> ([f32; 2], f32) {
    let depth_x = wall.half[0] - d[0].abs() + radius;
    let depth_y = wall.half[1] - d[1].abs() + radius;
    if depth_x <= depth_y {
        ([sign(d[0]), 0.0], depth_x)
    } else {
        ([0.0, sign(d[1])], depth_y)
    }
}

fn sign(v: f32) -> f32 {
    if v < 0.0 {
        -1.0
    } else {
        1.0
    }
}

impl Robot for PointMass {
    fn obs_dim(&self) -> usize {
        POINT_OBS_DIM
    }

    fn action_dim(&self) -> usize {
        POINT_ACTION_DIM
    }

    fn action_bound(&self) -> f32 {
        POINT_ACTION_BOUND
    }

    fn control_dt_secs(&self) -> f64 {
        self.params.control_dt_secs
    }

    fn reset(&mut self, rng: &mut rand_pcg::Pcg64Mcg) {
        let noise = self.params.reset_noise_m;
        self.pos = [
            rng.random_range(-noise..=noise),
            rng.random_range(-noise..=noise),
        ];
        self.vel = [0.0; 2];
    }

    fn step(&mut self, action: &[f32]) {
        let force = [
            action[0] * self.params.max_force_n,
            action[1] * self.params.max_force_n,
        ];
        for _ in 0..self.params.n_substeps {
            self.substep(force);
        }
    }

    fn write_obs(&self, out: &mut [f32]) {
        out[..POINT_OBS_DIM].copy_from_slice(&[self.pos[0], self.pos[1], self.vel[0], self.vel[1]]);
    }

    fn xy(&self) -> [f32; 2] {
        self.pos
    }

    fn torso_z(&self) -> Option<f32> {
        None
    }
}

fn invalid(field: &str, value: impl std::fmt::Display, reason: &str) -> EnvError {
    EnvError::InvalidParam {
        field: format!("point.{field}"),
        value: value.to_string(),
        reason: reason.to_string(),
    }
}
