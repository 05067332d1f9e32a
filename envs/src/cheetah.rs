//! HalfCheetahHurdle: the standard planar gym half-cheetah in rapier, with a 0.35 m hurdle at
//! x = 2 and a fixed goal on (rootx, rootz) (digest §9.5, SPEC §4).
//!
//! Model: seven capsule bodies (torso with head, back thigh/shin/foot, front thigh/shin/foot)
//! joined by rapier *multibody* (reduced-coordinate) joints. A fixed anchor carries one planar
//! root joint with three free axes (rootx slide, rootz slide, rooty hinge), so the generalized
//! coordinates are exactly MuJoCo's `qpos` (9) and `qvel` (9), in the same order and with the
//! same meaning: rootz is the displacement from the torso's build height (0.7 m), not the
//! height itself. Joint springs (rest 0), damping and armature use rapier's implicit multibody
//! joint springs, joint-space damping and armature, which match MuJoCo's `stiffness`,
//! `damping` and `armature`; motor torques `gear × action` act equal and opposite on the two
//! bodies of a joint, which is exactly a generalized force on that joint.
//!
//! Checked against MuJoCo 3.3.7 on the same model (gym contact parameters): total mass 14 kg
//! with the same per-body split; at rest (zero action, 3 s) rapier gives rootz −0.104,
//! rooty 0.037 versus MuJoCo's −0.132, 0.052, and MuJoCo with hard contacts gives −0.109, 0.041
//! with joint angles within 0.02 rad of ours, so the remaining gap is MuJoCo's soft contact.
//! Joint limits engage once a joint is past them in both engines; under bang-bang actions
//! rapier overshoots by at most ~0.13 rad, MuJoCo (soft limits) by ~0.2 rad.
//!
//! Invariants:
//! - Every `reset` (and `set_state`) builds a fresh rapier world, so the same seed gives the
//!   same trajectory whatever happened before.
//! - Self-collision is off (collision groups); the cheetah collides with floor, hurdle, block.
//! - Observations handed out are finite; a non-finite physics state ends the episode with
//!   `info.physics_failure` and the last finite observation, and is counted.

use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64Mcg;
use rapier3d::parry::query;
use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::api::{validate_action, Env, EnvError, EnvSpec, Reset, StaticBox, Step, StepInfo};
use crate::maze::Maze;
use crate::physics::{
    self, check_non_negative, check_positive, into_result, invalid, robot_groups, SolverParams,
};

/// Number of generalized coordinates (rootx, rootz, rooty, six leg joints).
pub const N_QPOS: usize = 9;
/// Number of actuated joints.
pub const N_ACTION: usize = 6;
/// Observation length: qpos then qvel.
pub const OBS_DIM: usize = 2 * N_QPOS;
/// Index of the rooty hinge axis in rapier's 6-D spatial joint layout (lin x, y, z, ang x, y, z).
const ANG_Y_AXIS: usize = 4;
/// Symmetric action bound (gym `ctrlrange = [-1, 1]`).
const ACTION_BOUND: f32 = 1.0;
/// Reward of every step that is not a success (0 on success): the sparse −1 of the reference
/// code (digest §9.5).
pub const STEP_PENALTY: f32 = 1.0;

/// A capsule in its body's frame, MuJoCo style: a centre, a rotation about +y and a half-length.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapsuleParams {
    /// Capsule centre in the body frame, (x, z), metres (MuJoCo geom `pos`).
    pub pos_m: [f32; 2],
    /// Rotation about +y taking the capsule axis from +z, radians (MuJoCo `axisangle="0 1 0 a"`).
    pub angle_rad: f32,
    /// Half-length of the cylindrical part, metres (MuJoCo capsule `size[1]`).
    pub half_length_m: f32,
}

/// One leg link: its joint (at the body origin), its capsule and its motor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkParams {
    /// Body origin (= hinge position) in the parent body's frame, (x, z), metres.
    pub body_pos_m: [f32; 2],
    /// The link's capsule in its own frame.
    pub geom: CapsuleParams,
    /// Hinge range `[low, high]` about +y, radians.
    pub range_rad: [f32; 2],
    /// Joint spring stiffness pulling the angle back to 0, N·m/rad.
    pub stiffness_nm_per_rad: f32,
    /// Joint damping, N·m·s/rad.
    pub damping_nms_per_rad: f32,
    /// Motor gear: torque = gear × action, N·m per unit action.
    pub gear_nm: f32,
}

/// An axis-aligned static box in world coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxParams {
    /// Box centre (x, y, z), metres.
    pub center_m: [f32; 3],
    /// Box half-extents (x, y, z), metres.
    pub half_extents_m: [f32; 3],
}

/// Every number of the HalfCheetahHurdle task. Sources: gym `half_cheetah.xml` (geometry,
/// joints, motors, timing) and the ASI `halfcheetahhurdle.xml` / `half_cheetah_hurdle_env.py`
/// (hurdle, block, goal, reward), digest §9.5.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CheetahParams {
    /// Physics timestep, seconds. Default 0.01 (gym `option timestep`).
    pub timestep_secs: f32,
    /// Physics steps per control step. Default 5 (gym `frame_skip`), so a control step is 0.05 s.
    pub frame_skip: u32,
    /// Gravity magnitude along −z, m/s². Default 9.81 (gym `option gravity`).
    pub gravity_m_s2: f32,
    /// Total mass of the seven bodies, kg; shared out by capsule volume (uniform density).
    /// Default 14 (gym `compiler settotalmass`).
    pub total_mass_kg: f32,
    /// Radius of every capsule, metres. Default 0.046 (gym geom `size[0]`).
    pub capsule_radius_m: f32,
    /// Half-length of the torso capsule along x, metres. Default 0.5 (gym `fromto="-.5 0 0 .5 0 0"`).
    pub torso_half_length_m: f32,
    /// Height of the torso origin at rootz = 0, metres. Default 0.7 (gym torso body `pos`).
    pub torso_height_m: f32,
    /// Head capsule on the torso. Default pos (0.6, 0.1), angle 0.87, half-length 0.15 (gym `head`).
    pub head: CapsuleParams,
    /// Back thigh. Default body (−0.5, 0), geom (0.1, −0.13) at −3.8 rad, half-length 0.145,
    /// range [−0.52, 1.05], stiffness 240, damping 6, gear 120 (gym `bthigh`).
    pub bthigh: LinkParams,
    /// Back shin. Default body (0.16, −0.25), geom (−0.14, −0.07) at −2.03 rad, half-length 0.15,
    /// range [−0.785, 0.785], stiffness 180, damping 4.5, gear 90 (gym `bshin`).
    pub bshin: LinkParams,
    /// Back foot. Default body (−0.28, −0.14), geom (0.03, −0.097) at −0.27 rad, half-length
    /// 0.094, range [−0.4, 0.785], stiffness 120, damping 3, gear 60 (gym `bfoot`).
    pub bfoot: LinkParams,
    /// Front thigh. Default body (0.5, 0), geom (−0.07, −0.12) at 0.52 rad, half-length 0.133,
    /// range [−1, 0.7], stiffness 180, damping 4.5, gear 120 (gym `fthigh`).
    pub fthigh: LinkParams,
    /// Front shin. Default body (−0.14, −0.24), geom (0.065, −0.09) at −0.6 rad, half-length
    /// 0.106, range [−1.2, 0.87], stiffness 120, damping 3, gear 60 (gym `fshin`).
    pub fshin: LinkParams,
    /// Front foot. Default body (0.13, −0.18), geom (0.045, −0.07) at −0.6 rad, half-length 0.07,
    /// range [−0.5, 0.5], stiffness 60, damping 1.5, gear 30 (gym `ffoot`).
    pub ffoot: LinkParams,
    /// Armature (reflected rotor inertia) of each leg joint, kg·m². Default 0.1 (gym joint
    /// default); the root joints have none, as in gym.
    pub armature_kg_m2: f32,
    /// Sliding friction of every collider. Default 0.4 (gym geom default `friction`).
    pub friction: f32,
    /// Contact prediction distance, metres: contacts are created this far ahead, which keeps a
    /// fast limb from sinking into the hurdle within one timestep. Default 0.1 (ours: about
    /// 10 m/s × one 0.01 s timestep; rapier's own default is 0.02).
    pub contact_prediction_m: f32,
    /// Rapier solver settings (substeps, contact and limit softness, contact skin); shared with
    /// the Ant. Default: the shared defaults except `contact_skin_m` = 0, since gym's
    /// half_cheetah.xml sets no geom margin (the Ant's 0.01 comes from its own XML).
    pub solver: SolverParams,
    /// The hurdle. Default centre (2, 0, 0.175), half-extents (0.2, 1, 0.175): x ∈ [1.8, 2.2],
    /// 0.35 m tall (ASI `halfcheetahhurdle.xml`).
    pub hurdle: BoxParams,
    /// The blocking box behind the start. Default centre (−20, 0, 1), half-extents (0.5, 1, 1)
    /// (ASI `halfcheetahhurdle.xml`).
    pub block: BoxParams,
    /// Goal on (rootx, rootz), metres. Default (4.0, 0.2) (ASI `half_cheetah_hurdle_env.py`).
    pub goal: [f32; 2],
    /// Success when ‖(rootx, rootz) − goal‖ ≤ this (inclusive), metres. Default 0.5 (ASI env).
    pub success_threshold_m: f32,
    /// Episode length in control steps. Default 1000 (ASI env).
    pub max_steps: u32,
    /// Reset noise on every qpos entry: U(−a, a), metres or radians. Default 0.1 (gym
    /// `reset_noise_scale`).
    pub reset_qpos_noise: f32,
    /// Reset noise on every qvel entry: this × N(0, 1), m/s or rad/s. Default 0.1 (gym).
    pub reset_qvel_noise_std: f32,
}

impl Default for CheetahParams {
    fn default() -> Self {
        Self {
            timestep_secs: 0.01,
            frame_skip: 5,
            gravity_m_s2: 9.81,
            total_mass_kg: 14.0,
            capsule_radius_m: 0.046,
            torso_half_length_m: 0.5,
            torso_height_m: 0.7,
            head: capsule([0.6, 0.1], 0.87, 0.15),
            bthigh: link(
                [-0.5, 0.0],
                capsule([0.1, -0.13], -3.8, 0.145),
                [-0.52, 1.05],
                [240.0, 6.0, 120.0],
            ),
            bshin: link(
                [0.16, -0.25],
                capsule([-0.14, -0.07], -2.03, 0.15),
                [-0.785, 0.785],
                [180.0, 4.5, 90.0],
            ),
            bfoot: link(
                [-0.28, -0.14],
                capsule([0.03, -0.097], -0.27, 0.094),
                [-0.4, 0.785],
                [120.0, 3.0, 60.0],
            ),
            fthigh: link(
                [0.5, 0.0],
                capsule([-0.07, -0.12], 0.52, 0.133),
                [-1.0, 0.7],
                [180.0, 4.5, 120.0],
            ),
            fshin: link(
                [-0.14, -0.24],
                capsule([0.065, -0.09], -0.6, 0.106),
                [-1.2, 0.87],
                [120.0, 3.0, 60.0],
            ),
            ffoot: link(
                [0.13, -0.18],
                capsule([0.045, -0.07], -0.6, 0.07),
                [-0.5, 0.5],
                [60.0, 1.5, 30.0],
            ),
            armature_kg_m2: 0.1,
            friction: 0.4,
            contact_prediction_m: 0.1,
            solver: SolverParams {
                contact_skin_m: 0.0,
                ..SolverParams::default()
            },
            hurdle: BoxParams {
                center_m: [2.0, 0.0, 0.175],
                half_extents_m: [0.2, 1.0, 0.175],
            },
            block: BoxParams {
                center_m: [-20.0, 0.0, 1.0],
                half_extents_m: [0.5, 1.0, 1.0],
            },
            goal: [4.0, 0.2],
            success_threshold_m: 0.5,
            max_steps: 1000,
            reset_qpos_noise: 0.1,
            reset_qvel_noise_std: 0.1,
        }
    }
}

fn capsule(pos_m: [f32; 2], angle_rad: f32, half_length_m: f32) -> CapsuleParams {
    CapsuleParams {
        pos_m,
        angle_rad,
        half_length_m,
    }
}

/// `joint` is (stiffness, damping, gear).
fn link(
    body_pos_m: [f32; 2],
    geom: CapsuleParams,
    range_rad: [f32; 2],
    joint: [f32; 3],
) -> LinkParams {
    let [stiffness_nm_per_rad, damping_nms_per_rad, gear_nm] = joint;
    LinkParams {
        body_pos_m,
        geom,
        range_rad,
        stiffness_nm_per_rad,
        damping_nms_per_rad,
        gear_nm,
    }
}

/// Parent of each leg link in [`CheetahParams::legs`] order; 0 is the torso, `i + 1` is leg `i`.
const LEG_PARENT: [usize; N_ACTION] = [0, 1, 2, 0, 4, 5];

impl CheetahParams {
    /// The six leg links in qpos / action order: bthigh, bshin, bfoot, fthigh, fshin, ffoot.
    pub fn legs(&self) -> [&LinkParams; N_ACTION] {
        [
            &self.bthigh,
            &self.bshin,
            &self.bfoot,
            &self.fthigh,
            &self.fshin,
            &self.ffoot,
        ]
    }

    /// Checks every field; all problems are reported in one error.
    pub fn validate(&self) -> Result<(), EnvError> {
        let mut errors = Vec::new();
        self.check_scalars(&mut errors);
        self.check_geometry(&mut errors);
        self.check_task(&mut errors);
        into_result(errors)
    }

    fn check_scalars(&self, errors: &mut Vec<EnvError>) {
        check_positive("timestep_secs", self.timestep_secs, errors);
        if self.frame_skip == 0 {
            errors.push(invalid("frame_skip".into(), 0, "must be at least 1"));
        }
        check_non_negative("gravity_m_s2", self.gravity_m_s2, errors);
        check_positive("total_mass_kg", self.total_mass_kg, errors);
        check_non_negative("armature_kg_m2", self.armature_kg_m2, errors);
        check_non_negative("friction", self.friction, errors);
        check_non_negative("contact_prediction_m", self.contact_prediction_m, errors);
        self.solver.check("solver", errors);
    }

    fn check_geometry(&self, errors: &mut Vec<EnvError>) {
        check_positive("capsule_radius_m", self.capsule_radius_m, errors);
        check_positive("torso_half_length_m", self.torso_half_length_m, errors);
        check_finite("torso_height_m", &[self.torso_height_m], errors);
        check_capsule("head", &self.head, errors);
        for (name, leg) in LEG_NAMES.iter().zip(self.legs()) {
            check_link(name, leg, errors);
        }
        physics::check_static_boxes(&[self.hurdle.to_static(), self.block.to_static()], errors);
    }

    fn check_task(&self, errors: &mut Vec<EnvError>) {
        check_finite("goal", &self.goal, errors);
        check_positive("success_threshold_m", self.success_threshold_m, errors);
        if self.max_steps == 0 {
            errors.push(invalid("max_steps".into(), 0, "must be at least 1"));
        }
        check_non_negative("reset_qpos_noise", self.reset_qpos_noise, errors);
        check_non_negative("reset_qvel_noise_std", self.reset_qvel_noise_std, errors);
    }

    /// Volume of all capsules, m³; the uniform density is `total_mass_kg` / this.
    fn total_volume_m3(&self) -> f32 {
        let r = self.capsule_radius_m;
        let mut volume = capsule_volume(r, self.torso_half_length_m)
            + capsule_volume(r, self.head.half_length_m);
        for leg in self.legs() {
            volume += capsule_volume(r, leg.geom.half_length_m);
        }
        volume
    }
}

const LEG_NAMES: [&str; N_ACTION] = ["bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"];

/// Volume of a capsule: a cylinder of length 2h plus a ball of radius r.
fn capsule_volume(radius: f32, half_length: f32) -> f32 {
    let pi = std::f32::consts::PI;
    pi * radius * radius * 2.0 * half_length + 4.0 / 3.0 * pi * radius.powi(3)
}

fn check_finite(field: &str, values: &[f32], errors: &mut Vec<EnvError>) {
    if !values.iter().all(|v| v.is_finite()) {
        errors.push(invalid(
            field.to_string(),
            format!("{values:?}"),
            "must be finite",
        ));
    }
}

fn check_capsule(name: &str, geom: &CapsuleParams, errors: &mut Vec<EnvError>) {
    check_finite(&format!("{name}.pos_m"), &geom.pos_m, errors);
    check_finite(&format!("{name}.angle_rad"), &[geom.angle_rad], errors);
    check_positive(&format!("{name}.half_length_m"), geom.half_length_m, errors);
}

fn check_link(name: &str, leg: &LinkParams, errors: &mut Vec<EnvError>) {
    check_finite(&format!("{name}.body_pos_m"), &leg.body_pos_m, errors);
    check_capsule(&format!("{name}.geom"), &leg.geom, errors);
    let [low, high] = leg.range_rad;
    if !(low.is_finite() && high.is_finite() && low < high) {
        errors.push(invalid(
            format!("{name}.range_rad"),
            format!("[{low}, {high}]"),
            "needs finite low < high",
        ));
    }
    check_non_negative(
        &format!("{name}.stiffness_nm_per_rad"),
        leg.stiffness_nm_per_rad,
        errors,
    );
    check_non_negative(
        &format!("{name}.damping_nms_per_rad"),
        leg.damping_nms_per_rad,
        errors,
    );
    check_positive(&format!("{name}.gear_nm"), leg.gear_nm, errors);
}

impl BoxParams {
    fn to_static(self) -> StaticBox {
        StaticBox {
            center: self.center_m,
            half_extents: self.half_extents_m,
        }
    }
}

/// The rapier world of one episode: scene, cheetah bodies and their multibody joints.
struct CheetahSim {
    world: PhysicsWorld,
    /// Joint handles, torso (root joint) first, then the legs in qpos order.
    joints: [MultibodyJointHandle; N_ACTION + 1],
    /// Body handles in the same order as `joints`.
    bodies: [RigidBodyHandle; N_ACTION + 1],
    /// Every cheetah collider.
    cheetah_colliders: Vec<ColliderHandle>,
    /// Whether rapier quarantined a non-finite body since the last check.
    saw_non_finite: bool,
}

impl CheetahSim {
    /// Builds a fresh world with the cheetah in generalized state (`qpos`, `qvel`).
    fn build(params: &CheetahParams, qpos: &[f32; N_QPOS], qvel: &[f32; N_QPOS]) -> Self {
        let mut world = new_world(params);
        add_scene(&mut world, params);
        let mut cheetah_colliders = Vec::new();
        let density = params.total_mass_kg / params.total_volume_m3();
        let anchor = world.insert_body(RigidBodyBuilder::fixed());
        let torso = add_torso(&mut world, params, density, &mut cheetah_colliders);
        let root = world
            .insert_multibody_joint(anchor, torso, root_joint(params))
            .expect("invariant: a fresh body always joins the anchor's multibody");
        let mut joints = [root; N_ACTION + 1];
        let mut bodies = [torso; N_ACTION + 1];
        for (i, leg) in params.legs().into_iter().enumerate() {
            let body = add_capsule_body(
                &mut world,
                params,
                &leg.geom,
                density,
                &mut cheetah_colliders,
            );
            joints[i + 1] = world
                .insert_multibody_joint(bodies[LEG_PARENT[i]], body, leg_joint(leg, &params.solver))
                .expect("invariant: a fresh body always joins its parent's multibody");
            bodies[i + 1] = body;
        }
        let mut sim = Self {
            world,
            joints,
            bodies,
            cheetah_colliders,
            saw_non_finite: false,
        };
        sim.configure_dofs(params);
        sim.set_state(qpos, qvel);
        sim
    }

    /// Sets per-DoF springs, damping and armature (the root joints have none).
    fn configure_dofs(&mut self, params: &CheetahParams) {
        let link_ids = self.link_ids();
        let bodies = &self.world.bodies;
        let (mb, _) = self
            .world
            .multibody_joints
            .get_mut(self.joints[0])
            .expect("invariant: root joint exists");
        // Collapses the fixed anchor's 6 free DoFs so that assembly ids index qvel directly.
        mb.forward_kinematics(bodies, false);
        mb.damping_mut().fill(0.0);
        mb.armature_mut().fill(0.0);
        mb.set_self_contacts_enabled(false);
        for (i, (leg, &link_id)) in params.legs().into_iter().zip(&link_ids[1..]).enumerate() {
            let link = mb
                .link_mut(link_id)
                .expect("invariant: link id comes from the joint set");
            link.joint
                .set_spring(ANG_Y_AXIS, leg.stiffness_nm_per_rad, 0.0);
            let dof = link.assembly_id();
            // Links were appended in qpos order, so generalized vectors are MuJoCo's qpos/qvel.
            debug_assert_eq!(dof, 3 + i, "generalized coordinates out of qpos order");
            mb.damping_mut()[dof] = leg.damping_nms_per_rad;
            mb.armature_mut()[dof] = params.armature_kg_m2;
        }
    }

    /// Multibody link ids of the torso and the legs, in `joints` order.
    fn link_ids(&self) -> [usize; N_ACTION + 1] {
        self.joints.map(|joint| {
            self.world
                .multibody_joints
                .get(joint)
                .expect("invariant: joint exists")
                .1
        })
    }

    /// Overwrites the generalized coordinates and velocities (of a freshly built world, whose
    /// coordinates are all 0) and moves the bodies there.
    fn set_state(&mut self, qpos: &[f32; N_QPOS], qvel: &[f32; N_QPOS]) {
        let (mb, _) = self
            .world
            .multibody_joints
            .get_mut(self.joints[0])
            .expect("invariant: root joint exists");
        mb.apply_displacements(qpos);
        mb.generalized_velocity_mut().copy_from_slice(qvel);
        mb.forward_kinematics(&self.world.bodies, false);
        mb.update_rigid_bodies(&mut self.world.bodies, true);
    }

    /// Generalized coordinates and velocities, MuJoCo order.
    fn state(&self) -> ([f32; N_QPOS], [f32; N_QPOS]) {
        let link_ids = self.link_ids();
        let (mb, _) = self
            .world
            .multibody_joints
            .get(self.joints[0])
            .expect("invariant: root joint exists");
        let coords = |link_id: usize| {
            mb.link(link_id)
                .expect("invariant: link id comes from the joint set")
                .joint()
                .coords()
        };
        let root = coords(link_ids[0]);
        let mut qpos = [0.0; N_QPOS];
        qpos[..3].copy_from_slice(&[root[0], root[2], root[ANG_Y_AXIS]]);
        for (q, &link_id) in qpos[3..].iter_mut().zip(&link_ids[1..]) {
            *q = coords(link_id)[ANG_Y_AXIS];
        }
        let mut qvel = [0.0; N_QPOS];
        qvel.copy_from_slice(mb.generalized_velocity().as_slice());
        (qpos, qvel)
    }

    /// Applies `gear × action` about +y, equal and opposite on each joint's two bodies, then runs
    /// `frame_skip` physics steps.
    fn advance(&mut self, params: &CheetahParams, action: &[f32]) {
        for body in self.bodies {
            self.world.bodies[body].reset_torques(false);
        }
        for (i, leg) in params.legs().into_iter().enumerate() {
            let torque = Vector::Y * (leg.gear_nm * action[i]);
            self.world.bodies[self.bodies[i + 1]].add_torque(torque, true);
            self.world.bodies[self.bodies[LEG_PARENT[i]]].add_torque(-torque, true);
        }
        for _ in 0..params.frame_skip {
            self.world.step();
            self.saw_non_finite |= !self.world.quarantine().bodies().is_empty();
        }
    }

    fn total_mass_kg(&self) -> f32 {
        self.bodies
            .iter()
            .map(|&h| self.world.bodies[h].mass())
            .sum()
    }

    /// Deepest overlap between any cheetah capsule and `obstacle`, metres (0 when apart).
    fn penetration_m(&self, obstacle: &BoxParams) -> f32 {
        let [hx, hy, hz] = obstacle.half_extents_m;
        let shape = Cuboid::new(Vector::new(hx, hy, hz));
        let pose = Pose::from_translation(Vector::from_array(obstacle.center_m));
        let mut deepest: f32 = 0.0;
        for &handle in &self.cheetah_colliders {
            let collider = &self.world.colliders[handle];
            let collider_pose = collider_world_pose(&self.world, collider);
            if let Ok(Some(contact)) =
                query::contact(&collider_pose, collider.shape(), &pose, &shape, 0.0)
            {
                deepest = deepest.max(-contact.dist);
            }
        }
        deepest
    }
}

/// A collider's pose from its parent body's current pose (valid before the first step too).
fn collider_world_pose(world: &PhysicsWorld, collider: &Collider) -> Pose {
    match (collider.parent(), collider.position_wrt_parent()) {
        (Some(parent), Some(local)) => *world.bodies[parent].position() * *local,
        _ => *collider.position(),
    }
}

fn new_world(params: &CheetahParams) -> PhysicsWorld {
    let mut world = physics::new_world(params.timestep_secs, params.gravity_m_s2, &params.solver);
    world.integration_parameters.normalized_prediction_distance = params.contact_prediction_m;
    world
}

/// Floor, hurdle and blocking box, all in the environment collision group.
fn add_scene(world: &mut PhysicsWorld, params: &CheetahParams) {
    physics::add_floor(world, params.friction);
    physics::add_static_boxes(
        world,
        &[params.hurdle.to_static(), params.block.to_static()],
        params.friction,
    );
}

fn cheetah_collider(params: &CheetahParams, a: Vector, b: Vector, density: f32) -> ColliderBuilder {
    ColliderBuilder::capsule_from_endpoints(a, b, params.capsule_radius_m)
        .density(density)
        .friction(params.friction)
        .contact_skin(params.solver.contact_skin_m)
        .collision_groups(robot_groups())
}

/// Endpoints of a MuJoCo-style capsule: centre ± h · (sin a, 0, cos a).
fn capsule_endpoints(geom: &CapsuleParams) -> (Vector, Vector) {
    let center = Vector::new(geom.pos_m[0], 0.0, geom.pos_m[1]);
    let axis = Vector::new(geom.angle_rad.sin(), 0.0, geom.angle_rad.cos()) * geom.half_length_m;
    (center - axis, center + axis)
}

fn add_torso(
    world: &mut PhysicsWorld,
    params: &CheetahParams,
    density: f32,
    out: &mut Vec<ColliderHandle>,
) -> RigidBodyHandle {
    let body = world.insert_body(RigidBodyBuilder::dynamic().can_sleep(false));
    let half = params.torso_half_length_m;
    let torso = cheetah_collider(
        params,
        Vector::new(-half, 0.0, 0.0),
        Vector::new(half, 0.0, 0.0),
        density,
    );
    out.push(world.insert_collider(torso, Some(body)));
    let (a, b) = capsule_endpoints(&params.head);
    out.push(world.insert_collider(cheetah_collider(params, a, b, density), Some(body)));
    body
}

fn add_capsule_body(
    world: &mut PhysicsWorld,
    params: &CheetahParams,
    geom: &CapsuleParams,
    density: f32,
    out: &mut Vec<ColliderHandle>,
) -> RigidBodyHandle {
    let body = world.insert_body(RigidBodyBuilder::dynamic().can_sleep(false));
    let (a, b) = capsule_endpoints(geom);
    out.push(world.insert_collider(cheetah_collider(params, a, b, density), Some(body)));
    body
}

/// The planar root: rootx and rootz slides and the rooty hinge, all at the torso origin, which
/// sits at (0, 0, torso_height) when they are 0.
fn root_joint(params: &CheetahParams) -> GenericJoint {
    let locked = JointAxesMask::LIN_Y | JointAxesMask::ANG_X | JointAxesMask::ANG_Z;
    GenericJointBuilder::new(locked)
        .local_frame1(Pose::from_translation(Vector::new(
            0.0,
            0.0,
            params.torso_height_m,
        )))
        .local_frame2(Pose::IDENTITY)
        .build()
}

/// A limited hinge about +y at the child's origin, placed at `body_pos` in the parent frame.
fn leg_joint(leg: &LinkParams, solver: &SolverParams) -> GenericJoint {
    let locked = JointAxesMask::LIN_AXES | JointAxesMask::ANG_X | JointAxesMask::ANG_Z;
    let [x, z] = leg.body_pos_m;
    GenericJointBuilder::new(locked)
        .local_frame1(Pose::from_translation(Vector::new(x, 0.0, z)))
        .local_frame2(Pose::IDENTITY)
        .limits(JointAxis::AngY, leg.range_rad)
        .softness(solver.joint_limit_softness())
        .build()
}

/// HalfCheetahHurdle: run and jump the hurdle to reach (rootx, rootz) = goal.
pub struct CheetahHurdle {
    params: CheetahParams,
    spec: EnvSpec,
    sim: CheetahSim,
    rng: Pcg64Mcg,
    goal: [f32; 2],
    /// The last finite observation handed out.
    last_obs: Vec<f32>,
    n_episode_steps: u32,
    /// Whether `step` may be called (after `reset`, until the episode ends).
    episode_live: bool,
    n_physics_failures: u64,
}

impl CheetahHurdle {
    /// Builds the task; `terminate_on_success` is false for training and true for the test
    /// variant. The episode starts at the noiseless pose; call `reset` before stepping.
    pub fn new(params: CheetahParams, terminate_on_success: bool) -> Result<Self, EnvError> {
        params.validate()?;
        let spec = cheetah_spec(&params, terminate_on_success);
        let sim = CheetahSim::build(&params, &[0.0; N_QPOS], &[0.0; N_QPOS]);
        let mut env = Self {
            goal: params.goal,
            params,
            spec,
            sim,
            rng: Pcg64Mcg::seed_from_u64(0),
            last_obs: vec![0.0; OBS_DIM],
            n_episode_steps: 0,
            episode_live: false,
            n_physics_failures: 0,
        };
        env.last_obs = env.current_obs();
        Ok(env)
    }

    pub fn params(&self) -> &CheetahParams {
        &self.params
    }

    /// Generalized coordinates and velocities (MuJoCo `qpos`, `qvel`; rootz relative to
    /// `torso_height_m`).
    pub fn state(&self) -> ([f32; N_QPOS], [f32; N_QPOS]) {
        self.sim.state()
    }

    /// Puts the cheetah in the given state (rebuilding the world, so contacts start afresh) and
    /// returns its observation. Episode bookkeeping (step count, goal) is unchanged.
    pub fn set_state(
        &mut self,
        qpos: [f32; N_QPOS],
        qvel: [f32; N_QPOS],
    ) -> Result<Vec<f32>, EnvError> {
        if let Some(index) = qpos.iter().chain(&qvel).position(|v| !v.is_finite()) {
            return Err(EnvError::InvalidParam {
                field: if index < N_QPOS {
                    format!("qpos[{index}]")
                } else {
                    format!("qvel[{}]", index - N_QPOS)
                },
                value: format!("{:?}", qpos.iter().chain(&qvel).nth(index)),
                reason: "state values must be finite".into(),
            });
        }
        self.sim = CheetahSim::build(&self.params, &qpos, &qvel);
        self.last_obs = self.current_obs();
        Ok(self.last_obs.clone())
    }

    /// Total mass of the cheetah's bodies as rapier computed it, kg.
    pub fn total_mass_kg(&self) -> f32 {
        self.sim.total_mass_kg()
    }

    /// Deepest overlap between a cheetah capsule and the hurdle right now, metres (0 if apart).
    pub fn hurdle_penetration_m(&self) -> f32 {
        self.sim.penetration_m(&self.params.hurdle)
    }

    /// The hurdle and the blocking box, for plots.
    pub fn obstacles(&self) -> [StaticBox; 2] {
        [
            self.params.hurdle.to_static(),
            self.params.block.to_static(),
        ]
    }

    fn current_obs(&self) -> Vec<f32> {
        let (qpos, qvel) = self.sim.state();
        qpos.iter().chain(&qvel).copied().collect()
    }

    fn is_success(&self, achieved: [f32; 2]) -> bool {
        let (dx, dz) = (achieved[0] - self.goal[0], achieved[1] - self.goal[1]);
        (dx * dx + dz * dz).sqrt() <= self.params.success_threshold_m
    }

    /// Reset pose: qpos U(±a), qvel σ·N(0, 1), drawn in that order as in gym.
    fn sample_reset_state(&mut self) -> ([f32; N_QPOS], [f32; N_QPOS]) {
        let noise = self.params.reset_qpos_noise;
        let std = self.params.reset_qvel_noise_std;
        let qpos = std::array::from_fn(|_| noise * (2.0 * self.rng.random::<f32>() - 1.0));
        let qvel = std::array::from_fn(|_| std * self.rng.sample::<f32, _>(StandardNormal));
        (qpos, qvel)
    }

    fn ensure_live(&self) -> Result<(), EnvError> {
        if self.episode_live {
            Ok(())
        } else {
            Err(EnvError::NotReady {
                task: self.spec.name.clone(),
            })
        }
    }

    /// The observation after a step, or `None` when the physics went non-finite.
    fn finite_obs_after_step(&mut self) -> Option<Vec<f32>> {
        let obs = self.current_obs();
        let failed =
            std::mem::take(&mut self.sim.saw_non_finite) || obs.iter().any(|v| !v.is_finite());
        (!failed).then_some(obs)
    }
}

fn cheetah_spec(params: &CheetahParams, terminate_on_success: bool) -> EnvSpec {
    let name = if terminate_on_success {
        "halfcheetah-hurdle-test"
    } else {
        "halfcheetah-hurdle"
    };
    EnvSpec {
        name: name.to_string(),
        obs_dim: OBS_DIM,
        action_dim: N_ACTION,
        goal_dim: 2,
        action_low: vec![-ACTION_BOUND; N_ACTION],
        action_high: vec![ACTION_BOUND; N_ACTION],
        control_dt_secs: f64::from(params.timestep_secs) * f64::from(params.frame_skip),
        max_steps: params.max_steps,
        success_threshold: params.success_threshold_m,
        terminate_on_success,
    }
}

impl Env for CheetahHurdle {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64) -> Reset {
        self.rng = Pcg64Mcg::seed_from_u64(seed);
        self.goal = self.params.goal;
        let (qpos, qvel) = self.sample_reset_state();
        self.sim = CheetahSim::build(&self.params, &qpos, &qvel);
        self.last_obs = self.current_obs();
        self.n_episode_steps = 0;
        self.episode_live = true;
        Reset {
            achieved_goal: self.achieved_goal(&self.last_obs),
            obs: self.last_obs.clone(),
            goal: self.goal,
        }
    }

    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        self.ensure_live()?;
        validate_action(&self.spec, action)?;
        let clipped: Vec<f32> = action
            .iter()
            .map(|a| a.clamp(-ACTION_BOUND, ACTION_BOUND))
            .collect();
        self.sim.advance(&self.params, &clipped);
        self.n_episode_steps += 1;
        let physics_failure = match self.finite_obs_after_step() {
            Some(obs) => {
                self.last_obs = obs;
                false
            }
            None => {
                self.n_physics_failures += 1;
                true
            }
        };
        let achieved_goal = self.achieved_goal(&self.last_obs);
        let success = self.is_success(achieved_goal);
        let terminated = physics_failure || (success && self.spec.terminate_on_success);
        let truncated = self.n_episode_steps >= self.params.max_steps;
        self.episode_live = !(terminated || truncated);
        Ok(Step {
            obs: self.last_obs.clone(),
            reward: if success { 0.0 } else { -STEP_PENALTY },
            terminated,
            truncated,
            info: StepInfo {
                success,
                achieved_goal,
                physics_failure,
                fell: false,
            },
        })
    }

    fn goal(&self) -> [f32; 2] {
        self.goal
    }

    /// The goal is fixed per task, but may be replaced for the current episode (any finite
    /// (rootx, rootz)); `reset` restores the configured goal.
    fn set_goal(&mut self, goal: [f32; 2]) -> Result<(), EnvError> {
        if goal.iter().all(|g| g.is_finite()) {
            self.goal = goal;
            Ok(())
        } else {
            Err(EnvError::InvalidGoal {
                x: goal[0],
                y: goal[1],
                reason: "goal must be finite".into(),
            })
        }
    }

    fn achieved_goal(&self, obs: &[f32]) -> [f32; 2] {
        [obs[0], obs[1]]
    }

    fn maze(&self) -> Option<&Maze> {
        None
    }

    fn n_physics_failures(&self) -> u64 {
        self.n_physics_failures
    }
}
