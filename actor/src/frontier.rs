//! Frontier-reaching (FR) episodes (paper "Exploration with Frontier-Reaching Episodes", Eq. 9–10;
//! SPEC §6.6; reference digest §2.2, §7) as pure logic over a [`GraphOracle`].
//!
//! - **Assignment** ([`assign`]), at episode start: with probability `schedule.fr_prob` (drawn
//!   only when `asi.frontier_reaching` is on and `fr_prob > 0`, so runs without FR draw nothing
//!   extra), the oracle is asked for the frontier g_F seen from φ(s_0) and the route to it. No
//!   answer → a normal episode ([`Assignment::NoRoute`], counted by the actor).
//! - **Each decision** of an FR episode ([`FrontierEpisode::decide`]), in the reference order:
//!   1. switch tests on ag = φ(s_t): within ε (`asi.frontier_epsilon`, strict `<`) of g_F →
//!      count mode for the rest of the episode ([`Switch::NearFrontier`]; with
//!      `asi.near_frontier = "end_fr"`, an experiment, for this decision only, then FR mode
//!      ends as after a stuck switch); otherwise, when the
//!      two previous FR decision points are both closer than `asi.stuck_threshold` to ag →
//!      count mode for this decision and FR mode ends ([`Switch::Stuck`]): later decisions
//!      use the normal HESS/policy sources (digest §7 item 1);
//!   2. navigation: the route point nearest to ag (Eq. 9, Euclidean, first on ties), then the
//!      point k further (k uniform in `asi.fr_k_range`, inclusive), clamped to the last node;
//!      an empty route gives g_F itself ([`waypoint`]). With `asi.fr_waypoint_straightness`
//!      r > 0, an experiment, the waypoint is cut back to where the route folds
//!      ([`straight_waypoint_index`]). The low level acts deterministically
//!      (with `asi.fr_noise_free_low = false`, an experiment, it keeps its noise);
//!   3. count mode: `asi.count_mode_candidates` points uniform in the ±abs_range box around ag,
//!      the least visited by the graph's n(v) (Eq. 10) chosen by the oracle; with no answer the
//!      first candidate is taken (counted). The low level keeps its exploration noise;
//!   4. prev2 ← prev, prev ← ag.
//! - **Potential reports**: whether the segment reports its reaching error to HESS's potential
//!   map at the next decision is the actor's business (`asi.fr_potential_reports`, see
//!   `Episode::decide_frontier`).
//! - The stored high action is `subgoal − φ(s_t)`, not clipped (as HESS explore decisions).
//!
//! Invariants: random numbers come only from the caller's generator, in a fixed order (k for a
//! waypoint; the candidates' coordinates, x then y, candidate by candidate, in count mode); the
//! route and g_F are points of the φ-space the episode started in (the actor ends FR mode when
//! a new φ arrives mid-episode, as those points would no longer mean anything).

use protocol::config::{FrPotentialReports, NearFrontier};
use protocol::graph::FrontierRoute;
use protocol::{Config, DecisionKind, LatentPoint, PhiVersion};
use rand::Rng;
use rand_pcg::Pcg64Mcg;

use crate::error::ActorError;
use crate::oracle::GraphOracle;

/// The FR parameters of a run (`[asi]` and `hierarchy.abs_range`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontierParams {
    /// Inclusive range of the waypoint offset k (`asi.fr_k_range`; route nodes).
    pub k_range: [u32; 2],
    /// Cut the waypoint where the route folds (`asi.fr_waypoint_straightness`; 0: never).
    pub straightness: f32,
    /// Count mode within this φ-distance of g_F (`asi.frontier_epsilon`, ε).
    pub epsilon: f32,
    /// Stuck when φ(s_t) is closer than this to both previous FR decision points
    /// (`asi.stuck_threshold`; φ units).
    pub stuck_threshold: f32,
    /// Count-mode candidates per decision (`asi.count_mode_candidates`).
    pub n_candidates: usize,
    /// Half-width of the candidate box (`hierarchy.abs_range`; φ units).
    pub abs_range: f32,
    /// FR mode ends after the near-frontier switch (`asi.near_frontier = "end_fr"`); false:
    /// count mode for the rest of the episode.
    pub end_at_frontier: bool,
    /// The low level navigates without exploration noise (`asi.fr_noise_free_low`).
    pub noise_free_navigation: bool,
    /// Which FR segments report their reaching error to the potential map
    /// (`asi.fr_potential_reports`).
    pub potential_reports: FrPotentialReports,
}

impl FrontierParams {
    /// The parameters of `config`; `Ok(None)` when `asi.frontier_reaching` is off. (How
    /// count-mode candidates are scored, `asi.count_mode_score`, is the graph-service's
    /// business: it answers `LeastVisited`.)
    pub fn from_config(config: &Config) -> Result<Option<Self>, ActorError> {
        let asi = &config.asi;
        if !asi.frontier_reaching {
            return Ok(None);
        }
        Ok(Some(Self {
            k_range: asi.fr_k_range,
            straightness: asi.fr_waypoint_straightness as f32,
            epsilon: asi.frontier_epsilon as f32,
            stuck_threshold: asi.stuck_threshold as f32,
            n_candidates: asi.count_mode_candidates,
            abs_range: config.hierarchy.abs_range as f32,
            end_at_frontier: asi.near_frontier == NearFrontier::EndFr,
            noise_free_navigation: asi.fr_noise_free_low,
            potential_reports: asi.fr_potential_reports,
        }))
    }
}

/// Counters of the FR part of an actor, over all its episodes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrontierStats {
    /// Episodes started in FR mode (a frontier route was answered).
    pub n_episodes: u64,
    /// Episodes drawn to be FR that fell back to normal ones: the oracle had no frontier route.
    pub n_no_route: u64,
    /// FR episodes whose env goal was forced to a far goal (digest §2.2).
    pub n_goals_forced: u64,
    /// FR decisions that took a route waypoint.
    pub n_waypoint_decisions: u64,
    /// Of those, the waypoints cut back where the route folds (`asi.fr_waypoint_straightness`).
    #[serde(default)]
    pub n_waypoints_cut: u64,
    /// FR decisions in count mode.
    pub n_count_decisions: u64,
    /// Count-mode decisions whose least-visited query got no answer (the first candidate was
    /// taken).
    pub n_count_fallbacks: u64,
    /// Switches to count mode because φ(s_t) came within ε of the frontier.
    pub n_near_frontier_switches: u64,
    /// Switches to count mode because the agent was stuck (FR mode ended). The test also runs
    /// in the count mode after a near-frontier switch, so this counts those too.
    pub n_stuck_switches: u64,
    /// Finished FR episodes whose navigation ended stuck, before the frontier
    /// ([`FrOutcome::Stuck`]; the stuck switches that ended navigation).
    #[serde(default)]
    pub n_stuck_while_navigating: u64,
    /// FR episodes whose FR mode ended because a new φ arrived mid-episode (also after a
    /// near-frontier switch, in count mode).
    pub n_ended_by_new_phi: u64,
    /// Finished FR episodes whose navigation a new φ ended ([`FrOutcome::NewPhi`]).
    #[serde(default)]
    pub n_new_phi_while_navigating: u64,
    /// FR episodes that ended still navigating: neither near the frontier nor stuck nor
    /// ended by a new φ before the env ended the episode ([`FrOutcome::Navigating`]).
    #[serde(default)]
    pub n_navigating_at_end: u64,
}

/// How an FR episode's navigation ended: the first of a switch, a new φ, or the episode's end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FrOutcome {
    /// φ(s_t) came within ε of g_F ([`Switch::NearFrontier`]).
    NearFrontier,
    /// The agent was stuck ([`Switch::Stuck`]).
    Stuck,
    /// A new φ arrived mid-episode (the route belonged to the old φ-space).
    NewPhi,
    /// The episode ended (truncation, termination or a physics failure) while navigating.
    Navigating,
}

impl FrOutcome {
    /// The outcome as a metric value: 0 near the frontier, 1 stuck, 2 new φ, 3 navigating.
    pub fn code(self) -> f64 {
        match self {
            Self::NearFrontier => 0.0,
            Self::Stuck => 1.0,
            Self::NewPhi => 2.0,
            Self::Navigating => 3.0,
        }
    }
}

/// Where an FR episode's navigation ended ([`FrontierEpisode::navigation_end`]): the
/// evidence for "why did FR not reach the frontier".
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrEnd {
    /// How it ended.
    pub outcome: FrOutcome,
    /// Index of the route point nearest to φ(s_t) over the last index: 0 at the route's
    /// start node, 1 at its last node (1 for a route of one node; 0 for an empty route).
    pub route_progress: f32,
    /// φ-distance from φ(s_t) to that nearest route point (how far off the route).
    pub off_route: f32,
    /// φ-distance from φ(s_t) to g_F.
    pub frontier_distance: f32,
    /// The env's first two observation coordinates (x, y of the maze tasks) at that moment.
    pub xy: [f32; 2],
    /// Waypoint decisions the episode took until then.
    pub waypoint_decisions: u32,
}

/// The outcome of the FR draw at episode start.
#[derive(Debug, Clone, PartialEq)]
pub enum Assignment {
    /// Not an FR episode (switch off, `fr_prob` 0, or the draw said no).
    Normal,
    /// Drawn FR, but the oracle had no frontier route: a normal episode (counted).
    NoRoute,
    /// An FR episode.
    Frontier(FrontierEpisode),
}

/// The FR draw at episode start (see the module doc): `phi0` = φ(s_0).
pub fn assign(
    params: Option<&FrontierParams>,
    fr_prob: f32,
    phi0: &[f32],
    phi_version: PhiVersion,
    rng: &mut Pcg64Mcg,
    oracle: &mut dyn GraphOracle,
) -> Result<Assignment, ActorError> {
    if params.is_none() || fr_prob <= 0.0 {
        return Ok(Assignment::Normal);
    }
    if rng.random::<f64>() >= f64::from(fr_prob) {
        return Ok(Assignment::Normal);
    }
    let Ok(from) = LatentPoint::try_from(phi0) else {
        return Ok(Assignment::NoRoute);
    };
    Ok(match oracle.frontier_route(from, phi_version)? {
        Some(found) => Assignment::Frontier(FrontierEpisode::new(found)),
        None => Assignment::NoRoute,
    })
}

/// Index of the route point nearest to `at` (Eq. 9; Euclidean, first on ties); `None` for an
/// empty route.
pub fn nearest_route_index(route: &[LatentPoint], at: &[f32]) -> Option<usize> {
    route
        .iter()
        .enumerate()
        .map(|(i, p)| (i, squared_distance(p, at)))
        .fold(None, |best: Option<(usize, f32)>, (i, d)| match best {
            Some((_, best_d)) if best_d <= d => best,
            _ => Some((i, d)),
        })
        .map(|(i, _)| i)
}

/// Index of the waypoint: k route points past the point nearest to `at`, clamped to the last
/// node; `None` for an empty route.
pub fn waypoint_index(route: &[LatentPoint], at: &[f32], k: u32) -> Option<usize> {
    straight_waypoint_index(route, at, k, 0.0).map(|(index, _)| index)
}

/// Index of the waypoint with the fold cut: [`waypoint_index`], cut back to the furthest
/// point `j` up to which every route point `i` (nearest < i ≤ j) is at least `straightness`
/// times as far from the nearest point in a straight line as along the route; `j` is at least
/// one past the nearest (a single hop is straight). Returns the index and whether it was cut;
/// `straightness` 0 never cuts. `None` for an empty route.
pub fn straight_waypoint_index(
    route: &[LatentPoint],
    at: &[f32],
    k: u32,
    straightness: f32,
) -> Option<(usize, bool)> {
    let nearest = nearest_route_index(route, at)?;
    let end = nearest.saturating_add(k as usize).min(route.len() - 1);
    if straightness <= 0.0 {
        return Some((end, false));
    }
    let origin = &route[nearest];
    let mut along = 0.0f32;
    for i in nearest + 1..=end {
        along += squared_distance(&route[i], &route[i - 1]).sqrt();
        let straight = squared_distance(&route[i], origin).sqrt();
        if i > nearest + 1 && straight < straightness * along {
            return Some((i - 1, true));
        }
    }
    Some((end, false))
}

/// The waypoint ([`waypoint_index`]); the frontier itself when the route is empty.
pub fn waypoint(route: &[LatentPoint], frontier: LatentPoint, at: &[f32], k: u32) -> LatentPoint {
    waypoint_index(route, at, k).map_or(frontier, |index| route[index])
}

/// `n` candidates uniform in the ±`abs_range` box around `at` (x then y per candidate).
pub fn count_candidates(
    at: LatentPoint,
    abs_range: f32,
    n: usize,
    rng: &mut Pcg64Mcg,
) -> Vec<LatentPoint> {
    (0..n)
        .map(|_| at.map(|v| v + rng.random_range(-abs_range..=abs_range)))
        .collect()
}

/// Why count mode began at a decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Switch {
    /// φ(s_t) is within ε of g_F: count mode for the rest of the episode.
    NearFrontier,
    /// φ(s_t) moved less than the stuck threshold since both previous FR decisions: count mode
    /// for this decision, then FR mode ends.
    Stuck,
}

/// How an FR decision chose its subgoal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FrChoice {
    /// A route waypoint: route index `index`, `k` past the nearest point (`index` is `None`
    /// when the route was empty and g_F was taken), or nearer when `cut` where the route folds.
    Waypoint {
        /// The drawn offset.
        k: u32,
        /// Route index taken.
        index: Option<usize>,
        /// The index was cut back where the route folds ([`straight_waypoint_index`]).
        cut: bool,
    },
    /// Count mode: the least-visited candidate; `fallback` when the oracle did not answer and
    /// the first candidate was taken.
    Count {
        /// The oracle had no answer.
        fallback: bool,
    },
}

/// One FR decision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrDecision {
    /// Absolute subgoal for the low level.
    pub subgoal: LatentPoint,
    /// How it was chosen.
    pub choice: FrChoice,
    /// The switch that fired at this decision, if any.
    pub switch: Option<Switch>,
}

impl FrDecision {
    /// The decision code written into the record.
    pub fn decision_kind(&self) -> DecisionKind {
        match self.choice {
            FrChoice::Waypoint { .. } => DecisionKind::FrontierRoute,
            FrChoice::Count { .. } => DecisionKind::FrontierCount,
        }
    }

    /// Whether the low level acts without exploration noise in this segment (navigation).
    pub fn deterministic_low(&self) -> bool {
        matches!(self.choice, FrChoice::Waypoint { .. })
    }
}

/// The FR state of one episode.
#[derive(Debug, Clone, PartialEq)]
pub struct FrontierEpisode {
    frontier: LatentPoint,
    route: Vec<LatentPoint>,
    count_mode: bool,
    active: bool,
    prev: Option<LatentPoint>,
    prev2: Option<LatentPoint>,
    n_waypoints: u32,
}

impl FrontierEpisode {
    /// FR mode towards the oracle's frontier, navigating.
    pub fn new(found: FrontierRoute) -> Self {
        Self {
            frontier: found.frontier,
            route: found.route,
            count_mode: false,
            active: true,
            prev: None,
            prev2: None,
            n_waypoints: 0,
        }
    }

    /// g_F.
    pub fn frontier(&self) -> LatentPoint {
        self.frontier
    }

    /// The route, start node first.
    pub fn route(&self) -> &[LatentPoint] {
        &self.route
    }

    /// Whether the episode's decisions still go through FR (false after a stuck switch or a
    /// new φ).
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Whether count mode is on (after a switch).
    pub fn in_count_mode(&self) -> bool {
        self.count_mode
    }

    /// Where navigation stands at `at` = φ(s_t), with the env's observation `obs` (its first
    /// two coordinates are recorded as xy; missing ones as NaN), reported as `outcome`.
    pub fn navigation_end(&self, outcome: FrOutcome, at: &[f32], obs: &[f32]) -> FrEnd {
        let nearest = nearest_route_index(&self.route, at);
        let route_progress = match (nearest, self.route.len()) {
            (None, _) => 0.0,
            (Some(_), 1) => 1.0,
            (Some(i), n) => i as f32 / (n - 1) as f32,
        };
        let off_route = nearest.map_or(f32::NAN, |i| distance(&self.route[i], at));
        let coordinate = |i: usize| obs.get(i).copied().unwrap_or(f32::NAN);
        FrEnd {
            outcome,
            route_progress,
            off_route,
            frontier_distance: distance(&self.frontier, at),
            xy: [coordinate(0), coordinate(1)],
            waypoint_decisions: self.n_waypoints,
        }
    }

    /// Ends FR mode: later decisions use the normal sources.
    pub fn end(&mut self) {
        self.active = false;
    }

    /// The switch tests at `at` = φ(s_t) (module doc, step 1), applied to the state.
    pub fn check_switch(&mut self, at: LatentPoint, params: &FrontierParams) -> Option<Switch> {
        let close =
            |p: Option<LatentPoint>| p.is_some_and(|p| distance(&p, &at) < params.stuck_threshold);
        if distance(&self.frontier, &at) < params.epsilon {
            let first = !self.count_mode;
            self.count_mode = true;
            if params.end_at_frontier {
                self.active = false;
            }
            first.then_some(Switch::NearFrontier)
        } else if close(self.prev) && close(self.prev2) {
            self.count_mode = true;
            self.active = false;
            Some(Switch::Stuck)
        } else {
            None
        }
    }

    /// One FR decision at `at` = φ(s_t) (module doc, steps 1–4). Call only while
    /// [`FrontierEpisode::is_active`].
    pub fn decide(
        &mut self,
        at: LatentPoint,
        params: &FrontierParams,
        phi_version: PhiVersion,
        rng: &mut Pcg64Mcg,
        oracle: &mut dyn GraphOracle,
    ) -> Result<FrDecision, ActorError> {
        let switch = self.check_switch(at, params);
        let (subgoal, choice) = if self.count_mode {
            count_mode_subgoal(at, params, phi_version, rng, oracle)?
        } else {
            let k = rng.random_range(params.k_range[0]..=params.k_range[1]);
            let found = straight_waypoint_index(&self.route, &at, k, params.straightness);
            let (index, cut) = (found.map(|(i, _)| i), found.is_some_and(|(_, cut)| cut));
            let subgoal = index.map_or(self.frontier, |i| self.route[i]);
            self.n_waypoints += 1;
            (subgoal, FrChoice::Waypoint { k, index, cut })
        };
        self.prev2 = self.prev;
        self.prev = Some(at);
        Ok(FrDecision {
            subgoal,
            choice,
            switch,
        })
    }
}

/// Count mode (module doc, step 3): the oracle's least-visited candidate, or the first one.
fn count_mode_subgoal(
    at: LatentPoint,
    params: &FrontierParams,
    phi_version: PhiVersion,
    rng: &mut Pcg64Mcg,
    oracle: &mut dyn GraphOracle,
) -> Result<(LatentPoint, FrChoice), ActorError> {
    let candidates = count_candidates(at, params.abs_range, params.n_candidates.max(1), rng);
    let answer = oracle.least_visited(&candidates, phi_version)?;
    let chosen = answer.and_then(|a| candidates.get(a.index).copied());
    Ok(match chosen {
        Some(subgoal) => (subgoal, FrChoice::Count { fallback: false }),
        None => (candidates[0], FrChoice::Count { fallback: true }),
    })
}

fn squared_distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    squared_distance(a, b).sqrt()
}
