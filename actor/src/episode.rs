//! One training episode as a state machine: the high level decides every c steps, the low level
//! acts every step, and each step becomes one record (SPEC §6.1).
//!
//! Invariants:
//! - `phi` is φ(`obs`) under the acting φ version; each step computes φ(s_{t+1}) once and it
//!   becomes the next step's `phi` (the record's `next_phi` of step t equals `phi` of t+1).
//! - `subgoal = φ(decision_obs) + delta`, where `decision_obs` and `delta` are those of the last
//!   decision; when a new φ arrives mid-segment the subgoal is re-anchored in the new φ-space
//!   with the same delta ([`Episode::relabel_phi`]).
//!   An explore decision sets `subgoal` to the oracle's point and `delta = subgoal − φ(s_t)`.
//! - A step whose physics failed is not recorded; it ends the episode with
//!   `EPISODE_END | TERMINATED | PHYSICS_FAILURE`.
//! - Reaching errors (digest §2.3 A.1, §5.3): a segment that ran all c steps has the error
//!   ‖subgoal − φ(s_{t+c})‖ at its end. Every such segment enters the episode's reaching
//!   statistics; an explore segment followed by another decision (not the episode's last) also
//!   yields a [`ReachSample`] at its un-pushed candidate, for the graph-service's potential map.
//!   FR segments (waypoint or count mode) report the same way, at their subgoal (no push), when
//!   `asi.fr_potential_reports` picks them: by default those whose decision's count draw
//!   (probability `count_prob`, the decision's last random number) came up.
//! - Frontier-reaching episodes ([`crate::frontier`]): while FR mode lasts, every decision comes
//!   from the episode's [`FrontierEpisode`] instead of the plan; the low level acts without
//!   noise in navigation segments and with its usual noise otherwise.

use envs::api::{Env, Reset, Step};
use protocol::config::FrPotentialReports;
use protocol::graph::ReachSample;
use protocol::{DecisionKind, EpisodeId, LatentPoint, PhiVersion, StepView, TrajectoryFlags};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::error::ActorError;
use crate::exploration::{clip, low_action, noise_free_low_action, DeterministicNoise};
use crate::frontier::{
    FrChoice, FrEnd, FrOutcome, FrontierEpisode, FrontierParams, FrontierStats, Switch,
};
use crate::networks::ActorNets;
use crate::oracle::GraphOracle;
use crate::record::RecordWriter;
use crate::subgoal::{DecisionInputs, SubgoalPlan, SubgoalSource};

/// Fixed per-run parameters of stepping.
#[derive(Debug, Clone)]
pub(crate) struct RolloutParams {
    /// High-level interval c (env steps).
    pub c: u32,
    /// Half-width of the high action box.
    pub abs_range: f32,
    /// Noise of the deterministic low-level variant.
    pub noise: DeterministicNoise,
    /// Env action bounds.
    pub action_low: Vec<f32>,
    pub action_high: Vec<f32>,
    /// Frontier-reaching parameters; `None` when `asi.frontier_reaching` is off.
    pub frontier: Option<FrontierParams>,
}

/// Everything a step uses besides the episode's own state.
pub(crate) struct Rollout {
    pub env: Box<dyn Env>,
    pub nets: ActorNets,
    pub rng: Pcg64Mcg,
    pub writer: RecordWriter,
    pub params: RolloutParams,
    /// Scratch: the low-level action.
    pub action: Vec<f32>,
    /// Scratch: zeros of latent length (high action on non-decision steps).
    pub zeros: Vec<f32>,
    /// Scratch: the record being written.
    pub record: Vec<f32>,
    /// φ version of the acting encoder.
    pub phi_version: PhiVersion,
    /// Decision counters over all episodes.
    pub decisions: DecisionCounters,
    /// Frontier-reaching counters over all episodes.
    pub frontier_stats: FrontierStats,
}

/// Decision counters of an actor, over all its episodes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct DecisionCounters {
    /// High-level decisions taken.
    pub n_decisions: u64,
    /// Decisions that took the graph-service's explore subgoal.
    pub n_explore: u64,
    /// Decisions that took a uniform random subgoal (the warm-up).
    pub n_random: u64,
    /// Decisions that asked for an explore subgoal and got none (the base source decided).
    pub n_explore_fallbacks: u64,
}

/// Sum and count of segment reaching errors.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct ReachTally {
    /// Σ ‖subgoal − φ(s_{t+c})‖ over the counted segments.
    pub sum: f64,
    /// Segments counted.
    pub n: u64,
}

impl ReachTally {
    fn add(&mut self, error: f32) {
        self.sum += f64::from(error);
        self.n += 1;
    }

    /// The mean, `None` when nothing was counted.
    pub fn mean(&self) -> Option<f32> {
        (self.n > 0).then(|| (self.sum / self.n as f64) as f32)
    }
}

/// What a step produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum StepOutcome {
    /// A record was written to `Rollout::record`; `Some(flags)` if the episode ended with it.
    Recorded(Option<u32>),
    /// The physics failed: nothing recorded, the episode is over.
    PhysicsFailure,
}

/// State of the running episode.
#[derive(Debug, Clone)]
pub(crate) struct Episode {
    /// Run-unique id.
    pub id: EpisodeId,
    /// How this episode's subgoals are chosen.
    pub plan: SubgoalPlan,
    /// The goal is a far goal (chunks carry `FAR_GOAL`).
    pub far_goal: bool,
    /// Env steps taken so far (= episode step index of the next step).
    pub t: u32,
    /// Index of the next chunk to cut.
    pub next_chunk_index: u32,
    /// `TrajectoryFlags` of the end, once the episode has ended.
    pub end_flags: Option<u32>,
    /// Sum of recorded rewards.
    pub episode_return: f32,
    /// The env reported success on some recorded step.
    pub success: bool,
    /// Reaching errors of every full segment.
    pub reach_all: ReachTally,
    /// Reaching errors of the full explore segments.
    pub reach_explore: ReachTally,
    /// Reaching ratios ‖subgoal − φ(s_{t+c})‖ / ‖subgoal − φ(s_t)‖ of the full segments whose
    /// φ did not change mid-segment and whose subgoal was not at the start: scale-free, so
    /// comparable across φ versions (1 = no progress, 0 = reached).
    pub reach_ratio: ReachTally,
    /// Reaching samples not yet reported to the graph-service.
    pub reach_samples: Vec<ReachSample>,
    /// FR state, for frontier-reaching episodes.
    pub frontier: Option<FrontierEpisode>,
    /// Where the FR episode's navigation ended, once it has (a switch or a new φ).
    fr_end: Option<FrEnd>,
    /// The segment in progress is FR navigation: the low level acts without noise.
    low_noise_free: bool,
    /// Source of the segment in progress (`None` before the first decision).
    segment_source: Option<SubgoalSource>,
    /// ‖subgoal − φ(s_t)‖ at the segment's decision; `None` after a φ change mid-segment.
    segment_start_distance: Option<f32>,
    /// Un-pushed candidate of the explore segment in progress; `None` when the segment
    /// reports no reaching sample (not graph-chosen, or FR not chosen to report by
    /// `asi.fr_potential_reports`).
    candidate: Option<LatentPoint>,
    obs: Vec<f32>,
    phi: Vec<f32>,
    goal: Vec<f32>,
    subgoal: Vec<f32>,
    decision_obs: Vec<f32>,
    delta: Vec<f32>,
}

impl Episode {
    /// An episode starting from `reset`, with φ(s_0) = `phi`; `frontier` for an FR episode.
    pub fn new(
        id: EpisodeId,
        plan: SubgoalPlan,
        far_goal: bool,
        reset: Reset,
        phi: Vec<f32>,
        frontier: Option<FrontierEpisode>,
    ) -> Self {
        let latent = phi.len();
        Self {
            id,
            plan,
            far_goal,
            t: 0,
            next_chunk_index: 0,
            end_flags: None,
            episode_return: 0.0,
            success: false,
            reach_all: ReachTally::default(),
            reach_explore: ReachTally::default(),
            reach_ratio: ReachTally::default(),
            segment_start_distance: None,
            reach_samples: Vec::new(),
            frontier,
            fr_end: None,
            low_noise_free: false,
            segment_source: None,
            candidate: None,
            decision_obs: reset.obs.clone(),
            obs: reset.obs,
            goal: reset.goal.to_vec(),
            subgoal: phi.clone(),
            phi,
            delta: vec![0.0; latent],
        }
    }

    /// Takes one env step; on `Recorded` the record is in `rollout.record`.
    pub fn step(
        &mut self,
        rollout: &mut Rollout,
        oracle: &mut dyn GraphOracle,
    ) -> Result<StepOutcome, ActorError> {
        let decision = self.decide_if_due(rollout, oracle)?;
        self.choose_action(rollout)?;
        let step = rollout.env.step(&rollout.action)?;
        self.t += 1;
        if step.info.physics_failure {
            let flags = TrajectoryFlags::EPISODE_END
                | TrajectoryFlags::TERMINATED
                | TrajectoryFlags::PHYSICS_FAILURE;
            self.end_flags = Some(flags);
            return Ok(StepOutcome::PhysicsFailure);
        }
        let next_phi = rollout.nets.phi_rows(&step.obs, 1)?;
        let truncated = step.truncated;
        self.write_record(rollout, &step, &next_phi, decision, truncated)?;
        self.episode_return += step.reward;
        self.success |= step.info.success;
        self.obs = step.obs;
        self.phi = next_phi;
        if step.terminated || truncated {
            let mut flags = TrajectoryFlags::EPISODE_END;
            flags |= if step.terminated {
                TrajectoryFlags::TERMINATED
            } else {
                0
            };
            flags |= if truncated {
                TrajectoryFlags::TRUNCATED
            } else {
                0
            };
            self.end_flags = Some(flags);
            if self.t.is_multiple_of(rollout.params.c) {
                self.close_segment(false);
            }
        }
        Ok(StepOutcome::Recorded(self.end_flags))
    }

    /// Tallies the reaching error of the segment that ends now at φ(s_t) = `phi`; `followed`:
    /// another decision follows (then an explore segment is also reported).
    fn close_segment(&mut self, followed: bool) {
        let Some(source) = self.segment_source else {
            return;
        };
        let error = self.subgoal_distance();
        self.reach_all.add(error);
        if let Some(start) = self.segment_start_distance.take() {
            if start > f32::EPSILON {
                self.reach_ratio.add(error / start);
            }
        }
        if source == SubgoalSource::Explore {
            self.reach_explore.add(error);
        }
        if source.is_graph_chosen() {
            if let (true, Some(subgoal)) = (followed, self.candidate) {
                self.reach_samples.push(ReachSample { subgoal, error });
            }
        }
    }

    /// ‖subgoal − φ(s_t)‖ at the current state.
    fn subgoal_distance(&self) -> f32 {
        self.subgoal
            .iter()
            .zip(&self.phi)
            .map(|(sg, phi)| (sg - phi) * (sg - phi))
            .sum::<f32>()
            .sqrt()
    }

    /// At t mod c = 0: closes the previous segment and decides the next (delta and subgoal from
    /// the episode's plan).
    fn decide_if_due(
        &mut self,
        rollout: &mut Rollout,
        oracle: &mut dyn GraphOracle,
    ) -> Result<DecisionKind, ActorError> {
        if !self.t.is_multiple_of(rollout.params.c) {
            return Ok(DecisionKind::None);
        }
        self.close_segment(true);
        if let Some(kind) = self.decide_frontier(rollout, oracle)? {
            return Ok(kind);
        }
        let inputs = DecisionInputs {
            obs: &self.obs,
            phi: &self.phi,
            goal: &self.goal,
            abs_range: rollout.params.abs_range,
            phi_version: rollout.phi_version,
        };
        let decided = self.plan.decide(
            &inputs,
            &mut rollout.nets,
            &mut rollout.rng,
            oracle,
            &mut self.delta,
            &mut self.subgoal,
        )?;
        self.decision_obs.copy_from_slice(&self.obs);
        self.segment_source = Some(decided.source);
        self.segment_start_distance = Some(self.subgoal_distance());
        self.candidate = decided.candidate;
        self.low_noise_free = false;
        let counters = &mut rollout.decisions;
        counters.n_decisions += 1;
        counters.n_explore += u64::from(decided.source == SubgoalSource::Explore);
        counters.n_random += u64::from(decided.source == SubgoalSource::UniformRandom);
        counters.n_explore_fallbacks += u64::from(decided.fallback);
        Ok(decided.source.decision_kind())
    }

    /// An FR decision while the episode's FR mode lasts (`None` otherwise): subgoal, stored
    /// delta = subgoal − φ(s_t) (unclipped), counters.
    fn decide_frontier(
        &mut self,
        rollout: &mut Rollout,
        oracle: &mut dyn GraphOracle,
    ) -> Result<Option<DecisionKind>, ActorError> {
        let (Some(fr), Some(params)) = (self.frontier.as_mut(), rollout.params.frontier) else {
            return Ok(None);
        };
        let Ok(at) = LatentPoint::try_from(&self.phi[..]) else {
            return Ok(None);
        };
        if !fr.is_active() {
            return Ok(None);
        }
        let decided = fr.decide(at, &params, rollout.phi_version, &mut rollout.rng, oracle)?;
        if let (Some(switch), None) = (decided.switch, self.fr_end) {
            let outcome = match switch {
                Switch::NearFrontier => FrOutcome::NearFrontier,
                Switch::Stuck => FrOutcome::Stuck,
            };
            self.fr_end = Some(fr.navigation_end(outcome, &at, &self.obs));
        }
        // The trace of an FR episode, for `RUST_LOG=actor=debug` (where do they get stuck).
        tracing::debug!(
            episode = self.id.0,
            t = self.t,
            xy = ?self.obs.get(..2),
            phi = ?at,
            choice = ?decided.choice,
            subgoal = ?decided.subgoal,
            switch = ?decided.switch,
            route_len = fr.route().len(),
            "FR decision"
        );
        self.subgoal.copy_from_slice(&decided.subgoal);
        for ((d, sg), phi) in self.delta.iter_mut().zip(&decided.subgoal).zip(&self.phi) {
            *d = sg - phi;
        }
        self.decision_obs.copy_from_slice(&self.obs);
        self.low_noise_free = decided.deterministic_low() && params.noise_free_navigation;
        let source = match decided.choice {
            FrChoice::Waypoint { .. } => SubgoalSource::FrontierRoute,
            FrChoice::Count { .. } => SubgoalSource::FrontierCount,
        };
        self.segment_source = Some(source);
        self.segment_start_distance = Some(self.subgoal_distance());
        // Whether this segment reports its reaching error to the potential map. The count
        // draw is the decision's last random number, after the FR logic's own draws; it is
        // drawn only while HESS exploration is open, as the released code's `valid_count`
        // matters only then (digest §2.3 A.1, §7 item 4).
        let reports = match params.potential_reports {
            FrPotentialReports::Every => true,
            FrPotentialReports::Off => false,
            FrPotentialReports::CountDraw => self
                .plan
                .explore
                .is_some_and(|gate| rollout.rng.random::<f64>() < f64::from(gate.count_prob)),
        };
        self.candidate = reports.then_some(decided.subgoal);
        rollout.decisions.n_decisions += 1;
        let stats = &mut rollout.frontier_stats;
        match decided.choice {
            FrChoice::Waypoint { cut, .. } => {
                stats.n_waypoint_decisions += 1;
                stats.n_waypoints_cut += u64::from(cut);
            }
            FrChoice::Count { fallback } => {
                stats.n_count_decisions += 1;
                stats.n_count_fallbacks += u64::from(fallback);
            }
        }
        match decided.switch {
            Some(Switch::NearFrontier) => stats.n_near_frontier_switches += 1,
            Some(Switch::Stuck) => stats.n_stuck_switches += 1,
            None => {}
        }
        Ok(Some(decided.decision_kind()))
    }

    /// Ends the episode's FR mode because a new φ arrived (its route and frontier are points of
    /// the old φ-space); `true` if FR mode was on.
    pub fn end_frontier_for_new_phi(&mut self) -> bool {
        match self.frontier.as_mut() {
            Some(fr) if fr.is_active() => {
                if self.fr_end.is_none() {
                    // φ(s_t) is still the old φ here: the route's coordinates.
                    self.fr_end = Some(fr.navigation_end(FrOutcome::NewPhi, &self.phi, &self.obs));
                }
                fr.end();
                true
            }
            _ => false,
        }
    }

    /// For an FR episode, where its navigation ended: at its switch or new φ, else here
    /// ([`FrOutcome::Navigating`], at the last state); `None` for other episodes.
    /// The first two coordinates of the current observation (x, y on the maze tasks); `None`
    /// for an observation shorter than two.
    pub(crate) fn xy(&self) -> Option<[f32; 2]> {
        match self.obs.as_slice() {
            [x, y, ..] => Some([*x, *y]),
            _ => None,
        }
    }

    pub fn frontier_end(&self) -> Option<FrEnd> {
        let fr = self.frontier.as_ref()?;
        Some(
            self.fr_end
                .unwrap_or_else(|| fr.navigation_end(FrOutcome::Navigating, &self.phi, &self.obs)),
        )
    }

    /// The low level's action on `[obs, φ(obs), subgoal]` — noise-free in FR navigation
    /// segments, exploratory otherwise — clipped to the env bounds, into `rollout.action`.
    fn choose_action(&self, rollout: &mut Rollout) -> Result<(), ActorError> {
        let head = rollout.nets.low_head(&self.obs, &self.phi, &self.subgoal)?;
        if self.low_noise_free {
            noise_free_low_action(&head, &mut rollout.action);
        } else {
            low_action(
                &head,
                rollout.params.noise,
                &mut rollout.rng,
                &mut rollout.action,
            );
        }
        let params = &rollout.params;
        clip(&mut rollout.action, &params.action_low, &params.action_high);
        Ok(())
    }

    fn write_record(
        &self,
        rollout: &mut Rollout,
        step: &Step,
        next_phi: &[f32],
        decision: DecisionKind,
        truncated: bool,
    ) -> Result<(), ActorError> {
        let high_action = if decision.is_decision() {
            &self.delta
        } else {
            &rollout.zeros
        };
        let fields = StepView {
            obs: &self.obs,
            next_obs: &step.obs,
            phi: &self.phi,
            next_phi,
            subgoal: &self.subgoal,
            high_action,
            action: &rollout.action,
            goal: &self.goal,
            achieved_goal: &step.info.achieved_goal,
            reward: step.reward,
            decision,
            success: step.info.success,
            terminated: step.terminated,
            truncated,
        };
        rollout
            .writer
            .write(&fields, &mut rollout.record)
            .map_err(|bad| ActorError::NonFinite {
                field: bad.field,
                index: bad.index,
                value: bad.value,
            })
    }

    /// Recomputes every φ-dependent value under new encoder weights: `phi`, the re-anchored
    /// `subgoal`, and the φ fields of the not-yet-cut `records` (which belong to the current
    /// segment: see the buffer invariant in [`crate::chunk`]).
    pub fn relabel_phi<'r>(
        &mut self,
        nets: &mut ActorNets,
        writer: &RecordWriter,
        records: impl Iterator<Item = &'r mut [f32]>,
    ) -> Result<(), ActorError> {
        let latent = self.phi.len();
        // Start and end distance would be in different φ-spaces.
        self.segment_start_distance = None;
        let fresh = nets.phi_rows(&[&self.obs[..], &self.decision_obs[..]].concat(), 2)?;
        self.phi.copy_from_slice(&fresh[..latent]);
        for (i, ((sg, phi_d), delta)) in self
            .subgoal
            .iter_mut()
            .zip(&fresh[latent..])
            .zip(&self.delta)
            .enumerate()
        {
            let moved = phi_d + delta;
            // The candidate moves with the subgoal, so both stay in the acting φ-space.
            if let Some(candidate) = self.candidate.as_mut().and_then(|c| c.get_mut(i)) {
                *candidate += moved - *sg;
            }
            *sg = moved;
        }
        for record in records {
            let rows = [writer.obs(record), writer.next_obs(record)].concat();
            let phis = nets.phi_rows(&rows, 2)?;
            writer.relabel(record, &phis[..latent], &phis[latent..], &self.subgoal);
        }
        Ok(())
    }
}
