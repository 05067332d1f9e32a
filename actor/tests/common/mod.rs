//! Helpers shared by the actor's integration tests.
#![allow(dead_code)]

use actor::{Actor, Chunk, GraphOracle};
use protocol::{Config, StepRecord, TrajectoryFlags};

/// Point maze U, small networks, c = 10, episodes of `episode_length` steps cut every
/// `chunk_steps`, one random-subgoal episode before the policy takes over.
pub fn config(chunk_steps: u32, episode_length: u32) -> Config {
    let mut config = Config::default();
    config.env.task = "pointmaze-u".into();
    config.env.episode_length = Some(episode_length);
    config.transport.chunk_steps = chunk_steps;
    config.hierarchy.c = 10;
    config.learner.high.random_episodes = 1;
    config.learner.high.hidden = vec![32, 32];
    config.learner.low.hidden = vec![32, 32];
    config.encoder.hidden = vec![16, 16];
    config
}

/// Every record of a chunk, decoded through its header (which must match the payload).
pub fn decode(chunk: &Chunk) -> Vec<StepRecord> {
    let layout = chunk
        .header
        .check(chunk.records.len())
        .expect("header matches payload");
    let views = layout
        .view_chunk(&chunk.records, chunk.header.n_steps as usize)
        .expect("records decode");
    views.iter().map(|v| v.to_record()).collect()
}

/// The chunks of the actor's next episode.
pub fn episode(actor: &mut Actor, oracle: &mut dyn GraphOracle) -> Vec<Chunk> {
    let mut chunks = Vec::new();
    loop {
        let chunk = actor.next_chunk(oracle).unwrap();
        let ended = chunk.header.flags.contains(TrajectoryFlags::EPISODE_END);
        chunks.push(chunk);
        if ended {
            return chunks;
        }
    }
}

/// The chunks of the next `n` episodes, grouped by episode.
pub fn episodes(actor: &mut Actor, oracle: &mut dyn GraphOracle, n: usize) -> Vec<Vec<Chunk>> {
    (0..n).map(|_| episode(actor, oracle)).collect()
}

/// Every record of an episode's chunks.
pub fn records_of(episode: &[Chunk]) -> Vec<StepRecord> {
    episode.iter().flat_map(decode).collect()
}
