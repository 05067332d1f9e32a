//! HESS exploration in the actor (SPEC §6.4) on the real point-maze task: explore decisions from
//! a graph oracle, the run-wide schedule gate, reaching reports, fallbacks, far-goal flags, and
//! the protocol side of [`ServiceOracle`].

mod common;
use common::*;

use actor::{
    Actor, ActorError, Chunk, ExploreAnswer, GraphOracle, GraphTransport, NoGraph, ServiceOracle,
};
use protocol::graph::{GraphRequestHeader, GraphResponseHeader, GraphStatus, ReachSample};
use protocol::{
    ActorId, Config, DecisionKind, GraphRequest, GraphResponse, LatentPoint, PhiVersion,
    PolicyVersion, RunSchedule, StepRecord, TrajectoryFlags as F, WeightsHeader,
};

/// An actor of `config(50, 100)` whose own weights were reloaded with `schedule`.
fn actor_with_schedule(seed: u64, schedule: RunSchedule) -> Actor {
    let mut actor = Actor::new(&config(50, 100), ActorId(0), seed).unwrap();
    let bytes = actor.weights_bytes().unwrap();
    let header = WeightsHeader::new(
        PolicyVersion(1),
        PhiVersion(1),
        actor.layout_hash(),
        bytes.len(),
    )
    .with_schedule(schedule);
    actor.load_weights(&header, &bytes).unwrap();
    actor
}

fn schedule(train_episodes: u64, count_prob: f32) -> RunSchedule {
    RunSchedule {
        train_episodes,
        count_prob,
        fr_prob: 0.0,
    }
}

/// Answers every explore request with a fixed subgoal and candidate (or nothing), and records
/// what it was asked and told.
#[derive(Default)]
struct FixedOracle {
    answer: Option<ExploreAnswer>,
    acknowledge: bool,
    asked: Vec<(LatentPoint, u64, PhiVersion)>,
    reports: Vec<Vec<ReachSample>>,
}

impl FixedOracle {
    fn answering(subgoal: LatentPoint, candidate: LatentPoint) -> Self {
        Self {
            answer: Some(ExploreAnswer { subgoal, candidate }),
            acknowledge: true,
            ..Self::default()
        }
    }
}

impl GraphOracle for FixedOracle {
    fn explore(
        &mut self,
        from: LatentPoint,
        episode: u64,
        phi_version: PhiVersion,
    ) -> Result<Option<ExploreAnswer>, ActorError> {
        self.asked.push((from, episode, phi_version));
        Ok(self.answer)
    }

    fn report_reaching(
        &mut self,
        samples: &[ReachSample],
        _phi_version: PhiVersion,
    ) -> Result<bool, ActorError> {
        self.reports.push(samples.to_vec());
        Ok(self.acknowledge)
    }
}

const SUBGOAL: LatentPoint = [30.0, -25.0];
const CANDIDATE: LatentPoint = [26.0, -21.5];

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

#[test]
fn explore_decisions_take_the_oracles_subgoal_and_store_the_unclipped_delta() {
    let mut actor = actor_with_schedule(1, schedule(101, 1.0));
    let mut oracle = FixedOracle::answering(SUBGOAL, CANDIDATE);
    let mut n_decisions = 0;
    for episode in episodes(&mut actor, &mut oracle, 2) {
        for (t, r) in records_of(&episode).iter().enumerate() {
            if t % 10 != 0 {
                assert_eq!(r.decision, DecisionKind::None);
                continue;
            }
            assert_eq!(r.decision, DecisionKind::Explore, "step {t}");
            assert_eq!(
                r.subgoal, SUBGOAL,
                "the low level gets the absolute subgoal"
            );
            let delta: Vec<f32> = SUBGOAL.iter().zip(&r.phi).map(|(s, p)| s - p).collect();
            assert_eq!(r.high_action, delta, "step {t}: delta = subgoal − φ(s_t)");
            assert!(r.high_action.iter().any(|d| d.abs() > 10.0), "not clipped");
            let (from, train_episodes, phi_version) = oracle.asked[n_decisions];
            assert_eq!(
                (from.to_vec(), train_episodes, phi_version),
                (r.phi.clone(), 101, PhiVersion(1))
            );
            n_decisions += 1;
        }
    }
    assert_eq!(n_decisions, 20);
    assert_eq!(oracle.asked.len(), 20);
    let stats = actor.stats();
    assert_eq!(
        (
            stats.n_decisions,
            stats.n_explore_decisions,
            stats.n_explore_fallbacks
        ),
        (20, 20, 0)
    );
}

/// Decision kinds of the first two episodes under `schedule`, and how often the oracle was asked.
fn kinds_under(schedule: RunSchedule) -> (Vec<DecisionKind>, usize) {
    let mut actor = actor_with_schedule(2, schedule);
    let mut oracle = FixedOracle::answering(SUBGOAL, CANDIDATE);
    let kinds = episodes(&mut actor, &mut oracle, 2)
        .iter()
        .flat_map(|e| records_of(e))
        .map(|r| r.decision)
        .filter(|k| k.is_decision())
        .collect();
    (kinds, oracle.asked.len())
}

#[test]
fn count_prob_zero_never_explores_and_one_always_does_after_the_start_episode() {
    let no_explore: Vec<DecisionKind> = [DecisionKind::Random; 10]
        .into_iter()
        .chain([DecisionKind::Policy; 10])
        .collect();
    assert_eq!(kinds_under(schedule(101, 0.0)), (no_explore.clone(), 0));
    assert_eq!(
        kinds_under(schedule(100, 1.0)),
        (no_explore.clone(), 0),
        "explore_start_episode = 100: exploration needs more than 100 episodes"
    );
    assert_eq!(kinds_under(RunSchedule::START), (no_explore, 0));
    assert_eq!(
        kinds_under(schedule(101, 1.0)),
        (vec![DecisionKind::Explore; 20], 20)
    );
}

/// The reaching errors of the full segments of `records` (c = 10), each with its source:
/// ‖subgoal of the decision step − φ(s_{t+c})‖.
fn segment_errors(records: &[StepRecord]) -> Vec<(DecisionKind, f32)> {
    (0..records.len() / 10)
        .map(|k| {
            let first = &records[10 * k];
            let last = &records[10 * k + 9];
            (first.decision, distance(&first.subgoal, &last.next_phi))
        })
        .collect()
}

/// The reaching ratios of the full segments of `records` (c = 10): ‖subgoal − φ(s_{t+c})‖ over
/// ‖subgoal − φ(s_t)‖ at the decision step.
fn segment_ratios(records: &[StepRecord]) -> Vec<f32> {
    (0..records.len() / 10)
        .map(|k| {
            let first = &records[10 * k];
            let last = &records[10 * k + 9];
            distance(&first.subgoal, &last.next_phi) / distance(&first.subgoal, &first.phi)
        })
        .collect()
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * b.abs().max(1.0)
}

fn mean(values: impl Iterator<Item = f32>) -> Option<f32> {
    let values: Vec<f32> = values.collect();
    (!values.is_empty()).then(|| values.iter().sum::<f32>() / values.len() as f32)
}

#[test]
fn reaching_samples_and_means_carry_the_hand_computed_segment_errors() {
    let mut actor = actor_with_schedule(3, schedule(150, 0.5));
    let mut oracle = FixedOracle::answering(SUBGOAL, CANDIDATE);
    let (mut n_samples, mut n_reports) = (0, 0);
    for e in 0..3 {
        let n_reports_before = oracle.reports.len();
        let episode = episodes(&mut actor, &mut oracle, 1).remove(0);
        let errors = segment_errors(&records_of(&episode));
        assert_eq!(errors.len(), 10);
        // Explore segments other than the last one are reported, at the candidate's cell.
        let expected: Vec<f32> = errors[..9]
            .iter()
            .filter(|(k, _)| *k == DecisionKind::Explore)
            .map(|(_, err)| *err)
            .collect();
        let reported: Vec<ReachSample> = oracle.reports[n_reports_before..].concat();
        assert_eq!(reported.len(), expected.len(), "episode {e}");
        for (sample, err) in reported.iter().zip(&expected) {
            assert_eq!(sample.subgoal, CANDIDATE);
            assert!(close(sample.error, *err), "{} vs {err}", sample.error);
        }
        n_samples += expected.len() as u64;
        n_reports += u64::from(!expected.is_empty());
        // The means cover every full segment, the last one included.
        let stats = actor.stats();
        let all = mean(errors.iter().map(|(_, err)| *err)).unwrap();
        assert!(close(stats.last_episode_reach_error.unwrap(), all));
        let ratio = mean(segment_ratios(&records_of(&episode)).into_iter()).unwrap();
        let got = stats.last_episode_reach_ratio.unwrap();
        assert!(close(got, ratio), "reach ratio {got} vs {ratio}");
        let explore = mean(
            errors
                .iter()
                .filter(|(k, _)| *k == DecisionKind::Explore)
                .map(|(_, err)| *err),
        );
        match (stats.last_episode_explore_reach_error, explore) {
            (Some(got), Some(want)) => assert!(close(got, want), "{got} vs {want}"),
            (got, want) => assert_eq!(got, want),
        }
    }
    let stats = actor.stats();
    assert!(
        stats.n_explore_decisions > 5 && stats.n_explore_decisions < 25,
        "count_prob 0.5 over 30 decisions: {}",
        stats.n_explore_decisions
    );
    assert_eq!(stats.n_reach_segments, 30);
    assert_eq!(stats.n_reach_ratio_segments, 30);
    assert_eq!(stats.n_reach_samples_sent, n_samples);
    assert_eq!(stats.n_reach_reports, n_reports);
    assert_eq!(stats.n_reach_samples_dropped, 0);
}

#[test]
fn unacknowledged_reports_are_counted_as_dropped() {
    let mut actor = actor_with_schedule(4, schedule(500, 1.0));
    let mut oracle = FixedOracle {
        acknowledge: false,
        ..FixedOracle::answering(SUBGOAL, CANDIDATE)
    };
    episodes(&mut actor, &mut oracle, 2);
    let stats = actor.stats();
    assert_eq!(oracle.reports.len(), 2);
    assert_eq!(
        (
            stats.n_reach_reports,
            stats.n_reach_samples_sent,
            stats.n_reach_samples_dropped
        ),
        (0, 0, 18)
    );
}

#[test]
fn an_oracle_without_answer_falls_back_to_the_base_source_and_is_counted() {
    let mut actor = actor_with_schedule(5, schedule(101, 1.0));
    let mut oracle = FixedOracle::default();
    let episodes = episodes(&mut actor, &mut oracle, 2);
    for (e, episode) in episodes.iter().enumerate() {
        let expected = [DecisionKind::Random, DecisionKind::Policy][e];
        for (t, r) in records_of(episode).iter().enumerate() {
            if t % 10 == 0 {
                assert_eq!(r.decision, expected, "episode {e} step {t}");
                assert!(r.high_action.iter().all(|d| d.abs() <= 10.0));
            }
        }
    }
    assert_eq!(oracle.asked.len(), 20);
    assert!(
        oracle.reports.is_empty(),
        "no explore segment, nothing to report"
    );
    let stats = actor.stats();
    assert_eq!(
        (
            stats.n_decisions,
            stats.n_explore_decisions,
            stats.n_explore_fallbacks
        ),
        (20, 0, 20)
    );
    assert_eq!(stats.n_explore_reach_segments, 0);
    assert_eq!(stats.last_episode_explore_reach_error, None);
}

#[test]
fn a_seed_and_the_oracles_answers_fix_every_chunk_and_request() {
    let run = |seed| {
        let mut actor = actor_with_schedule(seed, schedule(420, 0.4));
        let mut oracle = FixedOracle::answering(SUBGOAL, CANDIDATE);
        let chunks: Vec<Chunk> = (0..8)
            .map(|_| actor.next_chunk(&mut oracle).unwrap())
            .collect();
        (chunks, oracle.asked, oracle.reports, actor.stats())
    };
    let (a, b) = (run(6), run(6));
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1);
    assert_eq!(a.2, b.2);
    assert_eq!(a.3, b.3);
    assert_ne!(a.0, run(7).0);
}

#[test]
fn far_goal_is_flagged_on_every_chunk_of_exactly_the_far_goal_episodes() {
    let mut actor = Actor::new(&config(10, 20), ActorId(0), 8).unwrap();
    let env = envs::make("pointmaze-u").unwrap();
    let maze = env.maze().unwrap();
    let fraction = Config::default().exploration.far_goal_fraction;
    let (mut n_far, mut n_near) = (0, 0);
    for _ in 0..40 {
        let episode = episodes(&mut actor, &mut NoGraph, 1).remove(0);
        let goal = records_of(&episode)[0].goal.clone();
        let far = maze.is_far_goal_with_fraction([goal[0], goal[1]], fraction);
        for chunk in &episode {
            assert_eq!(
                chunk.header.flags.contains(F::FAR_GOAL),
                far,
                "goal {goal:?}"
            );
            assert!(
                !chunk.header.flags.contains(F::FRONTIER),
                "no FR episode is drawn in the first 40 (FR starts after episode 200)"
            );
        }
        assert_eq!(actor.stats().last_episode_far_goal, far);
        if far {
            n_far += 1;
        } else {
            n_near += 1;
        }
    }
    assert!(n_far > 0 && n_near > 0, "far {n_far}, near {n_near}");
}

/// A transport that decodes the request, checks it, and answers with a canned status and body.
struct Canned {
    status: GraphStatus,
    response: Option<GraphResponse>,
    fail: bool,
    requests: Vec<(GraphRequestHeader, GraphRequest)>,
}

impl Canned {
    fn new(status: GraphStatus, response: Option<GraphResponse>) -> Self {
        Self {
            status,
            response,
            fail: false,
            requests: Vec::new(),
        }
    }
}

impl GraphTransport for Canned {
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String> {
        let request: GraphRequest = protocol::decode(body).map_err(|e| e.to_string())?;
        assert_eq!(header.kind().unwrap(), request.kind());
        self.requests.push((*header, request));
        if self.fail {
            return Err("no response within 10ms".into());
        }
        let reply = GraphResponseHeader::answering(header, self.status, 3, PhiVersion(2));
        let bytes = match &self.response {
            Some(r) => protocol::encode(r).unwrap(),
            None => Vec::new(),
        };
        Ok((reply, bytes))
    }
}

#[test]
fn the_service_oracle_encodes_requests_and_reads_only_usable_answers() {
    let explore = GraphResponse::ExploreSubgoal {
        subgoal: SUBGOAL,
        candidate: CANDIDATE,
    };
    let mut ok = ServiceOracle::new(Canned::new(GraphStatus::Ok, Some(explore.clone())));
    let answer = ok.explore([1.0, -2.0], 420, PhiVersion(2)).unwrap();
    assert_eq!(
        answer,
        Some(ExploreAnswer {
            subgoal: SUBGOAL,
            candidate: CANDIDATE
        })
    );
    ok.explore([1.0, -2.0], 421, PhiVersion(2)).unwrap();
    let requests = &ok.transport().requests;
    assert_eq!(
        requests[0].1,
        GraphRequest::ExploreSubgoal {
            from: [1.0, -2.0],
            episode: 420
        }
    );
    assert_eq!(requests[0].0.phi_version, PhiVersion(2));
    assert_ne!(
        requests[0].0.request_id, requests[1].0.request_id,
        "request ids differ"
    );

    let nan = GraphResponse::ExploreSubgoal {
        subgoal: [f32::NAN, 0.0],
        candidate: CANDIDATE,
    };
    let error = GraphResponse::Error {
        message: "bad".into(),
    };
    let unusable = [
        Canned::new(GraphStatus::NotReady, None),
        Canned::new(GraphStatus::NotReady, Some(error.clone())),
        Canned::new(GraphStatus::InvalidRequest, Some(error)),
        Canned::new(GraphStatus::Ok, Some(GraphResponse::Ack)),
        Canned::new(GraphStatus::Ok, Some(nan)),
        Canned {
            fail: true,
            ..Canned::new(GraphStatus::Ok, Some(explore))
        },
    ];
    for transport in unusable {
        let status = transport.status;
        let mut oracle = ServiceOracle::new(transport);
        let answer = oracle.explore([0.0, 0.0], 500, PhiVersion(0)).unwrap();
        assert_eq!(answer, None, "status {status:?}");
    }

    let sample = ReachSample {
        subgoal: CANDIDATE,
        error: 2.5,
    };
    let mut acked = ServiceOracle::new(Canned::new(GraphStatus::Ok, Some(GraphResponse::Ack)));
    assert!(acked
        .report_reaching(std::slice::from_ref(&sample), PhiVersion(1))
        .unwrap());
    assert_eq!(
        acked.transport().requests[0].1,
        GraphRequest::ReportReaching {
            samples: vec![sample.clone()]
        }
    );
    let mut not_ready = ServiceOracle::new(Canned::new(GraphStatus::NotReady, None));
    assert!(!not_ready.report_reaching(&[sample], PhiVersion(1)).unwrap());
}
