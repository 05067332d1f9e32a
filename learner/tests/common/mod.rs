//! Shared helpers for the learner tests: a tiny valid config, task dims, hand-built step
//! records and chunk headers.
#![allow(dead_code)]

use learner::{Learner, TaskDims};
use protocol::{
    ActorId, Config, DecisionKind, EpisodeId, PolicyVersion, StepLayout, StepRecord,
    TrajectoryFlags, TrajectoryHeader,
};

/// obs 3, goal 2, action 2 (bound 1), latent 2 (the config's φ size).
pub const DIMS: TaskDims = TaskDims {
    obs_dim: 3,
    goal_dim: 2,
    action_dim: 2,
    action_scale: 1.0,
};

/// A small config that validates: c = 2, capacity 256, batches of 4, tiny networks,
/// low ratio 0.4 (explicit), publish every 10 env steps, slack 10.
pub fn config() -> Config {
    let mut c = Config::default();
    c.run.n_actors = 2;
    c.env.episode_length = Some(10);
    c.hierarchy.c = 2;
    c.replay.capacity_steps = 256;
    c.replay.replay_slack_steps = 10;
    c.encoder.hidden = vec![8];
    c.learner.high.hidden = vec![16, 16];
    c.learner.high.batch_size = 4;
    c.learner.high.min_transitions = 4;
    c.learner.low.hidden = vec![16, 16];
    c.learner.low.batch_size = 4;
    c.learner.low.updates_per_env_step = Some(0.4);
    c.transport.weights_check_interval_steps = 10;
    c.validate().unwrap();
    c
}

/// A learner on [`config`].
pub fn learner() -> Learner {
    Learner::new(&config(), DIMS, 7).unwrap()
}

/// The record layout of [`DIMS`].
pub fn layout() -> StepLayout {
    StepLayout::new(3, 2, 2, 2).unwrap()
}

/// Step `t` of episode `ep`: obs = [t, ep, 0.5], next_obs = [t+1, ep, 0.5],
/// φ = [0.1 t, 0], next φ = [0.1 (t+1), 0], subgoal [1, 0], reward −(t+1), no decision,
/// action [0.01 t, −0.01 t], goal [5, 6].
pub fn step(t: usize, ep: u64) -> StepRecord {
    let tf = t as f32;
    StepRecord {
        obs: vec![tf, ep as f32, 0.5],
        next_obs: vec![tf + 1.0, ep as f32, 0.5],
        phi: vec![0.1 * tf, 0.0],
        next_phi: vec![0.1 * (tf + 1.0), 0.0],
        subgoal: vec![1.0, 0.0],
        high_action: vec![0.0, 0.0],
        action: vec![0.01 * tf, -0.01 * tf],
        goal: vec![5.0, 6.0],
        achieved_goal: vec![tf, 0.0],
        reward: -(tf + 1.0),
        decision: DecisionKind::None,
        success: false,
        terminated: false,
        truncated: false,
    }
}

/// Steps `range` of episode `ep`, decisions every `every` steps (none if 0; high action [t, −t]),
/// the episode's last step (`last`) truncated.
pub fn steps(range: std::ops::Range<usize>, ep: u64, every: usize, last: usize) -> Vec<StepRecord> {
    range
        .map(|t| {
            let mut s = step(t, ep);
            if every > 0 && t % every == 0 {
                s.decision = DecisionKind::Policy;
                s.high_action = vec![t as f32, -(t as f32)];
            }
            s.truncated = t == last;
            s
        })
        .collect()
}

/// A valid header for `records` as chunk `chunk` of episode `ep` from `actor`.
pub fn header(
    actor: u32,
    ep: u64,
    chunk: u32,
    records: &[StepRecord],
    flags: u32,
) -> TrajectoryHeader {
    let mut h = TrajectoryHeader::for_layout(&layout()).unwrap();
    h.actor_id = ActorId(actor);
    h.episode_id = EpisodeId(ep);
    h.chunk_index = chunk;
    h.n_steps = records.len() as u32;
    h.first_env_step = 0;
    h.policy_version = PolicyVersion(0);
    h.flags = TrajectoryFlags(flags);
    h
}

/// Encodes and ingests one chunk.
pub fn ingest(
    l: &mut Learner,
    actor: u32,
    ep: u64,
    chunk: u32,
    records: &[StepRecord],
    flags: u32,
) -> Result<(), learner::LearnerError> {
    let payload = layout().encode_chunk(records).unwrap();
    l.ingest(&header(actor, ep, chunk, records, flags), &payload)
}

/// Ingests a full episode of `len` steps (decisions every `every`) in chunks of `chunk` steps.
pub fn ingest_episode(
    l: &mut Learner,
    actor: u32,
    ep: u64,
    len: usize,
    every: usize,
    chunk: usize,
) {
    let all = steps(0..len, ep, every, len - 1);
    for (i, part) in all.chunks(chunk).enumerate() {
        let mut flags = 0;
        if i == 0 {
            flags |= TrajectoryFlags::EPISODE_START;
        }
        if (i + 1) * chunk >= len {
            flags |= TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
        }
        ingest(l, actor, ep, i as u32, part, flags).unwrap();
    }
}
