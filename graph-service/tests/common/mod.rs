//! Test helpers: a small config, hand-made chunks, and encoder weights with known φ.

#![allow(dead_code)]

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use graph_service::GraphService;
use protocol::graph::{GraphRequestHeader, GraphResponseHeader, GraphStatus};
use protocol::{
    ActorId, Config, DecisionKind, EpisodeId, GraphRequest, GraphResponse, LatentPoint, PhiVersion,
    PolicyVersion, StepRecord, TrajectoryFlags, TrajectoryHeader, WeightsHeader,
};

/// Observation length of the test task: (x, y, z); φ uses x and y.
pub const OBS_DIM: usize = 3;

pub fn dims() -> nets::TaskDims {
    nets::TaskDims {
        obs_dim: OBS_DIM,
        goal_dim: 2,
        action_dim: 2,
        action_scale: 1.0,
    }
}

/// Unit cells, small networks (φ: 3 → 4 → 2).
pub fn config() -> Config {
    let mut config = Config::default();
    config.graph.cell_size = 1.0;
    config.encoder.hidden = vec![4];
    config.learner.high.hidden = vec![8];
    config.learner.low.hidden = vec![8];
    config
}

pub fn service(config: &Config) -> GraphService {
    GraphService::new(config, dims(), 7).unwrap()
}

/// A point inside unit cell (x, y).
pub fn at(x: i32, y: i32) -> LatentPoint {
    [x as f32 + 0.5, y as f32 + 0.5]
}

/// The obs of a state whose xy is `p`.
fn obs(p: LatentPoint) -> Vec<f32> {
    vec![p[0], p[1], 0.25]
}

/// A chunk holding steps from `points[i]` to `points[i + 1]`: `points.len() − 1` records,
/// φ labels = xy. Flags: start if `chunk_index` is 0, end if `end`.
pub struct Chunk {
    pub actor: u32,
    pub episode: u64,
    pub chunk_index: u32,
    pub first_env_step: u64,
    pub end: bool,
    pub phi_version: u64,
}

impl Chunk {
    pub fn new(actor: u32, episode: u64) -> Self {
        Self {
            actor,
            episode,
            chunk_index: 0,
            first_env_step: 0,
            end: true,
            phi_version: 0,
        }
    }

    pub fn encode(&self, points: &[LatentPoint]) -> (TrajectoryHeader, Vec<f32>) {
        let layout = protocol::StepLayout::new(OBS_DIM, 2, 2, 2).unwrap();
        let records: Vec<StepRecord> = points.windows(2).map(|w| record(w[0], w[1])).collect();
        let mut header = TrajectoryHeader::for_layout(&layout).unwrap();
        header.actor_id = ActorId(self.actor);
        header.episode_id = EpisodeId(self.episode);
        header.chunk_index = self.chunk_index;
        header.first_env_step = self.first_env_step;
        header.n_steps = records.len() as u32;
        header.policy_version = PolicyVersion(0);
        header.phi_version = PhiVersion(self.phi_version);
        if self.chunk_index == 0 {
            header.flags.insert(TrajectoryFlags::EPISODE_START);
        }
        if self.end {
            header
                .flags
                .insert(TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED);
        }
        (header, layout.encode_chunk(&records).unwrap())
    }
}

fn record(from: LatentPoint, to: LatentPoint) -> StepRecord {
    StepRecord {
        obs: obs(from),
        next_obs: obs(to),
        phi: from.to_vec(),
        next_phi: to.to_vec(),
        subgoal: vec![0.0, 0.0],
        high_action: vec![0.0, 0.0],
        action: vec![0.0, 0.0],
        goal: vec![0.0, 0.0],
        achieved_goal: to.to_vec(),
        reward: -1.0,
        decision: DecisionKind::None,
        success: false,
        terminated: false,
        truncated: false,
    }
}

/// Ingests one whole episode through `points` (one chunk).
pub fn ingest_episode(
    service: &mut GraphService,
    actor: u32,
    episode: u64,
    points: &[LatentPoint],
) {
    let (header, payload) = Chunk::new(actor, episode).encode(points);
    service.ingest(&header, &payload).unwrap();
}

/// The actor-side parameter set of the test config, with φ(s) = scale · (s_x, s_y).
pub fn actor_side_params(config: &Config, scale: f32) -> VarMap {
    let params = VarMap::new();
    let spec = nets::spec_from_config(config, dims()).unwrap();
    let vb = nets::seeded_var_builder(&params, 1, &Device::Cpu);
    nets::PolicySet::new(&spec, &vb).unwrap();
    let relu_split = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
    ];
    let merge = [[scale, -scale, 0.0, 0.0], [0.0, 0.0, scale, -scale]];
    set(&params, "encoder.l0.weight", &relu_split.concat(), (4, 3));
    set(&params, "encoder.l0.bias", &[0.0; 4], (4,));
    set(&params, "encoder.l1.weight", &merge.concat(), (2, 4));
    set(&params, "encoder.l1.bias", &[0.0; 2], (2,));
    params
}

fn set<S: Into<candle_core::Shape>>(params: &VarMap, name: &str, values: &[f32], shape: S) {
    let data = params.data().lock().unwrap();
    let var = data
        .get(name)
        .unwrap_or_else(|| panic!("no parameter {name}"));
    var.set(&Tensor::from_slice(values, shape, &Device::Cpu).unwrap())
        .unwrap();
}

/// A weights message of `params` at φ version `phi_version`.
pub fn weights(params: &VarMap, phi_version: u64) -> (WeightsHeader, Vec<u8>) {
    let bytes = nets::to_safetensors_bytes(params).unwrap();
    let hash = nets::layout_hash(params);
    (
        WeightsHeader::new(
            PolicyVersion(phi_version),
            PhiVersion(phi_version),
            hash,
            bytes.len(),
        ),
        bytes,
    )
}

/// Loads φ(s) = s_xy at `phi_version` (builds the first graph).
pub fn load_identity(service: &mut GraphService, config: &Config, phi_version: u64) {
    let (header, bytes) = weights(&actor_side_params(config, 1.0), phi_version);
    service.load_weights(&header, &bytes).unwrap();
}

/// Sends `request` through `handle`; returns the status and the decoded body (None if empty).
pub fn ask(
    service: &mut GraphService,
    request: &GraphRequest,
) -> (GraphResponseHeader, Option<GraphResponse>) {
    let header = GraphRequestHeader::new(1, request.kind(), service.phi_version());
    let body = protocol::encode(request).unwrap();
    let (response, bytes) = service.handle(&header, &body);
    (response, decode_body(&bytes))
}

pub fn decode_body(bytes: &[u8]) -> Option<GraphResponse> {
    (!bytes.is_empty()).then(|| protocol::decode(bytes).unwrap())
}

pub fn status(header: &GraphResponseHeader) -> GraphStatus {
    header.status().unwrap()
}
