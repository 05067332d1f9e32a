//! The Ant robot (rllab/HIRO lineage, digest §9.4) as a rapier reduced-coordinate multibody.
//!
//! Role: physics and observation of the quadruped used by the Ant mazes; the maze task owns the
//! goal, the reward and the episode bookkeeping (see [`crate::api::Robot`]).
//!
//! Model: nine rigid bodies joined by a free root and eight hinges, mirroring the MuJoCo
//! `ant.xml` body tree. The torso body carries the torso sphere and the four fixed hip-link
//! capsules; each leg adds a thigh (hip hinge about z) and a shin (ankle hinge about a
//! horizontal axis). Joint damping and armature are rapier's per-DoF multibody `damping` and
//! `armature`, which enter the joint-space mass matrix like MuJoCo's. Actuator torques are
//! applied as equal and opposite couples about the hinge axis on the joint's two bodies, which
//! projects onto exactly that joint's generalised force.
//!
//! Invariants:
//! - Observation (29) = MuJoCo `qpos[0:15] ++ qvel[0:14]`: torso xyz, torso quaternion
//!   (w, x, y, z), eight hinge angles in the order hip_1, ankle_1, … hip_4, ankle_4 (legs
//!   front_left, front_right, back, right_back), torso linear velocity (world frame), torso
//!   angular velocity (torso frame, as MuJoCo's free joint), eight hinge velocities.
//! - Action (8) = the reference's actuator order hip_4, ankle_4, hip_1, ankle_1, hip_2,
//!   ankle_2, hip_3, ankle_3 ([`ACTUATOR_TO_JOINT`]); each is clipped to ±`ctrl_range` and
//!   multiplied by `gear` to give a torque in N·m.
//! - The ant collides with the floor and the walls only, never with itself.
//! - `reset` rebuilds the world, so an episode depends only on the reset's random draws:
//!   no solver warm start or contact cache leaks from one episode into the next.

use rand::Rng;
use rand_distr::StandardNormal;
use rapier3d::prelude::{
    ColliderBuilder, Multibody, MultibodyIndex, PhysicsWorld, Pose, RevoluteJointBuilder,
    RigidBodyBuilder, RigidBodyHandle, Rotation, Vector,
};
use serde::{Deserialize, Serialize};

use crate::api::{EnvError, Robot, StaticBox};
use crate::physics::{self, SolverParams};

/// Length of the observation: `qpos[0:15] ++ qvel[0:14]`.
pub const OBS_DIM: usize = QPOS_DIM + QVEL_DIM;
/// Generalised positions: torso xyz (3), quaternion (4), hinge angles (8).
pub const QPOS_DIM: usize = 15;
/// Generalised velocities: torso linear (3), angular (3), hinge velocities (8).
pub const QVEL_DIM: usize = 14;
/// Number of hinges (and actuators).
pub const N_JOINTS: usize = 8;
/// Number of legs; leg `l` owns hinges `2l` (hip) and `2l + 1` (ankle).
pub const N_LEGS: usize = 4;
/// Actuator `k` drives hinge `ACTUATOR_TO_JOINT[k]` (hinges in observation order). The
/// reference lists its motors as hip_4, ankle_4, hip_1, ankle_1, hip_2, ankle_2, hip_3, ankle_3.
pub const ACTUATOR_TO_JOINT: [usize; N_JOINTS] = [6, 7, 0, 1, 2, 3, 4, 5];

/// Offset of the first hinge angle in `qpos`.
const QPOS_JOINTS: usize = 7;
/// Offset of the first hinge velocity in `qvel`.
const QVEL_JOINTS: usize = 6;
/// Generalised velocities of the free root in rapier: linear (3) then angular (3), world frame.
const ROOT_DOFS: usize = 6;
/// Index of a hinge's angle in rapier's spatial joint coordinates (the free angular axis x).
const HINGE_COORD: usize = 3;
/// Number of rigid bodies: torso plus thigh and shin per leg.
const N_BODIES: usize = 1 + 2 * N_LEGS;

/// Every number of the Ant model. Defaults reproduce the reference `ant.xml` (digest §9.4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AntParams {
    /// Radius of the torso sphere. Default 0.25. Unit: m. Source: digest §9.4.
    pub torso_radius_m: f32,
    /// Height of the torso centre at reset (before noise). Default 0.75. Unit: m.
    /// Source: digest §9.4 (`qpos0`).
    pub start_z_m: f32,
    /// Radius of every leg capsule. Default 0.08. Unit: m. Source: digest §9.4.
    pub leg_radius_m: f32,
    /// Per-axis reach of the hip link and of the thigh: each spans (±0.2, ±0.2, 0), i.e.
    /// 0.283 m. Default 0.2. Unit: m. Source: digest §9.4.
    pub hip_reach_m: f32,
    /// Per-axis reach of the shin: it spans (±0.4, ±0.4, 0), i.e. 0.566 m. Default 0.4.
    /// Unit: m. Source: digest §9.4.
    pub shin_reach_m: f32,
    /// Signs (x, y) of each leg's direction, legs in order front_left, front_right, back,
    /// right_back. Default [[1, 1], [−1, 1], [−1, −1], [1, −1]]. Unit: sign. Source: `ant.xml`.
    pub leg_directions: [[f32; 2]; N_LEGS],
    /// Density of every geom; masses follow from the shapes (total ≈ 0.91 kg). Default 5.
    /// Unit: kg/m³. Source: digest §9.4.
    pub density_kg_m3: f32,
    /// Viscous damping of every hinge. Default 1. Unit: N·m·s/rad. Source: digest §9.4.
    pub joint_damping_nms_per_rad: f32,
    /// Armature (reflected rotor inertia) of every hinge. Default 1. Unit: kg·m².
    /// Source: digest §9.4.
    pub joint_armature_kg_m2: f32,
    /// Sliding friction coefficient of the ant, floor and walls. Default 1. Unit:
    /// dimensionless. Source: digest §9.4 (friction (1, 0.5, 0.5); the torsional and rolling
    /// parts have no rapier counterpart and are unused with condim 3).
    pub friction: f32,
    /// Hip range: every hip turns about z within ±this. Default 30. Unit: degrees.
    /// Source: digest §9.4.
    pub hip_range_deg: f32,
    /// Ankle hinge axis of each leg in the torso frame (normalised on use).
    /// Default [(−1, 1, 0), (1, 1, 0), (−1, 1, 0), (1, 1, 0)]. Unit: direction.
    /// Source: digest §9.4.
    pub ankle_axes: [[f32; 3]; N_LEGS],
    /// Ankle range [low, high] of each leg. Default [[30, 70], [−70, −30], [−70, −30],
    /// [30, 70]]. Unit: degrees. Source: digest §9.4.
    pub ankle_ranges_deg: [[f32; 2]; N_LEGS],
    /// Control range: actions are clipped to ±this. Default 16. Unit: action (N·m at gear 1).
    /// Source: digest §9.4 (`ctrlrange`).
    pub ctrl_range: f32,
    /// Motor gear: torque = gear × action. Default 1. Unit: N·m per action unit.
    /// Source: digest §9.4 (no gear attribute).
    pub gear: f32,
    /// Rapier physics step. Default 0.04. Unit: s. Source: tuned. MuJoCo steps 0.02 s with
    /// RK4 (four force evaluations per step); one semi-implicit rapier step of 0.04 s with
    /// implicit joint damping matched the MuJoCo random-torque statistics within a few percent
    /// (`docs/ENVIRONMENTS.md`) and is what makes the 2,000 control steps/s target.
    pub timestep_secs: f32,
    /// Physics steps per control step; the control step timestep × frame_skip = 0.2 s equals
    /// MuJoCo's 0.02 × 10. Default 5. Unit: count. Source: digest §9.4 (0.2 s), tuned split.
    pub frame_skip: u32,
    /// Reset noise on every qpos entry: U(−this, this). Default 0.1. Unit: qpos units (m,
    /// quaternion, rad). Source: digest §9.4.
    pub reset_qpos_noise: f32,
    /// Reset noise on every qvel entry: this × N(0, 1). Default 0.1. Unit: qvel units (m/s,
    /// rad/s). Source: digest §9.4.
    pub reset_qvel_noise_std: f32,
    /// Gravity along −z. Default 9.81. Unit: m/s². Source: MuJoCo default.
    pub gravity_m_s2: f32,
    /// Rapier solver settings, tuned against MuJoCo (see `docs/ENVIRONMENTS.md`). Default:
    /// [`SolverParams::default`] except `broad_phase_optimization = false` (measured to save
    /// ~2.5 % of a maze step without changing any fidelity figure).
    pub solver: SolverParams,
}

impl Default for AntParams {
    fn default() -> Self {
        Self {
            torso_radius_m: 0.25,
            start_z_m: 0.75,
            leg_radius_m: 0.08,
            hip_reach_m: 0.2,
            shin_reach_m: 0.4,
            leg_directions: [[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]],
            density_kg_m3: 5.0,
            joint_damping_nms_per_rad: 1.0,
            joint_armature_kg_m2: 1.0,
            friction: 1.0,
            hip_range_deg: 30.0,
            ankle_axes: [
                [-1.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
                [-1.0, 1.0, 0.0],
                [1.0, 1.0, 0.0],
            ],
            ankle_ranges_deg: [[30.0, 70.0], [-70.0, -30.0], [-70.0, -30.0], [30.0, 70.0]],
            ctrl_range: 16.0,
            gear: 1.0,
            timestep_secs: 0.04,
            frame_skip: 5,
            reset_qpos_noise: 0.1,
            reset_qvel_noise_std: 0.1,
            gravity_m_s2: 9.81,
            solver: SolverParams {
                // The broad-phase tree holds ~35 boxes; re-optimising it every step cost ~2.5 %
                // of a maze step and never changes which pairs overlap (`docs/ENVIRONMENTS.md`,
                // "Speed").
                broad_phase_optimization: false,
                ..SolverParams::default()
            },
        }
    }
}

impl AntParams {
    /// Checks every field; all problems are reported in one error.
    pub fn validate(&self) -> Result<(), EnvError> {
        let mut errors = Vec::new();
        let positives = [
            ("torso_radius_m", self.torso_radius_m),
            ("start_z_m", self.start_z_m),
            ("leg_radius_m", self.leg_radius_m),
            ("hip_reach_m", self.hip_reach_m),
            ("shin_reach_m", self.shin_reach_m),
            ("density_kg_m3", self.density_kg_m3),
            ("hip_range_deg", self.hip_range_deg),
            ("ctrl_range", self.ctrl_range),
            ("gear", self.gear),
            ("timestep_secs", self.timestep_secs),
        ];
        for (name, value) in positives {
            physics::check_positive(name, value, &mut errors);
        }
        let non_negatives = [
            ("joint_damping_nms_per_rad", self.joint_damping_nms_per_rad),
            ("joint_armature_kg_m2", self.joint_armature_kg_m2),
            ("friction", self.friction),
            ("reset_qpos_noise", self.reset_qpos_noise),
            ("reset_qvel_noise_std", self.reset_qvel_noise_std),
            ("gravity_m_s2", self.gravity_m_s2),
        ];
        for (name, value) in non_negatives {
            physics::check_non_negative(name, value, &mut errors);
        }
        if self.frame_skip == 0 {
            errors.push(physics::invalid(
                "frame_skip".into(),
                self.frame_skip,
                "must be at least 1",
            ));
        }
        self.check_legs(&mut errors);
        self.solver.check("solver", &mut errors);
        physics::into_result(errors)
    }

    fn check_legs(&self, errors: &mut Vec<EnvError>) {
        for leg in 0..N_LEGS {
            let [sx, sy] = self.leg_directions[leg];
            if !(sx.abs() == 1.0 && sy.abs() == 1.0) {
                let field = format!("leg_directions[{leg}]");
                errors.push(physics::invalid(
                    field,
                    format!("{:?}", [sx, sy]),
                    "entries must be ±1",
                ));
            }
            let axis = Vector::from_array(self.ankle_axes[leg]);
            if !(axis.is_finite() && axis.length() > 0.0) {
                let field = format!("ankle_axes[{leg}]");
                errors.push(physics::invalid(
                    field,
                    format!("{axis:?}"),
                    "must be finite and non-zero",
                ));
            }
            let [low, high] = self.ankle_ranges_deg[leg];
            if !(low.is_finite() && high.is_finite() && low < high) {
                let field = format!("ankle_ranges_deg[{leg}]");
                errors.push(physics::invalid(
                    field,
                    format!("{:?}", [low, high]),
                    "needs finite low < high",
                ));
            }
        }
    }

    /// Simulated seconds per control step.
    pub fn control_dt_secs(&self) -> f64 {
        f64::from(self.timestep_secs) * f64::from(self.frame_skip)
    }

    /// MuJoCo's `qpos0`: torso at (0, 0, start_z), identity orientation, hinges at 0.
    pub fn qpos0(&self) -> [f32; QPOS_DIM] {
        let mut qpos = [0.0; QPOS_DIM];
        qpos[2] = self.start_z_m;
        qpos[3] = 1.0;
        qpos
    }
}

/// One hinge: the bodies it joins and its axis, fixed in the parent body's frame.
#[derive(Debug, Clone, Copy)]
struct Hinge {
    parent: RigidBodyHandle,
    child: RigidBodyHandle,
    axis_in_parent: Vector,
    /// Index of the child link inside the multibody.
    link_id: usize,
}

/// Handles of a freshly built ant.
struct Built {
    world: PhysicsWorld,
    bodies: [RigidBodyHandle; N_BODIES],
    hinges: [Hinge; N_JOINTS],
    multibody: MultibodyIndex,
}

/// The Ant robot. Build it with [`Ant::new`]; it starts at `qpos0` with zero velocity.
pub struct Ant {
    params: AntParams,
    walls: Vec<StaticBox>,
    world: PhysicsWorld,
    bodies: [RigidBodyHandle; N_BODIES],
    hinges: [Hinge; N_JOINTS],
    multibody: MultibodyIndex,
    /// Index of each hinge's velocity in the multibody's generalised velocity vector.
    dof_index: [usize; N_JOINTS],
}

impl Ant {
    /// Validates `params` and builds the ant at `qpos0` among `walls` (plus the floor).
    pub fn new(params: AntParams, walls: &[StaticBox]) -> Result<Ant, EnvError> {
        params.validate()?;
        let mut errors = Vec::new();
        physics::check_static_boxes(walls, &mut errors);
        physics::into_result(errors)?;
        let built = build(&params, walls);
        let mut ant = Ant {
            params,
            walls: walls.to_vec(),
            world: built.world,
            bodies: built.bodies,
            hinges: built.hinges,
            multibody: built.multibody,
            dof_index: [0; N_JOINTS],
        };
        ant.configure_dofs();
        Ok(ant)
    }

    /// The parameters this ant was built with.
    pub fn params(&self) -> &AntParams {
        &self.params
    }

    /// Total mass of the nine bodies (kg); ≈ 0.91 with the default parameters.
    pub fn total_mass(&self) -> f32 {
        self.bodies
            .iter()
            .map(|handle| self.world.bodies[*handle].mass())
            .sum()
    }

    /// MuJoCo-style generalised positions (see the module invariants).
    pub fn qpos(&self) -> [f32; QPOS_DIM] {
        let multibody = self.multibody();
        let pose = multibody.root().local_to_world();
        let rotation = pose.rotation;
        let mut qpos = [0.0; QPOS_DIM];
        qpos[..3].copy_from_slice(&pose.translation.to_array());
        qpos[3..QPOS_JOINTS].copy_from_slice(&[rotation.w, rotation.x, rotation.y, rotation.z]);
        for (joint, hinge) in self.hinges.iter().enumerate() {
            qpos[QPOS_JOINTS + joint] = hinge_angle(multibody, hinge);
        }
        qpos
    }

    /// MuJoCo-style generalised velocities: linear velocity in the world frame, angular
    /// velocity in the torso frame, hinge velocities.
    pub fn qvel(&self) -> [f32; QVEL_DIM] {
        let multibody = self.multibody();
        let velocity = multibody.generalized_velocity();
        let rotation = multibody.root().local_to_world().rotation;
        let angvel_world = Vector::new(velocity[3], velocity[4], velocity[5]);
        let angvel_body = rotation.inverse() * angvel_world;
        let mut qvel = [0.0; QVEL_DIM];
        qvel[..3].copy_from_slice(&[velocity[0], velocity[1], velocity[2]]);
        qvel[3..QVEL_JOINTS].copy_from_slice(&angvel_body.to_array());
        for (joint, dof) in self.dof_index.iter().enumerate() {
            qvel[QVEL_JOINTS + joint] = velocity[*dof];
        }
        qvel
    }

    /// Sets the generalised coordinates (MuJoCo layout; the quaternion is normalised).
    pub fn set_state(&mut self, qpos: &[f32; QPOS_DIM], qvel: &[f32; QVEL_DIM]) {
        let rotation = Rotation::from_xyzw(qpos[4], qpos[5], qpos[6], qpos[3]).normalize();
        let translation = Vector::new(qpos[0], qpos[1], qpos[2]);
        let torso = self.bodies[0];
        self.world.bodies[torso].set_position(Pose::from_parts(translation, rotation), true);
        let hinges = self.hinges;
        let dof_index = self.dof_index;
        let (multibody, bodies) = self.multibody_mut_with_bodies();
        let mut displacement = vec![0.0; multibody.ndofs()];
        for (joint, hinge) in hinges.iter().enumerate() {
            displacement[dof_index[joint]] =
                qpos[QPOS_JOINTS + joint] - hinge_angle(multibody, hinge);
        }
        multibody.apply_displacements(&displacement);
        let angvel_world = rotation * Vector::new(qvel[3], qvel[4], qvel[5]);
        let mut velocity = multibody.generalized_velocity_mut();
        velocity.fill(0.0);
        for axis in 0..3 {
            velocity[axis] = qvel[axis];
            velocity[3 + axis] = angvel_world[axis];
        }
        for (joint, dof) in dof_index.iter().enumerate() {
            velocity[*dof] = qvel[QVEL_JOINTS + joint];
        }
        multibody.forward_kinematics(bodies, true);
        multibody.update_rigid_bodies(bodies, true);
    }

    /// Whether every generalised coordinate is finite.
    pub fn is_finite(&self) -> bool {
        self.qpos()
            .iter()
            .chain(self.qvel().iter())
            .all(|v| v.is_finite())
    }

    /// Rebuilds the world at `qpos0` with zero velocity (fresh solver and contact caches).
    pub fn rebuild(&mut self) {
        let built = build(&self.params, &self.walls);
        self.world = built.world;
        self.bodies = built.bodies;
        self.hinges = built.hinges;
        self.multibody = built.multibody;
        self.configure_dofs();
    }

    /// Torques (N·m) per hinge, hinges in observation order, from an action in actuator order.
    fn hinge_torques(&self, action: &[f32]) -> [f32; N_JOINTS] {
        let bound = self.params.ctrl_range;
        let mut torques = [0.0; N_JOINTS];
        for (actuator, value) in action.iter().take(N_JOINTS).enumerate() {
            torques[ACTUATOR_TO_JOINT[actuator]] = self.params.gear * value.clamp(-bound, bound);
        }
        torques
    }

    /// Sets the user torques for the next physics step: a couple about each hinge axis.
    fn apply_torques(&mut self, torques: &[f32; N_JOINTS]) {
        for handle in self.bodies {
            self.world.bodies[handle].reset_torques(false);
        }
        for (hinge, torque) in self.hinges.iter().zip(torques) {
            let axis = *self.world.bodies[hinge.parent].rotation() * hinge.axis_in_parent;
            self.world.bodies[hinge.child].add_torque(axis * *torque, false);
            self.world.bodies[hinge.parent].add_torque(axis * -*torque, false);
        }
    }

    /// Sets per-DoF armature and damping (zero on the free root, whose MuJoCo joint has none).
    fn configure_dofs(&mut self) {
        let armature = self.params.joint_armature_kg_m2;
        let damping = self.params.joint_damping_nms_per_rad;
        let hinges = self.hinges;
        let (multibody, bodies) = self.multibody_mut_with_bodies();
        // Makes the root a free joint now, so the DoF layout is final before we index into it.
        multibody.forward_kinematics(bodies, true);
        multibody.armature_mut().fill(0.0);
        multibody.damping_mut().fill(0.0);
        let mut dof_index = [0; N_JOINTS];
        for (joint, hinge) in hinges.iter().enumerate() {
            let dof = multibody
                .link(hinge.link_id)
                .map_or(0, |link| link.assembly_id());
            debug_assert!(dof >= ROOT_DOFS, "hinge DoFs follow the free root's six");
            multibody.armature_mut()[dof] = armature;
            multibody.damping_mut()[dof] = damping;
            dof_index[joint] = dof;
        }
        self.dof_index = dof_index;
    }

    fn multibody(&self) -> &Multibody {
        self.world
            .multibody_joints
            .get_multibody(self.multibody)
            .expect("invariant: the ant's multibody lives as long as its world")
    }

    fn multibody_mut_with_bodies(
        &mut self,
    ) -> (&mut Multibody, &mut rapier3d::prelude::RigidBodySet) {
        let multibody = self
            .world
            .multibody_joints
            .get_multibody_mut(self.multibody)
            .expect("invariant: the ant's multibody lives as long as its world");
        (multibody, &mut self.world.bodies)
    }
}

impl Robot for Ant {
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }

    fn action_dim(&self) -> usize {
        N_JOINTS
    }

    fn action_bound(&self) -> f32 {
        self.params.ctrl_range
    }

    fn control_dt_secs(&self) -> f64 {
        self.params.control_dt_secs()
    }

    fn reset(&mut self, rng: &mut rand_pcg::Pcg64Mcg) {
        self.rebuild();
        let mut qpos = self.params.qpos0();
        for value in qpos.iter_mut() {
            *value += self.params.reset_qpos_noise * (2.0 * rng.random::<f32>() - 1.0);
        }
        let mut qvel = [0.0; QVEL_DIM];
        for value in qvel.iter_mut() {
            *value = self.params.reset_qvel_noise_std * rng.sample::<f32, _>(StandardNormal);
        }
        self.set_state(&qpos, &qvel);
    }

    fn step(&mut self, action: &[f32]) {
        let torques = self.hinge_torques(action);
        for _ in 0..self.params.frame_skip {
            self.apply_torques(&torques);
            self.world.step();
        }
    }

    fn write_obs(&self, out: &mut [f32]) {
        out[..QPOS_DIM].copy_from_slice(&self.qpos());
        out[QPOS_DIM..OBS_DIM].copy_from_slice(&self.qvel());
    }

    fn xy(&self) -> [f32; 2] {
        let translation = self.multibody().root().local_to_world().translation;
        [translation.x, translation.y]
    }

    fn torso_z(&self) -> Option<f32> {
        Some(self.multibody().root().local_to_world().translation.z)
    }
}

/// A hinge's angle (rad), read from the multibody's joint coordinates.
fn hinge_angle(multibody: &Multibody, hinge: &Hinge) -> f32 {
    multibody
        .link(hinge.link_id)
        .map_or(0.0, |link| link.joint.coords()[HINGE_COORD])
}

/// Builds the world: floor, walls and the ant at `qpos0`.
fn build(params: &AntParams, walls: &[StaticBox]) -> Built {
    let mut world = physics::new_world(params.timestep_secs, params.gravity_m_s2, &params.solver);
    physics::add_floor(&mut world, params.friction);
    physics::add_static_boxes(&mut world, walls, params.friction);
    let start = Vector::new(0.0, 0.0, params.start_z_m);
    let torso = world.insert_body(dynamic_body(start));
    world.insert_collider(torso_collider(params), Some(torso));
    let mut bodies = [torso; N_BODIES];
    let mut hinges = Vec::with_capacity(N_JOINTS);
    for leg in 0..N_LEGS {
        let (thigh, shin, hip, ankle) = build_leg(&mut world, params, torso, leg);
        bodies[1 + 2 * leg] = thigh;
        bodies[2 + 2 * leg] = shin;
        hinges.push(hip);
        hinges.push(ankle);
    }
    let root_link = world.multibody_joints.rigid_body_link(torso).copied();
    let multibody = root_link.map(|link| link.multibody);
    let hinges = link_hinges(&world, hinges);
    Built {
        world,
        bodies,
        hinges,
        multibody: multibody.expect("invariant: the torso is the root of the multibody just built"),
    }
}

/// Fills each hinge's multibody link id from its child body.
fn link_hinges(world: &PhysicsWorld, hinges: Vec<Hinge>) -> [Hinge; N_JOINTS] {
    let mut out = [hinges[0]; N_JOINTS];
    for (slot, mut hinge) in out.iter_mut().zip(hinges) {
        hinge.link_id = world
            .multibody_joints
            .rigid_body_link(hinge.child)
            .map(|link| link.id)
            .expect("invariant: every leg body was just attached to the multibody");
        *slot = hinge;
    }
    out
}

/// Adds one leg: the hip-link capsule on the torso, a thigh on a hip hinge and a shin on an
/// ankle hinge. Returns (thigh, shin, hip hinge, ankle hinge).
fn build_leg(
    world: &mut PhysicsWorld,
    params: &AntParams,
    torso: RigidBodyHandle,
    leg: usize,
) -> (RigidBodyHandle, RigidBodyHandle, Hinge, Hinge) {
    let [sx, sy] = params.leg_directions[leg];
    let hip_reach = Vector::new(sx * params.hip_reach_m, sy * params.hip_reach_m, 0.0);
    let shin_reach = Vector::new(sx * params.shin_reach_m, sy * params.shin_reach_m, 0.0);
    let torso_position = world.bodies[torso].translation();
    world.insert_collider(leg_collider(params, hip_reach), Some(torso));

    let thigh = world.insert_body(dynamic_body(torso_position + hip_reach));
    world.insert_collider(leg_collider(params, hip_reach), Some(thigh));
    let hip_range = params.hip_range_deg.to_radians();
    let hip = attach_hinge(
        world,
        params,
        torso,
        thigh,
        hip_reach,
        Vector::Z,
        [-hip_range, hip_range],
    );

    let shin = world.insert_body(dynamic_body(torso_position + 2.0 * hip_reach));
    world.insert_collider(leg_collider(params, shin_reach), Some(shin));
    let axis = Vector::from_array(params.ankle_axes[leg]).normalize();
    let [low, high] = params.ankle_ranges_deg[leg];
    let ankle_range = [low.to_radians(), high.to_radians()];
    let ankle = attach_hinge(world, params, thigh, shin, hip_reach, axis, ankle_range);
    (thigh, shin, hip, ankle)
}

/// Joins `child` to `parent` by a multibody hinge at `anchor` (parent frame; the child's
/// origin) about `axis` (parent frame), limited to `limits` (rad).
fn attach_hinge(
    world: &mut PhysicsWorld,
    params: &AntParams,
    parent: RigidBodyHandle,
    child: RigidBodyHandle,
    anchor: Vector,
    axis: Vector,
    limits: [f32; 2],
) -> Hinge {
    let joint = RevoluteJointBuilder::new(axis)
        .local_anchor1(anchor)
        .local_anchor2(Vector::ZERO)
        .limits(limits)
        .softness(params.solver.joint_limit_softness())
        .contacts_enabled(false);
    let attached = world.insert_multibody_joint(parent, child, joint);
    debug_assert!(
        attached.is_some(),
        "a tree of new bodies cannot form a cycle"
    );
    Hinge {
        parent,
        child,
        axis_in_parent: axis,
        link_id: 0,
    }
}

/// A dynamic body that never sleeps (an idle ant must still react to its next action).
fn dynamic_body(translation: Vector) -> RigidBodyBuilder {
    RigidBodyBuilder::dynamic()
        .translation(translation)
        .can_sleep(false)
}

/// The torso sphere.
fn torso_collider(params: &AntParams) -> ColliderBuilder {
    robot_collider(params, ColliderBuilder::ball(params.torso_radius_m))
}

/// A leg capsule from the body origin to `end` (body frame).
fn leg_collider(params: &AntParams, end: Vector) -> ColliderBuilder {
    let capsule = ColliderBuilder::capsule_from_endpoints(Vector::ZERO, end, params.leg_radius_m);
    robot_collider(params, capsule)
}

/// Material, contact skin and collision groups shared by every ant geom.
fn robot_collider(params: &AntParams, shape: ColliderBuilder) -> ColliderBuilder {
    shape
        .density(params.density_kg_m3)
        .friction(params.friction)
        .contact_skin(params.solver.contact_skin_m)
        .collision_groups(physics::robot_groups())
}
