//! Saving and restoring an actor between episodes, for serial-mode checkpoints (issue #7).
//!
//! An [`ActorState`] holds everything an [`Actor`] carries from one episode to the next apart
//! from its weights: the generator (action noise, random subgoals, FR draws, far-goal draws),
//! the episode counter (which fixes the next episode's id and env seed, see [`crate::seeds`]),
//! and every counter of [`ActorStats`] (decisions, FR, reaching, physics failures, the last
//! episode's values, the schedule of the last weights). The weights come back by loading the
//! last weights message the actor acted with ([`Actor::load_weights`]).
//!
//! Invariants:
//! - Exact between episodes: an actor restored from the state of one that had no open episode
//!   ([`Actor::has_open_episode`]) and given the same weights produces the same chunks as the
//!   saved one would have. The environment needs nothing else: each episode starts with
//!   `Env::reset(env_seed(..))`, which sets its whole state; only its physics-failure counter
//!   carries over, and it is kept as an offset in the actor.
//! - An open episode is not saved (its env and rollout state are not): a restore of a state
//!   taken mid-episode continues as if that episode had been abandoned — the next episode has
//!   the next index, so ids and env seeds never repeat.
//! - A state is restored only into a fresh actor of the same id, before its first episode.

use protocol::{ActorId, RunSchedule};
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::actor::{Actor, ActorStats};
use crate::error::ActorError;

/// An actor's state between episodes (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActorState {
    /// The actor it was taken from.
    pub actor_id: ActorId,
    /// Episodes started (the open one, if any, included): the next episode's index.
    pub n_episodes_started: u64,
    /// Whether an episode was open when it was taken (then a restore is not exact).
    pub had_open_episode: bool,
    /// The actor's generator.
    pub(crate) rng: Pcg64Mcg,
    /// Every counter, as [`Actor::stats`] reported it.
    pub(crate) stats: ActorStats,
}

impl Actor {
    /// Whether an episode is in progress (its state would be lost by [`Actor::save_state`]).
    pub fn has_open_episode(&self) -> bool {
        self.episode.is_some()
    }

    /// The state to continue from (see the module doc).
    pub fn save_state(&self) -> ActorState {
        ActorState {
            actor_id: self.actor_id,
            n_episodes_started: self.n_episodes_started,
            had_open_episode: self.episode.is_some(),
            rng: self.rollout.rng.clone(),
            stats: self.stats(),
        }
    }

    /// Continues from `state`: only into a fresh actor (no episode started yet) of the same
    /// id, else [`ActorError::Misuse`]. Load the weights the saved actor acted with as well.
    pub fn restore_state(&mut self, state: ActorState) -> Result<(), ActorError> {
        if state.actor_id != self.actor_id {
            return Err(ActorError::Misuse(format!(
                "the state of actor {} restored into actor {}",
                state.actor_id, self.actor_id
            )));
        }
        if self.episode.is_some() || self.n_episodes_started > 0 {
            return Err(ActorError::Misuse(format!(
                "restore_state after {} episodes already started",
                self.n_episodes_started
            )));
        }
        let s = state.stats;
        self.n_episodes_started = state.n_episodes_started;
        self.rollout.rng = state.rng;
        self.rollout.phi_version = s.phi_version;
        self.rollout.decisions.n_decisions = s.n_decisions;
        self.rollout.decisions.n_explore = s.n_explore_decisions;
        self.rollout.decisions.n_random = s.n_random_decisions;
        self.rollout.decisions.n_explore_fallbacks = s.n_explore_fallbacks;
        self.rollout.frontier_stats = s.frontier;
        self.physics_failures_before = s
            .n_physics_failures
            .saturating_sub(self.rollout.env.n_physics_failures());
        self.stats = s;
        Ok(())
    }
}

/// [`RunSchedule`] as `(train_episodes, count_prob, fr_prob)` (protocol types carry no serde
/// beyond ids).
pub(crate) mod schedule_fields {
    use super::*;

    pub fn serialize<S: serde::Serializer>(s: &RunSchedule, out: S) -> Result<S::Ok, S::Error> {
        (s.train_episodes, s.count_prob, s.fr_prob).serialize(out)
    }

    pub fn deserialize<'de, D: serde::Deserializer<'de>>(
        input: D,
    ) -> Result<RunSchedule, D::Error> {
        let (train_episodes, count_prob, fr_prob) = <(u64, f32, f32)>::deserialize(input)?;
        Ok(RunSchedule {
            train_episodes,
            count_prob,
            fr_prob,
        })
    }
}
