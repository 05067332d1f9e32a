//! [`Actor`]: the rollout component as a transport-agnostic state machine (SPEC §3, §6.1).
//!
//! The caller drives it: [`Actor::next_chunk`] steps the environment until a chunk is complete
//! and returns it; [`Actor::load_weights`] installs a weights message (and the run-wide
//! [`RunSchedule`] it carries) between calls. The actor does no I/O and owns no threads: the
//! graph-service is reached through the [`GraphOracle`] the caller passes to `next_chunk`, so the
//! `asi` binary can wire it to iceoryx2 (process mode) or to in-process calls (serial mode) with
//! the same behaviour.
//!
//! Invariants:
//! - Determinism: for a given config, actor id, seed and sequence of calls (including which
//!   weights are loaded between which chunks, and the oracle's answers), the chunks are
//!   bit-identical.
//! - An episode's exploration gate (`count_prob`, run-wide episode count) and its FR draw
//!   (`fr_prob`) use the schedule of the last weights loaded before it started; they do not
//!   change mid-episode.
//! - Frontier-reaching episodes ([`crate::frontier`]): drawn at episode start, after the reset
//!   and φ(s_0); an FR episode on a maze task has its env goal forced to a far goal (the
//!   generalisation of the reference's U-maze `g_x ≤ 2, g_y ≥ 8` re-reset, digest §2.2, §9.3),
//!   re-drawn with [`envs::maze::Maze::sample_goal`] from the actor's generator. A new φ
//!   version arriving mid-episode ends FR mode (counted).
//! - `FAR_GOAL` is set on every chunk of an episode whose goal is a far goal
//!   (`Maze::is_far_goal_with_fraction` with `exploration.far_goal_fraction`; tasks without a
//!   maze have no far goals, as the code's `g_y ≥ 8` rule never holds for the cheetah).
//! - `FRONTIER` is set on every chunk of an FR episode (one that got a frontier and route at its
//!   start; an FR draw that fell back to a normal episode is not one), also after its FR mode
//!   ended; the learner's `asi.fr_in_low_replay` / `asi.fr_in_high_replay` act on it.
//! - Every chunk is non-empty; chunk indices of an episode run 0, 1, 2, … without gaps;
//!   `EPISODE_START` marks exactly the first chunk and `EPISODE_END` exactly the last.
//! - Episode ids are `(actor_id << 40) | local episode index` ([`crate::seeds::episode_id`]),
//!   unique across the actors of a run; env seeds derive from `(seed, actor_id, episode)`.
//! - A chunk's `policy_version` is the version that acted its first step (the oldest one in
//!   it); its `phi_version` is the version of every φ value in its records.

use envs::api::{Env, EnvSpec};
use nets::{NetsSpec, TaskDims};
use protocol::{
    ActorId, Config, PhiVersion, PolicyVersion, RunSchedule, StepLayout, TrajectoryFlags,
    TrajectoryHeader, WeightsHeader,
};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use crate::chunk::{header_for, Chunk, ChunkBuffer};
use crate::episode::{DecisionCounters, Episode, Rollout, RolloutParams, StepOutcome};
use crate::error::{ActorError, WeightsRejection};
use crate::exploration::DeterministicNoise;
use crate::frontier::{
    assign, Assignment, FrEnd, FrOutcome, FrontierEpisode, FrontierParams, FrontierStats,
};
use crate::networks::ActorNets;
use crate::oracle::GraphOracle;
use crate::record::RecordWriter;
use crate::seeds::{actor_rng_seed, actor_rng_seed_from, env_seed, episode_id};
use crate::subgoal::{ExploreGate, SubgoalPlan, SubgoalSource};

/// Consecutive episodes without a single recorded step after which [`Actor::next_chunk`] gives up
/// with [`ActorError::NoProgress`] instead of looping on a broken environment. Source: ours.
pub const MAX_EMPTY_EPISODES: u32 = 100;

/// Reaching samples are reported at episode end, or as soon as this many are pending.
/// Source: ours (an episode has at most T/c of them: 25 on U, 50 elsewhere).
pub const REACH_REPORT_BATCH: usize = 64;

/// Goal draws an FR episode makes to find a far goal before it keeps the env's own goal.
/// Source: ours (far goals cover about a fifth of the U-maze's goal box, so 1000 draws all
/// missing has probability below 1e-90).
pub const MAX_FAR_GOAL_DRAWS: u32 = 1000;

/// Counters of one actor, for metrics (saved whole in an [`crate::resume::ActorState`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ActorStats {
    /// Env steps taken (recorded or not), over all episodes.
    pub env_steps: u64,
    /// Episodes finished (ended by truncation or termination; abandoned ones excluded).
    pub episodes: u64,
    /// Policy version acting now.
    pub policy_version: PolicyVersion,
    /// φ version acting now.
    pub phi_version: PhiVersion,
    /// Steps whose physics blew up (from the environment's counter).
    pub n_physics_failures: u64,
    /// Sum of the recorded rewards of the last finished episode.
    pub last_episode_return: f32,
    /// Whether the env reported success on any step of the last finished episode (training
    /// episodes do not stop on success; reference code: the first success counts).
    pub last_episode_success: bool,
    /// Weights messages refused by [`Actor::load_weights`].
    pub n_weights_rejected: u64,
    /// The run-wide schedule of the last weights loaded ([`RunSchedule::START`] before any).
    #[serde(with = "crate::resume::schedule_fields")]
    pub schedule: RunSchedule,
    /// High-level decisions taken.
    pub n_decisions: u64,
    /// Decisions that took the graph-service's HESS explore subgoal.
    pub n_explore_decisions: u64,
    /// Decisions that took a uniform random subgoal (the warm-up, SPEC §6.2).
    #[serde(default)]
    pub n_random_decisions: u64,
    /// Decisions that asked for an explore subgoal and got no answer (the policy, or the random
    /// warm-up source, decided instead).
    pub n_explore_fallbacks: u64,
    /// Reaching reports acknowledged by the graph-service.
    pub n_reach_reports: u64,
    /// Reaching samples delivered.
    pub n_reach_samples_sent: u64,
    /// Reaching samples dropped (the report was not acknowledged, or its episode was abandoned).
    pub n_reach_samples_dropped: u64,
    /// Σ of the reaching errors ‖subgoal − φ(s_{t+c})‖ of every full segment of finished
    /// episodes.
    pub reach_error_sum: f64,
    /// Full segments in `reach_error_sum`.
    pub n_reach_segments: u64,
    /// Σ of the reaching errors of the full explore segments of finished episodes.
    pub explore_reach_error_sum: f64,
    /// Full explore segments in `explore_reach_error_sum`.
    pub n_explore_reach_segments: u64,
    /// Σ of the reaching ratios (end over start distance to the subgoal) of the full segments
    /// of finished episodes that kept one φ (see `Episode::reach_ratio`).
    pub reach_ratio_sum: f64,
    /// Segments in `reach_ratio_sum`.
    pub n_reach_ratio_segments: u64,
    /// Mean reaching ratio over the last finished episode (`None`: no such segment).
    pub last_episode_reach_ratio: Option<f32>,
    /// Mean reaching error over the full segments of the last finished episode (`None`: none).
    pub last_episode_reach_error: Option<f32>,
    /// Mean reaching error over the full explore segments of the last finished episode.
    pub last_episode_explore_reach_error: Option<f32>,
    /// Whether the last finished episode had a far goal.
    pub last_episode_far_goal: bool,
    /// The observation's first two coordinates (x, y in m on the maze tasks) where the last
    /// finished episode ended (`None` before one).
    #[serde(default)]
    pub last_episode_xy: Option<[f32; 2]>,
    /// Frontier-reaching counters (SPEC §6.6).
    pub frontier: FrontierStats,
    /// Where the navigation of the last finished FR episode ended (`None` before one).
    #[serde(default)]
    pub last_fr_end: Option<FrEnd>,
    /// `episodes` when that FR episode finished (tells which episode `last_fr_end` is).
    #[serde(default)]
    pub last_fr_episode: u64,
}

/// An actor's share of what is left of the run's random warm-up when it starts, the run
/// having completed `run_episodes` training episodes: `learner.high.random_episodes` counts
/// the run's first training episodes (SPEC §6.2: "the first 300 training episodes"), which the
/// `run.n_actors` actors run side by side, so each takes ⌈left / n_actors⌉ (one actor: all of
/// them). A fresh actor takes `warm_up_share(config, 0)` ([`Actor::new`]); a restarted or
/// resumed one is told its share ([`Actor::start_at_episode`]). Before, every actor took all
/// 300 (14 actors on a 16-core machine: 4,200 random episodes), and again at every resume.
pub fn warm_up_share(config: &Config, run_episodes: u64) -> u64 {
    let actors = u64::try_from(config.run.n_actors.max(1)).unwrap_or(u64::MAX);
    let left = config
        .learner
        .high
        .random_episodes
        .saturating_sub(run_episodes);
    left.div_ceil(actors)
}

/// One actor: an environment, the actor-side networks, and the episode in progress.
pub struct Actor {
    pub(crate) rollout: Rollout,
    pub(crate) episode: Option<Episode>,
    buffer: ChunkBuffer,
    layout: StepLayout,
    nets_spec: NetsSpec,
    header_template: TrajectoryHeader,
    pub(crate) actor_id: ActorId,
    seed: u64,
    chunk_steps: usize,
    /// Episode indices below this one use random high actions (the warm-up share).
    random_until: u64,
    explore_start_episode: u64,
    far_goal_fraction: f64,
    pub(crate) n_episodes_started: u64,
    /// Physics failures counted before a restore ([`Actor::restore_state`]): the env's own
    /// counter starts at 0 in a restored actor.
    pub(crate) physics_failures_before: u64,
    pub(crate) stats: ActorStats,
}

impl Actor {
    /// Builds env (`envs::make_with(&config.env.task, …)` with `env.episode_length` as the
    /// env's own episode length), networks
    /// (`nets::spec_from_config` with the env's dims; a `PolicySet` on a `VarMap` seeded from
    /// `seed`, so a learner that builds its `PolicySet` first from the same seed starts from the
    /// same weights) and the generator for noise (`Pcg64Mcg` from `seed` mixed with `actor_id`).
    pub fn new(config: &Config, actor_id: ActorId, seed: u64) -> Result<Actor, ActorError> {
        let options = envs::EnvOptions {
            max_steps: config.env.episode_length,
        };
        Self::with_env(
            config,
            actor_id,
            seed,
            envs::make_with(&config.env.task, options)?,
        )
    }

    /// As [`Actor::new`], on an environment the caller built (e.g. a task with non-default
    /// parameters); `config.env.task` is not looked at, and `config.env.episode_length`, if
    /// set, must equal the env's own length (the env truncates its episodes).
    pub fn with_env(
        config: &Config,
        actor_id: ActorId,
        seed: u64,
        env: Box<dyn Env>,
    ) -> Result<Actor, ActorError> {
        config.validate()?;
        let spec = env.spec().clone();
        let dims = TaskDims {
            obs_dim: spec.obs_dim,
            goal_dim: spec.goal_dim,
            action_dim: spec.action_dim,
            action_scale: f64::from(symmetric_action_bound(&spec)?),
        };
        let nets_spec = nets::spec_from_config(config, dims)?;
        let nets = ActorNets::new(&nets_spec, seed)?;
        let layout = StepLayout::new(
            spec.obs_dim,
            spec.action_dim,
            spec.goal_dim,
            nets_spec.latent_dim,
        )?;
        let writer = RecordWriter::new(layout)?;
        let mut header_template = TrajectoryHeader::for_layout(&layout)?;
        header_template.actor_id = actor_id;
        let params = rollout_params(config, &spec)?;
        let chunk_steps = config.transport.chunk_steps as usize;
        let rollout = Rollout {
            env,
            nets,
            rng: Pcg64Mcg::seed_from_u64(actor_rng_seed(seed, actor_id)),
            writer,
            params,
            action: vec![0.0; spec.action_dim],
            zeros: vec![0.0; nets_spec.latent_dim],
            record: vec![0.0; layout.record_len()],
            phi_version: PhiVersion(0),
            decisions: DecisionCounters::default(),
            frontier_stats: FrontierStats::default(),
        };
        Ok(Actor {
            rollout,
            episode: None,
            buffer: ChunkBuffer::new(layout.record_len(), chunk_steps),
            layout,
            nets_spec,
            header_template,
            actor_id,
            seed,
            chunk_steps,
            random_until: warm_up_share(config, 0),
            explore_start_episode: config.exploration.explore_start_episode,
            far_goal_fraction: config.exploration.far_goal_fraction,
            n_episodes_started: 0,
            physics_failures_before: 0,
            stats: ActorStats {
                env_steps: 0,
                episodes: 0,
                policy_version: PolicyVersion(0),
                phi_version: PhiVersion(0),
                n_physics_failures: 0,
                last_episode_return: 0.0,
                last_episode_success: false,
                n_weights_rejected: 0,
                schedule: RunSchedule::START,
                n_decisions: 0,
                n_explore_decisions: 0,
                n_random_decisions: 0,
                n_explore_fallbacks: 0,
                n_reach_reports: 0,
                n_reach_samples_sent: 0,
                n_reach_samples_dropped: 0,
                reach_error_sum: 0.0,
                n_reach_segments: 0,
                explore_reach_error_sum: 0.0,
                n_explore_reach_segments: 0,
                last_episode_reach_error: None,
                reach_ratio_sum: 0.0,
                n_reach_ratio_segments: 0,
                last_episode_reach_ratio: None,
                last_episode_explore_reach_error: None,
                last_episode_far_goal: false,
                last_episode_xy: None,
                frontier: FrontierStats::default(),
                last_fr_end: None,
                last_fr_episode: 0,
            },
        })
    }

    /// The record layout of this actor's chunks.
    pub fn layout(&self) -> StepLayout {
        self.layout
    }

    /// Layout hash of the actor-side tensors (encoder, high policy, low policy) — what the
    /// learner publishes in [`WeightsHeader::layout_hash`].
    pub fn layout_hash(&self) -> u64 {
        self.rollout.nets.layout_hash()
    }

    /// The network spec the actor built (the learner must build the same).
    pub fn nets_spec(&self) -> &NetsSpec {
        &self.nets_spec
    }

    /// The acting parameters as safetensors bytes (names under `nets::prefix::ACTOR_SIDE`).
    pub fn weights_bytes(&self) -> Result<Vec<u8>, ActorError> {
        Ok(nets::to_safetensors_bytes(self.rollout.nets.varmap())?)
    }

    /// Steps the env until a chunk is complete: `transport.chunk_steps` records, or fewer at
    /// episode end. Never returns an empty chunk. On error the current episode is abandoned.
    /// `oracle` answers the HESS exploration requests and takes the reaching reports
    /// ([`crate::NoGraph`] where there is no graph-service).
    pub fn next_chunk(&mut self, oracle: &mut dyn GraphOracle) -> Result<Chunk, ActorError> {
        let result = self.fill_chunk(oracle);
        if let Err(err) = &result {
            tracing::warn!(actor = self.actor_id.0, error = %err, "abandoning the current episode");
            if let Some(episode) = self.episode.take() {
                self.stats.n_reach_samples_dropped += episode.reach_samples.len() as u64;
            }
            self.buffer.clear();
        }
        result
    }

    fn fill_chunk(&mut self, oracle: &mut dyn GraphOracle) -> Result<Chunk, ActorError> {
        let mut n_empty_episodes = 0;
        loop {
            if let Some(chunk) = self.take_ready_chunk(oracle) {
                return Ok(chunk);
            }
            if self.episode.is_none() {
                if n_empty_episodes == MAX_EMPTY_EPISODES {
                    let (actor_id, n_episodes) = (self.actor_id.0, n_empty_episodes);
                    return Err(ActorError::NoProgress {
                        actor_id,
                        n_episodes,
                    });
                }
                n_empty_episodes += 1;
                self.start_episode(oracle)?;
            }
            self.step(oracle)?;
        }
    }

    /// A full chunk once `chunk_steps + 1` records are buffered, or the rest of an episode that
    /// has ended (then the episode is finished). `None` if neither.
    fn take_ready_chunk(&mut self, oracle: &mut dyn GraphOracle) -> Option<Chunk> {
        let end_flags = self.episode.as_ref()?.end_flags;
        let n_records = self.buffer.n_records();
        if n_records > self.chunk_steps {
            return self.cut_chunk(self.chunk_steps, 0);
        }
        let flags = end_flags?;
        let chunk = if n_records > 0 {
            self.cut_chunk(n_records, flags)
        } else {
            None
        };
        self.finish_episode(oracle);
        chunk
    }

    fn cut_chunk(&mut self, n_records: usize, mut flags: u32) -> Option<Chunk> {
        let episode = self.episode.as_mut()?;
        if episode.next_chunk_index == 0 {
            flags |= TrajectoryFlags::EPISODE_START;
        }
        if episode.far_goal {
            flags |= TrajectoryFlags::FAR_GOAL;
        }
        if episode.frontier.is_some() {
            flags |= TrajectoryFlags::FRONTIER;
        }
        let cut = self.buffer.cut(n_records, self.stats.policy_version);
        let mut header = header_for(&self.header_template, &cut, episode.next_chunk_index, flags);
        header.episode_id = episode.id;
        header.phi_version = self.stats.phi_version;
        episode.next_chunk_index += 1;
        Some(Chunk {
            header,
            records: cut.records,
        })
    }

    fn start_episode(&mut self, oracle: &mut dyn GraphOracle) -> Result<(), ActorError> {
        let index = self.n_episodes_started;
        let id = episode_id(self.actor_id, index).ok_or(ActorError::EpisodeIdsExhausted {
            actor_id: self.actor_id.0,
            n_episodes: index,
        })?;
        self.n_episodes_started += 1;
        let mut reset = self
            .rollout
            .env
            .reset(env_seed(self.seed, self.actor_id, index));
        let phi = self.rollout.nets.phi_rows(&reset.obs, 1)?;
        let frontier = self.assign_frontier(&phi, oracle)?;
        if frontier.is_some() {
            self.force_far_goal(&mut reset)?;
        }
        let plan = SubgoalPlan {
            base: SubgoalSource::for_training_episode(index, self.random_until),
            explore: ExploreGate::for_schedule(&self.stats.schedule, self.explore_start_episode),
        };
        let far_goal =
            self.rollout.env.maze().is_some_and(|maze| {
                maze.is_far_goal_with_fraction(reset.goal, self.far_goal_fraction)
            });
        self.episode = Some(Episode::new(id, plan, far_goal, reset, phi, frontier));
        Ok(())
    }

    /// The FR draw of a new episode (counted), with φ(s_0) = `phi`.
    fn assign_frontier(
        &mut self,
        phi: &[f32],
        oracle: &mut dyn GraphOracle,
    ) -> Result<Option<FrontierEpisode>, ActorError> {
        let rollout = &mut self.rollout;
        let assignment = assign(
            rollout.params.frontier.as_ref(),
            self.stats.schedule.fr_prob,
            phi,
            rollout.phi_version,
            &mut rollout.rng,
            oracle,
        )?;
        let stats = &mut rollout.frontier_stats;
        Ok(match assignment {
            Assignment::Normal => None,
            Assignment::NoRoute => {
                stats.n_no_route += 1;
                None
            }
            Assignment::Frontier(fr) => {
                stats.n_episodes += 1;
                tracing::debug!(
                    actor = self.actor_id.0,
                    frontier = ?fr.frontier(),
                    route = ?fr.route(),
                    "FR episode assigned"
                );
                Some(fr)
            }
        })
    }

    /// Re-draws the goal of an FR episode until it is a far goal and sets it in the env
    /// (digest §2.2). Tasks without a maze keep their goal (the reference hack has no cheetah
    /// branch); so does an episode whose goal is already far, or that finds none in
    /// [`MAX_FAR_GOAL_DRAWS`] draws.
    fn force_far_goal(&mut self, reset: &mut envs::api::Reset) -> Result<(), ActorError> {
        let fraction = self.far_goal_fraction;
        let rollout = &mut self.rollout;
        let Some(maze) = rollout.env.maze() else {
            return Ok(());
        };
        if maze.is_far_goal_with_fraction(reset.goal, fraction) {
            return Ok(());
        }
        let far = (0..MAX_FAR_GOAL_DRAWS)
            .map(|_| maze.sample_goal(&mut rollout.rng))
            .find(|goal| maze.is_far_goal_with_fraction(*goal, fraction));
        let Some(goal) = far else {
            tracing::warn!(
                actor = self.actor_id.0,
                "no far goal found for an FR episode"
            );
            return Ok(());
        };
        rollout.env.set_goal(goal)?;
        reset.goal = goal;
        rollout.frontier_stats.n_goals_forced += 1;
        Ok(())
    }

    fn step(&mut self, oracle: &mut dyn GraphOracle) -> Result<(), ActorError> {
        let Some(episode) = self.episode.as_mut() else {
            return Ok(());
        };
        let env_step = u64::from(episode.t);
        let outcome = episode.step(&mut self.rollout, oracle)?;
        self.stats.env_steps += 1;
        let full_batch = (episode.reach_samples.len() >= REACH_REPORT_BATCH)
            .then(|| std::mem::take(&mut episode.reach_samples));
        match outcome {
            StepOutcome::Recorded(_) => {
                self.buffer
                    .push(&self.rollout.record, env_step, self.stats.policy_version)
            }
            StepOutcome::PhysicsFailure => tracing::warn!(
                actor = self.actor_id.0,
                episode = episode.id.0,
                env_step,
                "physics failure: step not recorded, episode ended"
            ),
        }
        if let Some(samples) = full_batch {
            self.report_reaching(oracle, &samples);
        }
        Ok(())
    }

    fn finish_episode(&mut self, oracle: &mut dyn GraphOracle) {
        if let Some(episode) = self.episode.take() {
            if !episode.reach_samples.is_empty() {
                self.report_reaching(oracle, &episode.reach_samples);
            }
            let stats = &mut self.stats;
            stats.episodes += 1;
            stats.last_episode_return = episode.episode_return;
            stats.last_episode_success = episode.success;
            stats.last_episode_far_goal = episode.far_goal;
            stats.last_episode_xy = episode.xy();
            stats.reach_error_sum += episode.reach_all.sum;
            stats.n_reach_segments += episode.reach_all.n;
            stats.explore_reach_error_sum += episode.reach_explore.sum;
            stats.n_explore_reach_segments += episode.reach_explore.n;
            stats.last_episode_reach_error = episode.reach_all.mean();
            stats.reach_ratio_sum += episode.reach_ratio.sum;
            stats.n_reach_ratio_segments += episode.reach_ratio.n;
            stats.last_episode_reach_ratio = episode.reach_ratio.mean();
            stats.last_episode_explore_reach_error = episode.reach_explore.mean();
            if let Some(end) = episode.frontier_end() {
                stats.last_fr_end = Some(end);
                stats.last_fr_episode = stats.episodes;
                // One outcome per finished FR episode (near-frontier switches count at the
                // switch: only navigation can end in one).
                let fr = &mut self.rollout.frontier_stats;
                match end.outcome {
                    FrOutcome::NearFrontier => {}
                    FrOutcome::Stuck => fr.n_stuck_while_navigating += 1,
                    FrOutcome::NewPhi => fr.n_new_phi_while_navigating += 1,
                    FrOutcome::Navigating => fr.n_navigating_at_end += 1,
                }
            }
            tracing::debug!(
                actor = self.actor_id.0,
                episode = episode.id.0,
                steps = episode.t,
                episode_return = episode.episode_return,
                success = episode.success,
                "episode finished"
            );
        }
    }

    /// Sends reaching samples; a report that is not acknowledged drops them (counted).
    fn report_reaching(
        &mut self,
        oracle: &mut dyn GraphOracle,
        samples: &[protocol::graph::ReachSample],
    ) {
        let n = samples.len() as u64;
        match oracle.report_reaching(samples, self.stats.phi_version) {
            Ok(true) => {
                self.stats.n_reach_reports += 1;
                self.stats.n_reach_samples_sent += n;
            }
            Ok(false) => self.stats.n_reach_samples_dropped += n,
            Err(err) => {
                tracing::warn!(actor = self.actor_id.0, error = %err, "reaching report failed");
                self.stats.n_reach_samples_dropped += n;
            }
        }
    }

    /// Checks `header` (protocol version, layout hash, length), loads the actor-side weights,
    /// keeps the run-wide schedule it carries (used from the next episode on) and relabels the
    /// φ values of the running episode. A rejected message is an
    /// [`ActorError::WeightsRejected`], changes nothing and is counted.
    pub fn load_weights(&mut self, header: &WeightsHeader, bytes: &[u8]) -> Result<(), ActorError> {
        let loaded = header
            .check(self.layout_hash(), bytes.len())
            .map_err(WeightsRejection::from)
            .and_then(|()| self.rollout.nets.load(bytes));
        if let Err(reason) = loaded {
            self.stats.n_weights_rejected += 1;
            tracing::warn!(actor = self.actor_id.0, policy_version = header.policy_version.0, %reason, "weights rejected");
            return Err(ActorError::WeightsRejected {
                policy_version: header.policy_version.0,
                phi_version: header.phi_version.0,
                reason,
            });
        }
        let new_phi = header.phi_version != self.stats.phi_version;
        self.stats.policy_version = header.policy_version;
        self.stats.phi_version = header.phi_version;
        self.stats.schedule = header.schedule;
        self.rollout.phi_version = header.phi_version;
        if let Some(episode) = self.episode.as_mut() {
            if new_phi && episode.end_frontier_for_new_phi() {
                self.rollout.frontier_stats.n_ended_by_new_phi += 1;
            }
            episode.relabel_phi(
                &mut self.rollout.nets,
                &self.rollout.writer,
                self.buffer.records_mut(),
            )?;
        }
        Ok(())
    }

    /// Makes the next episode the `episode`-th of this actor (its id and env seed follow from
    /// it), its first `warm_up_episodes` random-action episodes (its [`warm_up_share`] of what
    /// the run has left of the warm-up), and, for `episode > 0`, gives its generator a stream
    /// of its own ([`crate::seeds::actor_rng_seed_from`]). A restarted or resumed actor process
    /// starts at a fresh range (`incarnation << 28`), so its episode ids, env seeds and noise
    /// never repeat those of an earlier start. Only allowed before the first episode starts.
    pub fn start_at_episode(
        &mut self,
        episode: u64,
        warm_up_episodes: u64,
    ) -> Result<(), ActorError> {
        if self.episode.is_some() || self.n_episodes_started > 0 {
            return Err(ActorError::Misuse(format!(
                "start_at_episode({episode}) after {} episodes already started",
                self.n_episodes_started
            )));
        }
        self.n_episodes_started = episode;
        self.random_until = episode.saturating_add(warm_up_episodes);
        self.rollout.rng =
            Pcg64Mcg::seed_from_u64(actor_rng_seed_from(self.seed, self.actor_id, episode));
        Ok(())
    }

    /// Counters for metrics.
    pub fn stats(&self) -> ActorStats {
        let decisions = self.rollout.decisions;
        ActorStats {
            n_physics_failures: self.physics_failures_before
                + self.rollout.env.n_physics_failures(),
            n_decisions: decisions.n_decisions,
            n_explore_decisions: decisions.n_explore,
            n_random_decisions: decisions.n_random,
            n_explore_fallbacks: decisions.n_explore_fallbacks,
            frontier: self.rollout.frontier_stats,
            ..self.stats
        }
    }
}

/// The env's action bound, which must be the same symmetric `[−b, b]` in every dimension (the
/// low policy squashes to one scale).
fn symmetric_action_bound(spec: &EnvSpec) -> Result<f32, ActorError> {
    let bound = spec.action_high.first().copied().unwrap_or(0.0);
    let symmetric = spec.action_high.iter().all(|h| *h == bound)
        && spec.action_low.iter().all(|l| *l == -bound);
    if symmetric && bound.is_finite() && bound > 0.0 {
        Ok(bound)
    } else {
        Err(ActorError::TaskMismatch {
            task: spec.name.clone(),
            reason: format!(
                "action bounds low {:?} / high {:?} are not one symmetric [-b, b]; the low policy needs that",
                spec.action_low, spec.action_high
            ),
        })
    }
}

/// Stepping parameters; `env.episode_length`, if set, must be the env's own length (the env
/// truncates; [`Actor::new`] builds it with that length).
fn rollout_params(config: &Config, spec: &EnvSpec) -> Result<RolloutParams, ActorError> {
    if let Some(episode_length) = config.env.episode_length {
        if episode_length != spec.max_steps {
            return Err(ActorError::TaskMismatch {
                task: spec.name.clone(),
                reason: format!(
                    "env.episode_length = {episode_length} but the environment was built with max_steps = {}; \
                     build it with envs::make_with and EnvOptions {{ max_steps: Some({episode_length}) }}",
                    spec.max_steps
                ),
            });
        }
    }
    if spec.goal_dim != 2 {
        return Err(ActorError::TaskMismatch {
            task: spec.name.clone(),
            reason: format!(
                "goal_dim = {}, but the env API's goals are 2-D",
                spec.goal_dim
            ),
        });
    }
    let deterministic = &config.learner.low.deterministic;
    Ok(RolloutParams {
        c: config.hierarchy.c,
        abs_range: config.hierarchy.abs_range as f32,
        noise: DeterministicNoise {
            noise_scale: deterministic.noise_scale as f32,
            random_eps: deterministic.random_eps,
        },
        action_low: spec.action_low.clone(),
        action_high: spec.action_high.clone(),
        frontier: FrontierParams::from_config(config)?,
    })
}
