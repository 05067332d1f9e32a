//! Task registry: names map through one table to typed tasks, and each builds the right env.

use std::collections::HashSet;

use envs::api::EnvError;
use envs::maze::MazeLayout;
use envs::maze_env::Variant;
use envs::registry::{
    make, make_with, parse_task, task_name, task_names, EnvOptions, RobotKind, Task, TaskId, TASKS,
};

#[test]
fn every_maze_task_is_registered_once_for_both_robots_and_variants() {
    let names = task_names();
    assert_eq!(names.len(), 18, "16 maze tasks and 2 half-cheetah variants");
    assert_eq!(
        names.iter().collect::<HashSet<_>>().len(),
        names.len(),
        "names are unique"
    );
    let tasks: HashSet<Task> = TASKS.iter().map(|(_, t)| *t).collect();
    assert_eq!(tasks.len(), names.len(), "tasks are unique");
    for robot in [RobotKind::Ant, RobotKind::Point] {
        for layout in MazeLayout::ALL {
            for variant in [Variant::Train, Variant::Test] {
                assert!(tasks.contains(&Task::Maze(TaskId {
                    robot,
                    layout,
                    variant
                })));
            }
        }
    }
}

#[test]
fn names_parse_to_the_expected_tasks_and_back() {
    let cases = [
        ("antmaze-u", RobotKind::Ant, MazeLayout::U, Variant::Train),
        (
            "antmaze-w-test",
            RobotKind::Ant,
            MazeLayout::W,
            Variant::Test,
        ),
        (
            "ant-fourrooms-test",
            RobotKind::Ant,
            MazeLayout::FourRooms,
            Variant::Test,
        ),
        (
            "pointmaze-s",
            RobotKind::Point,
            MazeLayout::S,
            Variant::Train,
        ),
        (
            "pointmaze-fourrooms",
            RobotKind::Point,
            MazeLayout::FourRooms,
            Variant::Train,
        ),
    ];
    for (name, robot, layout, variant) in cases {
        let task = parse_task(name).expect("registered");
        assert_eq!(
            task,
            Task::Maze(TaskId {
                robot,
                layout,
                variant
            })
        );
        assert_eq!(task_name(task), name);
    }
}

#[test]
fn an_unknown_name_is_an_error_listing_the_known_names() {
    for name in ["antmaze", "antmaze-u-", "pointmaze-x", "ANTMAZE-U", ""] {
        match make(name) {
            Err(EnvError::UnknownTask { name: got, known }) => {
                assert_eq!(got, name);
                assert!(task_names().iter().all(|n| known.contains(n)), "{known}");
            }
            Err(other) => panic!("{name}: unexpected error {other}"),
            Ok(_) => panic!("{name}: built an env"),
        }
    }
}

#[test]
fn point_maze_tasks_have_the_expected_specs() {
    for (name, max_steps, terminate, test_goal) in [
        ("pointmaze-u", 500, false, None),
        ("pointmaze-u-test", 500, true, Some([0.0, 8.0])),
        ("pointmaze-s-test", 1000, true, Some([16.0, 16.0])),
        ("pointmaze-w-test", 1000, true, Some([0.0, 8.0])),
        ("pointmaze-fourrooms-test", 1000, true, Some([14.0, 14.0])),
    ] {
        let mut env = make(name).expect("registered");
        let spec = env.spec().clone();
        assert_eq!(spec.name, name);
        assert_eq!((spec.obs_dim, spec.action_dim, spec.goal_dim), (4, 2, 2));
        assert_eq!(
            (spec.action_low, spec.action_high),
            (vec![-1.0; 2], vec![1.0; 2])
        );
        assert_eq!(
            (
                spec.max_steps,
                spec.terminate_on_success,
                spec.success_threshold
            ),
            (max_steps, terminate, 1.5)
        );
        let reset = env.reset(3);
        if let Some(goal) = test_goal {
            assert_eq!(reset.goal, goal);
        }
        assert!(env.maze().is_some());
    }
}

#[test]
fn ant_maze_tasks_have_the_ants_dimensions_and_step() {
    let mut env = make("antmaze-u-test").expect("registered");
    let spec = env.spec().clone();
    assert_eq!((spec.obs_dim, spec.action_dim), (29, 8));
    assert_eq!((spec.action_low[0], spec.action_high[0]), (-16.0, 16.0));
    assert!((spec.control_dt_secs - 0.2).abs() < 1e-6);
    assert_eq!((spec.max_steps, spec.terminate_on_success), (500, true));
    let reset = env.reset(0);
    assert_eq!(reset.goal, [0.0, 8.0]);
    let step = env.step(&[0.0; 8]).expect("valid action");
    assert!(step.obs.iter().all(|v| v.is_finite()));
    assert_eq!(
        (step.reward, step.info.fell),
        (-1.0, false),
        "a resting ant far from the goal, upright"
    );
}

#[test]
fn the_half_cheetah_is_registered_with_a_test_variant_that_stops_on_success() {
    assert_eq!(
        parse_task("halfcheetah-hurdle").unwrap(),
        Task::HalfCheetahHurdle(Variant::Train)
    );
    let train = make("halfcheetah-hurdle").unwrap();
    let test = make("halfcheetah-hurdle-test").unwrap();
    assert_eq!(train.spec().obs_dim, 18);
    assert!(!train.spec().terminate_on_success);
    assert!(test.spec().terminate_on_success);
}

#[test]
fn an_episode_length_override_truncates_every_task_kind() {
    for name in ["pointmaze-u", "halfcheetah-hurdle"] {
        let mut env = make_with(name, EnvOptions { max_steps: Some(3) }).unwrap();
        assert_eq!(env.spec().max_steps, 3);
        env.reset(1);
        let action = vec![0.0; env.spec().action_dim];
        let truncated: Vec<bool> = (0..3)
            .map(|_| env.step(&action).unwrap().truncated)
            .collect();
        assert_eq!(truncated, vec![false, false, true], "{name}");
    }
}

#[test]
fn the_sparse_reward_of_every_task_matches_what_its_env_pays_and_how_long_it_runs() {
    for name in task_names() {
        for max_steps in [None, Some(4)] {
            let options = EnvOptions { max_steps };
            let expected = envs::sparse_reward(name, options).unwrap();
            let mut env = make_with(name, options).unwrap();
            assert_eq!(env.spec().max_steps, expected.max_steps, "{name}");
            env.reset(3);
            let action = vec![0.0; env.spec().action_dim];
            for _ in 0..3 {
                let step = env.step(&action).unwrap();
                let paid = if step.info.success {
                    0.0
                } else {
                    expected.step_penalty
                } + if step.info.fell {
                    expected.fall_penalty
                } else {
                    0.0
                };
                assert_eq!(step.reward, -paid, "{name}");
            }
        }
        let robot = match parse_task(name).unwrap() {
            Task::Maze(id) => Some(id.robot),
            Task::HalfCheetahHurdle(_) => None,
        };
        let reward = envs::sparse_reward(name, EnvOptions::default()).unwrap();
        assert_eq!(
            reward.step_penalty, 1.0,
            "{name}: every task pays −1 per step"
        );
        let fall = if robot == Some(RobotKind::Ant) {
            10.0
        } else {
            0.0
        };
        assert_eq!(reward.fall_penalty, fall, "{name}: only the Ant can fall");
    }
    let lengths: Vec<u32> = [
        "antmaze-u",
        "antmaze-s",
        "pointmaze-w",
        "halfcheetah-hurdle",
    ]
    .iter()
    .map(|name| {
        envs::sparse_reward(name, EnvOptions::default())
            .unwrap()
            .max_steps
    })
    .collect();
    assert_eq!(lengths, vec![500, 1000, 1000, 1000]);
    assert!(matches!(
        envs::sparse_reward("no-such-task", EnvOptions::default()),
        Err(EnvError::UnknownTask { .. })
    ));
}
