//! The goal-conditioned, Gymnasium-like environment contract shared by every task.
//!
//! Invariants every implementation keeps:
//! - `reset(seed)` fully re-seeds the environment: the same seed gives the same episode.
//! - `step` validates the action first; a bad action is an [`EnvError`] and changes nothing.
//! - An observation handed out is always finite. If the physics blows up, the step returns the
//!   last finite observation with `terminated = true` and `info.physics_failure = true`, and the
//!   failure is counted ([`Env::n_physics_failures`]).
//! - `terminated` and `truncated` are never merged: `truncated` means the time limit was hit,
//!   `terminated` means success (only when the variant stops on success) or a physics failure.

use crate::maze::Maze;

/// Static description of a task: dimensions, bounds and timing.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvSpec {
    /// Registry name, e.g. `antmaze-u` or `pointmaze-u-test`.
    pub name: String,
    /// Length of the observation vector.
    pub obs_dim: usize,
    /// Length of the action vector.
    pub action_dim: usize,
    /// Length of the goal / achieved-goal vector (always 2 here).
    pub goal_dim: usize,
    /// Per-dimension lower action bound.
    pub action_low: Vec<f32>,
    /// Per-dimension upper action bound.
    pub action_high: Vec<f32>,
    /// Simulated seconds per control step (timestep × frame skip).
    pub control_dt_secs: f64,
    /// Episode length in control steps; `truncated` is set on the last one.
    pub max_steps: u32,
    /// Success when the distance between achieved goal and goal is below this (metres).
    pub success_threshold: f32,
    /// Whether `terminated` is set on success (test variants) or not (training variants).
    pub terminate_on_success: bool,
}

/// What `reset` hands back.
#[derive(Debug, Clone, PartialEq)]
pub struct Reset {
    pub obs: Vec<f32>,
    /// The goal of this episode (sampled for training variants, fixed for test variants).
    pub goal: [f32; 2],
    pub achieved_goal: [f32; 2],
}

/// Side information of one step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInfo {
    /// Whether the achieved goal is within the success threshold after this step.
    pub success: bool,
    pub achieved_goal: [f32; 2],
    /// The physics produced a non-finite state; `obs` is the last finite observation.
    pub physics_failure: bool,
    /// The fall penalty applied on this step (torso height outside its healthy range).
    pub fell: bool,
}

/// What `step` hands back.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub obs: Vec<f32>,
    pub reward: f32,
    pub terminated: bool,
    pub truncated: bool,
    pub info: StepInfo,
}

/// Errors of the environment API. None of them changes the environment's state.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EnvError {
    #[error("action has {got} values, the task `{task}` expects {expected}")]
    ActionLength {
        task: String,
        expected: usize,
        got: usize,
    },
    #[error("action value {index} is {value}, but actions must be finite")]
    NonFiniteAction { index: usize, value: f32 },
    #[error("step called before reset (or after the episode ended) on `{task}`")]
    NotReady { task: String },
    #[error("unknown task `{name}`; known tasks: {known}")]
    UnknownTask { name: String, known: String },
    #[error("goal ({x}, {y}) is not usable: {reason}")]
    InvalidGoal { x: f32, y: f32, reason: String },
    #[error("invalid environment parameter `{field}` = {value}: {reason}")]
    InvalidParam {
        field: String,
        value: String,
        reason: String,
    },
}

/// A goal-conditioned environment.
pub trait Env: Send {
    fn spec(&self) -> &EnvSpec;
    /// Starts a new episode, re-seeding every random choice (reset noise, goal) from `seed`.
    fn reset(&mut self, seed: u64) -> Reset;
    /// Advances one control step. Actions outside the bounds are clipped; wrong length or
    /// non-finite values are an error.
    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError>;
    /// The current episode's goal.
    fn goal(&self) -> [f32; 2];
    /// Replaces the current episode's goal (e.g. to force a far goal); must be a free cell.
    fn set_goal(&mut self, goal: [f32; 2]) -> Result<(), EnvError>;
    /// The achieved goal of an observation of this task (torso xy, or rootx/rootz).
    fn achieved_goal(&self, obs: &[f32]) -> [f32; 2];
    /// The maze, for tasks that have one.
    fn maze(&self) -> Option<&Maze>;
    /// How many steps ended in a non-finite physics state since construction.
    fn n_physics_failures(&self) -> u64;
}

/// Checks an action's length and finiteness; shared by every environment.
pub fn validate_action(spec: &EnvSpec, action: &[f32]) -> Result<(), EnvError> {
    if action.len() != spec.action_dim {
        return Err(EnvError::ActionLength {
            task: spec.name.clone(),
            expected: spec.action_dim,
            got: action.len(),
        });
    }
    match action.iter().position(|a| !a.is_finite()) {
        Some(index) => Err(EnvError::NonFiniteAction {
            index,
            value: action[index],
        }),
        None => Ok(()),
    }
}

/// An axis-aligned static box (a maze wall or a hurdle), in world coordinates (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StaticBox {
    pub center: [f32; 3],
    pub half_extents: [f32; 3],
}

/// A simulated body driven by an action: the part of a maze task that is not the maze.
///
/// Implemented by the Ant (rapier multibody) and the point mass. The maze task owns the goal,
/// reward and episode bookkeeping; the robot owns physics and observation.
pub trait Robot: Send {
    fn obs_dim(&self) -> usize;
    fn action_dim(&self) -> usize;
    /// Symmetric action bound: actions are clipped to `[-bound, bound]`.
    fn action_bound(&self) -> f32;
    /// Simulated seconds per control step.
    fn control_dt_secs(&self) -> f64;
    /// Puts the robot at its start pose plus reset noise drawn from `rng`.
    fn reset(&mut self, rng: &mut rand_pcg::Pcg64Mcg);
    /// Applies a validated, clipped action for one control step.
    fn step(&mut self, action: &[f32]);
    /// Writes the observation into `out` (length `obs_dim`).
    fn write_obs(&self, out: &mut [f32]);
    /// Torso (or body) position in the plane.
    fn xy(&self) -> [f32; 2];
    /// Torso height for the fall penalty; `None` for robots that cannot fall.
    fn torso_z(&self) -> Option<f32>;
}
