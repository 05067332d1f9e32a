//! Shared helpers for the learner tests: a tiny valid config (and its φ and SI variants), task
//! dims, hand-built step records and chunk headers, overflowing states, a straight-line route
//! source, and readers of the learner's metrics and parameters.
#![allow(dead_code)]

use candle_core::{DType, Device};
use candle_nn::VarBuilder;
use learner::{Learner, RouteSource, RoutesReply, TaskDims};
use nets::{prefix, Encoder};
use protocol::graph::{LatentPoint, RouteAnswer, RouteQuery};
use protocol::{
    ActorId, Config, DecisionKind, EpisodeId, PhiVersion, PolicyVersion, StepLayout, StepRecord,
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

/// [`config`] with φ rounds after 4 and 8 episodes, 300 steps each, batch 16, lr 0.01,
/// k = c = 2.
pub fn phi_config() -> Config {
    let mut c = config();
    c.encoder.first_round_episode = 4;
    c.encoder.interval_episodes = 4;
    c.encoder.steps_per_round = 300;
    c.encoder.batch_size = 16;
    c.encoder.lr = 0.01;
    c.validate().unwrap();
    c
}

/// [`config`] with self-imitation on or off, rounds due from the third training episode on
/// (`si_start_episode` 2), SI batches of 8 and an SI buffer of `buffer_capacity` entries.
pub fn si_config(self_imitation: bool, buffer_capacity: u64) -> Config {
    let mut c = config();
    c.asi.self_imitation = self_imitation;
    c.asi.si_start_episode = 2;
    c.asi.si_batch_size = 8;
    c.asi.si_buffer_capacity = buffer_capacity;
    c.validate().unwrap();
    c
}

/// An overflowing but finite state at time `t` (the protocol refuses NaN and infinities): all
/// components ±3e38, the sign alternating with `t` so that neighbours are far apart.
pub fn huge_state(t: usize) -> [f32; 3] {
    let sign = if t.is_multiple_of(2) { 1.0 } else { -1.0 };
    [sign * 3.0e38; 3]
}

/// Ingests episode `ep` of 10 steps from actor 0 in one chunk (decisions every 2 steps, the
/// last step truncated), its states [`huge_state`]s or those of [`step`].
pub fn ingest_episode_in_one_chunk(l: &mut Learner, ep: u64, huge: bool) {
    let mut records = steps(0..10, ep, 2, 9);
    if huge {
        for (t, r) in records.iter_mut().enumerate() {
            r.obs = huge_state(t).to_vec();
            r.next_obs = huge_state(t + 1).to_vec();
        }
    }
    let flags =
        TrajectoryFlags::EPISODE_START | TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
    ingest(l, 0, ep, 0, &records, flags).unwrap();
}

/// The value of metric `name` (panics if the learner does not report it).
pub fn metric(l: &Learner, name: &str) -> f64 {
    l.metrics()
        .into_iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("{name} missing"))
        .1
}

/// The learner's current φ (sharing its parameters).
pub fn encoder_of(l: &Learner) -> Encoder {
    let vb = VarBuilder::from_varmap(l.policy_varmap(), DType::F32, &Device::Cpu);
    let spec = l.nets_spec();
    Encoder::new(
        &vb.pp(prefix::ENCODER),
        spec.obs_dim,
        &spec.encoder_hidden,
        spec.latent_dim,
    )
    .unwrap()
}

/// The values of the published variables whose names start with `prefix`, name-sorted, as bit
/// patterns so that a comparison is exact (and NaN would not equal itself).
pub fn policy_values(l: &Learner, prefix: &str) -> Vec<u32> {
    let data = l.policy_varmap().data().lock().unwrap();
    let mut names: Vec<_> = data
        .keys()
        .filter(|k| k.starts_with(prefix))
        .cloned()
        .collect();
    names.sort();
    names
        .iter()
        .flat_map(|n| {
            data[n]
                .as_tensor()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap()
                .into_iter()
                .map(f32::to_bits)
        })
        .collect()
}

/// Answers every query with a straight route of `nodes` points from its start to its end
/// (`Direct`), or reports a φ mismatch when `mismatch` is set; records what it was asked.
pub struct StraightRoutes {
    pub nodes: usize,
    pub mismatch: bool,
    pub asked: Vec<(Vec<RouteQuery>, PhiVersion)>,
}

impl StraightRoutes {
    pub fn new(nodes: usize) -> Self {
        Self {
            nodes,
            mismatch: false,
            asked: Vec::new(),
        }
    }
}

impl RouteSource for StraightRoutes {
    fn routes(&mut self, queries: &[RouteQuery], phi_version: PhiVersion) -> RoutesReply {
        self.asked.push((queries.to_vec(), phi_version));
        if self.mismatch {
            return RoutesReply::PhiMismatch {
                graph: PhiVersion(phi_version.0 + 1),
            };
        }
        let line = |q: &RouteQuery| -> Vec<LatentPoint> {
            (0..self.nodes)
                .map(|i| {
                    let f = i as f32 / (self.nodes - 1).max(1) as f32;
                    [
                        q.start[0] + f * (q.end[0] - q.start[0]),
                        q.start[1] + f * (q.end[1] - q.start[1]),
                    ]
                })
                .collect()
        };
        RoutesReply::Answered(
            queries
                .iter()
                .map(|q| RouteAnswer::Direct(line(q)))
                .collect(),
        )
    }
}
