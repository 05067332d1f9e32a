//! The maze task around a robot: reward, success, fall penalty, termination, truncation, bad
//! actions, physics failures and determinism. A tiny teleporting robot places the body exactly.

use envs::api::{Env, EnvError, Robot};
use envs::maze::{Maze, MazeLayout};
use envs::maze_env::{MazeEnv, MazeTaskParams, Variant};
use envs::registry::make;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Actions above this x make the teleport robot's state non-finite.
const BLOW_UP_X: f32 = 500.0;

/// A robot whose action is its next pose: `[x, y, z]`; obs = `[x, y, z]`.
struct Teleport {
    pose: [f32; 3],
    has_torso: bool,
}

impl Robot for Teleport {
    fn obs_dim(&self) -> usize {
        3
    }
    fn action_dim(&self) -> usize {
        3
    }
    fn action_bound(&self) -> f32 {
        1000.0
    }
    fn control_dt_secs(&self) -> f64 {
        0.2
    }
    fn reset(&mut self, _rng: &mut Pcg64Mcg) {
        self.pose = [0.0, 0.0, 0.75];
    }
    fn step(&mut self, action: &[f32]) {
        self.pose = [action[0], action[1], action[2]];
        if action[0] > BLOW_UP_X {
            self.pose[0] = f32::NAN;
        }
    }
    fn write_obs(&self, out: &mut [f32]) {
        out.copy_from_slice(&self.pose);
    }
    fn xy(&self) -> [f32; 2] {
        [self.pose[0], self.pose[1]]
    }
    fn torso_z(&self) -> Option<f32> {
        self.has_torso.then_some(self.pose[2])
    }
}

fn teleport_env(variant: Variant, params: MazeTaskParams) -> MazeEnv<Teleport> {
    let robot = Teleport {
        pose: [0.0, 0.0, 0.75],
        has_torso: true,
    };
    let mut env = MazeEnv::new(
        "teleport-u",
        Maze::new(MazeLayout::U),
        robot,
        variant,
        params,
    )
    .expect("valid");
    env.reset(0);
    env
}

#[test]
fn reward_is_minus_one_until_strictly_within_one_and_a_half_metres_of_the_goal() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    env.set_goal([0.0, 8.0]).expect("free cell");
    // (0, 6.5) is exactly 1.5 m from (0, 8): not a success (strict).
    let cases = [
        ([8.0, 8.0], -1.0, false),
        ([0.0, 6.5], -1.0, false),
        ([0.0, 6.6], 0.0, true),
        ([1.0, 8.0], 0.0, true),
    ];
    for (xy, reward, success) in cases {
        let step = env.step(&[xy[0], xy[1], 0.75]).expect("valid action");
        assert_eq!(
            (step.reward, step.info.success),
            (reward, success),
            "at {xy:?}"
        );
        assert!(!step.terminated, "training episodes do not stop on success");
        assert_eq!(step.info.achieved_goal, xy);
    }
}

#[test]
fn fall_penalty_applies_outside_the_healthy_torso_height() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    env.set_goal([0.0, 8.0]).expect("free cell");
    let far = [8.0, 0.0];
    let cases = [
        (0.75, -1.0, false),
        (0.3, -1.0, false),
        (1.0, -1.0, false),
        (0.29, -11.0, true),
        (1.01, -11.0, true),
    ];
    for (z, reward, fell) in cases {
        let step = env.step(&[far[0], far[1], z]).expect("valid action");
        assert_eq!((step.reward, step.info.fell), (reward, fell), "z = {z}");
    }
    let step = env.step(&[0.0, 8.0, 0.1]).expect("valid action");
    assert_eq!(
        (step.reward, step.info.success, step.info.fell),
        (-10.0, true, true),
        "success while fallen"
    );
}

#[test]
fn robots_without_a_torso_never_pay_the_fall_penalty() {
    let robot = Teleport {
        pose: [0.0; 3],
        has_torso: false,
    };
    let mut env = MazeEnv::new(
        "t",
        Maze::new(MazeLayout::U),
        robot,
        Variant::Train,
        MazeTaskParams::default(),
    )
    .expect("valid");
    env.reset(1);
    env.set_goal([0.0, 8.0]).expect("free cell");
    let step = env.step(&[8.0, 0.0, -5.0]).expect("valid action");
    assert_eq!((step.reward, step.info.fell), (-1.0, false));
}

#[test]
fn test_variant_has_the_fixed_goal_and_terminates_on_success() {
    let mut env = teleport_env(Variant::Test, MazeTaskParams::default());
    assert_eq!(env.goal(), [0.0, 8.0]);
    assert!(env.spec().terminate_on_success);
    let step = env.step(&[4.0, 8.0, 0.75]).expect("valid action");
    assert!(!step.terminated && !step.info.success);
    let step = env.step(&[0.5, 8.0, 0.75]).expect("valid action");
    assert!(step.terminated && step.info.success && !step.truncated);
    assert!(matches!(
        env.step(&[0.0, 0.0, 0.75]),
        Err(EnvError::NotReady { .. })
    ));
}

#[test]
fn truncated_is_set_on_the_last_step_and_stepping_then_needs_a_reset() {
    let params = MazeTaskParams {
        max_steps: Some(3),
        ..MazeTaskParams::default()
    };
    let mut env = teleport_env(Variant::Train, params);
    assert_eq!(env.spec().max_steps, 3);
    let truncated: Vec<bool> = (0..3)
        .map(|_| env.step(&[8.0, 0.0, 0.75]).expect("valid").truncated)
        .collect();
    assert_eq!(truncated, [false, false, true]);
    assert!(matches!(
        env.step(&[8.0, 0.0, 0.75]),
        Err(EnvError::NotReady { .. })
    ));
    env.reset(5);
    assert!(env.step(&[8.0, 0.0, 0.75]).is_ok());
}

#[test]
fn wrong_length_and_non_finite_actions_are_errors_that_change_nothing() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    env.step(&[8.0, 0.0, 0.75]).expect("valid action");
    let before = (env.robot().xy(), env.n_steps(), env.goal());
    let bad: [&[f32]; 4] = [
        &[1.0, 2.0],
        &[1.0, 2.0, 3.0, 4.0],
        &[f32::NAN, 0.0, 0.75],
        &[0.0, f32::INFINITY, 0.75],
    ];
    for action in bad {
        let err = env.step(action).expect_err("bad action accepted");
        assert!(
            matches!(
                err,
                EnvError::ActionLength { .. } | EnvError::NonFiniteAction { .. }
            ),
            "{err}"
        );
        assert_eq!((env.robot().xy(), env.n_steps(), env.goal()), before);
    }
}

#[test]
fn a_non_finite_robot_state_ends_the_episode_with_the_last_finite_observation() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    let good = env.step(&[8.0, 0.0, 0.75]).expect("valid action");
    let failed = env
        .step(&[BLOW_UP_X + 1.0, 0.0, 0.75])
        .expect("a failure is a step, not an error");
    assert!(failed.terminated && failed.info.physics_failure);
    assert_eq!(failed.obs, good.obs);
    assert!(failed.obs.iter().all(|v| v.is_finite()));
    assert_eq!(env.n_physics_failures(), 1);
    assert!(matches!(
        env.step(&[0.0, 0.0, 0.75]),
        Err(EnvError::NotReady { .. })
    ));
    env.reset(2);
    assert!(env.step(&[0.0, 0.0, 0.75]).is_ok());
}

#[test]
fn stepping_before_reset_is_not_ready() {
    let robot = Teleport {
        pose: [0.0; 3],
        has_torso: true,
    };
    let mut env = MazeEnv::new(
        "t",
        Maze::new(MazeLayout::U),
        robot,
        Variant::Train,
        MazeTaskParams::default(),
    )
    .expect("valid");
    assert!(matches!(
        env.step(&[0.0, 0.0, 0.75]),
        Err(EnvError::NotReady { .. })
    ));
}

#[test]
fn actions_outside_the_bounds_are_clipped() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    let step = env.step(&[8.0, -2000.0, 0.75]).expect("valid action");
    assert_eq!(step.info.achieved_goal, [8.0, -1000.0]);
}

#[test]
fn set_goal_accepts_free_cells_only() {
    let mut env = teleport_env(Variant::Train, MazeTaskParams::default());
    env.set_goal([8.0, 4.0]).expect("free cell");
    assert_eq!(env.goal(), [8.0, 4.0]);
    for goal in [[0.0, 4.0], [50.0, 0.0], [f32::NAN, 0.0]] {
        assert!(
            matches!(env.set_goal(goal), Err(EnvError::InvalidGoal { .. })),
            "{goal:?}"
        );
        assert_eq!(env.goal(), [8.0, 4.0]);
    }
}

#[test]
fn invalid_task_params_are_rejected() {
    let bad = [
        MazeTaskParams {
            success_threshold_m: 0.0,
            ..MazeTaskParams::default()
        },
        MazeTaskParams {
            healthy_z_min_m: 2.0,
            ..MazeTaskParams::default()
        },
        MazeTaskParams {
            max_steps: Some(0),
            ..MazeTaskParams::default()
        },
        MazeTaskParams {
            fall_penalty: f32::NAN,
            ..MazeTaskParams::default()
        },
    ];
    for params in bad {
        let robot = Teleport {
            pose: [0.0; 3],
            has_torso: true,
        };
        assert!(
            MazeEnv::new("t", Maze::new(MazeLayout::U), robot, Variant::Train, params).is_err(),
            "{params:?}"
        );
    }
}

/// Steps `name` from `seed` with actions drawn from a second seeded generator.
fn rollout(name: &str, seed: u64, n_steps: usize) -> (Vec<Vec<f32>>, [f32; 2]) {
    let mut env = make(name).expect("registered");
    let reset = env.reset(seed);
    let mut actions = Pcg64Mcg::seed_from_u64(99);
    let mut obs = vec![reset.obs];
    for _ in 0..n_steps {
        let action: Vec<f32> = (0..env.spec().action_dim)
            .map(|_| actions.random_range(-1.0..=1.0))
            .collect();
        obs.push(env.step(&action).expect("valid action").obs);
    }
    (obs, reset.goal)
}

#[test]
fn the_same_seed_gives_the_same_point_maze_trajectory() {
    let (a, goal_a) = rollout("pointmaze-u", 11, 300);
    let (b, goal_b) = rollout("pointmaze-u", 11, 300);
    assert_eq!(a, b);
    assert_eq!(goal_a, goal_b);
    let (c, goal_c) = rollout("pointmaze-u", 12, 300);
    assert_ne!(a[0], c[0], "reset noise differs between seeds");
    assert_ne!(goal_a, goal_c, "training goals differ between seeds");
}

#[test]
fn point_maze_reset_noise_is_within_bounds_and_goals_are_free() {
    let mut env = make("pointmaze-fourrooms").expect("registered");
    for seed in 0..200 {
        let reset = env.reset(seed);
        assert!(
            reset.obs[0].abs() <= 0.1 && reset.obs[1].abs() <= 0.1,
            "{:?}",
            reset.obs
        );
        assert_eq!(reset.achieved_goal, [reset.obs[0], reset.obs[1]]);
        let maze = env.maze().expect("maze task");
        assert!(maze.is_free_xy(reset.goal) && maze.goal_box().contains(reset.goal));
    }
}
