//! Goal-conditioned rapier environments for ASI: the Ant in four mazes, HalfCheetahHurdle and a
//! fast point mass in the same mazes.
//!
//! The contract every task follows lives in [`api`]; tasks are built by name through
//! [`registry`]. Geometry and constants follow `shared/reference/asi-reference-code.md` §9; each
//! one is a documented parameter field.

pub mod ant;
pub mod api;
pub mod bench;
pub mod cheetah;
pub mod coverage;
pub mod maze;
pub mod maze_env;
pub mod pendulum;
pub mod physics;
pub mod point;
pub mod registry;
pub mod render;

pub use api::{Env, EnvError, EnvSpec, Reset, Robot, StaticBox, Step, StepInfo};
pub use coverage::Coverage;
pub use maze::{Cell, Maze, MazeLayout, Rect};
pub use maze_env::{MazeEnv, MazeTaskParams, Variant};
pub use point::{PointMass, PointParams};
pub use registry::{
    make, make_with, parse_task, sparse_reward, task_names, EnvOptions, RobotKind, SparseReward,
    Task, TaskId,
};
pub use render::{render_maze_png, RenderError};
