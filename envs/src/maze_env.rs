//! `MazeEnv<R>`: a goal-conditioned maze task around any [`Robot`] (Ant or point mass).
//!
//! The task owns the maze, the goal, the random generator and the episode bookkeeping; the robot
//! owns physics and observation. Reward (digest §9.1, SPEC §4): `−step_penalty` per step while
//! `‖xy − g‖ ≥ success_threshold` (0 once strictly inside), plus `−fall_penalty` per step while
//! the torso height is outside `[healthy_z_min_m, healthy_z_max_m]` (robots with a torso only).
//!
//! Invariants:
//! - `reset(seed)` re-seeds a `Pcg64Mcg` from `seed` and draws, in this order, the robot's reset
//!   noise and (training variant) the goal: the same seed gives the same episode.
//! - `step` validates the action before touching anything; a bad action is an error and changes
//!   nothing. Valid actions are clipped to `[−bound, bound]`.
//! - Observations handed out are finite. A non-finite observation from the robot ends the episode
//!   (`terminated`, `info.physics_failure`), hands back the last finite observation with reward
//!   `−step_penalty` (no success, no fall: the state is unknown) and is counted. After `terminated` or `truncated`, `step` is [`EnvError::NotReady`] until `reset`.
//! - Robots used here put their planar position in `obs[0..2]` (the achieved goal).

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::api::{validate_action, Env, EnvError, EnvSpec, Reset, Robot, Step, StepInfo};
use crate::maze::Maze;

/// Length of goals and achieved goals (planar position).
pub const GOAL_DIM: usize = 2;

/// Training or evaluation flavour of a task.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Goals sampled uniformly over free cells of the goal box; success does not end the episode.
    Train,
    /// The fixed evaluation goal; success ends the episode (`terminated`).
    Test,
}

/// Constants of the maze task (reward, success, episode length).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MazeTaskParams {
    /// Success when `‖xy − g‖` is strictly below this, metres. Default 1.5. Source: code
    /// (digest §9.1).
    pub success_threshold_m: f32,
    /// Reward subtracted on every step that is not a success. Default 1.0. Source: code.
    pub step_penalty: f32,
    /// Reward subtracted on every step whose torso height is outside the healthy range.
    /// Default 10.0. Source: code (digest §9.4).
    pub fall_penalty: f32,
    /// Lower end of the healthy torso height, metres. Default 0.3. Source: code.
    pub healthy_z_min_m: f32,
    /// Upper end of the healthy torso height, metres. Default 1.0. Source: code.
    pub healthy_z_max_m: f32,
    /// Episode length override in control steps; `None` uses the maze's (U 500, others 1000,
    /// source: code). Meant for smoke tests.
    pub max_steps: Option<u32>,
}

impl Default for MazeTaskParams {
    fn default() -> Self {
        MazeTaskParams {
            success_threshold_m: 1.5,
            step_penalty: 1.0,
            fall_penalty: 10.0,
            healthy_z_min_m: 0.3,
            healthy_z_max_m: 1.0,
            max_steps: None,
        }
    }
}

impl MazeTaskParams {
    /// Checks every field; reports the first problem found.
    pub fn validate(&self) -> Result<(), EnvError> {
        if !(self.success_threshold_m.is_finite() && self.success_threshold_m > 0.0) {
            return Err(invalid(
                "success_threshold_m",
                self.success_threshold_m,
                "must be finite and positive",
            ));
        }
        for (field, value) in [
            ("step_penalty", self.step_penalty),
            ("fall_penalty", self.fall_penalty),
        ] {
            if !value.is_finite() {
                return Err(invalid(field, value, "must be finite"));
            }
        }
        if !(self.healthy_z_min_m.is_finite() && self.healthy_z_max_m.is_finite())
            || self.healthy_z_min_m > self.healthy_z_max_m
        {
            let range = format!("[{}, {}]", self.healthy_z_min_m, self.healthy_z_max_m);
            return Err(invalid(
                "healthy_z_min_m",
                range,
                "must be a finite range with min ≤ max",
            ));
        }
        if self.max_steps == Some(0) {
            return Err(invalid("max_steps", 0, "must be positive"));
        }
        Ok(())
    }
}

/// Reward of one state and the two facts it depends on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RewardOutcome {
    pub reward: f32,
    /// `‖xy − g‖ < success_threshold_m`.
    pub success: bool,
    /// The torso height is outside the healthy range (robots with a torso only).
    pub fell: bool,
}

/// A robot in a maze, chasing a goal.
pub struct MazeEnv<R: Robot> {
    spec: EnvSpec,
    params: MazeTaskParams,
    variant: Variant,
    maze: Maze,
    robot: R,
    goal: [f32; 2],
    rng: Pcg64Mcg,
    n_steps: u32,
    ready: bool,
    /// Last finite observation handed out.
    last_obs: Vec<f32>,
    /// Scratch for the robot's new observation.
    next_obs: Vec<f32>,
    /// Scratch for the clipped action.
    clipped: Vec<f32>,
    n_physics_failures: u64,
}

impl<R: Robot> MazeEnv<R> {
    /// A task named `name` (registry name) around `robot` in `maze`. Call `reset` before `step`.
    pub fn new(
        name: &str,
        maze: Maze,
        robot: R,
        variant: Variant,
        params: MazeTaskParams,
    ) -> Result<Self, EnvError> {
        params.validate()?;
        let spec = build_spec(name, &maze, &robot, variant, &params);
        let obs_dim = robot.obs_dim();
        let goal = maze.test_goal();
        Ok(MazeEnv {
            clipped: vec![0.0; spec.action_dim],
            spec,
            params,
            variant,
            maze,
            robot,
            goal,
            rng: Pcg64Mcg::seed_from_u64(0),
            n_steps: 0,
            ready: false,
            last_obs: vec![0.0; obs_dim],
            next_obs: vec![0.0; obs_dim],
            n_physics_failures: 0,
        })
    }

    pub fn robot(&self) -> &R {
        &self.robot
    }

    pub fn params(&self) -> &MazeTaskParams {
        &self.params
    }

    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// Control steps taken in the current episode.
    pub fn n_steps(&self) -> u32 {
        self.n_steps
    }

    /// Reward of being at `xy` with torso height `torso_z` under the current goal (pure; the rule
    /// of the module docs).
    pub fn reward_at(&self, xy: [f32; 2], torso_z: Option<f32>) -> RewardOutcome {
        let p = &self.params;
        let success = distance(xy, self.goal) < p.success_threshold_m;
        let fell = torso_z.is_some_and(|z| !(p.healthy_z_min_m..=p.healthy_z_max_m).contains(&z));
        let mut reward = if success { 0.0 } else { -p.step_penalty };
        if fell {
            reward -= p.fall_penalty;
        }
        RewardOutcome {
            reward,
            success,
            fell,
        }
    }

    fn clip_action(&mut self, action: &[f32]) {
        let bound = self.robot.action_bound();
        for (out, &a) in self.clipped.iter_mut().zip(action) {
            *out = a.clamp(-bound, bound);
        }
    }

    /// The step after a non-finite robot state: last finite obs, terminated, counted.
    fn physics_failure_step(&mut self, truncated: bool) -> Step {
        self.n_physics_failures += 1;
        self.ready = false;
        let achieved_goal = self.achieved_goal(&self.last_obs);
        let info = StepInfo {
            success: false,
            achieved_goal,
            physics_failure: true,
            fell: false,
        };
        Step {
            obs: self.last_obs.clone(),
            reward: -self.params.step_penalty,
            terminated: true,
            truncated,
            info,
        }
    }
}

impl<R: Robot> Env for MazeEnv<R> {
    fn spec(&self) -> &EnvSpec {
        &self.spec
    }

    fn reset(&mut self, seed: u64) -> Reset {
        self.rng = Pcg64Mcg::seed_from_u64(seed);
        self.robot.reset(&mut self.rng);
        self.goal = match self.variant {
            Variant::Train => self.maze.sample_goal(&mut self.rng),
            Variant::Test => self.maze.test_goal(),
        };
        self.n_steps = 0;
        self.ready = true;
        self.robot.write_obs(&mut self.last_obs);
        Reset {
            obs: self.last_obs.clone(),
            goal: self.goal,
            achieved_goal: self.achieved_goal(&self.last_obs),
        }
    }

    fn step(&mut self, action: &[f32]) -> Result<Step, EnvError> {
        if !self.ready {
            return Err(EnvError::NotReady {
                task: self.spec.name.clone(),
            });
        }
        validate_action(&self.spec, action)?;
        self.clip_action(action);
        self.robot.step(&self.clipped);
        self.n_steps += 1;
        let truncated = self.n_steps >= self.spec.max_steps;
        self.robot.write_obs(&mut self.next_obs);
        let torso_z = self.robot.torso_z();
        if !self.next_obs.iter().all(|v| v.is_finite()) || torso_z.is_some_and(|z| !z.is_finite()) {
            return Ok(self.physics_failure_step(truncated));
        }
        std::mem::swap(&mut self.last_obs, &mut self.next_obs);
        let achieved_goal = self.achieved_goal(&self.last_obs);
        let RewardOutcome {
            reward,
            success,
            fell,
        } = self.reward_at(achieved_goal, torso_z);
        let terminated = success && self.spec.terminate_on_success;
        self.ready = !(terminated || truncated);
        let info = StepInfo {
            success,
            achieved_goal,
            physics_failure: false,
            fell,
        };
        Ok(Step {
            obs: self.last_obs.clone(),
            reward,
            terminated,
            truncated,
            info,
        })
    }

    fn goal(&self) -> [f32; 2] {
        self.goal
    }

    fn set_goal(&mut self, goal: [f32; 2]) -> Result<(), EnvError> {
        if !(goal[0].is_finite() && goal[1].is_finite()) {
            return Err(EnvError::InvalidGoal {
                x: goal[0],
                y: goal[1],
                reason: "not finite".to_string(),
            });
        }
        if !self.maze.is_free_xy(goal) {
            let reason = "not in a free cell of the maze".to_string();
            return Err(EnvError::InvalidGoal {
                x: goal[0],
                y: goal[1],
                reason,
            });
        }
        self.goal = goal;
        Ok(())
    }

    fn achieved_goal(&self, obs: &[f32]) -> [f32; 2] {
        [obs[0], obs[1]]
    }

    fn maze(&self) -> Option<&Maze> {
        Some(&self.maze)
    }

    fn n_physics_failures(&self) -> u64 {
        self.n_physics_failures
    }
}

fn build_spec<R: Robot>(
    name: &str,
    maze: &Maze,
    robot: &R,
    variant: Variant,
    params: &MazeTaskParams,
) -> EnvSpec {
    let bound = robot.action_bound();
    EnvSpec {
        name: name.to_string(),
        obs_dim: robot.obs_dim(),
        action_dim: robot.action_dim(),
        goal_dim: GOAL_DIM,
        action_low: vec![-bound; robot.action_dim()],
        action_high: vec![bound; robot.action_dim()],
        control_dt_secs: robot.control_dt_secs(),
        max_steps: params.max_steps.unwrap_or(maze.max_steps()),
        success_threshold: params.success_threshold_m,
        terminate_on_success: variant == Variant::Test,
    }
}

fn distance(a: [f32; 2], b: [f32; 2]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

fn invalid(field: &str, value: impl std::fmt::Display, reason: &str) -> EnvError {
    EnvError::InvalidParam {
        field: format!("task.{field}"),
        value: value.to_string(),
        reason: reason.to_string(),
    }
}
