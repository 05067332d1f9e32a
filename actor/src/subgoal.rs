//! How the high level decides (SPEC §6.1, §6.4): the [`SubgoalSource`] of each decision.
//!
//! At every decision step (t mod c = 0) a source produces the stored high action `delta` and the
//! subgoal `sg`, held for c steps:
//! - [`SubgoalSource::UniformRandom`] and [`SubgoalSource::Policy`] propose
//!   `delta ∈ [−abs_range, abs_range]^latent_dim` and `sg = φ(s_t) + delta`;
//! - [`SubgoalSource::Explore`] (HESS count-based exploration) takes the graph-service's
//!   absolute subgoal `sg` as it is and stores `delta = sg − φ(s_t)`. That delta is **not**
//!   clipped to the action box: the released code stores it unclipped (digest §5.4 item 6; it
//!   reaches about 25 in norm after the outward push), and clipping would make the stored action
//!   disagree with the subgoal the low level actually chased.
//!
//! An episode's `SubgoalPlan` fixes its base source (random for the actor's share of the run's
//! random warm-up, `learner.high.random_episodes`, see `actor::warm_up_share`; the policy
//! afterwards) and, once the run-wide
//! training episode count exceeds `exploration.explore_start_episode`, an [`ExploreGate`]: at
//! each decision, with probability `count_prob`, the explore subgoal is asked for; when the
//! oracle has no answer the base source decides (a counted fallback). As in the reference code
//! (digest §2.3 A.4, §2.5), exploration also applies while the base source is still random.
//!
//! Frontier-reaching episodes decide through [`crate::frontier`] while their FR mode lasts; the
//! sources [`SubgoalSource::FrontierRoute`] and [`SubgoalSource::FrontierCount`] name those
//! decisions (never an episode's base source).
//!
//! Invariant: a decision draws its random numbers only from the actor's generator, in a fixed
//! order (the exploration draw first, when the gate is open, then the base source's draws if it
//! decides), so a seed and the oracle's answers fix every subgoal.

use protocol::{DecisionKind, LatentPoint, PhiVersion, RunSchedule};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::error::ActorError;
use crate::exploration::{sample_gaussian, sample_uniform};
use crate::networks::ActorNets;
use crate::oracle::{ExploreAnswer, GraphOracle};

/// Where the high-level action of one decision comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SubgoalSource {
    /// Uniform random deltas in the action box (the run's first `learner.high.random_episodes`
    /// training episodes, shared by the actors; SPEC §6.2).
    UniformRandom,
    /// A stochastic sample of the high policy on `[obs, goal]`.
    Policy,
    /// HESS exploration: the graph-service's subgoal near φ(s_t) (SPEC §6.4).
    Explore,
    /// Frontier-reaching navigation: a waypoint on the route to the frontier (SPEC §6.6;
    /// [`crate::frontier`]).
    FrontierRoute,
    /// Frontier-reaching count mode: the least-visited candidate near φ(s_t).
    FrontierCount,
}

/// HESS exploration of one episode: the run-wide schedule values it was started with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExploreGate {
    /// Probability that a decision asks for an explore subgoal.
    pub count_prob: f32,
    /// Run-wide training episodes (sent with the request: gates the potential and the push).
    pub train_episodes: u64,
}

impl ExploreGate {
    /// The gate for an episode started under `schedule`: open once
    /// `schedule.train_episodes > explore_start_episode` (the code's `epoch > start_explore`).
    pub fn for_schedule(schedule: &RunSchedule, explore_start_episode: u64) -> Option<Self> {
        (schedule.train_episodes > explore_start_episode).then_some(Self {
            count_prob: schedule.count_prob,
            train_episodes: schedule.train_episodes,
        })
    }
}

impl SubgoalSource {
    /// The base source of a training episode: random for episode indices below `random_until`
    /// (the end of this actor's warm-up share), the policy afterwards.
    pub fn for_training_episode(episode: u64, random_until: u64) -> Self {
        if episode < random_until {
            Self::UniformRandom
        } else {
            Self::Policy
        }
    }

    /// The decision code written into records of decision steps.
    pub fn decision_kind(self) -> DecisionKind {
        match self {
            Self::UniformRandom => DecisionKind::Random,
            Self::Policy => DecisionKind::Policy,
            Self::Explore => DecisionKind::Explore,
            Self::FrontierRoute => DecisionKind::FrontierRoute,
            Self::FrontierCount => DecisionKind::FrontierCount,
        }
    }

    /// Whether the subgoal was chosen by the graph (HESS explore or FR): such segments report
    /// their reaching error to the potential map (digest §5.3: "count/FR-chosen" segments).
    pub fn is_graph_chosen(self) -> bool {
        matches!(
            self,
            Self::Explore | Self::FrontierRoute | Self::FrontierCount
        )
    }
}

/// How one episode decides: its base source and, when open, the exploration gate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SubgoalPlan {
    /// [`SubgoalSource::UniformRandom`] or [`SubgoalSource::Policy`].
    pub base: SubgoalSource,
    /// HESS exploration, if open for this episode.
    pub explore: Option<ExploreGate>,
}

/// What a decision looks at.
pub(crate) struct DecisionInputs<'a> {
    /// s_t.
    pub obs: &'a [f32],
    /// φ(s_t).
    pub phi: &'a [f32],
    /// The env goal g.
    pub goal: &'a [f32],
    /// Half-width of the high action box (`hierarchy.abs_range`).
    pub abs_range: f32,
    /// Version of the φ that computed `phi`.
    pub phi_version: PhiVersion,
}

/// The outcome of one decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Decided {
    /// Which source decided.
    pub source: SubgoalSource,
    /// For [`SubgoalSource::Explore`]: the un-pushed candidate (potential cell).
    pub candidate: Option<LatentPoint>,
    /// An explore subgoal was asked for and not answered.
    pub fallback: bool,
}

impl SubgoalPlan {
    /// Decides the next segment: writes the stored high action into `delta` and the subgoal
    /// into `subgoal` (see the module doc).
    pub fn decide(
        &self,
        inputs: &DecisionInputs<'_>,
        nets: &mut ActorNets,
        rng: &mut Pcg64Mcg,
        oracle: &mut dyn GraphOracle,
        delta: &mut [f32],
        subgoal: &mut [f32],
    ) -> Result<Decided, ActorError> {
        let mut fallback = false;
        if let Some(gate) = self.explore {
            if rng.random::<f64>() < f64::from(gate.count_prob) {
                match explore_answer(inputs, gate, oracle)? {
                    Some(answer) => {
                        subgoal.copy_from_slice(&answer.subgoal);
                        for ((d, sg), phi) in delta.iter_mut().zip(&answer.subgoal).zip(inputs.phi)
                        {
                            *d = sg - phi;
                        }
                        return Ok(Decided {
                            source: SubgoalSource::Explore,
                            candidate: Some(answer.candidate),
                            fallback: false,
                        });
                    }
                    None => fallback = true,
                }
            }
        }
        match self.base {
            SubgoalSource::UniformRandom => sample_uniform(inputs.abs_range, rng, delta),
            SubgoalSource::Policy
            | SubgoalSource::Explore
            | SubgoalSource::FrontierRoute
            | SubgoalSource::FrontierCount => {
                sample_gaussian(&nets.high_head(inputs.obs, inputs.goal)?, rng, delta)
            }
        }
        for ((sg, phi), d) in subgoal.iter_mut().zip(inputs.phi).zip(delta.iter()) {
            *sg = phi + d;
        }
        Ok(Decided {
            source: self.base,
            candidate: None,
            fallback,
        })
    }
}

/// The oracle's explore subgoal near φ(s_t); `None` when it has none (or φ is not 2-D, which
/// the config forbids).
fn explore_answer(
    inputs: &DecisionInputs<'_>,
    gate: ExploreGate,
    oracle: &mut dyn GraphOracle,
) -> Result<Option<ExploreAnswer>, ActorError> {
    let Ok(from) = LatentPoint::try_from(inputs.phi) else {
        return Ok(None);
    };
    oracle.explore(from, gate.train_episodes, inputs.phi_version)
}
