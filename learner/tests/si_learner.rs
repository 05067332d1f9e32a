//! Self-imitation wired into the learner: rounds fall due per training episode after
//! `asi.si_start_episode`, each runs a high then a low Adam step on the published policies,
//! the route queries carry φ(s_t), φ(g̃) and φ(s_0) under the learner's encoder and its φ
//! version, and every skip is counted by reason.

mod common;

use candle_core::{DType, Device, Tensor};
use candle_nn::VarBuilder;
use common::*;
use learner::si::{SiStats, SI_PHI_MISMATCH_ATTEMPTS};
use learner::{Learner, NoRouteSource, RouteSource, RoutesReply};
use nets::{spec_from_config, PolicySet};
use protocol::graph::{LatentPoint, NoRouteReason, RouteAnswer, RouteQuery};
use protocol::{Config, PhiVersion};

/// SI on or off, with room for every entry of the tests (1000).
fn config(self_imitation: bool) -> Config {
    si_config(self_imitation, 1000)
}

/// A learner that has ingested `episodes` episodes of 10 steps (obs [t, ep, 0.5], goal [5, 6]).
fn learner_after(config: &Config, episodes: u64) -> Learner {
    let mut l = Learner::new(config, DIMS, 11).unwrap();
    for ep in 0..episodes {
        ingest_episode(&mut l, 0, ep, 10, 2, 5);
    }
    l
}

fn stats(l: &Learner) -> SiStats {
    *l.self_imitation().stats()
}

fn phi_of(l: &Learner, config: &Config, obs: [f32; 3]) -> LatentPoint {
    let spec = spec_from_config(config, DIMS).unwrap();
    let vb = VarBuilder::from_varmap(l.policy_varmap(), DType::F32, &Device::Cpu);
    let set = PolicySet::new(&spec, &vb).unwrap();
    let x = Tensor::from_slice(&obs, (1, 3), &Device::Cpu).unwrap();
    let v = set
        .encoder
        .forward(&x)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    [v[0], v[1]]
}

#[test]
fn rounds_fall_due_after_the_start_episode_and_train_both_policies_once_each() {
    let config = config(true);
    let mut l = learner_after(&config, 4);
    assert_eq!(
        l.self_imitation().buffer().len(),
        40,
        "one entry per env step"
    );
    assert_eq!(
        stats(&l).rounds_due,
        2,
        "episodes 3 and 4 end after si_start_episode = 2"
    );
    assert_eq!(l.si_pending(), 2);
    let (high0, low0, enc0) = (
        policy_values(&l, "high_policy"),
        policy_values(&l, "low_policy"),
        policy_values(&l, "encoder"),
    );
    let mut routes = StraightRoutes::new(6);
    assert_eq!(
        l.train_self_imitation(&mut routes).unwrap(),
        2,
        "a high and a low step"
    );
    assert_ne!(
        policy_values(&l, "high_policy"),
        high0,
        "the high policy moved"
    );
    assert_ne!(
        policy_values(&l, "low_policy"),
        low0,
        "the low policy moved"
    );
    assert_eq!(policy_values(&l, "encoder"), enc0, "φ is not trained by SI");
    assert_eq!(l.train_self_imitation(&mut routes).unwrap(), 2);
    assert_eq!(
        l.train_self_imitation(&mut routes).unwrap(),
        0,
        "nothing left due"
    );
    let s = stats(&l);
    assert_eq!((s.high_steps, s.low_steps, s.skipped()), (2, 2, 0));
    assert!(s.high.loss > 0.0 && s.high.loss.is_finite());
    assert!(s.low.loss > 0.0 && s.low.loss.is_finite());
    assert!(
        (s.high.loss - 0.01 * s.high.mse).abs() <= 1e-6 * s.high.mse,
        "α = 0.01"
    );
    assert!(
        (s.low.loss - 0.001 * s.low.mse).abs() <= 1e-6 * s.low.mse,
        "β = 0.001"
    );
    assert_eq!((s.usable_fraction, s.low_usable_fraction), (1.0, 1.0));
    let metrics = l.metrics();
    let get = |name| metrics.iter().find(|(n, _)| *n == name).unwrap().1;
    assert!(s.high_grad_norm > 0.0 && s.low_grad_norm > 0.0);
    assert_eq!(get("si/high_grad_norm"), s.high_grad_norm);
    assert_eq!(get("si/low_grad_norm"), s.low_grad_norm);
    // Four requests (two rounds × two levels), each a batch of 8 in the learner's φ version.
    assert_eq!(routes.asked.len(), 4);
    // The queries' points are φ under the learner's encoder (taken before the round: SI leaves
    // φ alone): every end is φ(g̃) with g̃ = [goal xy, 0.5]; every origin is some φ(s_0).
    let end = phi_of(&l, &config, [5.0, 6.0, 0.5]);
    let starts: Vec<LatentPoint> = (0..4)
        .map(|ep| phi_of(&l, &config, [0.0, ep as f32, 0.5]))
        .collect();
    for (queries, version) in &routes.asked {
        assert_eq!(*version, l.progress().phi_version);
        assert_eq!(queries.len(), 8);
        for q in queries {
            assert!(
                (q.end[0] - end[0]).abs() < 1e-5 && (q.end[1] - end[1]).abs() < 1e-5,
                "{q:?}"
            );
            let origin = q
                .fallback_origin
                .expect("SI queries carry the fallback origin");
            assert!(starts
                .iter()
                .any(|s| (s[0] - origin[0]).abs() < 1e-5 && (s[1] - origin[1]).abs() < 1e-5));
        }
    }
}

#[test]
fn no_answer_skips_the_steps_and_counts_them() {
    let mut l = learner_after(&config(true), 3);
    assert_eq!(l.train_self_imitation(&mut NoRouteSource).unwrap(), 0);
    let s = stats(&l);
    assert_eq!((s.skipped_no_answer, s.skipped()), (2, 2));
    assert_eq!(s.high_steps + s.low_steps, 0);
    assert_eq!(
        l.si_pending(),
        0,
        "a round without an answer is not retried"
    );
}

#[test]
fn a_phi_mismatch_keeps_the_round_pending_until_the_graph_catches_up() {
    let mut l = learner_after(&config(true), 3);
    let mut graph = StraightRoutes::new(6);
    graph.mismatch = true;
    for attempt in 1..SI_PHI_MISMATCH_ATTEMPTS {
        assert_eq!(l.train_self_imitation(&mut graph).unwrap(), 0);
        assert_eq!(l.si_pending(), 1, "attempt {attempt}: the round stays due");
    }
    assert_eq!(
        stats(&l).skipped(),
        0,
        "nothing is counted while the round waits"
    );
    // The graph has re-mapped to the learner's φ: the same round now trains both levels.
    graph.mismatch = false;
    assert_eq!(l.train_self_imitation(&mut graph).unwrap(), 2);
    let s = stats(&l);
    assert_eq!((s.high_steps, s.low_steps, s.skipped()), (1, 1, 0));
    assert_eq!(l.si_pending(), 0);
    assert_eq!(graph.asked.len() as u32, SI_PHI_MISMATCH_ATTEMPTS - 1 + 2);
}

#[test]
fn a_phi_mismatch_that_lasts_gives_the_round_up_and_counts_it() {
    let mut l = learner_after(&config(true), 4);
    assert_eq!(l.si_pending(), 2);
    let mut stale = StraightRoutes::new(6);
    stale.mismatch = true;
    for _ in 0..SI_PHI_MISMATCH_ATTEMPTS {
        assert_eq!(l.train_self_imitation(&mut stale).unwrap(), 0);
    }
    let s = stats(&l);
    assert_eq!((s.skipped_phi_mismatch, s.skipped()), (2, 2));
    assert_eq!(s.high_steps + s.low_steps, 0);
    assert_eq!(l.si_pending(), 1, "only the oldest round was given up");
    // The attempt count starts over for the next round.
    for _ in 1..SI_PHI_MISMATCH_ATTEMPTS {
        assert_eq!(l.train_self_imitation(&mut stale).unwrap(), 0);
    }
    assert_eq!((stats(&l).skipped_phi_mismatch, l.si_pending()), (2, 1));
}

#[test]
fn routes_too_short_for_the_low_level_train_only_the_high_level() {
    let mut l = learner_after(&config(true), 3);
    // Two nodes: usable by the high level (L > 1), not by the low level (L > 2).
    assert_eq!(
        l.train_self_imitation(&mut StraightRoutes::new(2)).unwrap(),
        1
    );
    let s = stats(&l);
    assert_eq!(
        (s.high_steps, s.low_steps, s.skipped_no_usable_route),
        (1, 0, 1)
    );
    assert_eq!((s.usable_fraction, s.low_usable_fraction), (1.0, 0.0));
}

#[test]
fn with_self_imitation_off_the_buffer_still_fills_and_due_rounds_count_as_skipped() {
    let mut l = learner_after(&config(false), 4);
    // Filled as with SI on, so that the run can be resumed with SI on (tests/serial_resume.rs).
    assert_eq!(
        l.self_imitation().buffer().len(),
        learner_after(&config(true), 4)
            .self_imitation()
            .buffer()
            .len()
    );
    assert!(!l.self_imitation().buffer().is_empty());
    assert_eq!(l.si_pending(), 0);
    assert_eq!(
        l.train_self_imitation(&mut StraightRoutes::new(6)).unwrap(),
        0
    );
    assert_eq!(
        stats(&l).skipped_disabled,
        4,
        "two rounds, two level steps each"
    );
}

#[test]
fn the_si_metrics_are_reported() {
    let mut l = learner_after(&config(true), 3);
    l.train_self_imitation(&mut StraightRoutes::new(6)).unwrap();
    let metrics = l.metrics();
    let get = |name: &str| metrics.iter().find(|(k, _)| *k == name).map(|(_, v)| *v);
    assert_eq!(get("si/steps"), Some(2.0));
    assert_eq!(get("si/buffer_len"), Some(30.0));
    assert_eq!(get("si/skipped"), Some(0.0));
    assert_eq!(get("si/usable_fraction"), Some(1.0));
    assert!(get("si/high_loss").is_some_and(|v| v > 0.0));
    assert!(get("si/low_loss").is_some_and(|v| v > 0.0));
}

/// Answers every query as an unexplored goal would be answered: no route to φ(g̃); with a
/// fallback origin a straight 6-node route from the start to a "frontier" 10 units along x, without one no
/// route at all (as `graph_service::frontier::answer_route_query`).
struct UnexploredGoals {
    asked: Vec<RouteQuery>,
}

impl RouteSource for UnexploredGoals {
    fn routes(&mut self, queries: &[RouteQuery], _phi_version: PhiVersion) -> RoutesReply {
        self.asked.extend_from_slice(queries);
        let answer = |q: &RouteQuery| match q.fallback_origin {
            Some(_) => RouteAnswer::ViaFrontier(
                (0..6)
                    .map(|i| [q.start[0] + 2.0 * i as f32, q.start[1]])
                    .collect(),
            ),
            None => RouteAnswer::NoRoute {
                direct: NoRouteReason::EndUnknown,
                fallback: None,
            },
        };
        RoutesReply::Answered(queries.iter().map(answer).collect())
    }
}

/// The SI-on test config changed by `change`, validated.
fn si_config_with(change: impl FnOnce(&mut Config)) -> Config {
    let mut c = config(true);
    change(&mut c);
    c.validate().unwrap();
    c
}

/// The high and the low policy's weights.
fn policies(l: &Learner) -> (Vec<u32>, Vec<u32>) {
    (
        policy_values(l, "high_policy"),
        policy_values(l, "low_policy"),
    )
}

#[test]
fn a_zero_weight_turns_only_that_levels_step_off() {
    for (alpha, beta) in [(0.0, 0.001), (0.01, 0.0)] {
        let mut l = learner_after(
            &si_config_with(|c| {
                c.asi.si_alpha = alpha;
                c.asi.si_beta = beta;
            }),
            3,
        );
        let (high0, low0) = policies(&l);
        let steps = l.train_self_imitation(&mut StraightRoutes::new(6)).unwrap();
        let s = stats(&l);
        assert_eq!(steps, 1, "α = {alpha}, β = {beta}: one level step");
        assert_eq!(
            (s.high_steps, s.low_steps, s.skipped_disabled, s.skipped()),
            (u64::from(alpha > 0.0), u64::from(beta > 0.0), 1, 1)
        );
        let (high, low) = policies(&l);
        assert_eq!(high == high0, alpha == 0.0);
        assert_eq!(low == low0, beta == 0.0);
        // The skipped level's batch was still drawn and its routes reported.
        assert_eq!((s.usable_fraction, s.low_usable_fraction), (1.0, 1.0));
        assert_eq!(l.si_pending(), 0);
    }
}

#[test]
fn without_the_frontier_fallback_entries_with_no_route_to_their_goal_are_dropped() {
    // Default: the queries carry φ(s_0) and the frontier routes are imitated.
    let mut l = learner_after(&config(true), 3);
    let mut source = UnexploredGoals { asked: Vec::new() };
    assert_eq!(l.train_self_imitation(&mut source).unwrap(), 2);
    assert!(source.asked.iter().all(|q| q.fallback_origin.is_some()));
    assert_eq!(stats(&l).via_frontier_fraction, 1.0);

    let mut l = learner_after(&si_config_with(|c| c.asi.si_frontier_fallback = false), 3);
    let (high0, low0) = policies(&l);
    let mut source = UnexploredGoals { asked: Vec::new() };
    assert_eq!(l.train_self_imitation(&mut source).unwrap(), 0);
    assert_eq!(source.asked.len(), 16, "two batches of 8 were still asked");
    assert!(source.asked.iter().all(|q| q.fallback_origin.is_none()));
    let s = stats(&l);
    assert_eq!(
        (s.skipped_no_usable_route, s.high_steps, s.low_steps),
        (2, 0, 0)
    );
    assert_eq!((s.usable_fraction, s.via_frontier_fraction), (0.0, 0.0));
    assert_eq!(policies(&l), (high0, low0));
}
