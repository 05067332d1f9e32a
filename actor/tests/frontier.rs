//! Frontier-reaching episodes (SPEC §6.6, digest §7): the pure FR logic on hand-built routes,
//! and FR episodes of a real actor on the point-maze U task with a scripted graph oracle (a test
//! double for the graph-service; the actor's logic is the real one).

mod common;
use common::*;

use actor::frontier::{
    assign, count_candidates, nearest_route_index, straight_waypoint_index, waypoint,
    waypoint_index, Assignment, FrChoice, FrEnd, FrOutcome, FrontierEpisode, FrontierParams,
    Switch,
};
use actor::{
    Actor, ActorError, Chunk, ExploreAnswer, GraphOracle, GraphTransport, LeastVisitedAnswer,
    ServiceOracle,
};
use protocol::config::FrPotentialReports;
use protocol::graph::{
    FrontierRoute, GraphRequestHeader, GraphResponseHeader, GraphStatus, NoRouteReason, ReachSample,
};
use protocol::{
    ActorId, Config, DecisionKind, GraphRequest, GraphResponse, LatentPoint, PhiVersion,
    PolicyVersion, RunSchedule, StepRecord, TrajectoryFlags as F, WeightsHeader,
};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

// ---------------------------------------------------------------------------------------------
// A scripted oracle
// ---------------------------------------------------------------------------------------------

/// Answers frontier requests with `route_from(from)` and least-visited requests with the
/// candidate of lowest `x` (or nothing), recording every question.
struct ScriptedOracle {
    route_from: fn(LatentPoint) -> Option<FrontierRoute>,
    answer_least_visited: bool,
    frontier_asked: Vec<LatentPoint>,
    candidates_asked: Vec<Vec<LatentPoint>>,
    reported: Vec<ReachSample>,
}

impl ScriptedOracle {
    fn new(route_from: fn(LatentPoint) -> Option<FrontierRoute>) -> Self {
        Self {
            route_from,
            answer_least_visited: true,
            frontier_asked: Vec::new(),
            candidates_asked: Vec::new(),
            reported: Vec::new(),
        }
    }
}

/// The scripted visit measure: a candidate's x coordinate (shifted to be non-negative).
fn least_x(candidates: &[LatentPoint]) -> usize {
    (0..candidates.len())
        .min_by(|&a, &b| candidates[a][0].total_cmp(&candidates[b][0]))
        .unwrap()
}

impl GraphOracle for ScriptedOracle {
    fn explore(
        &mut self,
        _from: LatentPoint,
        _episode: u64,
        _phi_version: PhiVersion,
    ) -> Result<Option<ExploreAnswer>, ActorError> {
        Ok(None)
    }

    fn report_reaching(
        &mut self,
        samples: &[ReachSample],
        _phi_version: PhiVersion,
    ) -> Result<bool, ActorError> {
        self.reported.extend_from_slice(samples);
        Ok(true)
    }

    fn frontier_route(
        &mut self,
        from: LatentPoint,
        _phi_version: PhiVersion,
    ) -> Result<Option<FrontierRoute>, ActorError> {
        self.frontier_asked.push(from);
        Ok((self.route_from)(from))
    }

    fn least_visited(
        &mut self,
        candidates: &[LatentPoint],
        _phi_version: PhiVersion,
    ) -> Result<Option<LeastVisitedAnswer>, ActorError> {
        self.candidates_asked.push(candidates.to_vec());
        Ok(self.answer_least_visited.then(|| LeastVisitedAnswer {
            index: least_x(candidates),
            visits: 0.0,
        }))
    }
}

/// A straight route of 16 nodes from `from`, 1.8 apart; the frontier is its last node (27 away).
fn straight_route(from: LatentPoint) -> Option<FrontierRoute> {
    let route: Vec<LatentPoint> = (0..16)
        .map(|i| [from[0] + 1.5 * i as f32, from[1] - 1.0 * i as f32])
        .collect();
    Some(FrontierRoute {
        frontier: *route.last().unwrap(),
        distance: 15.0,
        route,
    })
}

/// A frontier on the start point itself: count mode from the first decision.
fn frontier_here(from: LatentPoint) -> Option<FrontierRoute> {
    Some(FrontierRoute {
        frontier: from,
        route: vec![from],
        distance: 0.0,
    })
}

fn no_route(_from: LatentPoint) -> Option<FrontierRoute> {
    None
}

// ---------------------------------------------------------------------------------------------
// Pure logic on hand-built routes
// ---------------------------------------------------------------------------------------------

fn params() -> FrontierParams {
    FrontierParams {
        k_range: [3, 6],
        straightness: 0.0,
        epsilon: 8.0,
        stuck_threshold: 1.0,
        n_candidates: 100,
        abs_range: 10.0,
        end_at_frontier: false,
        noise_free_navigation: true,
        potential_reports: FrPotentialReports::CountDraw,
    }
}

fn found(route: Vec<LatentPoint>, frontier: LatentPoint) -> FrontierRoute {
    FrontierRoute {
        frontier,
        route,
        distance: 1.0,
    }
}

/// Route along the x axis: nodes at x = 0, 2, 4, …, 18.
fn x_route() -> Vec<LatentPoint> {
    (0..10).map(|i| [2.0 * i as f32, 0.0]).collect()
}

#[test]
fn the_nearest_route_point_is_the_euclidean_argmin_and_the_first_on_ties() {
    let route = x_route();
    assert_eq!(nearest_route_index(&route, &[4.9, 3.0]), Some(2));
    assert_eq!(nearest_route_index(&route, &[5.1, -3.0]), Some(3));
    assert_eq!(nearest_route_index(&route, &[-7.0, 0.0]), Some(0));
    assert_eq!(nearest_route_index(&route, &[100.0, 0.0]), Some(9));
    assert_eq!(
        nearest_route_index(&route, &[5.0, 0.0]),
        Some(2),
        "x = 5 is as close to node 2 as to node 3: the first wins"
    );
    assert_eq!(nearest_route_index(&[], &[0.0, 0.0]), None);
}

#[test]
fn the_waypoint_is_k_nodes_past_the_nearest_and_clamped_to_the_last_node() {
    let route = x_route();
    let frontier = [18.0, 0.0];
    assert_eq!(waypoint(&route, frontier, &[2.2, 1.0], 3), [8.0, 0.0]);
    assert_eq!(waypoint(&route, frontier, &[2.2, 1.0], 6), [14.0, 0.0]);
    assert_eq!(waypoint(&route, frontier, &[12.0, 0.0], 5), [18.0, 0.0]);
    assert_eq!(
        waypoint(&route, frontier, &[12.0, 0.0], u32::MAX),
        [18.0, 0.0]
    );
    assert_eq!(
        waypoint(&[], [7.0, -7.0], &[0.0, 0.0], 4),
        [7.0, -7.0],
        "an empty route gives the frontier itself"
    );
}

/// A route that runs along a corridor and turns back under it (a U-turn, as PointMaze-S's
/// route at a fold): x = 0, 2, …, 12 at y = 0, down to (12, 2) and (12, 4), back along y = 4 to
/// x = 0. Indices 0–6 on the first leg, 7–8 in the turn, 9–14 on the way back.
fn u_route() -> Vec<LatentPoint> {
    let out = (0..7).map(|i| [2.0 * i as f32, 0.0]);
    let turn = [[12.0, 2.0], [12.0, 4.0]];
    let back = (0..6).map(|i| [10.0 - 2.0 * i as f32, 4.0]);
    out.chain(turn).chain(back).collect()
}

#[test]
fn the_fold_cut_stops_the_waypoint_where_the_route_turns_back() {
    let route = u_route();
    let at = [2.2, -0.5]; // nearest: index 1, (2, 0)
                          // Without the cut: k = 8 past index 1 is index 9, (10, 4), on the way back, 8 away from
                          // (2, 0) in a straight line, through the wall between the legs.
    assert_eq!(waypoint_index(&route, &at, 8), Some(9));
    assert_eq!(
        straight_waypoint_index(&route, &at, 8, 0.0),
        Some((9, false))
    );
    // Straight distances from (2, 0) over route lengths: index 6 10/10, 7 √104/12 = 0.850,
    // 8 √116/14 = 0.769, 9 √80/16 = 0.559.
    assert_eq!(
        straight_waypoint_index(&route, &at, 8, 0.9),
        Some((6, true))
    );
    assert_eq!(
        straight_waypoint_index(&route, &at, 8, 0.8),
        Some((7, true))
    );
    assert_eq!(
        straight_waypoint_index(&route, &at, 8, 0.7),
        Some((8, true))
    );
    assert_eq!(
        straight_waypoint_index(&route, &at, 8, 0.5),
        Some((9, false))
    );
    // Before the turn nothing is cut; the cut never goes below one point past the nearest.
    assert_eq!(
        straight_waypoint_index(&route, &at, 4, 1.0),
        Some((5, false))
    );
    assert_eq!(
        straight_waypoint_index(&route, &[12.1, 2.0], 3, 1.0),
        Some((8, true))
    );
    assert_eq!(
        straight_waypoint_index(&route, &[12.0, 0.1], 3, 1.0),
        Some((8, true))
    );
    assert_eq!(
        straight_waypoint_index(&route, &[8.0, 4.1], 5, 1.0),
        Some((14, false))
    );
    assert_eq!(
        straight_waypoint_index(&route, &[0.0, 4.0], 3, 1.0),
        Some((14, false))
    );
    assert_eq!(straight_waypoint_index(&[], &at, 3, 0.9), None);
}

/// The fold cut by its definition, in f64: the largest j in (nearest, nearest + k] (clamped)
/// such that every i in (nearest, j] has straight ≥ r · along, at least nearest + 1.
fn straight_waypoint_brute(route: &[LatentPoint], at: &[f32], k: u32, r: f64) -> (usize, bool) {
    let n = nearest_route_index(route, at).unwrap();
    let end = (n + k as usize).min(route.len() - 1);
    let dist = |a: &LatentPoint, b: &LatentPoint| {
        (f64::from(a[0]) - f64::from(b[0])).hypot(f64::from(a[1]) - f64::from(b[1]))
    };
    let straight_to = |j: usize| {
        (n + 1..=j).all(|i| {
            let along: f64 = (n + 1..=i).map(|m| dist(&route[m], &route[m - 1])).sum();
            i == n + 1 || dist(&route[i], &route[n]) >= r * along
        })
    };
    let j = (n + 1..=end).rev().find(|&j| straight_to(j)).unwrap_or(end);
    (j, j < end)
}

#[test]
fn the_fold_cut_agrees_with_its_definition_on_random_routes() {
    use rand::Rng;
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    let mut cuts = 0;
    for _ in 0..2_000 {
        let len = rng.random_range(1..12);
        // A random walk of unit-ish steps that often turns.
        let mut p = [0.0f32, 0.0];
        let route: Vec<LatentPoint> = (0..len)
            .map(|_| {
                let angle: f32 = rng.random_range(0.0..std::f32::consts::TAU);
                let step: f32 = rng.random_range(0.5..2.0);
                p = [p[0] + step * angle.cos(), p[1] + step * angle.sin()];
                p
            })
            .collect();
        let at = [rng.random_range(-5.0..5.0), rng.random_range(-5.0..5.0)];
        let k = rng.random_range(1..8);
        let r: f32 = rng.random_range(0.1..1.0);
        let got = straight_waypoint_index(&route, &at, k, r).unwrap();
        assert_eq!(
            got,
            straight_waypoint_brute(&route, &at, k, f64::from(r)),
            "{route:?} at {at:?}, k {k}, r {r}"
        );
        cuts += usize::from(got.1);
    }
    assert!(cuts > 200, "the random routes exercise the cut: {cuts}");
}

#[test]
fn navigation_with_the_fold_cut_takes_the_turn_and_says_so() {
    let mut fr = FrontierEpisode::new(found(u_route(), [0.0, 4.0]));
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut oracle = ScriptedOracle::new(no_route);
    let p = FrontierParams {
        k_range: [6, 6],
        straightness: 0.9,
        ..params()
    };
    // Nearest index 1: k = 6 would take index 7 in the turn; cut back to index 6, the corner.
    let decided = fr
        .decide([2.2, -20.0], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(
        decided.choice,
        FrChoice::Waypoint {
            k: 6,
            index: Some(6),
            cut: true
        }
    );
    assert_eq!(decided.subgoal, [12.0, 0.0]);
    assert_eq!(decided.decision_kind(), DecisionKind::FrontierRoute);
}

#[test]
fn navigation_draws_k_in_the_inclusive_range_and_takes_that_node() {
    let mut fr = FrontierEpisode::new(found(
        (0..40).map(|i| [i as f32, 0.0]).collect(),
        [39.0, 0.0],
    ));
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let mut oracle = ScriptedOracle::new(no_route);
    let mut seen = [false; 4];
    for i in 0..200 {
        // Move 2 units per decision along y so neither switch fires (30 from the frontier).
        let at = [0.2, 2.0 * i as f32 - 200.0];
        let decided = fr
            .decide(at, &params(), PhiVersion(0), &mut rng, &mut oracle)
            .unwrap();
        let FrChoice::Waypoint { k, index, cut } = decided.choice else {
            panic!("navigation expected, got {decided:?}");
        };
        assert!((3..=6).contains(&k), "k = {k}");
        assert_eq!(index, Some(k as usize));
        assert!(!cut, "a straight route is never cut");
        assert_eq!(decided.subgoal, [k as f32, 0.0]);
        assert_eq!(decided.decision_kind(), DecisionKind::FrontierRoute);
        assert!(decided.deterministic_low());
        seen[k as usize - 3] = true;
    }
    assert_eq!(seen, [true; 4], "every k of [3, 6] is drawn");
    assert!(oracle.candidates_asked.is_empty());
}

#[test]
fn within_epsilon_of_the_frontier_count_mode_starts_and_stays() {
    let mut fr = FrontierEpisode::new(found(x_route(), [18.0, 0.0]));
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut oracle = ScriptedOracle::new(no_route);
    let far = fr
        .decide([10.0, 0.0], &params(), PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(
        (far.switch, far.decision_kind()),
        (None, DecisionKind::FrontierRoute)
    );
    // 8.0 away is not within ε = 8 (strict); 7.9 is.
    let at_eps = fr.decide([18.0, 8.0], &params(), PhiVersion(0), &mut rng, &mut oracle);
    assert_eq!(
        at_eps.unwrap().switch,
        None,
        "exactly ε away is not within ε"
    );
    let near = fr
        .decide([18.0, 7.9], &params(), PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(near.switch, Some(Switch::NearFrontier));
    assert_eq!(near.decision_kind(), DecisionKind::FrontierCount);
    assert!(
        !near.deterministic_low(),
        "count mode keeps the exploration noise"
    );
    assert!(fr.is_active() && fr.in_count_mode());
    // Far again: count mode stays, no second switch, FR mode still on.
    let later = fr
        .decide([0.0, 30.0], &params(), PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(
        (later.switch, later.decision_kind()),
        (None, DecisionKind::FrontierCount)
    );
    assert!(fr.is_active());
}

#[test]
fn with_near_frontier_end_fr_the_switching_decision_is_count_mode_and_fr_mode_ends() {
    let mut fr = FrontierEpisode::new(found(x_route(), [18.0, 0.0]));
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let mut oracle = ScriptedOracle::new(no_route);
    let p = FrontierParams {
        end_at_frontier: true,
        ..params()
    };
    let far = fr
        .decide([10.0, 0.0], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(far.decision_kind(), DecisionKind::FrontierRoute);
    assert!(fr.is_active());
    let near = fr
        .decide([18.0, 7.9], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(
        (near.switch, near.decision_kind()),
        (Some(Switch::NearFrontier), DecisionKind::FrontierCount)
    );
    assert_eq!(oracle.candidates_asked.len(), 1);
    assert!(!fr.is_active(), "later decisions leave FR mode");
}

#[test]
fn stuck_over_the_two_previous_decisions_switches_to_count_mode_and_ends_fr_mode() {
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let mut oracle = ScriptedOracle::new(no_route);
    let mut fr = FrontierEpisode::new(found(x_route(), [18.0, 0.0]));
    let p = params();
    let first = fr
        .decide([0.0, 0.0], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    let second = fr
        .decide([0.5, 0.0], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(
        (first.switch, second.switch),
        (None, None),
        "two previous points needed"
    );
    let third = fr
        .decide([0.5, 0.5], &p, PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(third.switch, Some(Switch::Stuck));
    assert_eq!(
        third.decision_kind(),
        DecisionKind::FrontierCount,
        "the stuck decision itself is count mode"
    );
    assert!(!fr.is_active(), "later decisions leave FR mode");

    // Moved ≥ 1 from the decision two back: not stuck.
    let mut moving = FrontierEpisode::new(found(x_route(), [18.0, 0.0]));
    for at in [[0.0, 0.0], [0.6, 0.0], [1.2, 0.0], [1.8, 0.0]] {
        let d = moving
            .decide(at, &p, PhiVersion(0), &mut rng, &mut oracle)
            .unwrap();
        assert_eq!(d.switch, None, "at {at:?}");
    }
    assert!(moving.is_active());
}

#[test]
fn the_navigation_end_reports_progress_along_the_route_and_the_distance_off_it() {
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut oracle = ScriptedOracle::new(no_route);
    let mut fr = FrontierEpisode::new(found(x_route(), [18.0, 0.0]));
    let p = params();
    for at in [[0.0, 0.0], [3.0, 0.0]] {
        fr.decide(at, &p, PhiVersion(0), &mut rng, &mut oracle)
            .unwrap();
    }
    // Nearest node of (7.1, 3) is x = 8 (index 4 of 0..=9): progress 4/9, off the route by
    // √(0.9² + 3²), 3 from y = 0 and 10.9 short of x = 18 in φ; xy = the observation's first two.
    let end = fr.navigation_end(FrOutcome::Stuck, &[7.1, 3.0], &[1.5, -2.5, 9.0]);
    let off = (0.9f32 * 0.9 + 9.0).sqrt();
    let to_frontier = (10.9f32 * 10.9 + 9.0).sqrt();
    assert_eq!(end.outcome, FrOutcome::Stuck);
    assert!((end.route_progress - 4.0 / 9.0).abs() < 1e-6, "{end:?}");
    assert!((end.off_route - off).abs() < 1e-5, "{end:?}");
    assert!(
        (end.frontier_distance - to_frontier).abs() < 1e-5,
        "{end:?}"
    );
    assert_eq!((end.xy, end.waypoint_decisions), ([1.5, -2.5], 2));
    // The ends of the route, a one-node route, and an observation without y.
    let at_start = fr.navigation_end(FrOutcome::Navigating, &[-1.0, 0.0], &[0.0]);
    assert_eq!(at_start.route_progress, 0.0);
    assert!(at_start.xy[1].is_nan());
    let at_last = fr.navigation_end(FrOutcome::Navigating, &[30.0, 0.0], &[0.0, 0.0]);
    assert_eq!((at_last.route_progress, at_last.off_route), (1.0, 12.0));
    let single = FrontierEpisode::new(found(vec![[1.0, 1.0]], [1.0, 1.0]));
    let end = single.navigation_end(FrOutcome::NearFrontier, &[1.0, 2.0], &[0.0, 0.0]);
    assert_eq!(
        (end.route_progress, end.off_route, end.waypoint_decisions),
        (1.0, 1.0, 0)
    );
}

#[test]
fn count_mode_draws_candidates_in_the_box_and_takes_the_oracles_least_visited() {
    let mut fr = FrontierEpisode::new(found(vec![[1.0, 1.0]], [1.0, 1.0]));
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut oracle = ScriptedOracle::new(no_route);
    let at = [2.0, -3.0];
    let decided = fr
        .decide(at, &params(), PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(decided.choice, FrChoice::Count { fallback: false });
    let candidates = &oracle.candidates_asked[0];
    assert_eq!(candidates.len(), 100);
    for c in candidates {
        assert!(
            (c[0] - at[0]).abs() <= 10.0 && (c[1] - at[1]).abs() <= 10.0,
            "{c:?}"
        );
    }
    assert_eq!(decided.subgoal, candidates[least_x(candidates)]);
    // The candidates are the documented draw: the same generator state gives the same points.
    let mut replay = Pcg64Mcg::seed_from_u64(3);
    assert_eq!(&count_candidates(at, 10.0, 100, &mut replay), candidates);

    oracle.answer_least_visited = false;
    let unanswered = fr
        .decide(at, &params(), PhiVersion(0), &mut rng, &mut oracle)
        .unwrap();
    assert_eq!(unanswered.choice, FrChoice::Count { fallback: true });
    assert_eq!(
        unanswered.subgoal, oracle.candidates_asked[1][0],
        "the first candidate"
    );
}

#[test]
fn the_draw_asks_for_a_route_only_when_fr_is_on_and_fr_prob_is_positive() {
    let phi0 = [0.5, 0.25];
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    let mut oracle = ScriptedOracle::new(straight_route);
    let p = params();
    let off = assign(None, 1.0, &phi0, PhiVersion(0), &mut rng, &mut oracle).unwrap();
    let zero = assign(Some(&p), 0.0, &phi0, PhiVersion(0), &mut rng, &mut oracle).unwrap();
    assert_eq!((off, zero), (Assignment::Normal, Assignment::Normal));
    assert!(oracle.frontier_asked.is_empty());
    let Assignment::Frontier(fr) =
        assign(Some(&p), 1.0, &phi0, PhiVersion(0), &mut rng, &mut oracle).unwrap()
    else {
        panic!("fr_prob = 1 with a route is an FR episode");
    };
    assert_eq!(oracle.frontier_asked, vec![phi0]);
    assert_eq!(fr.route().len(), 16);
    let mut none = ScriptedOracle::new(no_route);
    let fallback = assign(Some(&p), 1.0, &phi0, PhiVersion(0), &mut rng, &mut none).unwrap();
    assert_eq!(fallback, Assignment::NoRoute);
    let drawn = (0..1000)
        .filter(|_| {
            let a = assign(Some(&p), 0.25, &phi0, PhiVersion(0), &mut rng, &mut oracle);
            matches!(a.unwrap(), Assignment::Frontier(_))
        })
        .count();
    assert!(
        (170..330).contains(&drawn),
        "fr_prob 0.25 over 1000 draws: {drawn}"
    );
}

#[test]
fn future_count_scoring_is_accepted_and_left_to_the_graph_service() {
    let mut config = Config::default();
    config.asi.count_mode_score = protocol::config::CountModeScore::FutureCount;
    assert!(config.validate().is_ok());
    let mut default = Config::default();
    default.asi.count_mode_score = protocol::config::CountModeScore::GraphVisits;
    assert_eq!(
        FrontierParams::from_config(&config).unwrap(),
        FrontierParams::from_config(&default).unwrap(),
        "the actor's count mode is the same; the graph-service scores the candidates"
    );
}

// ---------------------------------------------------------------------------------------------
// FR episodes of a real actor on point-maze U
// ---------------------------------------------------------------------------------------------

/// Point maze U, small networks, c = 10, 100 steps: 10 decisions per episode.
fn config() -> Config {
    common::config(50, 100)
}

fn fr_schedule(fr_prob: f32) -> RunSchedule {
    RunSchedule {
        train_episodes: 0,
        count_prob: 0.0,
        fr_prob,
    }
}

/// Reloads the actor's own weights with `schedule` and φ version `phi_version`.
fn reload(actor: &mut Actor, schedule: RunSchedule, phi_version: u64) {
    let bytes = actor.weights_bytes().unwrap();
    let header = WeightsHeader::new(
        PolicyVersion(phi_version),
        PhiVersion(phi_version),
        actor.layout_hash(),
        bytes.len(),
    )
    .with_schedule(schedule);
    actor.load_weights(&header, &bytes).unwrap();
}

fn actor(config: &Config, seed: u64, fr_prob: f32) -> Actor {
    let mut actor = Actor::new(config, ActorId(0), seed).unwrap();
    reload(&mut actor, fr_schedule(fr_prob), 1);
    actor
}

fn decisions(chunks: &[Chunk]) -> Vec<StepRecord> {
    chunks
        .iter()
        .flat_map(decode)
        .filter(|r| r.decision.is_decision())
        .collect()
}

fn kinds(records: &[StepRecord]) -> Vec<DecisionKind> {
    records.iter().map(|r| r.decision).collect()
}

#[test]
fn an_fr_episode_follows_the_route_with_waypoints_k_nodes_ahead_and_a_far_goal() {
    let mut config = config();
    config.asi.stuck_threshold = 0.0; // never stuck: every decision navigates
    let mut actor = actor(&config, 7, 1.0);
    let mut oracle = ScriptedOracle::new(straight_route);
    let chunks = episode(&mut actor, &mut oracle);
    let records: Vec<StepRecord> = chunks.iter().flat_map(decode).collect();
    assert_eq!(
        oracle.frontier_asked,
        vec![[records[0].phi[0], records[0].phi[1]]]
    );
    let route = straight_route(oracle.frontier_asked[0]).unwrap().route;
    let decided = decisions(&chunks);
    assert_eq!(kinds(&decided), vec![DecisionKind::FrontierRoute; 10]);
    let mut ks = Vec::new();
    for r in &decided {
        // Brute force: the nearest node, then which k in [3, 6] gives the recorded subgoal.
        let nearest = (0..route.len())
            .min_by(|&a, &b| dist(&route[a], &r.phi).total_cmp(&dist(&route[b], &r.phi)))
            .unwrap();
        let index = route
            .iter()
            .position(|p| p[..] == r.subgoal[..])
            .expect("a route node");
        let k = index - nearest;
        assert!((3..=6).contains(&k) || index == route.len() - 1, "k = {k}");
        ks.push(k);
        let delta: Vec<f32> = r.subgoal.iter().zip(&r.phi).map(|(s, p)| s - p).collect();
        assert_eq!(
            r.high_action, delta,
            "stored action = subgoal − φ(s_t), unclipped"
        );
    }
    // What the segments report to the potential: `with_every_all_fr_segments_but_the_last_*`
    // and `with_count_draw_*` below.
    ks.sort_unstable();
    ks.dedup();
    assert!(ks.len() > 1, "k is drawn per decision: {ks:?}");
    assert!(
        chunks.iter().all(|c| c.header.flags.contains(F::FAR_GOAL)),
        "FR episodes get a far goal"
    );
    assert!(
        chunks.iter().all(|c| c.header.flags.contains(F::FRONTIER)),
        "every chunk of an FR episode is flagged FRONTIER"
    );
    let maze = envs::make("pointmaze-u").unwrap();
    let goal = [records[0].goal[0], records[0].goal[1]];
    assert!(maze
        .maze()
        .unwrap()
        .is_far_goal_with_fraction(goal, config.exploration.far_goal_fraction));
    let stats = actor.stats().frontier;
    assert_eq!((stats.n_episodes, stats.n_no_route), (1, 0));
    assert_eq!(
        (stats.n_waypoint_decisions, stats.n_count_decisions),
        (10, 0)
    );
    assert_eq!(actor.stats().n_decisions, 10);
    // Never stuck, never near the frontier: the episode ends navigating, at its last state.
    assert_eq!(outcomes(&stats), (0, 0, 0, 1));
    let last = records.last().unwrap();
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!(end.outcome, FrOutcome::Navigating);
    assert_eq!(end.xy, [last.next_obs[0], last.next_obs[1]]);
    assert_eq!(end.waypoint_decisions, 10);
    assert_nav_end(&end, &route, &last.next_phi);
    assert_eq!(actor.stats().last_fr_episode, actor.stats().episodes);
}

/// `end`'s route progress, distance off the route and to the frontier (the last route node)
/// at φ = `at`, by brute force.
fn assert_nav_end(end: &FrEnd, route: &[LatentPoint], at: &[f32]) {
    let nearest = (0..route.len())
        .min_by(|&a, &b| dist(&route[a], at).total_cmp(&dist(&route[b], at)))
        .unwrap();
    let progress = nearest as f32 / (route.len() - 1) as f32;
    assert!((end.route_progress - progress).abs() < 1e-6, "{end:?}");
    assert!(
        (end.off_route - dist(&route[nearest], at)).abs() < 1e-4,
        "{end:?}"
    );
    let frontier = route.last().unwrap();
    assert!(
        (end.frontier_distance - dist(frontier, at)).abs() < 1e-4,
        "{end:?}"
    );
}

fn dist(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

/// The finished FR episodes by how their navigation ended: near the frontier, stuck, new φ,
/// still navigating (the four counters add up to the finished FR episodes).
fn outcomes(stats: &actor::FrontierStats) -> (u64, u64, u64, u64) {
    (
        stats.n_near_frontier_switches,
        stats.n_stuck_while_navigating,
        stats.n_new_phi_while_navigating,
        stats.n_navigating_at_end,
    )
}

#[test]
fn a_stuck_fr_episode_counts_once_then_decides_with_its_normal_source() {
    let mut config = config();
    config.asi.stuck_threshold = 1.0e6; // always stuck once two decisions are behind
    let mut actor = actor(&config, 8, 1.0);
    let mut oracle = ScriptedOracle::new(straight_route);
    let decided = decisions(&episode(&mut actor, &mut oracle));
    let mut expected = vec![DecisionKind::FrontierRoute; 2];
    expected.push(DecisionKind::FrontierCount);
    expected.extend([DecisionKind::Random; 7]); // the actor's first episode is a random one
    assert_eq!(kinds(&decided), expected);
    let candidates = &oracle.candidates_asked;
    assert_eq!(candidates.len(), 1);
    assert_eq!(decided[2].subgoal, candidates[0][least_x(&candidates[0])]);
    let stats = actor.stats().frontier;
    assert_eq!(
        (stats.n_stuck_switches, stats.n_near_frontier_switches),
        (1, 0)
    );
    assert_eq!(
        (stats.n_waypoint_decisions, stats.n_count_decisions),
        (2, 1)
    );
    // The navigation ended at the stuck decision, after two waypoints.
    assert_eq!(outcomes(&stats), (0, 1, 0, 0));
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!((end.outcome, end.waypoint_decisions), (FrOutcome::Stuck, 2));
    assert_eq!(end.xy, [decided[2].obs[0], decided[2].obs[1]]);
    let route = straight_route(oracle.frontier_asked[0]).unwrap().route;
    assert_nav_end(&end, &route, &decided[2].phi);
}

#[test]
fn near_the_frontier_every_decision_is_the_least_visited_candidate() {
    let mut config = config();
    config.asi.stuck_threshold = 0.0;
    let mut actor = actor(&config, 9, 1.0);
    let mut oracle = ScriptedOracle::new(frontier_here);
    let decided = decisions(&episode(&mut actor, &mut oracle));
    assert_eq!(kinds(&decided), vec![DecisionKind::FrontierCount; 10]);
    assert_eq!(oracle.candidates_asked.len(), 10);
    for (r, candidates) in decided.iter().zip(&oracle.candidates_asked) {
        assert_eq!(r.subgoal, candidates[least_x(candidates)]);
        for c in candidates {
            assert!(dist(c, &r.phi) <= 10.0 * 2f32.sqrt() + 1e-4);
        }
    }
    let stats = actor.stats().frontier;
    assert_eq!(
        (stats.n_near_frontier_switches, stats.n_count_decisions),
        (1, 10)
    );
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!(
        (end.outcome, end.waypoint_decisions, end.route_progress),
        (FrOutcome::NearFrontier, 0, 1.0)
    );
    assert_eq!(end.xy, [decided[0].obs[0], decided[0].obs[1]]);
    assert_eq!(outcomes(&stats), (1, 0, 0, 0));
}

#[test]
fn a_stuck_switch_after_the_frontier_is_not_counted_as_stuck_while_navigating() {
    let mut config = config();
    config.asi.frontier_epsilon = 1.0e-4; // near the frontier only where the episode starts
    config.asi.stuck_threshold = 1.0e6; // stuck once two decisions are behind
    let mut actor = actor(&config, 9, 1.0);
    let mut oracle = ScriptedOracle::new(frontier_here);
    let decided = decisions(&episode(&mut actor, &mut oracle));
    assert!(
        dist(&decided[1].phi, &decided[0].phi) > 1.0e-4,
        "the test needs φ to move off the frontier"
    );
    // Near the frontier at t = 0 (count mode), stuck at t = 20 (FR mode ends).
    let mut expected = vec![DecisionKind::FrontierCount; 3];
    expected.extend([DecisionKind::Random; 7]); // the actor's first episode is a random one
    assert_eq!(kinds(&decided), expected);
    let stats = actor.stats().frontier;
    assert_eq!(
        (stats.n_near_frontier_switches, stats.n_stuck_switches),
        (1, 1)
    );
    assert_eq!(outcomes(&stats), (1, 0, 0, 0));
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!(end.outcome, FrOutcome::NearFrontier);
}

#[test]
fn with_near_frontier_end_fr_an_episode_at_its_frontier_decides_once_in_count_mode_then_normally() {
    let mut config = config();
    config.asi.stuck_threshold = 0.0;
    config.asi.near_frontier = protocol::config::NearFrontier::EndFr;
    let mut actor = actor(&config, 9, 1.0);
    let mut oracle = ScriptedOracle::new(frontier_here);
    let decided = decisions(&episode(&mut actor, &mut oracle));
    let mut expected = vec![DecisionKind::FrontierCount];
    expected.extend([DecisionKind::Random; 9]); // the actor's first episode is a random one
    assert_eq!(kinds(&decided), expected);
    assert_eq!(oracle.candidates_asked.len(), 1);
    let stats = actor.stats().frontier;
    assert_eq!(
        (stats.n_near_frontier_switches, stats.n_count_decisions),
        (1, 1)
    );
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!(end.outcome, FrOutcome::NearFrontier);
}

#[test]
fn without_a_route_the_episode_is_normal_and_the_fallback_is_counted() {
    let mut actor = actor(&config(), 10, 1.0);
    let mut oracle = ScriptedOracle::new(no_route);
    for _ in 0..2 {
        let decided = decisions(&episode(&mut actor, &mut oracle));
        assert!(kinds(&decided)
            .iter()
            .all(|k| matches!(k, DecisionKind::Random | DecisionKind::Policy)));
    }
    assert_eq!(oracle.frontier_asked.len(), 2);
    let stats = actor.stats().frontier;
    assert_eq!(
        (stats.n_episodes, stats.n_no_route, stats.n_goals_forced),
        (0, 2, 0)
    );
    assert_eq!(actor.stats().last_fr_end, None, "no FR episode ran");
}

#[test]
fn no_fr_episode_when_the_switch_is_off_or_fr_prob_is_zero() {
    let mut off = config();
    off.asi.frontier_reaching = false;
    for (config, fr_prob) in [(off, 1.0), (config(), 0.0)] {
        let mut actor = actor(&config, 11, fr_prob);
        let mut oracle = ScriptedOracle::new(straight_route);
        for _ in 0..2 {
            let decided = decisions(&episode(&mut actor, &mut oracle));
            assert!(kinds(&decided)
                .iter()
                .all(|k| matches!(k, DecisionKind::Random | DecisionKind::Policy)));
        }
        assert!(oracle.frontier_asked.is_empty());
        assert_eq!(actor.stats().frontier, actor::FrontierStats::default());
    }
}

#[test]
fn a_new_phi_mid_episode_ends_fr_mode() {
    let mut config = config();
    config.asi.stuck_threshold = 0.0;
    let mut actor = actor(&config, 12, 1.0);
    let mut oracle = ScriptedOracle::new(straight_route);
    // A chunk of 50 records is cut once the 51st step is taken: 6 decisions (t = 0, 10, …, 50).
    let first = actor.next_chunk(&mut oracle).unwrap();
    reload(&mut actor, fr_schedule(1.0), 2);
    let mut chunks = vec![first];
    chunks.extend(episode(&mut actor, &mut oracle));
    let decided = decisions(&chunks);
    let mut expected = vec![DecisionKind::FrontierRoute; 6];
    expected.extend([DecisionKind::Random; 4]);
    assert_eq!(kinds(&decided), expected);
    assert_eq!(actor.stats().frontier.n_ended_by_new_phi, 1);
    assert_eq!(outcomes(&actor.stats().frontier), (0, 0, 1, 0));
    let end = actor.stats().last_fr_end.expect("an FR episode finished");
    assert_eq!(
        (end.outcome, end.waypoint_decisions),
        (FrOutcome::NewPhi, 6)
    );
}

#[test]
fn a_new_phi_after_the_frontier_ends_fr_mode_but_not_navigation() {
    let mut config = config();
    config.asi.stuck_threshold = 0.0;
    let mut actor = actor(&config, 12, 1.0);
    let mut oracle = ScriptedOracle::new(frontier_here);
    let first = actor.next_chunk(&mut oracle).unwrap();
    reload(&mut actor, fr_schedule(1.0), 2);
    let mut chunks = vec![first];
    chunks.extend(episode(&mut actor, &mut oracle));
    let mut expected = vec![DecisionKind::FrontierCount; 6];
    expected.extend([DecisionKind::Random; 4]);
    assert_eq!(kinds(&decisions(&chunks)), expected);
    let stats = actor.stats().frontier;
    assert_eq!(stats.n_ended_by_new_phi, 1, "FR mode (count mode) ended");
    assert_eq!(
        outcomes(&stats),
        (1, 0, 0, 0),
        "navigation ended at the frontier"
    );
}

// ---------------------------------------------------------------------------------------------
// The protocol side: ServiceOracle's FR questions
// ---------------------------------------------------------------------------------------------

/// Answers every request with `response` (status `Ok`), recording the requests.
struct Canned {
    response: GraphResponse,
    requests: Vec<GraphRequest>,
}

impl GraphTransport for Canned {
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String> {
        let request: GraphRequest = protocol::decode(body).map_err(|e| e.to_string())?;
        assert_eq!(header.kind().unwrap(), request.kind());
        self.requests.push(request);
        let reply = GraphResponseHeader::answering(header, GraphStatus::Ok, 3, PhiVersion(2));
        Ok((reply, protocol::encode(&self.response).unwrap()))
    }
}

fn service(response: GraphResponse) -> ServiceOracle<Canned> {
    ServiceOracle::new(Canned {
        response,
        requests: Vec::new(),
    })
}

#[test]
fn the_service_oracle_asks_for_frontiers_and_refuses_unusable_routes() {
    let good = straight_route([1.0, 2.0]).unwrap();
    let mut oracle = service(GraphResponse::FrontierRoute(Ok(good.clone())));
    let answer = oracle.frontier_route([1.0, 2.0], PhiVersion(2)).unwrap();
    assert_eq!(answer, Some(good.clone()));
    assert_eq!(
        oracle.transport().requests,
        vec![GraphRequest::FrontierRoute { from: [1.0, 2.0] }]
    );
    let mut nan_route = good.clone();
    nan_route.route[3][1] = f32::NAN;
    let mut inf_distance = good;
    inf_distance.distance = f32::INFINITY;
    for bad in [
        GraphResponse::FrontierRoute(Ok(nan_route)),
        GraphResponse::FrontierRoute(Ok(inf_distance)),
        GraphResponse::FrontierRoute(Err(NoRouteReason::StartUnknown)),
        GraphResponse::Ack,
    ] {
        let mut oracle = service(bad.clone());
        assert_eq!(
            oracle.frontier_route([1.0, 2.0], PhiVersion(2)).unwrap(),
            None,
            "{bad:?}"
        );
    }
}

#[test]
fn the_service_oracle_takes_only_in_range_finite_least_visited_answers() {
    let candidates = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]];
    let mut oracle = service(GraphResponse::LeastVisited {
        index: 2,
        visits: 4.0,
    });
    let answer = oracle.least_visited(&candidates, PhiVersion(2)).unwrap();
    assert_eq!(
        answer,
        Some(LeastVisitedAnswer {
            index: 2,
            visits: 4.0
        })
    );
    assert_eq!(
        oracle.transport().requests,
        vec![GraphRequest::LeastVisited {
            candidates: candidates.to_vec()
        }]
    );
    for (index, visits) in [(3, 0.0), (0, f32::NAN), (0, -1.0)] {
        let mut oracle = service(GraphResponse::LeastVisited { index, visits });
        let answer = oracle.least_visited(&candidates, PhiVersion(2)).unwrap();
        assert_eq!(answer, None, "index {index}, visits {visits}");
    }
}

#[test]
fn fr_episodes_replay_exactly_for_a_seed() {
    let run = || {
        let mut actor = actor(&config(), 13, 0.5);
        let mut oracle = ScriptedOracle::new(straight_route);
        let chunks: Vec<Vec<f32>> = (0..4)
            .flat_map(|_| episode(&mut actor, &mut oracle))
            .map(|c| c.records)
            .collect();
        (chunks, actor.stats().frontier)
    };
    let (first, stats) = run();
    assert!(
        stats.n_episodes > 0,
        "fr_prob 0.5 over 4 episodes drew FR: {stats:?}"
    );
    assert_eq!(run(), (first, stats));
}

/// The actions of the first episode of an actor on the deterministic low level with the given
/// exploration noise, under `fr_prob`.
fn low_actions(noise_scale: f64, random_eps: f64, fr_prob: f32) -> Vec<Vec<f32>> {
    low_actions_with(noise_scale, random_eps, fr_prob, true)
}

/// [`low_actions`] with `asi.fr_noise_free_low` set to `noise_free`.
fn low_actions_with(
    noise_scale: f64,
    random_eps: f64,
    fr_prob: f32,
    noise_free: bool,
) -> Vec<Vec<f32>> {
    let mut config = config();
    config.asi.stuck_threshold = 0.0;
    config.asi.fr_noise_free_low = noise_free;
    config.learner.low.algo = protocol::config::LowAlgo::Deterministic;
    config.learner.low.deterministic.actor_hidden = vec![32, 32];
    config.learner.low.deterministic.critic_hidden = vec![32, 32];
    config.learner.low.deterministic.noise_scale = noise_scale;
    config.learner.low.deterministic.random_eps = random_eps;
    let mut actor = actor(&config, 14, fr_prob);
    let mut oracle = ScriptedOracle::new(straight_route);
    episode(&mut actor, &mut oracle)
        .iter()
        .flat_map(decode)
        .map(|r| r.action)
        .collect()
}

#[test]
fn the_low_level_navigates_without_exploration_noise() {
    // Same seed, same weights, different noise settings: in navigation segments no noise is
    // drawn or added, so the whole FR episode is the same step for step.
    assert_eq!(low_actions(0.1, 0.0, 1.0), low_actions(0.5, 0.3, 1.0));
    // Control: in a normal episode the noise settings change the actions.
    assert_ne!(low_actions(0.1, 0.0, 0.0), low_actions(0.5, 0.3, 0.0));
}

#[test]
fn with_fr_noise_free_low_off_navigation_keeps_the_exploration_noise() {
    // The same FR episode as above with the noise left on: the noise settings change it.
    assert_ne!(
        low_actions_with(0.1, 0.0, 1.0, false),
        low_actions_with(0.5, 0.3, 1.0, false)
    );
}

/// `episodes` FR episodes (every decision navigates) of one actor under `reports`, with the
/// schedule's `count_prob` and HESS exploration open or not: each episode's decisions and
/// the reaching samples reported during it.
fn fr_reports(
    reports: FrPotentialReports,
    count_prob: f32,
    explore_open: bool,
    episodes: usize,
) -> Vec<(Vec<StepRecord>, Vec<ReachSample>)> {
    let mut config = config();
    config.asi.stuck_threshold = 0.0; // every decision navigates
    config.asi.fr_potential_reports = reports;
    let schedule = RunSchedule {
        train_episodes: if explore_open {
            config.exploration.explore_start_episode + 1
        } else {
            0
        },
        count_prob,
        fr_prob: 1.0,
    };
    let mut actor = Actor::new(&config, ActorId(0), 7).unwrap();
    reload(&mut actor, schedule, 1);
    (0..episodes)
        .map(|_| {
            let mut oracle = ScriptedOracle::new(straight_route);
            let decided = decisions(&episode(&mut actor, &mut oracle));
            assert_eq!(kinds(&decided), vec![DecisionKind::FrontierRoute; 10]);
            (decided, oracle.reported)
        })
        .collect()
}

/// Asserts that the samples are, in order, the reaching errors of distinct segments of
/// `decided` other than the last (‖subgoal − φ(s_{t+c})‖ at the segment's waypoint, digest
/// §5.3): returns the indices of the reporting segments.
fn reporting_segments(decided: &[StepRecord], reported: &[ReachSample]) -> Vec<usize> {
    // Samples come in segment order; a waypoint can repeat, so each sample is matched to the
    // first later segment with its subgoal and error.
    let mut next = 0;
    reported
        .iter()
        .map(|sample| {
            let i = (next..decided.len().saturating_sub(1))
                .find(|&i| {
                    sample.subgoal == [decided[i].subgoal[0], decided[i].subgoal[1]]
                        && (sample.error - dist(&decided[i].subgoal, &decided[i + 1].phi)).abs()
                            < 1e-5
                })
                .unwrap_or_else(|| panic!("{sample:?} is no later segment's reaching error"));
            next = i + 1;
            i
        })
        .collect()
}

fn subgoals(decided: &[StepRecord]) -> Vec<Vec<f32>> {
    decided.iter().map(|r| r.subgoal.clone()).collect()
}

#[test]
fn with_every_all_fr_segments_but_the_last_feed_the_potential() {
    let [(decided, reported)] = fr_reports(FrPotentialReports::Every, 0.0, false, 1)
        .try_into()
        .unwrap();
    assert_eq!(
        reporting_segments(&decided, &reported),
        (0..9).collect::<Vec<_>>()
    );
}

#[test]
fn with_off_no_fr_segment_reports_and_the_subgoals_stay_the_same() {
    let [(every, _)] = fr_reports(FrPotentialReports::Every, 0.5, true, 1)
        .try_into()
        .unwrap();
    let [(off, reported)] = fr_reports(FrPotentialReports::Off, 0.5, true, 1)
        .try_into()
        .unwrap();
    assert!(reported.is_empty());
    assert_eq!(subgoals(&off), subgoals(&every));
}

#[test]
fn with_count_draw_fr_segments_report_with_probability_count_prob() {
    // count_prob 1 (and exploration open): every segment reports, as with "every".
    for (decided, reported) in fr_reports(FrPotentialReports::CountDraw, 1.0, true, 3) {
        assert_eq!(
            reporting_segments(&decided, &reported),
            (0..9).collect::<Vec<_>>()
        );
    }
    // count_prob 0: none does.
    for (_, reported) in fr_reports(FrPotentialReports::CountDraw, 0.0, true, 3) {
        assert!(reported.is_empty());
    }
    // Exploration not open yet: no draw and no report, the subgoals of "every" (same seed).
    let [(closed, reported)] = fr_reports(FrPotentialReports::CountDraw, 1.0, false, 1)
        .try_into()
        .unwrap();
    assert!(reported.is_empty());
    let [(every, _)] = fr_reports(FrPotentialReports::Every, 1.0, false, 1)
        .try_into()
        .unwrap();
    assert_eq!(subgoals(&closed), subgoals(&every));
    // count_prob 0.3 over 40 episodes (360 reportable segments): about 30 % report (the
    // binomial standard deviation is 2.4 points), and each is a segment's own error.
    let mut n_reported = 0;
    let mut segments_hit = [0u32; 9];
    for (decided, reported) in fr_reports(FrPotentialReports::CountDraw, 0.3, true, 40) {
        for i in reporting_segments(&decided, &reported) {
            segments_hit[i] += 1;
            n_reported += 1;
        }
    }
    let fraction = f64::from(n_reported) / 360.0;
    assert!((0.2..0.4).contains(&fraction), "{fraction}");
    // Not tied to a position in the episode.
    assert!(segments_hit.iter().all(|&n| n > 0), "{segments_hit:?}");
}
