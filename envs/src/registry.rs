//! Builds tasks by registry name (`antmaze-u`, `pointmaze-s-test`, …).
//!
//! Names are looked up in one table ([`TASKS`]) that maps each to a typed [`Task`]; nothing
//! dispatches on string prefixes. Every maze task exists for the Ant and the point mass, in a
//! training variant (sampled goals) and a `-test` variant (fixed evaluation goal, ends on
//! success). Tasks without a maze (the half-cheetah hurdle of `envs::cheetah`) get their own
//! [`Task`] variant and table rows; they are not maze robots, so they have no [`RobotKind`].

use crate::ant::{Ant, AntParams};
use crate::api::{Env, EnvError};
use crate::cheetah::{CheetahHurdle, CheetahParams};
use crate::maze::{Maze, MazeLayout};
use crate::maze_env::{MazeEnv, MazeTaskParams, Variant};
use crate::point::{PointMass, PointParams};

/// The robot of a maze task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RobotKind {
    /// The rllab/HIRO Ant (29-D obs, 8 torques ±16 N·m), as in the paper.
    Ant,
    /// The force-controlled ball of [`crate::point`] (4-D obs, 2-D force in [−1, 1]); ours.
    Point,
}

/// A maze task: which robot, which maze, which variant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TaskId {
    pub robot: RobotKind,
    pub layout: MazeLayout,
    pub variant: Variant,
}

/// What a registry name stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Task {
    /// A robot in one of the mazes.
    Maze(TaskId),
    /// HalfCheetahHurdle (no maze); the test variant ends on success.
    HalfCheetahHurdle(Variant),
}

const fn maze(robot: RobotKind, layout: MazeLayout, variant: Variant) -> Task {
    Task::Maze(TaskId {
        robot,
        layout,
        variant,
    })
}

use MazeLayout::{FourRooms, S, U, W};
use RobotKind::{Ant as A, Point as P};
use Variant::{Test, Train};

/// Every registered task name with what it builds.
pub const TASKS: &[(&str, Task)] = &[
    ("antmaze-u", maze(A, U, Train)),
    ("antmaze-u-test", maze(A, U, Test)),
    ("antmaze-s", maze(A, S, Train)),
    ("antmaze-s-test", maze(A, S, Test)),
    ("antmaze-w", maze(A, W, Train)),
    ("antmaze-w-test", maze(A, W, Test)),
    ("ant-fourrooms", maze(A, FourRooms, Train)),
    ("ant-fourrooms-test", maze(A, FourRooms, Test)),
    ("pointmaze-u", maze(P, U, Train)),
    ("pointmaze-u-test", maze(P, U, Test)),
    ("pointmaze-s", maze(P, S, Train)),
    ("pointmaze-s-test", maze(P, S, Test)),
    ("pointmaze-w", maze(P, W, Train)),
    ("pointmaze-w-test", maze(P, W, Test)),
    ("pointmaze-fourrooms", maze(P, FourRooms, Train)),
    ("pointmaze-fourrooms-test", maze(P, FourRooms, Test)),
    ("halfcheetah-hurdle", Task::HalfCheetahHurdle(Train)),
    ("halfcheetah-hurdle-test", Task::HalfCheetahHurdle(Test)),
];

/// All registered task names, in table order.
pub fn task_names() -> Vec<&'static str> {
    TASKS.iter().map(|(name, _)| *name).collect()
}

/// The task a name stands for; [`EnvError::UnknownTask`] (listing the known names) otherwise.
pub fn parse_task(name: &str) -> Result<Task, EnvError> {
    TASKS
        .iter()
        .find(|(known, _)| *known == name)
        .map(|(_, task)| *task)
        .ok_or_else(|| EnvError::UnknownTask {
            name: name.to_string(),
            known: task_names().join(", "),
        })
}

/// The registry name of a task (inverse of [`parse_task`]).
pub fn task_name(task: Task) -> &'static str {
    TASKS
        .iter()
        .find(|(_, t)| *t == task)
        .map(|(name, _)| *name)
        .expect("every Task value has a row in TASKS (checked by tests/registry.rs)")
}

/// Builds a task by name with default parameters.
pub fn make(name: &str) -> Result<Box<dyn Env>, EnvError> {
    make_with(name, EnvOptions::default())
}

/// Run-level choices that apply to every task.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EnvOptions {
    /// Episode length override in control steps (e.g. short episodes for smoke tests); `None`
    /// keeps the task's own length (maze: 500 or 1000; cheetah: 1000).
    pub max_steps: Option<u32>,
}

/// Builds a task by name with default parameters and run-level options.
pub fn make_with(name: &str, options: EnvOptions) -> Result<Box<dyn Env>, EnvError> {
    match parse_task(name)? {
        Task::Maze(id) => {
            let task = MazeTaskParams {
                max_steps: options.max_steps,
                ..MazeTaskParams::default()
            };
            make_maze(id, &MazeRobotParams::default(), task)
        }
        Task::HalfCheetahHurdle(variant) => {
            let mut params = CheetahParams::default();
            if let Some(max_steps) = options.max_steps {
                params.max_steps = max_steps;
            }
            Ok(Box::new(CheetahHurdle::new(
                params,
                variant == Variant::Test,
            )?))
        }
    }
}

/// The reward rule and episode length of a registered task as [`make_with`] builds it: every
/// step that is not a success pays `step_penalty`; a step of a robot with a torso (the Ant) whose
/// torso height is outside its healthy range pays `fall_penalty` on top (0 for the point mass and
/// the cheetah). Bounds on returns (e.g. the high level's `learner.high.clip_target`) derive
/// from it instead of repeating 500 or −1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SparseReward {
    /// Reward magnitude of a step that is neither a success nor a fall.
    pub step_penalty: f32,
    /// Extra reward magnitude of a fall step.
    pub fall_penalty: f32,
    /// Episode length in control steps (the task's own, or `options.max_steps`).
    pub max_steps: u32,
}

/// [`SparseReward`] of the task `name` with run-level `options`, without building it;
/// [`EnvError::UnknownTask`] for an unknown name.
pub fn sparse_reward(name: &str, options: EnvOptions) -> Result<SparseReward, EnvError> {
    Ok(match parse_task(name)? {
        Task::Maze(id) => {
            let task = MazeTaskParams::default();
            let fall_penalty = match id.robot {
                RobotKind::Ant => task.fall_penalty,
                RobotKind::Point => 0.0,
            };
            SparseReward {
                step_penalty: task.step_penalty,
                fall_penalty,
                max_steps: options
                    .max_steps
                    .unwrap_or(Maze::new(id.layout).max_steps()),
            }
        }
        Task::HalfCheetahHurdle(_) => SparseReward {
            step_penalty: crate::cheetah::STEP_PENALTY,
            fall_penalty: 0.0,
            max_steps: options
                .max_steps
                .unwrap_or(CheetahParams::default().max_steps),
        },
    })
}

/// Robot parameters for maze tasks; only the one matching the task's robot is used.
#[derive(Debug, Clone, Default)]
pub struct MazeRobotParams {
    pub ant: AntParams,
    pub point: PointParams,
}

/// Builds a maze task with explicit parameters.
pub fn make_maze(
    id: TaskId,
    robot: &MazeRobotParams,
    task: MazeTaskParams,
) -> Result<Box<dyn Env>, EnvError> {
    Ok(match id.robot {
        RobotKind::Ant => Box::new(make_ant_maze(
            id.layout,
            id.variant,
            robot.ant.clone(),
            task,
        )?),
        RobotKind::Point => Box::new(make_point_maze(id.layout, id.variant, robot.point, task)?),
    })
}

/// The Ant in `layout`, as a concrete type (no dynamic dispatch).
pub fn make_ant_maze(
    layout: MazeLayout,
    variant: Variant,
    params: AntParams,
    task: MazeTaskParams,
) -> Result<MazeEnv<Ant>, EnvError> {
    let id = TaskId {
        robot: RobotKind::Ant,
        layout,
        variant,
    };
    let maze = Maze::new(layout);
    let ant = Ant::new(params, &maze.walls())?;
    MazeEnv::new(task_name(Task::Maze(id)), maze, ant, variant, task)
}

/// The point mass in `layout`, as a concrete type (no dynamic dispatch).
pub fn make_point_maze(
    layout: MazeLayout,
    variant: Variant,
    params: PointParams,
    task: MazeTaskParams,
) -> Result<MazeEnv<PointMass>, EnvError> {
    let id = TaskId {
        robot: RobotKind::Point,
        layout,
        variant,
    };
    let maze = Maze::new(layout);
    let point = PointMass::new(params, &maze.walls())?;
    MazeEnv::new(task_name(Task::Maze(id)), maze, point, variant, task)
}
