//! [`Learner`]: the learner process's state machine, with no I/O and no threads. The `asi`
//! binary feeds it chunks ([`Learner::ingest`]), lets it train ([`Learner::train`]), forwards
//! the weights it produces ([`Learner::publish_due`]) and reads [`Learner::progress`] to
//! throttle the actors.
//!
//! Invariants:
//! - A chunk is stored entirely or not at all: header, layout, every record and its place in
//!   the episode are checked before any buffer changes.
//! - Updates never exceed the replay ratio ([`crate::ratio`]); the budget never deadlocks.
//! - Published policy versions only go up: the first publication is version 0 (the initial
//!   weights), each later one is the previous + 1.
//!
//! Weights schedule (choice): a new version is due when at least one update has run since the
//! last publication — or `count_prob`/`fr_prob` of the run schedule changed — and at least
//! `transport.weights_check_interval_steps` env steps have been ingested since then — the
//! cadence at which actors look for weights anyway. A finished φ round is published at once,
//! without waiting for env steps (actors are throttled during a round, so none may arrive).
//! The very first call publishes the initial weights so actors never act with weights of
//! their own. Every publication carries the current [`RunSchedule`] ([`crate::schedule`]);
//! `train_episodes` alone does not trigger one: actors receive it at the normal cadence.
//!
//! φ rounds ([`crate::phi::round`]) run inside [`Learner::train`], at most
//! `min(max_updates, PHI_STEPS_PER_CALL)` Adam steps per call. While a round is due or running, no SAC update
//! runs, so `updates_low` — and with it the actor throttle budget — does not grow: the actors
//! stop within `replay.replay_slack_steps`, as the reference code collects nothing during a
//! round, and what a round sees does not depend on actor speed (the φ store is frozen).
//! With `encoder.background_rounds` (process mode) a round's steps run on a thread of their
//! own instead ([`crate::phi::worker`]): the SAC updates, and so the actors, go on with the
//! encoder as it was, and the round's result replaces it when [`Learner::train`] finds the
//! round finished; the store is still frozen for the round, so what it sees is the same.
//! Low-level rewards keep the φ labels computed at collection time (SPEC §6.1, digest §3.2:
//! the code never relabels them): the low replay is not touched by a round.
//!
//! Self-imitation ([`crate::si`]): every training episode that ends after
//! `asi.si_start_episode` makes one SI round due (counted at ingest); the binary runs due rounds
//! with [`Learner::train_self_imitation`], handing it a [`RouteSource`] — the learner itself
//! never talks to the graph-service. Rounds wait while a φ round runs in line (not while one
//! runs in the background: the encoder does not change until it ends), and ask for routes in
//! the learner's current φ version.

use std::collections::BTreeMap;
use std::time::Instant;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use nets::{spec_from_config, NetsSpec, TaskDims};
use protocol::{
    Config, PhiVersion, PolicyVersion, RunSchedule, StepLayout, StepView, TrajectoryFlags,
    TrajectoryHeader, WeightsHeader,
};
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64Mcg;

use crate::deterministic::DeterministicStats;
use crate::error::LearnerError;
use crate::ingest::{Buffers, Episodes};
use crate::phi::{PhiParams, PhiRunner, PhiStats, PhiStore, PhiTrainer};
use crate::ratio::ReplayRatio;
use crate::replay::{sample_into, BatchStage, HighReplay, LowReplay, LowRewardSpec};
use crate::sac::{SacBatch, SacLevel, SacStats};
use crate::schedule::ScheduleTracker;
use crate::setup::{build_networks, LowLevel, Networks};

pub mod checkpoint;
use crate::si::{RouteSource, SelfImitation, SiParams, SiStats};

/// Offset of the sampling RNG seed from the run seed (ours; keeps it apart from the init).
const SAMPLING_SEED_OFFSET: u64 = 0x5a3b_1e00;
/// Offset of the φ triplet-sampling seed from the run seed (ours).
const PHI_SEED_OFFSET: u64 = 0x0f1e_5eed;
/// Most φ Adam steps one [`Learner::train`] call runs (ours): a slice of a round short enough
/// (milliseconds in release builds at the default sizes) that ingest, progress messages and
/// publication keep going — a long slice leaves actors acting on a stale progress message.
pub const PHI_STEPS_PER_CALL: u64 = 50;

/// Where training stands; the actor throttle reads `env_steps_ingested` and `env_step_budget`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LearnerProgress {
    /// Env steps stored so far (all actors, duplicates excluded).
    pub env_steps_ingested: u64,
    /// Actors stop producing while `env_steps_ingested ≥ env_step_budget` (SPEC §6.8).
    pub env_step_budget: u64,
    /// Low-level SAC updates run.
    pub updates_low: u64,
    /// High-level SAC updates run.
    pub updates_high: u64,
    /// Latest published policy version.
    pub policy_version: PolicyVersion,
    /// Latest published φ version.
    pub phi_version: PhiVersion,
}

/// Ingest counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct IngestStats {
    /// Chunks stored.
    pub chunks: u64,
    /// Env steps stored.
    pub env_steps: u64,
    /// Env steps stored per actor id.
    pub per_actor_steps: BTreeMap<u32, u64>,
    /// Chunks that never arrived (gaps in an episode's chunk indices).
    pub lost_chunks: u64,
    /// Repeated chunks (counted, not stored).
    pub duplicate_chunks: u64,
    /// Malformed or mismatched chunks (refused, nothing stored).
    pub rejected_chunks: u64,
    /// Episodes whose final chunk was stored.
    pub episodes_completed: u64,
    /// High-level transitions stored.
    pub high_transitions: u64,
    /// Open high-level segments dropped (a gap, or an abandoned episode).
    pub dropped_segments: u64,
    /// Open episodes abandoned because too many were open at once.
    pub abandoned_episodes: u64,
    /// Env steps stored from chunks flagged `FRONTIER` (frontier-reaching episodes); counted
    /// whether or not `asi.fr_in_low_replay` / `fr_in_high_replay` keep them out of a replay.
    pub frontier_steps: u64,
}

/// Publication bookkeeping.
#[derive(Debug, Clone, Copy, Default)]
struct PublishState {
    published_once: bool,
    steps_at_last: u64,
    updates_at_last: u64,
    phi_at_last: PhiVersion,
    schedule_at_last: RunSchedule,
}

/// Metrics-only measurements.
#[derive(Debug, Clone, Copy, Default)]
struct Telemetry {
    low: SacStats,
    low_deterministic: DeterministicStats,
    high: SacStats,
    train_secs: f64,
    updates_timed: u64,
    /// Updates skipped because a loss was NaN or infinite (nothing was stepped).
    skipped_nonfinite_low: u64,
    skipped_nonfinite_high: u64,
    last_policy_lag: u64,
    max_policy_lag: u64,
}

/// The learner state machine. See the module doc.
pub struct Learner {
    layout: StepLayout,
    spec: NetsSpec,
    nets: Networks,
    low_replay: LowReplay,
    high_replay: HighReplay,
    low_stage: BatchStage,
    high_stage: BatchStage,
    episodes: Episodes,
    ratio: ReplayRatio,
    rng: Pcg64Mcg,
    noise: Vec<f32>,
    stats: IngestStats,
    updates_low: u64,
    updates_high: u64,
    policy_version: PolicyVersion,
    phi_version: PhiVersion,
    publish: PublishState,
    publish_interval_steps: u64,
    telemetry: Telemetry,
    phi_store: PhiStore,
    phi: PhiRunner,
    schedule: ScheduleTracker,
    si: SelfImitation,
    fr_replay: FrReplay,
}

/// Which replay buffers an FR episode's transitions go to (`asi.fr_in_low_replay`,
/// `asi.fr_in_high_replay`; both by default, as the released code).
#[derive(Debug, Clone, Copy)]
struct FrReplay {
    low: bool,
    high: bool,
}

impl Learner {
    /// A learner for `config` and the task's `dims`; `seed` seeds the networks and sampling.
    /// The low replay ratio comes from `learner.low.updates_per_env_step`, else from
    /// `env.episode_length`; when neither is set use [`Learner::with_episode_length`] with the
    /// task's own episode length.
    pub fn new(config: &Config, dims: TaskDims, seed: u64) -> Result<Learner, LearnerError> {
        let explicit = config.learner.low.updates_per_env_step.is_some();
        match config.env.episode_length {
            Some(length) => Self::with_episode_length(config, dims, length, seed),
            // The length only derives the ratio, which is explicit here: any value will do.
            None if explicit => Self::with_episode_length(config, dims, 1, seed),
            None => Err(LearnerError::Unsupported {
                key: "env.episode_length",
                reason: "needed to derive learner.low.updates_per_env_step; set one of them or \
                         build the learner with Learner::with_episode_length(task length)"
                    .to_owned(),
            }),
        }
    }

    /// As [`Learner::new`], with the task's `episode_length` (env steps) for the derived low
    /// ratio `updates_per_episode / episode_length`; `env.episode_length` overrides it.
    pub fn with_episode_length(
        config: &Config,
        dims: TaskDims,
        episode_length: u32,
        seed: u64,
    ) -> Result<Learner, LearnerError> {
        config.validate()?;
        let spec = spec_from_config(config, dims)?;
        let layout = StepLayout::new(
            spec.obs_dim,
            spec.action_dim,
            spec.goal_dim,
            spec.latent_dim,
        )
        .map_err(|err| LearnerError::Nets(nets::NetsError::Spec(err.to_string())))?;
        let nets = build_networks(config, &spec, seed)?;
        let length = config.env.episode_length.unwrap_or(episode_length);
        let (low_replay, high_replay) = buffers(config, &spec);
        let phi_params = PhiParams::from_config(config);
        let phi_store = PhiStore::new(
            spec.obs_dim,
            phi_params.negative_offset,
            usize::try_from(config.replay.capacity_steps).unwrap_or(usize::MAX),
        );
        let background = config.encoder.background_rounds;
        let trainer = if background {
            PhiTrainer::with_private_copy
        } else {
            PhiTrainer::new
        };
        let trainer = trainer(
            phi_params,
            &spec,
            &nets.policy_vm,
            seed.wrapping_add(PHI_SEED_OFFSET),
        )?;
        let phi = PhiRunner::new(trainer, background);
        Ok(Learner {
            layout,
            low_stage: low_replay.stage(config.learner.low.batch_size),
            high_stage: high_replay.stage(config.learner.high.batch_size),
            low_replay,
            high_replay,
            episodes: Episodes::default(),
            ratio: replay_ratio(config, length),
            rng: Pcg64Mcg::seed_from_u64(seed.wrapping_add(SAMPLING_SEED_OFFSET)),
            noise: Vec::new(),
            stats: IngestStats::default(),
            updates_low: 0,
            updates_high: 0,
            policy_version: PolicyVersion(0),
            phi_version: PhiVersion(0),
            publish: PublishState::default(),
            publish_interval_steps: u64::from(config.transport.weights_check_interval_steps),
            fr_replay: FrReplay {
                low: config.asi.fr_in_low_replay,
                high: config.asi.fr_in_high_replay,
            },
            telemetry: Telemetry::default(),
            phi_store,
            phi,
            schedule: ScheduleTracker::new(config),
            si: SelfImitation::new(SiParams::from_config(config), spec.obs_dim, spec.goal_dim),
            spec,
            nets,
        })
    }

    /// Checks and stores one trajectory chunk (see the module doc of [`crate::ingest`]).
    /// Malformed or mismatched chunks are counted in `rejected_chunks`, repeats in
    /// `duplicate_chunks`; both return an error and change no buffer.
    pub fn ingest(
        &mut self,
        header: &TrajectoryHeader,
        payload: &[f32],
    ) -> Result<(), LearnerError> {
        let steps = self
            .decode(header, payload)
            .inspect_err(|_| self.stats.rejected_chunks += 1)?;
        let continuity = self.episodes.check(header).inspect_err(|err| match err {
            LearnerError::DuplicateChunk { .. } => self.stats.duplicate_chunks += 1,
            _ => self.stats.rejected_chunks += 1,
        })?;
        if let crate::ingest::Continuity::Gap { lost } = continuity {
            self.stats.lost_chunks += lost;
        }
        let fr = header.flags.contains(TrajectoryFlags::FRONTIER);
        let buffers = Buffers {
            low: (!fr || self.fr_replay.low).then_some(&mut self.low_replay),
            high: (!fr || self.fr_replay.high).then_some(&mut self.high_replay),
            phi: &mut self.phi_store,
            si: self.si.buffer_mut(),
        };
        let outcome = self.episodes.store(header, continuity, &steps, buffers);
        self.count_stored(header, steps.len() as u64, &outcome);
        Ok(())
    }

    /// Header and records, checked against the learner's layout; nothing is changed.
    fn decode<'a>(
        &self,
        header: &TrajectoryHeader,
        payload: &'a [f32],
    ) -> Result<Vec<StepView<'a>>, LearnerError> {
        let rejected = |source| LearnerError::Rejected {
            actor: header.actor_id,
            episode: header.episode_id,
            chunk_index: header.chunk_index,
            source,
        };
        let layout = header.check(payload.len()).map_err(rejected)?;
        if layout != self.layout {
            return Err(LearnerError::LayoutMismatch {
                actor: header.actor_id,
                episode: header.episode_id,
                chunk_index: header.chunk_index,
                expected: self.layout,
                found: layout,
            });
        }
        layout
            .view_chunk(payload, header.n_steps as usize)
            .map_err(rejected)
    }

    /// Counters after a stored chunk.
    fn count_stored(
        &mut self,
        header: &TrajectoryHeader,
        n_steps: u64,
        outcome: &crate::ingest::ChunkOutcome,
    ) {
        let s = &mut self.stats;
        s.chunks += 1;
        s.env_steps += n_steps;
        *s.per_actor_steps.entry(header.actor_id.0).or_default() += n_steps;
        s.episodes_completed += u64::from(outcome.episode_ended);
        s.high_transitions += outcome.high_added;
        s.dropped_segments += outcome.segments_dropped;
        s.abandoned_episodes = self.episodes.n_abandoned();
        let frontier = header.flags.contains(TrajectoryFlags::FRONTIER);
        if frontier {
            s.frontier_steps += n_steps;
        }
        if outcome.episode_ended {
            self.schedule
                .on_episode_end(outcome.far_goal_success, frontier);
            self.si.on_episode_end(self.schedule.train_episodes());
        }
        let lag = self
            .policy_version
            .0
            .saturating_sub(header.policy_version.0);
        self.telemetry.last_policy_lag = lag;
        self.telemetry.max_policy_lag = self.telemetry.max_policy_lag.max(lag);
    }

    /// Low updates the ratio allows now.
    fn low_due(&self) -> u64 {
        let stored = self.low_replay.ring().len() as u64;
        self.ratio
            .low_allowed(self.stats.env_steps, stored)
            .saturating_sub(self.updates_low)
    }

    /// High updates the ratio allows now.
    fn high_due(&self) -> u64 {
        let ring = self.high_replay.ring();
        self.ratio
            .high_allowed(ring.total(), ring.len() as u64)
            .saturating_sub(self.updates_high)
    }

    /// Runs the work due now and returns how much ran (0 = nothing to do): when a φ round is
    /// due or running in line, one slice of it (at most `max_updates` and
    /// [`PHI_STEPS_PER_CALL`] Adam steps, returned as their number; no SAC update runs
    /// meanwhile, see the module doc); otherwise the SAC updates that the replay ratio allows,
    /// at most `max_updates`, alternating low and high. With rounds in the background, first
    /// a finished round is collected (φ's version goes up) and a due one sent off, then the
    /// SAC updates run.
    pub fn train(&mut self, max_updates: usize) -> Result<usize, LearnerError> {
        let episodes = self.schedule.train_episodes();
        if self.phi.is_background() {
            self.collect_phi_round(false)?;
            self.phi.start_if_due(episodes, &mut self.phi_store)?;
            return self.train_sac(max_updates);
        }
        if self.phi.start_if_due(episodes, &mut self.phi_store)? {
            return self.phi_slice(max_updates);
        }
        self.train_sac(max_updates)
    }

    /// Runs the φ round in progress, if any, to its end (in line), or waits for it and collects
    /// it (background); no SAC update runs. Before a final checkpoint, which a round defers.
    pub fn finish_phi_round(&mut self) -> Result<(), LearnerError> {
        if self.phi.is_background() {
            return self.collect_phi_round(true);
        }
        while self.phi.is_active() {
            self.phi_slice(usize::MAX)?;
        }
        Ok(())
    }

    /// Collects a background round (at once when `wait`, else only if it has finished);
    /// φ's version goes up when the round changed φ.
    fn collect_phi_round(&mut self, wait: bool) -> Result<(), LearnerError> {
        if self.phi.collect(&mut self.phi_store, wait)? {
            self.phi_version = PhiVersion(self.phi_version.0 + 1);
        }
        Ok(())
    }

    /// One slice of the running φ round (at most `max_updates` and [`PHI_STEPS_PER_CALL`]
    /// steps, at least one); a finished round raises the φ version. Steps with a non-finite
    /// loss are skipped and counted by the trainer, and a round made only of them ends with
    /// the version unchanged, so no NaN reaches φ and the learner goes on.
    fn phi_slice(&mut self, max_updates: usize) -> Result<usize, LearnerError> {
        let cap = u64::try_from(max_updates).unwrap_or(u64::MAX);
        let steps = cap.clamp(1, PHI_STEPS_PER_CALL);
        let outcome = self.phi.run_slice(&mut self.phi_store, steps)?;
        if outcome.round_finished {
            self.phi_version = PhiVersion(self.phi_version.0 + 1);
        }
        // A slice always runs at least one step (a round has ≥ 1 step), so callers see work.
        Ok(usize::try_from(outcome.steps).unwrap_or(usize::MAX))
    }

    /// SAC updates the ratio allows, at most `max_updates`.
    fn train_sac(&mut self, max_updates: usize) -> Result<usize, LearnerError> {
        let start = Instant::now();
        let mut done = 0;
        while done < max_updates {
            let before = done;
            if self.low_due() > 0 {
                self.low_update()?;
                done += 1;
            }
            if done < max_updates && self.high_due() > 0 {
                self.high_update()?;
                done += 1;
            }
            if done == before {
                break;
            }
        }
        if done > 0 {
            self.telemetry.train_secs += start.elapsed().as_secs_f64();
            self.telemetry.updates_timed += done as u64;
        }
        Ok(done)
    }

    /// One low-level update (SAC, or the deterministic level's) on a uniform batch.
    fn low_update(&mut self) -> Result<(), LearnerError> {
        let len = self.low_replay.ring().len();
        let replay = &self.low_replay;
        sample_into(&mut self.rng, len, &mut self.low_stage, |stage, k, i| {
            replay.fill(stage, k, i)
        });
        let batch = to_tensors(&self.low_stage)?;
        let outcome = match &mut self.nets.low {
            LowLevel::Sac(level) => {
                let (batch_size, dim) = (self.low_stage.batch, self.spec.action_dim);
                let (next_eps, eps) = noise_pair(&mut self.rng, &mut self.noise, batch_size, dim)?;
                level
                    .update(&batch, &next_eps, &eps)
                    .map(|stats| self.telemetry.low = stats)
            }
            LowLevel::Deterministic(level) => {
                level.set_lr_for_episodes(self.schedule.train_episodes());
                level
                    .update(&batch, self.updates_low)
                    .map(|stats| self.telemetry.low_deterministic = stats)
            }
        };
        skip_if_nonfinite(outcome, &mut self.telemetry.skipped_nonfinite_low)?;
        self.updates_low += 1;
        Ok(())
    }

    /// One high-level SAC update on a uniform batch.
    fn high_update(&mut self) -> Result<(), LearnerError> {
        let len = self.high_replay.ring().len();
        let replay = &self.high_replay;
        sample_into(&mut self.rng, len, &mut self.high_stage, |stage, k, i| {
            replay.fill(stage, k, i)
        });
        let batch = to_tensors(&self.high_stage)?;
        let (batch_size, dim) = (self.high_stage.batch, self.spec.latent_dim);
        let (next_eps, eps) = noise_pair(&mut self.rng, &mut self.noise, batch_size, dim)?;
        let outcome = self
            .nets
            .high
            .update(&batch, &next_eps, &eps)
            .map(|stats| self.telemetry.high = stats);
        skip_if_nonfinite(outcome, &mut self.telemetry.skipped_nonfinite_high)?;
        self.updates_high += 1;
        Ok(())
    }

    /// Runs one due self-imitation round (a high-level step, then a low-level step, each on its
    /// own batch with routes from `routes`; see [`crate::si::step`]) and returns the Adam steps
    /// taken (0–2). Nothing runs while no round is due or a φ round runs in line (the round
    /// stays due); a φ round in the background does not hold it up. Call it until it returns 0 and [`Learner::si_pending`] is 0, or once
    /// per loop iteration.
    pub fn train_self_imitation(
        &mut self,
        routes: &mut dyn RouteSource,
    ) -> Result<usize, LearnerError> {
        if self.si.pending() == 0 || (self.phi.is_active() && !self.phi.is_background()) {
            return Ok(0);
        }
        self.si
            .run_round(&mut self.nets, &mut self.rng, routes, self.phi_version)
    }

    /// SI rounds due and not yet run.
    pub fn si_pending(&self) -> u64 {
        self.si.pending()
    }

    /// The self-imitation state (buffer, counters).
    pub fn self_imitation(&self) -> &SelfImitation {
        &self.si
    }

    /// Actor-side weights (encoder, high policy, low policy) as safetensors bytes with their
    /// header, if a new version is due (see the module doc for the schedule).
    pub fn publish_due(&mut self) -> Result<Option<(WeightsHeader, Vec<u8>)>, LearnerError> {
        let updates = self.updates_low + self.updates_high;
        let p = self.publish;
        let schedule = self.schedule.current();
        let schedule_changed = schedule.count_prob != p.schedule_at_last.count_prob
            || schedule.fr_prob != p.schedule_at_last.fr_prob;
        let changed = updates > p.updates_at_last || schedule_changed;
        let waited =
            self.stats.env_steps.saturating_sub(p.steps_at_last) >= self.publish_interval_steps;
        let new_phi = self.phi_version != p.phi_at_last;
        if p.published_once && !new_phi && !(changed && waited) {
            return Ok(None);
        }
        let bytes = nets::to_safetensors_bytes(&self.nets.policy_vm)?;
        let version = if p.published_once {
            PolicyVersion(self.policy_version.0 + 1)
        } else {
            self.policy_version
        };
        let header = WeightsHeader::new(
            version,
            self.phi_version,
            self.weights_layout_hash(),
            bytes.len(),
        )
        .with_schedule(schedule);
        self.policy_version = version;
        self.publish = PublishState {
            published_once: true,
            steps_at_last: self.stats.env_steps,
            updates_at_last: updates,
            phi_at_last: self.phi_version,
            schedule_at_last: schedule,
        };
        Ok(Some((header, bytes)))
    }

    /// After a restart from a checkpoint: continues the version counters above what an earlier
    /// incarnation of this learner already published (`policy`, `phi`), so the versions that
    /// actors, evaluator and graph-service see only go up even though the checkpoint is older.
    /// The φ version moves only if a φ round finished after the checkpoint (same φ version,
    /// same encoder: checkpoints are never written during a round); a moved φ version makes the
    /// next [`Learner::publish_due`] publish at once, so the graph-service re-maps with the
    /// restored encoder. Versions already above the given ones are kept.
    pub fn continue_versions_after(&mut self, policy: PolicyVersion, phi: PhiVersion) {
        if self.policy_version.0 <= policy.0 {
            self.policy_version = PolicyVersion(policy.0 + 1);
        }
        if self.phi_version.0 < phi.0 {
            self.phi_version = PhiVersion(phi.0 + 1);
        }
    }

    /// Layout hash of the published parameter set ([`nets::layout_hash`]).
    pub fn weights_layout_hash(&self) -> u64 {
        nets::layout_hash(&self.nets.policy_vm)
    }

    /// Counters for the throttle and the progress display.
    pub fn progress(&self) -> LearnerProgress {
        LearnerProgress {
            env_steps_ingested: self.stats.env_steps,
            env_step_budget: self.ratio.env_step_budget(self.updates_low),
            updates_low: self.updates_low,
            updates_high: self.updates_high,
            policy_version: self.policy_version,
            phi_version: self.phi_version,
        }
    }

    /// Ingest counters.
    pub fn ingest_stats(&self) -> &IngestStats {
        &self.stats
    }

    /// The run-wide schedule as it would be published now.
    pub fn run_schedule(&self) -> RunSchedule {
        self.schedule.current()
    }

    /// The φ observation store.
    pub fn phi_store(&self) -> &PhiStore {
        &self.phi_store
    }

    /// φ training statistics.
    pub fn phi_stats(&self) -> PhiStats {
        self.phi.stats()
    }

    /// Whether a φ round is running (SAC updates wait for it).
    pub fn phi_round_active(&self) -> bool {
        self.phi.is_active()
    }

    /// The replay-ratio constants in use.
    pub fn replay_ratio(&self) -> ReplayRatio {
        self.ratio
    }

    /// The record layout chunks must have.
    pub fn step_layout(&self) -> StepLayout {
        self.layout
    }

    /// The network spec (for checkpoints and the encoder trainer).
    pub fn nets_spec(&self) -> &NetsSpec {
        &self.spec
    }

    /// The published parameters (encoder, high policy, low policy).
    pub fn policy_varmap(&self) -> &VarMap {
        &self.nets.policy_vm
    }

    /// The low-level buffer.
    pub fn low_replay(&self) -> &LowReplay {
        &self.low_replay
    }

    /// The high-level buffer.
    pub fn high_replay(&self) -> &HighReplay {
        &self.high_replay
    }

    /// High-level SAC state (networks, α).
    pub fn high_level(&self) -> &SacLevel {
        &self.nets.high
    }

    /// Low-level state (SAC or deterministic).
    pub fn low_level(&self) -> &LowLevel {
        &self.nets.low
    }

    /// Scalar metrics, names as in `docs/METRICS.md` (prefixes `losses/`, `charts/`,
    /// `replay/`, `ingest/`, `phi/`, `schedule/`, `si/`).
    pub fn metrics(&self) -> Vec<(&'static str, f64)> {
        let mut out = match &self.nets.low {
            LowLevel::Sac(_) => sac_metrics(&self.telemetry.low, LOW_NAMES),
            LowLevel::Deterministic(level) => {
                deterministic_metrics(&self.telemetry.low_deterministic, level.learning_rate())
            }
        };
        out.extend(sac_metrics(&self.telemetry.high, HIGH_NAMES));
        out.extend(self.count_metrics());
        out.extend(self.phi_metrics());
        out.extend(si_metrics(self.si.stats(), &self.si));
        out
    }

    /// φ and run-schedule metrics.
    fn phi_metrics(&self) -> Vec<(&'static str, f64)> {
        let s = self.phi.stats();
        let st = self.phi_store.stats();
        let schedule = self.schedule.current();
        let per_sec = if s.secs > 0.0 {
            s.steps as f64 / s.secs
        } else {
            0.0
        };
        vec![
            ("phi/triplet_loss", s.triplet.loss),
            ("phi/positive_sq", s.triplet.positive_sq),
            ("phi/negative_sq", s.triplet.negative_sq),
            ("phi/hinge_active", s.triplet.hinge_active),
            ("phi/stable_loss", s.stable_loss),
            ("phi/round_start_loss", s.round_start_loss),
            ("phi/round_end_loss", s.round_end_loss),
            ("phi/rounds", s.rounds as f64),
            ("phi/skipped_rounds", s.skipped_rounds as f64),
            ("phi/coalesced_rounds", s.coalesced_rounds as f64),
            (
                "phi/skipped_nonfinite_steps",
                s.skipped_nonfinite_steps as f64,
            ),
            ("phi/nonfinite_rounds", s.nonfinite_rounds as f64),
            (
                "phi/round_active",
                f64::from(u8::from(self.phi.is_active())),
            ),
            ("phi/steps", s.steps as f64),
            ("phi/steps_per_sec", per_sec),
            ("phi/version", self.phi_version.0 as f64),
            ("phi/store_states", self.phi_store.n_states() as f64),
            ("phi/store_runs", self.phi_store.n_runs() as f64),
            ("phi/store_fragments", st.fragments as f64),
            ("phi/store_dropped_short", st.dropped_short as f64),
            ("phi/store_evicted", st.evicted as f64),
            ("phi/physics_failure_episodes", st.physics_failures as f64),
            ("schedule/train_episodes", schedule.train_episodes as f64),
            ("schedule/count_prob", f64::from(schedule.count_prob)),
            ("schedule/fr_prob", f64::from(schedule.fr_prob)),
            (
                "schedule/window_far_goal_successes",
                self.schedule.window_successes() as f64,
            ),
            (
                "schedule/window_episodes",
                self.schedule.window_episodes() as f64,
            ),
        ]
    }

    /// Counter metrics.
    fn count_metrics(&self) -> Vec<(&'static str, f64)> {
        let t = &self.telemetry;
        let s = &self.stats;
        let per_sec = if t.train_secs > 0.0 {
            t.updates_timed as f64 / t.train_secs
        } else {
            0.0
        };
        let p = self.progress();
        vec![
            ("charts/updates_per_sec", per_sec),
            ("charts/updates_low", p.updates_low as f64),
            ("charts/updates_high", p.updates_high as f64),
            (
                "charts/skipped_nonfinite_low",
                t.skipped_nonfinite_low as f64,
            ),
            (
                "charts/skipped_nonfinite_high",
                t.skipped_nonfinite_high as f64,
            ),
            ("charts/policy_version", p.policy_version.0 as f64),
            ("charts/policy_lag", t.last_policy_lag as f64),
            ("charts/policy_lag_max", t.max_policy_lag as f64),
            ("charts/env_step_budget", p.env_step_budget as f64),
            ("replay/low_size", self.low_replay.ring().len() as f64),
            ("replay/high_size", self.high_replay.ring().len() as f64),
            ("replay/open_episodes", self.episodes.n_open() as f64),
            ("ingest/chunks", s.chunks as f64),
            ("ingest/env_steps", s.env_steps as f64),
            ("ingest/frontier_steps", s.frontier_steps as f64),
            ("ingest/lost_chunks", s.lost_chunks as f64),
            ("ingest/duplicate_chunks", s.duplicate_chunks as f64),
            ("ingest/rejected_chunks", s.rejected_chunks as f64),
            ("ingest/episodes_completed", s.episodes_completed as f64),
            ("ingest/dropped_segments", s.dropped_segments as f64),
        ]
    }
}

/// Self-imitation metrics (`si/*`, `docs/METRICS.md`).
fn si_metrics(s: &SiStats, si: &SelfImitation) -> Vec<(&'static str, f64)> {
    vec![
        ("si/high_loss", s.high.loss),
        ("si/low_loss", s.low.loss),
        ("si/high_grad_norm", s.high_grad_norm),
        ("si/low_grad_norm", s.low_grad_norm),
        ("si/usable_fraction", s.usable_fraction),
        ("si/low_usable_fraction", s.low_usable_fraction),
        ("si/via_frontier_fraction", s.via_frontier_fraction),
        ("si/steps", (s.high_steps + s.low_steps) as f64),
        ("si/high_steps", s.high_steps as f64),
        ("si/low_steps", s.low_steps as f64),
        ("si/rounds_due", s.rounds_due as f64),
        ("si/pending", si.pending() as f64),
        ("si/skipped", s.skipped() as f64),
        ("si/skipped_disabled", s.skipped_disabled as f64),
        ("si/skipped_no_answer", s.skipped_no_answer as f64),
        ("si/skipped_phi_mismatch", s.skipped_phi_mismatch as f64),
        (
            "si/skipped_no_usable_route",
            s.skipped_no_usable_route as f64,
        ),
        ("si/skipped_empty_buffer", s.skipped_empty_buffer as f64),
        ("si/skipped_nonfinite", s.skipped_nonfinite as f64),
        ("si/buffer_len", si.buffer().len() as f64),
        ("si/buffer_evicted", si.buffer().n_evicted() as f64),
        ("si/buffer_orphaned", si.buffer().n_orphaned() as f64),
    ]
}

/// Metric names of one level's SAC statistics.
struct SacNames {
    critic: &'static str,
    actor: &'static str,
    alpha_loss: &'static str,
    alpha: &'static str,
    entropy: &'static str,
    q: &'static str,
    actor_grad_norm: &'static str,
}

const LOW_NAMES: SacNames = SacNames {
    critic: "losses/low_critic",
    actor: "losses/low_actor",
    alpha_loss: "losses/low_alpha",
    alpha: "charts/low_alpha",
    entropy: "charts/low_entropy",
    q: "charts/low_q",
    actor_grad_norm: "charts/low_actor_grad_norm",
};

const HIGH_NAMES: SacNames = SacNames {
    critic: "losses/high_critic",
    actor: "losses/high_actor",
    alpha_loss: "losses/high_alpha",
    alpha: "charts/high_alpha",
    entropy: "charts/high_entropy",
    q: "charts/high_q",
    actor_grad_norm: "charts/high_actor_grad_norm",
};

/// The last update's statistics under `names`.
fn sac_metrics(s: &SacStats, names: SacNames) -> Vec<(&'static str, f64)> {
    vec![
        (names.critic, s.critic.loss),
        (names.actor, s.actor.loss),
        (names.alpha_loss, s.alpha_loss),
        (names.alpha, s.alpha),
        (names.entropy, s.actor.entropy),
        (names.q, 0.5 * (s.critic.q1_mean + s.critic.q2_mean)),
        (names.actor_grad_norm, s.actor_grad_norm),
    ]
}

/// The last deterministic low update's statistics (`docs/METRICS.md`); the loss and Q names
/// are SAC's, so one chart serves either algorithm.
fn deterministic_metrics(s: &DeterministicStats, lr: f64) -> Vec<(&'static str, f64)> {
    let kept = if s.n_sampled > 0 {
        s.n_kept as f64 / s.n_sampled as f64
    } else {
        0.0
    };
    vec![
        (LOW_NAMES.critic, s.critic.loss),
        (LOW_NAMES.actor, s.actor_loss),
        (LOW_NAMES.q, s.critic.q_mean),
        ("charts/low_target_q", s.critic.target_mean),
        (LOW_NAMES.actor_grad_norm, s.actor_grad_norm),
        ("charts/low_critic_grad_norm", s.critic_grad_norm),
        ("charts/low_kept_fraction", kept),
        ("charts/low_lr", lr),
    ]
}

/// Two `[batch, dim]` standard-normal tensors from `rng` (`scratch` is reused).
fn noise_pair(
    rng: &mut Pcg64Mcg,
    scratch: &mut Vec<f32>,
    batch: usize,
    dim: usize,
) -> Result<(Tensor, Tensor), LearnerError> {
    let mut draw = || -> Result<Tensor, LearnerError> {
        scratch.clear();
        scratch.extend((0..batch * dim).map(|_| -> f32 { StandardNormal.sample(&mut *rng) }));
        Ok(Tensor::from_slice(scratch, (batch, dim), &Device::Cpu)?)
    };
    Ok((draw()?, draw()?))
}

/// Empty buffers sized from `[replay]`: low `capacity_steps`, high `capacity_steps / c`.
fn buffers(config: &Config, spec: &NetsSpec) -> (LowReplay, HighReplay) {
    let capacity = usize::try_from(config.replay.capacity_steps).unwrap_or(usize::MAX);
    let high_capacity = capacity / config.hierarchy.c.max(1) as usize;
    let reward = LowRewardSpec {
        scale: config.hierarchy.low_reward_scale as f32,
        threshold: config.hierarchy.low_reach_threshold as f32,
    };
    let low = LowReplay::new(
        capacity,
        spec.obs_dim,
        spec.latent_dim,
        spec.action_dim,
        reward,
    );
    let high = HighReplay::new(high_capacity, spec.obs_dim, spec.goal_dim, spec.latent_dim);
    (low, high)
}

/// The replay-ratio constants of `config` for episodes of `episode_length` steps.
fn replay_ratio(config: &Config, episode_length: u32) -> ReplayRatio {
    ReplayRatio {
        low_per_env_step: config.learner.low.updates_per_env_step_for(episode_length),
        low_batch: config.learner.low.batch_size as u64,
        high_per_transition: config.learner.high.updates_per_transition,
        high_min_transitions: config.learner.high.min_transitions,
        slack_steps: config.replay.replay_slack_steps,
    }
}

/// The staged batch as tensors (one copy each).
fn to_tensors(stage: &BatchStage) -> Result<SacBatch, LearnerError> {
    let b = stage.batch;
    let cpu = Device::Cpu;
    let head_w = stage.head.len() / b.max(1);
    let tail_w = stage.tail.len() / b.max(1);
    let action_w = stage.action.len() / b.max(1);
    let tail = if tail_w == 0 {
        None
    } else {
        Some(Tensor::from_slice(&stage.tail, (b, tail_w), &cpu)?)
    };
    Ok(SacBatch {
        head: Tensor::from_slice(&stage.head, (b, head_w), &cpu)?,
        next_head: Tensor::from_slice(&stage.next_head, (b, head_w), &cpu)?,
        tail,
        action: Tensor::from_slice(&stage.action, (b, action_w), &cpu)?,
        reward: Tensor::from_slice(&stage.reward, (b, 1), &cpu)?,
        terminal: Tensor::from_slice(&stage.terminal, (b, 1), &cpu)?,
    })
}

/// An update that met a NaN or infinite loss ends there: each loss is checked before its Adam
/// step, so the offending step and everything after it in that update (later steps, Polyak,
/// temperature) are not applied, and no non-finite value reaches the weights. The update is
/// counted in `skipped` (metrics `charts/skipped_nonfinite_*`) and training goes on; it still
/// counts toward the update ratio, so a recurring bad batch cannot stall the actors. Any
/// other error is returned.
fn skip_if_nonfinite(
    outcome: Result<(), LearnerError>,
    skipped: &mut u64,
) -> Result<(), LearnerError> {
    match outcome {
        Err(LearnerError::NonFinite { .. }) => {
            *skipped += 1;
            Ok(())
        }
        other => other,
    }
}
