//! [`Evaluator`]: deterministic evaluation episodes on a task's test variant (SPEC §7, digest
//! §10).
//!
//! Every `eval.interval_episodes` training episodes, `eval.n_episodes` episodes run on the fixed
//! evaluation goal (`<task>-test`) with both levels deterministic — high action `scale·tanh(μ)`
//! every c steps with `subgoal = φ(s_t) + delta`, low action `scale·tanh(μ)` (SAC) or the
//! deterministic actor's output — no exploration, no FR, no count-based choices. An episode ends
//! at its first success or at the time limit; its success is the env's success flag at its last
//! step; the success rate is the mean over the episodes.
//!
//! Invariants: like [`crate::Actor`], no I/O and no threads; episode seeds derive from
//! `(seed, evaluation index, episode)`, so an evaluation of given weights is reproducible; the
//! weights are checked exactly as an actor checks them (layout hash, protocol version).

use envs::api::Env;
use nets::TaskDims;
use protocol::{Config, PhiVersion, PolicyVersion, WeightsHeader};

use crate::error::{ActorError, WeightsRejection};
use crate::exploration::clip;
use crate::networks::{ActorNets, LowHead};

/// The outcome of one evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalReport {
    /// Which evaluation this is (0, 1, …), as passed to [`Evaluator::run`].
    pub index: u64,
    /// Episodes run.
    pub n_episodes: u32,
    /// Fraction of episodes whose last step was a success.
    pub success_rate: f64,
    /// Mean over episodes of the final xy distance to the goal, metres.
    pub mean_final_distance: f64,
    /// Mean over episodes of the distance along the maze from the final position to the goal
    /// (`Maze::path_distance_m`, cell resolution), metres; `None` on tasks without a maze or
    /// when no episode ended in a free cell (those that did not are left out of the mean).
    pub mean_final_path_distance: Option<f64>,
    /// Mean episode length, env steps.
    pub mean_length: f64,
    /// Mean undiscounted env return.
    pub mean_return: f64,
    /// The achieved xy of every step of every episode (start included), for pictures.
    pub trajectories: Vec<Vec<[f32; 2]>>,
    /// The goal of each episode.
    pub goals: Vec<[f32; 2]>,
    /// Policy version evaluated.
    pub policy_version: PolicyVersion,
    /// φ version evaluated.
    pub phi_version: PhiVersion,
}

/// The name of `task`'s evaluation variant: `task` itself if it already ends in `-test`.
pub fn test_task_name(task: &str) -> String {
    if task.ends_with("-test") {
        task.to_owned()
    } else {
        format!("{task}-test")
    }
}

/// Runs evaluation episodes with the latest weights it was given.
pub struct Evaluator {
    env: Box<dyn Env>,
    nets: ActorNets,
    c: u32,
    seed: u64,
    high_scale: f32,
    policy_version: PolicyVersion,
    phi_version: PhiVersion,
    action: Vec<f32>,
    subgoal: Vec<f32>,
}

impl Evaluator {
    /// Builds the test variant of `config.env.task` (with `env.episode_length` if set) and the
    /// actor-side networks (seeded from `seed`; replaced by the first [`Evaluator::load_weights`]).
    pub fn new(config: &Config, seed: u64) -> Result<Evaluator, ActorError> {
        config.validate()?;
        let name = test_task_name(&config.env.task);
        let env = envs::registry::make_with(
            &name,
            envs::registry::EnvOptions {
                max_steps: config.env.episode_length,
            },
        )?;
        let spec = env.spec().clone();
        let bound = spec.action_high.first().copied().unwrap_or(0.0);
        let dims = TaskDims {
            obs_dim: spec.obs_dim,
            goal_dim: spec.goal_dim,
            action_dim: spec.action_dim,
            action_scale: f64::from(bound),
        };
        let nets_spec = nets::spec_from_config(config, dims)?;
        let latent_dim = nets_spec.latent_dim;
        Ok(Evaluator {
            env,
            nets: ActorNets::new(&nets_spec, seed)?,
            c: config.hierarchy.c,
            seed,
            high_scale: nets_spec.high_action_scale as f32,
            policy_version: PolicyVersion(0),
            phi_version: PhiVersion(0),
            action: vec![0.0; spec.action_dim],
            subgoal: vec![0.0; latent_dim],
        })
    }

    /// The maze of the test task, if it has one (for pictures).
    pub fn maze(&self) -> Option<&envs::maze::Maze> {
        self.env.maze()
    }

    /// Layout hash of the networks (what a weights message must carry).
    pub fn layout_hash(&self) -> u64 {
        self.nets.layout_hash()
    }

    /// Installs a weights message, refusing a wrong protocol version, layout hash or payload.
    pub fn load_weights(&mut self, header: &WeightsHeader, bytes: &[u8]) -> Result<(), ActorError> {
        header
            .check(self.layout_hash(), bytes.len())
            .map_err(WeightsRejection::from)
            .and_then(|()| self.nets.load(bytes))
            .map_err(|reason| ActorError::WeightsRejected {
                policy_version: header.policy_version.0,
                phi_version: header.phi_version.0,
                reason,
            })?;
        self.policy_version = header.policy_version;
        self.phi_version = header.phi_version;
        Ok(())
    }

    /// Runs evaluation number `index`: `n_episodes` deterministic episodes.
    pub fn run(&mut self, index: u64, n_episodes: u32) -> Result<EvalReport, ActorError> {
        let mut report = EvalReport {
            index,
            n_episodes,
            success_rate: 0.0,
            mean_final_distance: 0.0,
            mean_final_path_distance: None,
            mean_length: 0.0,
            mean_return: 0.0,
            trajectories: Vec::with_capacity(n_episodes as usize),
            goals: Vec::with_capacity(n_episodes as usize),
            policy_version: self.policy_version,
            phi_version: self.phi_version,
        };
        let mut path_distances = Vec::with_capacity(n_episodes as usize);
        for episode in 0..n_episodes {
            let seed = eval_seed(self.seed, index, episode);
            let outcome = self.episode(seed)?;
            if let (Some(maze), Some(&last)) = (self.env.maze(), outcome.path.last()) {
                path_distances.extend(maze.path_distance_m(last, outcome.goal).map(f64::from));
            }
            report.success_rate += f64::from(u8::from(outcome.success));
            report.mean_final_distance += outcome.final_distance;
            report.mean_length += f64::from(outcome.length);
            report.mean_return += outcome.episode_return;
            report.trajectories.push(outcome.path);
            report.goals.push(outcome.goal);
        }
        let n = f64::from(n_episodes.max(1));
        report.success_rate /= n;
        report.mean_final_distance /= n;
        report.mean_length /= n;
        report.mean_return /= n;
        report.mean_final_path_distance = (!path_distances.is_empty())
            .then(|| path_distances.iter().sum::<f64>() / path_distances.len() as f64);
        Ok(report)
    }

    fn episode(&mut self, seed: u64) -> Result<EpisodeOutcome, ActorError> {
        let reset = self.env.reset(seed);
        let goal = reset.goal;
        let mut obs = reset.obs;
        let mut path = vec![reset.achieved_goal];
        let (mut episode_return, mut t) = (0.0f64, 0u32);
        let success = loop {
            let phi = self.nets.phi_rows(&obs, 1)?;
            if t % self.c == 0 {
                let head = self.nets.high_head(&obs, &goal)?;
                for ((sg, p), mean) in self.subgoal.iter_mut().zip(&phi).zip(&head.mean) {
                    *sg = p + self.high_scale * mean.tanh();
                }
            }
            match self.nets.low_head(&obs, &phi, &self.subgoal)? {
                LowHead::Gaussian(head) => {
                    for (a, mean) in self.action.iter_mut().zip(&head.mean) {
                        *a = head.scale * mean.tanh();
                    }
                }
                LowHead::Deterministic { action, .. } => self.action.copy_from_slice(&action),
            }
            let spec = self.env.spec();
            clip(&mut self.action, &spec.action_low, &spec.action_high);
            let step = self.env.step(&self.action)?;
            t += 1;
            episode_return += f64::from(step.reward);
            path.push(step.info.achieved_goal);
            if step.info.success || step.terminated || step.truncated || step.info.physics_failure {
                break step.info.success;
            }
            obs = step.obs;
        };
        let last = path.last().copied().unwrap_or(goal);
        let final_distance = f64::from((last[0] - goal[0]).hypot(last[1] - goal[1]));
        Ok(EpisodeOutcome {
            success,
            final_distance,
            length: t,
            episode_return,
            path,
            goal,
        })
    }
}

struct EpisodeOutcome {
    success: bool,
    final_distance: f64,
    length: u32,
    episode_return: f64,
    path: Vec<[f32; 2]>,
    goal: [f32; 2],
}

/// Seed of episode `episode` of evaluation `index` (SplitMix64 finaliser of the three).
fn eval_seed(seed: u64, index: u64, episode: u32) -> u64 {
    let mut z = seed
        ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ u64::from(episode).wrapping_mul(0xD1B5_4A32_D192_ED03)
        ^ 0xE7A1_0000_0000_0000;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn test_names() {
        assert_eq!(test_task_name("antmaze-u"), "antmaze-u-test");
        assert_eq!(test_task_name("pointmaze-s-test"), "pointmaze-s-test");
    }

    #[test]
    fn eval_seeds_differ_per_index_and_episode() {
        let seeds: std::collections::HashSet<u64> = (0..20)
            .flat_map(|i| (0..10).map(move |e| eval_seed(7, i, e)))
            .collect();
        assert_eq!(seeds.len(), 200);
    }
}
