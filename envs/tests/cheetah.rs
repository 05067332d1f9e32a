//! HalfCheetahHurdle: model facts (mass, limits), stability, the hurdle as a solid obstacle,
//! reward and success at hand-set states, determinism and action validation.

use envs::cheetah::{CheetahHurdle, CheetahParams, N_ACTION, N_QPOS};
use envs::{Env, EnvError};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

fn train_env() -> CheetahHurdle {
    CheetahHurdle::new(CheetahParams::default(), false).expect("default params are valid")
}

fn random_action(rng: &mut Pcg64Mcg) -> Vec<f32> {
    (0..N_ACTION).map(|_| rng.random_range(-1.0..1.0)).collect()
}

#[test]
fn total_mass_is_fourteen_kilograms() {
    let env = train_env();
    assert!(
        (env.total_mass_kg() - 14.0).abs() < 1e-3,
        "mass {}",
        env.total_mass_kg()
    );
}

#[test]
fn spec_matches_the_task() {
    let env = train_env();
    let spec = env.spec();
    assert_eq!(
        (spec.obs_dim, spec.action_dim, spec.goal_dim, spec.max_steps),
        (18, 6, 2, 1000)
    );
    assert!((spec.control_dt_secs - 0.05).abs() < 1e-6);
    assert_eq!(env.goal(), [4.0, 0.2]);
    assert!(env.maze().is_none());
}

#[test]
fn reset_puts_the_cheetah_near_the_build_pose() {
    let mut env = train_env();
    let reset = env.reset(3);
    assert_eq!(reset.obs.len(), 18);
    for (i, q) in reset.obs[..N_QPOS].iter().enumerate() {
        assert!(
            q.abs() <= 0.1 + 1e-6,
            "qpos[{i}] = {q} outside the reset noise"
        );
    }
    assert_eq!(reset.achieved_goal, [reset.obs[0], reset.obs[1]]);
}

#[test]
fn cheetah_settles_on_the_floor_with_zero_action() {
    let mut env = train_env();
    env.reset(0);
    let mut obs = Vec::new();
    for _ in 0..60 {
        obs = env.step(&[0.0; N_ACTION]).expect("valid action").obs;
    }
    // Standing on its feet, the torso origin sits a little below its 0.7 m build height.
    assert!(obs[1] > -0.35 && obs[1] < 0.05, "rootz {}", obs[1]);
    assert!(
        obs[N_QPOS..].iter().all(|v| v.abs() < 0.5),
        "not at rest: {:?}",
        &obs[N_QPOS..]
    );
}

/// Rapier enables a limit once the joint is past it (as MuJoCo does, whose limits are soft),
/// so a fast joint overshoots by about its speed × one timestep before being pushed back.
const LIMIT_TOLERANCE_RAD: f32 = 0.15;

#[test]
fn joint_limits_hold_under_saturating_actions() {
    let params = CheetahParams::default();
    let ranges: Vec<[f32; 2]> = params.legs().iter().map(|leg| leg.range_rad).collect();
    let mut env = CheetahHurdle::new(params, false).expect("valid");
    env.reset(1);
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut worst = [0.0f32; N_ACTION];
    for step in 0..400 {
        // Bang-bang actions, held 1 to 4 steps, to drive every joint into both limits.
        let action: Vec<f32> = (0..N_ACTION)
            .map(|_| if rng.random::<bool>() { 1.0 } else { -1.0 })
            .collect();
        for _ in 0..1 + step % 4 {
            let obs = env.step(&action).expect("valid action").obs;
            for (j, [low, high]) in ranges.iter().enumerate() {
                worst[j] = worst[j].max(low - obs[3 + j]).max(obs[3 + j] - high);
            }
        }
    }
    eprintln!("worst limit violation per joint (rad): {worst:?}");
    for (j, violation) in worst.iter().enumerate() {
        assert!(
            *violation < LIMIT_TOLERANCE_RAD,
            "joint {j} went {violation} rad past its limit"
        );
    }
}

#[test]
fn five_thousand_random_steps_stay_finite() {
    let mut env = train_env();
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    env.reset(5);
    for _ in 0..5000 {
        let step = env.step(&random_action(&mut rng)).expect("valid action");
        assert!(step.obs.iter().all(|v| v.is_finite()));
        assert!(!step.info.physics_failure);
        if step.terminated || step.truncated {
            env.reset(rng.random());
        }
    }
    assert_eq!(env.n_physics_failures(), 0);
}

/// Starts the cheetah 1.4 m before the hurdle at `speed` m/s with a random height and pitch,
/// drives it with random actions and returns the deepest overlap with the hurdle (metres).
fn crash_into_hurdle(speed: f32, seed: u64) -> f32 {
    let mut env = train_env();
    env.reset(seed);
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let mut qpos = [0.0; N_QPOS];
    qpos[0] = 0.6;
    qpos[1] = rng.random_range(-0.3..0.1);
    qpos[2] = rng.random_range(-0.5..0.5);
    let mut qvel = [0.0; N_QPOS];
    qvel[0] = speed;
    env.set_state(qpos, qvel).expect("finite state");
    let mut deepest: f32 = 0.0;
    for _ in 0..40 {
        env.step(&random_action(&mut rng)).expect("valid action");
        deepest = deepest.max(env.hurdle_penetration_m());
    }
    deepest
}

#[test]
fn the_hurdle_is_solid_when_the_cheetah_crashes_into_it() {
    // Measured with the default 0.1 m contact prediction: at most ~6 mm at 10 m/s over 20 seeds
    // (rapier's own 0.02 m lets a limb sink ~4 cm).
    for speed in [2.0, 5.0, 10.0] {
        for seed in 0..4 {
            let deepest = crash_into_hurdle(speed, seed);
            assert!(
                deepest < 0.03,
                "at {speed} m/s (seed {seed}) a limb sank {deepest} m into the hurdle"
            );
        }
    }
}

#[test]
fn the_hurdle_is_solid_when_the_cheetah_pushes_into_it() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut env = train_env();
    env.reset(0);
    env.set_state(
        [1.0, -0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    )
    .expect("finite state");
    let mut deepest: f32 = 0.0;
    for _ in 0..300 {
        env.step(&random_action(&mut rng)).expect("valid action");
        deepest = deepest.max(env.hurdle_penetration_m());
    }
    assert!(deepest < 0.03, "a limb sank {deepest} m into the hurdle");
}

#[test]
fn reward_and_success_follow_the_goal_distance() {
    let mut env = CheetahHurdle::new(CheetahParams::default(), true).expect("valid");
    env.reset(0);
    env.set_state([0.0; N_QPOS], [0.0; N_QPOS])
        .expect("finite state");
    let far = env.step(&[0.0; N_ACTION]).expect("valid");
    assert_eq!(
        (far.reward, far.info.success, far.terminated),
        (-1.0, false, false)
    );

    // Standing at rootx = 4: rootz settles near −0.1, within 0.5 of (4.0, 0.2).
    env.set_state(
        [4.0, -0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0; N_QPOS],
    )
    .expect("finite state");
    let near = env.step(&[0.0; N_ACTION]).expect("valid");
    let [x, z] = near.info.achieved_goal;
    assert!(((x - 4.0).powi(2) + (z - 0.2).powi(2)).sqrt() <= 0.5);
    assert_eq!(
        (near.reward, near.info.success, near.terminated),
        (0.0, true, true)
    );
    assert!(matches!(
        env.step(&[0.0; N_ACTION]),
        Err(EnvError::NotReady { .. })
    ));
}

#[test]
fn training_variant_keeps_going_after_success() {
    let mut env = train_env();
    env.reset(0);
    env.set_state(
        [4.0, -0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0; N_QPOS],
    )
    .expect("finite state");
    let step = env.step(&[0.0; N_ACTION]).expect("valid");
    assert!(step.info.success && !step.terminated);
    assert!(env.step(&[0.0; N_ACTION]).is_ok());
}

#[test]
fn episode_is_truncated_after_max_steps() {
    let params = CheetahParams {
        max_steps: 5,
        ..CheetahParams::default()
    };
    let mut env = CheetahHurdle::new(params, false).expect("valid");
    env.reset(0);
    for i in 0..5 {
        let step = env.step(&[0.0; N_ACTION]).expect("valid");
        assert_eq!(step.truncated, i == 4);
        assert!(!step.terminated);
    }
    assert!(matches!(
        env.step(&[0.0; N_ACTION]),
        Err(EnvError::NotReady { .. })
    ));
}

#[test]
fn same_seed_gives_the_same_trajectory() {
    let rollout = |env: &mut CheetahHurdle| {
        let mut rng = Pcg64Mcg::seed_from_u64(99);
        let mut observations = vec![env.reset(42).obs];
        for _ in 0..100 {
            observations.push(env.step(&random_action(&mut rng)).expect("valid").obs);
        }
        observations
    };
    let mut env = train_env();
    let first = rollout(&mut env);
    // A different episode in between must not leak into the next one.
    env.reset(7);
    env.step(&[1.0; N_ACTION]).expect("valid");
    let second = rollout(&mut env);
    assert_eq!(first, second);
    assert_ne!(env.reset(43).obs, first[0]);
}

#[test]
fn bad_actions_are_errors_and_change_nothing() {
    let mut env = train_env();
    env.reset(0);
    let before = env.state();
    assert!(matches!(
        env.step(&[0.0; 5]),
        Err(EnvError::ActionLength {
            expected: 6,
            got: 5,
            ..
        })
    ));
    let nan = [0.0, 0.0, f32::NAN, 0.0, 0.0, 0.0];
    assert!(matches!(
        env.step(&nan),
        Err(EnvError::NonFiniteAction { index: 2, .. })
    ));
    assert_eq!(env.state(), before);
    assert!(env.step(&[0.0; N_ACTION]).is_ok());
}

#[test]
fn step_before_reset_is_an_error() {
    let mut env = train_env();
    assert!(matches!(
        env.step(&[0.0; N_ACTION]),
        Err(EnvError::NotReady { .. })
    ));
}

#[test]
fn invalid_params_are_reported_together() {
    let mut params = CheetahParams {
        timestep_secs: 0.0,
        ..CheetahParams::default()
    };
    params.bthigh.range_rad = [1.0, -1.0];
    match CheetahHurdle::new(params, false) {
        Err(EnvError::InvalidParam { field, .. }) => {
            assert!(
                field.contains("timestep_secs") && field.contains("bthigh.range_rad"),
                "{field}"
            );
        }
        other => panic!("expected InvalidParam, got {:?}", other.err()),
    }
}

#[test]
fn positive_action_turns_each_joint_positively() {
    let after = |sign: f32| {
        let mut env = train_env();
        env.reset(0);
        env.set_state([0.0; N_QPOS], [0.0; N_QPOS])
            .expect("finite state");
        for _ in 0..2 {
            env.step(&[sign; N_ACTION]).expect("valid");
        }
        env.state().0
    };
    let (plus, minus) = (after(1.0), after(-1.0));
    for j in 3..N_QPOS {
        assert!(
            plus[j] > minus[j] + 0.05,
            "joint {j}: {} vs {}",
            plus[j],
            minus[j]
        );
    }
}
