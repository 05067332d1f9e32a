//! A small rapier world for one robot on a floor among static boxes (maze walls, hurdles).
//!
//! Role: build a [`PhysicsWorld`] with gravity along −z, the solver settings of
//! [`SolverParams`], an infinite floor at z = 0 and the static boxes of a task, so that robot
//! modules only add their own bodies and joints.
//!
//! Invariants:
//! - z is up; the floor is the half-space z ≤ 0.
//! - Floor and boxes belong to [`ENVIRONMENT_GROUP`] and collide only with [`ROBOT_GROUP`]; a
//!   robot's colliders belong to [`ROBOT_GROUP`] and collide only with [`ENVIRONMENT_GROUP`], so
//!   a robot never collides with itself.
//! - Nothing here is random: the same inputs build the same world.

use rapier3d::prelude::{
    BroadPhaseBvh, BvhOptimizationStrategy, ColliderBuilder, Group, IntegrationParameters,
    InteractionGroups, InteractionTestMode, PhysicsWorld, RigidBodyBuilder, SharedShape,
    SpringCoefficients, Vector,
};
use serde::{Deserialize, Serialize};

use crate::api::{EnvError, StaticBox};

/// Collision group of every robot collider.
pub const ROBOT_GROUP: Group = Group::GROUP_1;
/// Collision group of the floor and of static boxes.
pub const ENVIRONMENT_GROUP: Group = Group::GROUP_2;

/// Interaction groups of a robot collider: touches the environment only.
pub fn robot_groups() -> InteractionGroups {
    InteractionGroups::new(ROBOT_GROUP, ENVIRONMENT_GROUP, InteractionTestMode::And)
}

/// Interaction groups of the floor and walls: touch robots only.
pub fn environment_groups() -> InteractionGroups {
    InteractionGroups::new(ENVIRONMENT_GROUP, ROBOT_GROUP, InteractionTestMode::And)
}

/// Rapier solver settings. These have no MuJoCo counterpart one to one; they are tuned so that
/// the rapier robot reproduces the MuJoCo reference (see `docs/ENVIRONMENTS.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverParams {
    /// Solver substeps per physics step (rapier `num_solver_iterations`: each substep integrates
    /// the multibody dynamics and runs one constraint pass). Default 1. Unit: count. Source:
    /// tuned; each substep rebuilds the multibody mass matrix (~60 % of the step's time), so
    /// 2 costs ~1.8× and did not bring the Ant closer to MuJoCo.
    pub substeps: usize,
    /// Projected Gauss–Seidel sweeps per substep (rapier `num_internal_pgs_iterations`).
    /// Default 2. Unit: count. Source: tuned (1 gave visibly less converged contacts; 4–30
    /// changed the fidelity figures by less than their seed-to-seed spread).
    pub pgs_iterations: usize,
    /// Position-stabilisation sweeps per substep (rapier
    /// `num_internal_stabilization_iterations`). Default 1. Unit: count. Source: rapier default.
    pub stabilization_iterations: usize,
    /// Natural frequency of the contact spring that corrects penetration (rapier contact
    /// softness; applied to robot–floor and robot–wall contacts). Default 30. Unit: Hz.
    /// Source: rapier's dynamic–dynamic default (its dynamic–static default is 60 Hz); 10 Hz
    /// with damping ratio 1 (MuJoCo's solref numbers) moved no fidelity figure beyond noise.
    pub contact_frequency_hz: f32,
    /// Damping ratio of that contact spring. Default 10. Unit: dimensionless. Source: rapier
    /// default (MuJoCo's solref damping ratio is 1, but the two formulations differ).
    pub contact_damping_ratio: f32,
    /// Contact skin: contacts act as if every robot collider were this much larger, like
    /// MuJoCo's geom `margin`. Default 0.01. Unit: m. Source: digest §9.4 (margin 0.01).
    pub contact_skin_m: f32,
    /// Natural frequency of the spring that pushes a joint back inside its limits.
    /// Default 1e6 (effectively rigid). Unit: Hz. Source: rapier default (`joint_defaults`).
    pub joint_limit_frequency_hz: f32,
    /// Damping ratio of that joint-limit spring. Default 1. Unit: dimensionless. Source: rapier
    /// default.
    pub joint_limit_damping_ratio: f32,
    /// Largest speed at which penetration is pushed out. Default 3. Unit: m/s.
    /// Source: rapier default.
    pub max_corrective_velocity_m_s: f32,
    /// Continuous collision detection: at most this many CCD substeps per physics step (rapier
    /// `max_ccd_substeps`); 0 turns rapier's automatic CCD of fast bodies against fixed
    /// colliders off. Default 1. Unit: count. Source: rapier default.
    pub ccd_max_substeps: usize,
    /// Whether rapier re-optimises its broad-phase tree incrementally after each step (rapier
    /// `BvhOptimizationStrategy::SubtreeOptimizer`; `false` selects `None`). The tree only
    /// speeds up the search for overlapping bounding boxes; it never changes which pairs
    /// overlap. Default true. Unit: switch. Source: rapier default.
    pub broad_phase_optimization: bool,
}

impl Default for SolverParams {
    fn default() -> Self {
        Self {
            substeps: 1,
            pgs_iterations: 2,
            stabilization_iterations: 1,
            contact_frequency_hz: 30.0,
            contact_damping_ratio: 10.0,
            contact_skin_m: 0.01,
            joint_limit_frequency_hz: 1.0e6,
            joint_limit_damping_ratio: 1.0,
            max_corrective_velocity_m_s: 3.0,
            ccd_max_substeps: 1,
            broad_phase_optimization: true,
        }
    }
}

impl SolverParams {
    /// Appends one [`EnvError::InvalidParam`] per bad field, named `{prefix}.{field}`.
    pub fn check(&self, prefix: &str, errors: &mut Vec<EnvError>) {
        let counts = [
            ("substeps", self.substeps),
            ("pgs_iterations", self.pgs_iterations),
            ("stabilization_iterations", self.stabilization_iterations),
        ];
        for (name, value) in counts {
            if value == 0 {
                errors.push(invalid(
                    format!("{prefix}.{name}"),
                    value,
                    "must be at least 1",
                ));
            }
        }
        let positives = [
            ("contact_frequency_hz", self.contact_frequency_hz),
            ("contact_damping_ratio", self.contact_damping_ratio),
            ("joint_limit_frequency_hz", self.joint_limit_frequency_hz),
            ("joint_limit_damping_ratio", self.joint_limit_damping_ratio),
            (
                "max_corrective_velocity_m_s",
                self.max_corrective_velocity_m_s,
            ),
        ];
        for (name, value) in positives {
            check_positive(&format!("{prefix}.{name}"), value, errors);
        }
        check_non_negative(
            &format!("{prefix}.contact_skin_m"),
            self.contact_skin_m,
            errors,
        );
    }

    /// Softness of the joint-limit constraints, for rapier joint builders.
    pub fn joint_limit_softness(&self) -> SpringCoefficients<f32> {
        SpringCoefficients::new(
            self.joint_limit_frequency_hz,
            self.joint_limit_damping_ratio,
        )
    }

    fn integration_parameters(&self, timestep_secs: f32) -> IntegrationParameters {
        let contact =
            SpringCoefficients::new(self.contact_frequency_hz, self.contact_damping_ratio);
        IntegrationParameters {
            dt: timestep_secs,
            num_solver_iterations: self.substeps,
            num_internal_pgs_iterations: self.pgs_iterations,
            num_internal_stabilization_iterations: self.stabilization_iterations,
            contact_softness: contact,
            static_contact_softness: contact,
            normalized_max_corrective_velocity: self.max_corrective_velocity_m_s,
            max_ccd_substeps: self.ccd_max_substeps,
            ..IntegrationParameters::default()
        }
    }
}

/// An [`EnvError::InvalidParam`] for `field` holding `value`.
pub fn invalid(field: String, value: impl std::fmt::Display, reason: &str) -> EnvError {
    EnvError::InvalidParam {
        field,
        value: value.to_string(),
        reason: reason.to_string(),
    }
}

/// Records an error unless `value` is finite and strictly positive.
pub fn check_positive(field: &str, value: f32, errors: &mut Vec<EnvError>) {
    if !(value.is_finite() && value > 0.0) {
        errors.push(invalid(field.to_string(), value, "must be finite and > 0"));
    }
}

/// Records an error unless `value` is finite and not negative.
pub fn check_non_negative(field: &str, value: f32, errors: &mut Vec<EnvError>) {
    if !(value.is_finite() && value >= 0.0) {
        errors.push(invalid(field.to_string(), value, "must be finite and >= 0"));
    }
}

/// Folds a list of parameter problems into one error (all of them reported at once).
pub fn into_result(mut errors: Vec<EnvError>) -> Result<(), EnvError> {
    if errors.len() <= 1 {
        return errors.pop().map_or(Ok(()), Err);
    }
    let mut fields = Vec::new();
    let mut values = Vec::new();
    let mut reasons = Vec::new();
    for error in errors {
        if let EnvError::InvalidParam {
            field,
            value,
            reason,
        } = error
        {
            reasons.push(format!("{field}: {reason}"));
            fields.push(field);
            values.push(value);
        }
    }
    Err(EnvError::InvalidParam {
        field: fields.join(", "),
        value: values.join(", "),
        reason: reasons.join("; "),
    })
}

/// An empty world: gravity `gravity_m_s2` along −z, physics step `timestep_secs`.
pub fn new_world(timestep_secs: f32, gravity_m_s2: f32, solver: &SolverParams) -> PhysicsWorld {
    PhysicsWorld {
        gravity: Vector::new(0.0, 0.0, -gravity_m_s2),
        integration_parameters: solver.integration_parameters(timestep_secs),
        broad_phase: BroadPhaseBvh::with_optimization_strategy(
            if solver.broad_phase_optimization {
                BvhOptimizationStrategy::SubtreeOptimizer
            } else {
                BvhOptimizationStrategy::None
            },
        ),
        ..PhysicsWorld::default()
    }
}

/// Adds the floor: the infinite half-space below z = 0 (MuJoCo planes collide as infinite too).
pub fn add_floor(world: &mut PhysicsWorld, friction: f32) {
    let floor = ColliderBuilder::new(SharedShape::halfspace(Vector::Z))
        .friction(friction)
        .collision_groups(environment_groups());
    world.insert(RigidBodyBuilder::fixed(), floor);
}

/// Adds each box as a fixed cuboid with the given friction.
pub fn add_static_boxes(world: &mut PhysicsWorld, boxes: &[StaticBox], friction: f32) {
    for static_box in boxes {
        let [hx, hy, hz] = static_box.half_extents;
        let collider = ColliderBuilder::cuboid(hx, hy, hz)
            .friction(friction)
            .collision_groups(environment_groups());
        let body = RigidBodyBuilder::fixed().translation(Vector::from_array(static_box.center));
        world.insert(body, collider);
    }
}

/// Checks that every box has finite coordinates and positive half-extents.
pub fn check_static_boxes(boxes: &[StaticBox], errors: &mut Vec<EnvError>) {
    for (index, static_box) in boxes.iter().enumerate() {
        if !static_box.center.iter().all(|c| c.is_finite()) {
            errors.push(invalid(
                format!("walls[{index}].center"),
                format!("{:?}", static_box.center),
                "must be finite",
            ));
        }
        if !static_box
            .half_extents
            .iter()
            .all(|h| h.is_finite() && *h > 0.0)
        {
            errors.push(invalid(
                format!("walls[{index}].half_extents"),
                format!("{:?}", static_box.half_extents),
                "must be finite and > 0",
            ));
        }
    }
}
