//! Deterministic seeds and ids derived from `(seed, actor_id, episode)`.
//!
//! Invariants: every function here is a pure function of its arguments (no global state), so an
//! actor built with the same seed and id replays exactly the same episodes; streams of different
//! actors, and of different episodes of one actor, are decorrelated by SplitMix64 mixing.

use protocol::{ActorId, EpisodeId};

/// Bits of an [`EpisodeId`] that hold the actor-local episode counter; the actor id sits above.
pub const EPISODE_COUNTER_BITS: u32 = 40;

/// SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer.
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Seed of the actor's own generator (subgoal and action noise): the run seed mixed with the
/// actor id, so that actors started with the same run seed do not share noise.
pub fn actor_rng_seed(seed: u64, actor_id: ActorId) -> u64 {
    splitmix64(splitmix64(seed) ^ u64::from(actor_id.0))
}

/// Seed of the generator of an actor that starts at its `first_episode`-th episode
/// (`Actor::start_at_episode`; a restarted or resumed actor process starts at a fresh range):
/// [`actor_rng_seed`] for 0, a stream of its own for any other start, so a restarted actor does
/// not replay the action noise and random subgoals of the run's first start.
pub fn actor_rng_seed_from(seed: u64, actor_id: ActorId, first_episode: u64) -> u64 {
    let base = actor_rng_seed(seed, actor_id);
    if first_episode == 0 {
        base
    } else {
        splitmix64(base ^ splitmix64(first_episode))
    }
}

/// Seed passed to `Env::reset` for the actor's `episode`-th episode (0-based).
pub fn env_seed(seed: u64, actor_id: ActorId, episode: u64) -> u64 {
    let actor = splitmix64(splitmix64(seed ^ 0x656e_765f_7365_6564) ^ u64::from(actor_id.0));
    splitmix64(actor ^ episode)
}

/// Run-unique id of the actor's `episode`-th episode: `(actor_id << 40) | episode`.
/// `None` once `episode` no longer fits in 40 bits (10¹² episodes).
pub fn episode_id(actor_id: ActorId, episode: u64) -> Option<EpisodeId> {
    (episode < 1 << EPISODE_COUNTER_BITS)
        .then(|| EpisodeId((u64::from(actor_id.0) << EPISODE_COUNTER_BITS) | episode))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn episode_ids_of_different_actors_never_collide() {
        let a = episode_id(ActorId(1), 5).unwrap();
        let b = episode_id(ActorId(2), 5).unwrap();
        assert_ne!(a, b);
        assert_eq!(a.0 >> EPISODE_COUNTER_BITS, 1);
        assert_eq!(a.0 & ((1 << EPISODE_COUNTER_BITS) - 1), 5);
        assert!(episode_id(ActorId(0), 1 << EPISODE_COUNTER_BITS).is_none());
    }

    #[test]
    fn env_seeds_differ_across_actors_and_episodes() {
        let seeds = [
            env_seed(7, ActorId(0), 0),
            env_seed(7, ActorId(0), 1),
            env_seed(7, ActorId(1), 0),
            env_seed(8, ActorId(0), 0),
        ];
        for (i, a) in seeds.iter().enumerate() {
            for b in &seeds[i + 1..] {
                assert_ne!(a, b);
            }
        }
        assert_eq!(env_seed(7, ActorId(3), 9), env_seed(7, ActorId(3), 9));
    }

    #[test]
    fn a_start_past_episode_0_gets_a_generator_seed_of_its_own() {
        assert_eq!(
            actor_rng_seed_from(7, ActorId(1), 0),
            actor_rng_seed(7, ActorId(1))
        );
        let starts = [0, 1 << 28, 2 << 28];
        for (i, a) in starts.iter().enumerate() {
            for b in &starts[i + 1..] {
                assert_ne!(
                    actor_rng_seed_from(7, ActorId(1), *a),
                    actor_rng_seed_from(7, ActorId(1), *b)
                );
            }
        }
        assert_ne!(
            actor_rng_seed_from(7, ActorId(1), 1 << 28),
            actor_rng_seed_from(7, ActorId(2), 1 << 28)
        );
    }
}
