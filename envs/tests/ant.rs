//! Properties of the rapier Ant: mass, observation layout, actuator mapping, joint limits,
//! walls, reset noise, determinism and long-run finiteness.

use envs::ant::{Ant, AntParams, ACTUATOR_TO_JOINT, N_JOINTS, OBS_DIM, QPOS_DIM, QVEL_DIM};
use envs::{EnvError, Robot, StaticBox};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// MuJoCo's total mass of `assets/ant.xml` (sum of `body_mass`).
const MUJOCO_TOTAL_MASS_KG: f32 = 0.9109;
/// Slack allowed beyond a joint limit while a saturating torque pushes into it.
const LIMIT_SLACK_DEG: f32 = 3.0;

fn ant() -> Ant {
    Ant::new(AntParams::default(), &[]).expect("default parameters are valid")
}

fn obs(ant: &Ant) -> Vec<f32> {
    let mut out = vec![0.0; OBS_DIM];
    ant.write_obs(&mut out);
    out
}

fn random_action(rng: &mut Pcg64Mcg, bound: f32) -> [f32; N_JOINTS] {
    std::array::from_fn(|_| rng.random_range(-bound..=bound))
}

/// Hinge ranges (deg) in observation order.
fn hinge_ranges_deg(params: &AntParams) -> [[f32; 2]; N_JOINTS] {
    std::array::from_fn(|joint| {
        let leg = joint / 2;
        if joint % 2 == 0 {
            [-params.hip_range_deg, params.hip_range_deg]
        } else {
            params.ankle_ranges_deg[leg]
        }
    })
}

#[test]
fn total_mass_matches_the_mujoco_model() {
    let mass = ant().total_mass();
    assert!(
        (mass - MUJOCO_TOTAL_MASS_KG).abs() < 0.002,
        "total mass {mass} kg"
    );
}

#[test]
fn observation_at_rest_is_qpos0_with_zero_velocity() {
    let ant = ant();
    let params = AntParams::default();
    let out = obs(&ant);
    assert_eq!(out.len(), OBS_DIM);
    assert_eq!(&out[..QPOS_DIM], &params.qpos0()[..]);
    assert!(out[QPOS_DIM..].iter().all(|v| *v == 0.0));
}

#[test]
fn set_state_round_trips_through_the_observation() {
    let mut ant = ant();
    let angle: f32 = 0.3;
    let (s, c) = (angle / 2.0).sin_cos();
    let mut qpos = [0.0; QPOS_DIM];
    qpos[..7].copy_from_slice(&[0.5, -1.0, 0.8, c, 0.0, s, 0.0]);
    for (joint, value) in qpos[7..].iter_mut().enumerate() {
        *value = 0.05 * joint as f32 - 0.2;
    }
    let qvel: [f32; QVEL_DIM] = std::array::from_fn(|i| 0.1 * i as f32 - 0.5);
    ant.set_state(&qpos, &qvel);
    for (got, want) in ant.qpos().iter().zip(qpos) {
        assert!(
            (got - want).abs() < 1e-5,
            "qpos {:?} vs {qpos:?}",
            ant.qpos()
        );
    }
    for (got, want) in ant.qvel().iter().zip(qvel) {
        assert!(
            (got - want).abs() < 1e-5,
            "qvel {:?} vs {qvel:?}",
            ant.qvel()
        );
    }
}

#[test]
fn each_actuator_drives_its_hinge_in_the_positive_direction() {
    for (actuator, joint) in ACTUATOR_TO_JOINT.iter().enumerate() {
        let mut ant = ant();
        let mut held = ant.qpos();
        let mut action = [0.0; N_JOINTS];
        action[actuator] = 4.0;
        // Start mid-range so that the hinge is free to move both ways.
        let ranges = hinge_ranges_deg(ant.params());
        for (value, range) in held[7..].iter_mut().zip(ranges) {
            *value = (0.5 * (range[0] + range[1])).to_radians();
        }
        held[2] = 2.0; // in the air: no contact
        ant.set_state(&held, &[0.0; QVEL_DIM]);
        ant.step(&action);
        let moved = ant.qpos()[7 + joint] - held[7 + joint];
        assert!(
            moved > 0.01,
            "actuator {actuator} moved hinge {joint} by {moved}"
        );
    }
}

#[test]
fn joint_limits_hold_under_saturating_torques() {
    let params = AntParams::default();
    let ranges = hinge_ranges_deg(&params);
    for sign in [1.0, -1.0] {
        let mut ant = ant();
        let action = [sign * params.ctrl_range; N_JOINTS];
        for _ in 0..30 {
            ant.step(&action);
        }
        for (joint, range) in ranges.iter().enumerate() {
            let angle = ant.qpos()[7 + joint].to_degrees();
            assert!(
                angle > range[0] - LIMIT_SLACK_DEG && angle < range[1] + LIMIT_SLACK_DEG,
                "hinge {joint} at {angle}° outside {range:?} under torque sign {sign}"
            );
        }
    }
}

#[test]
fn ten_thousand_random_steps_stay_finite() {
    let mut ant = ant();
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let bound = ant.action_bound();
    for step in 0..10_000 {
        if step % 1000 == 0 {
            ant.reset(&mut rng);
        }
        ant.step(&random_action(&mut rng, bound));
        assert!(ant.is_finite(), "non-finite state at step {step}");
    }
}

#[test]
fn the_ant_cannot_pass_through_a_wall() {
    let wall_face_x = 1.5;
    let wall = StaticBox {
        center: [wall_face_x + 0.5, 0.0, 0.5],
        half_extents: [0.5, 4.0, 0.5],
    };
    let mut ant = Ant::new(AntParams::default(), &[wall]).expect("valid");
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut max_x = f32::MIN;
    for _ in 0..40 {
        // Throw it at the wall at 4 m/s again and again while it flails.
        let mut qvel = ant.qvel();
        qvel[0] = 4.0;
        ant.set_state(&ant.qpos(), &qvel);
        ant.step(&random_action(&mut rng, 16.0));
        max_x = max_x.max(ant.xy()[0]);
    }
    let torso_radius = AntParams::default().torso_radius_m;
    assert!(
        max_x < wall_face_x - 0.8 * torso_radius,
        "torso reached x = {max_x}"
    );
    assert!(
        max_x > wall_face_x - 2.0 * torso_radius,
        "the ant never reached the wall (x = {max_x})"
    );
}

#[test]
fn reset_noise_stays_within_its_bounds() {
    let mut ant = ant();
    let params = AntParams::default();
    let qpos0 = params.qpos0();
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    for _ in 0..50 {
        ant.reset(&mut rng);
        let qpos = ant.qpos();
        for index in (0..3).chain(7..QPOS_DIM) {
            let offset = qpos[index] - qpos0[index];
            assert!(
                offset.abs() <= params.reset_qpos_noise + 1e-5,
                "qpos[{index}] offset {offset}"
            );
        }
        let norm: f32 = qpos[3..7].iter().map(|q| q * q).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5);
        let qvel = ant.qvel();
        assert!(qvel
            .iter()
            .all(|v| v.abs() < 6.0 * params.reset_qvel_noise_std));
        assert!(qvel.iter().any(|v| *v != 0.0));
    }
}

#[test]
fn the_same_seed_gives_the_same_trajectory() {
    let run = |ant: &mut Ant| {
        ant.reset(&mut Pcg64Mcg::seed_from_u64(42));
        let mut actions = Pcg64Mcg::seed_from_u64(43);
        (0..40)
            .map(|_| {
                ant.step(&random_action(&mut actions, 16.0));
                obs(ant)
            })
            .collect::<Vec<_>>()
    };
    let mut ant = ant();
    let first = run(&mut ant);
    // A different history in between must not matter.
    ant.reset(&mut Pcg64Mcg::seed_from_u64(1));
    ant.step(&[16.0; N_JOINTS]);
    let second = run(&mut ant);
    assert_eq!(first, second);
    assert_eq!(
        first,
        run(&mut Ant::new(AntParams::default(), &[]).expect("valid"))
    );
}

#[test]
fn skipping_broad_phase_tree_optimisation_leaves_the_trajectory_on_the_floor_unchanged() {
    // The shipped default turns rapier's broad-phase re-optimisation off for speed; on the
    // floor (where the fidelity figures are measured) it must not change a single number.
    // Among walls the tree's shape can reorder contact pairs, which changes f32 rounding only.
    let run = |params: AntParams| {
        let mut ant = Ant::new(params, &[]).expect("valid");
        ant.reset(&mut Pcg64Mcg::seed_from_u64(5));
        let mut actions = Pcg64Mcg::seed_from_u64(6);
        (0..60)
            .map(|_| {
                ant.step(&random_action(&mut actions, 16.0));
                obs(&ant)
            })
            .collect::<Vec<_>>()
    };
    let shipped = AntParams::default();
    assert!(!shipped.solver.broad_phase_optimization);
    let mut rapier_default = shipped.clone();
    rapier_default.solver.broad_phase_optimization = true;
    assert_eq!(run(shipped), run(rapier_default));
}

#[test]
fn invalid_parameters_are_rejected_with_their_field_names() {
    let params = AntParams {
        density_kg_m3: -1.0,
        frame_skip: 0,
        ..AntParams::default()
    };
    match Ant::new(params, &[]) {
        Err(EnvError::InvalidParam { field, .. }) => {
            assert!(
                field.contains("density_kg_m3") && field.contains("frame_skip"),
                "{field}"
            );
        }
        other => panic!("expected InvalidParam, got {:?}", other.err()),
    }
    let bad_wall = StaticBox {
        center: [0.0; 3],
        half_extents: [0.0, 1.0, 1.0],
    };
    assert!(matches!(
        Ant::new(AntParams::default(), &[bad_wall]),
        Err(EnvError::InvalidParam { .. })
    ));
}
