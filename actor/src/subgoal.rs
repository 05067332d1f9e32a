//! How the high level decides (SPEC §6.1): the [`SubgoalSource`] of an episode.
//!
//! At every decision step (t mod c = 0) the source produces the stored high action
//! `delta ∈ [−abs_range, abs_range]^latent_dim`; the subgoal is `sg = φ(s_t) + delta`, held for
//! c steps. Later sources (HESS count exploration, frontier routes, evaluation) are added as new
//! variants of [`SubgoalSource`] and chosen in [`SubgoalSource::for_training_episode`]; one that
//! proposes an absolute subgoal reports `delta = sg − φ(s_t)`.
//!
//! Invariant: a decision draws its random numbers only from the actor's generator, in a fixed
//! order, so a seed fixes every subgoal.

use protocol::DecisionKind;
use rand_pcg::Pcg64Mcg;

use crate::error::ActorError;
use crate::exploration::{sample_gaussian, sample_uniform};
use crate::networks::ActorNets;

/// Where the high-level actions of one episode come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SubgoalSource {
    /// Uniform random deltas in the action box (the first `learner.high.random_episodes`
    /// training episodes of each actor; SPEC §6.2).
    UniformRandom,
    /// A stochastic sample of the high policy on `[obs, goal]`.
    Policy,
}

/// What a decision looks at.
pub(crate) struct DecisionInputs<'a> {
    /// s_t.
    pub obs: &'a [f32],
    /// The env goal g.
    pub goal: &'a [f32],
    /// Half-width of the high action box (`hierarchy.abs_range`).
    pub abs_range: f32,
}

impl SubgoalSource {
    /// The source of a training episode: random for this actor's first `random_episodes`
    /// episodes (`episode` is 0-based), the policy afterwards.
    pub fn for_training_episode(episode: u64, random_episodes: u64) -> Self {
        if episode < random_episodes {
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
        }
    }

    /// Writes the high action (delta) into `delta`.
    pub(crate) fn decide(
        self,
        inputs: &DecisionInputs<'_>,
        nets: &mut ActorNets,
        rng: &mut Pcg64Mcg,
        delta: &mut [f32],
    ) -> Result<(), ActorError> {
        match self {
            Self::UniformRandom => sample_uniform(inputs.abs_range, rng, delta),
            Self::Policy => sample_gaussian(&nets.high_head(inputs.obs, inputs.goal)?, rng, delta),
        }
        Ok(())
    }
}
