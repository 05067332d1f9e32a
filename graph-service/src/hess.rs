//! HESS's exploration maps and its count-based subgoal choice (SPEC §6.4, digest §5): the
//! non-FR "explore" subgoal of an actor is a stored state near φ(s_t) whose cell has been
//! little visited in the discounted future of the stored episodes and where the low level has
//! not repeatedly failed to arrive.
//!
//! All three maps live on their own grid of side `exploration.count_cell_size` (default 3.0,
//! not the graph's d), with keys by floor division ([`Grid::key`]):
//!
//! - **visits** n(cell): every stored state counts once, in the cell of its latent point at
//!   arrival (the φ the service holds then, as the code's `pruned_phi`). Decision: like the
//!   released code, these counts are **never reset** — not when φ changes (old counts stay in
//!   the cells the old φ put them in; HESS's stability loss keeps φ from moving far) and not
//!   when the store evicts (they measure experience, not the store). States whose key is out of
//!   range are not counted. As in the code, counting starts only once more than
//!   `explore_start_episode` closed episodes are stored ([`HessMaps::count_arrival`]; the
//!   code's `epoch > start_explore`), so the φ of the first episodes, untrained, puts no counts
//!   in cells it will not mean later; with `exploration.visits_from_start` every stored state
//!   counts (this project's behaviour before that existed).
//! - **future counts** F(cell), recomputed after every `future_count_interval_episodes` stored
//!   (closed) episodes and after every φ re-map (in the code the φ round falls on a recompute
//!   episode too). For every closed stored trajectory, the states at env steps c, 2c, … (c =
//!   `hierarchy.c`; step 0 excluded), with their latent points under the current φ, give visit
//!   counts n_1 … n_H; backward, N_H = n_H and N_j = n_j + γ·N_{j+1} (γ =
//!   `future_count_discount`). Per cell with K samples, F = (S + 1)/(K + 1) where S is the sum
//!   of their N (`Intended`, the per-cell mean with +1 smoothing) or the N of the last sample
//!   written, trajectories oldest first and j ascending (`CodeCompatible`, the numpy
//!   duplicate-index quirk). Cells with no sample have F = 1.
//! - **potential** P(cell): [`ReachSample`]s add their `error` at the cell of their (un-pushed)
//!   `subgoal`; cumulative, never reset. Negative errors are refused.
//!
//! [`HessMaps::explore`]: draw `n_candidates` stored states uniformly with replacement; keep
//! those with 0 < ‖φ(cand) − from‖ < `candidate_radius`; score = F(cand) + `potential_coeff` ·
//! P(cand), the potential term only when `episode > potential_start_episode`; the argmin (first
//! on ties) is the candidate, or the first draw when none qualifies. When `episode >
//! potential_start_episode` the subgoal is pushed outward: sg = cand + `push_distance` ·
//! (cand − from)/‖cand − from‖ (no push when cand = from, where the direction is undefined).

use std::collections::HashMap;

use protocol::config::{Config, FutureCountAveraging, NodePosition};
use protocol::graph::ReachSample;
use protocol::LatentPoint;
use rand::Rng;

use crate::grid::{CellKey, Grid};
use crate::store::{Trajectory, TrajectoryStore};

/// The constants of HESS exploration, from `[exploration]` and `hierarchy.c`.
#[derive(Debug, Clone, PartialEq)]
pub struct HessParams {
    /// Side of the count/potential cells, φ units (`count_cell_size`).
    pub cell_size: f64,
    /// Stored states drawn per decision (`n_candidates`).
    pub n_candidates: usize,
    /// Candidates lie strictly within this φ-distance of `from` (`candidate_radius`).
    pub candidate_radius: f64,
    /// Outward push, φ units (`push_distance`).
    pub push_distance: f64,
    /// Weight of the potential in the score (`potential_coeff`).
    pub potential_coeff: f64,
    /// Potential term and push apply for episodes after this one (`potential_start_episode`).
    pub potential_start_episode: u64,
    /// Closed episodes stored between future-count recomputations
    /// (`future_count_interval_episodes`).
    pub future_interval_episodes: u64,
    /// γ of the discounted future count (`future_count_discount`).
    pub discount: f64,
    /// Per-cell averaging of the future counts (`future_count_averaging`).
    pub averaging: FutureCountAveraging,
    /// c: env steps between the states that enter the future counts (`hierarchy.c`).
    pub subgoal_interval: u32,
    /// Arriving states count as visits once more than this many closed episodes are stored
    /// (`explore_start_episode`); `None`: from the first (`visits_from_start`).
    pub count_after_episodes: Option<u64>,
}

impl HessParams {
    /// The parameters of a (validated) run config.
    pub fn from_config(config: &Config) -> Self {
        let e = &config.exploration;
        Self {
            cell_size: e.count_cell_size,
            n_candidates: e.n_candidates,
            candidate_radius: e.candidate_radius,
            push_distance: e.push_distance,
            potential_coeff: e.potential_coeff,
            potential_start_episode: e.potential_start_episode,
            future_interval_episodes: e.future_count_interval_episodes,
            discount: e.future_count_discount,
            averaging: e.future_count_averaging,
            subgoal_interval: config.hierarchy.c,
            count_after_episodes: (!e.visits_from_start).then_some(e.explore_start_episode),
        }
    }
}

/// An explore subgoal and how it was found.
#[derive(Debug, Clone, PartialEq)]
pub struct ExploreChoice {
    /// The subgoal for the low level (pushed when the episode is past the potential start).
    pub subgoal: LatentPoint,
    /// The chosen stored state's latent point, before the push.
    pub candidate: LatentPoint,
    /// Its score F + coeff·P (`None` when no draw was within the radius and the first draw
    /// was taken).
    pub score: Option<f64>,
}

/// A reach sample with a negative error (an error is a distance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NegativeError {
    /// Index of the sample.
    pub index: usize,
    /// Its error.
    pub error: f32,
}

/// The contents of [`HessMaps`] as a checkpoint saves them: each map's cells sorted by key,
/// and the counters.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HessParts {
    /// n(cell) of every visited cell.
    pub visits: Vec<(CellKey, u64)>,
    /// F(cell) of every cell with samples.
    pub future: Vec<(CellKey, f64)>,
    /// P(cell) of every cell with reports.
    pub potential: Vec<(CellKey, f64)>,
    /// Closed episodes stored since the last future-count recomputation.
    pub episodes_since_future: u64,
    /// Future-count recomputations so far.
    pub n_future_recomputes: u64,
    /// Reach samples accepted so far.
    pub n_reach_samples: u64,
    /// Closed episodes stored so far.
    pub episodes_stored: u64,
}

/// Visit counts, future counts and potential on the count grid (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct HessMaps {
    params: HessParams,
    grid: Grid,
    visits: HashMap<CellKey, u64>,
    future: HashMap<CellKey, f64>,
    potential: HashMap<CellKey, f64>,
    episodes_since_future: u64,
    n_future_recomputes: u64,
    n_reach_samples: u64,
    episodes_stored: u64,
}

impl HessMaps {
    /// Empty maps (`cell_size` > 0, checked by the config validation).
    pub fn new(params: HessParams) -> Self {
        // Only keys are used; where a cell's node would sit does not matter here.
        let grid = Grid::new(params.cell_size, NodePosition::Corner);
        Self {
            params,
            grid,
            visits: HashMap::new(),
            future: HashMap::new(),
            potential: HashMap::new(),
            episodes_since_future: 0,
            n_future_recomputes: 0,
            n_reach_samples: 0,
            episodes_stored: 0,
        }
    }

    /// The maps' contents (checkpoints).
    pub fn parts(&self) -> HessParts {
        fn sorted<V: Copy>(map: &HashMap<CellKey, V>) -> Vec<(CellKey, V)> {
            let mut cells: Vec<_> = map.iter().map(|(&k, &v)| (k, v)).collect();
            cells.sort_unstable_by_key(|&(k, _)| k);
            cells
        }
        HessParts {
            visits: sorted(&self.visits),
            future: sorted(&self.future),
            potential: sorted(&self.potential),
            episodes_since_future: self.episodes_since_future,
            n_future_recomputes: self.n_future_recomputes,
            n_reach_samples: self.n_reach_samples,
            episodes_stored: self.episodes_stored,
        }
    }

    /// Maps with `params` and saved `parts`; the error names the first value that no map
    /// could hold (a repeated cell, a zero visit count, a future count that is not finite and
    /// positive, a potential that is not finite and ≥ 0).
    pub fn from_parts(params: HessParams, parts: HessParts) -> Result<Self, String> {
        fn map<V: Copy>(
            name: &str,
            cells: Vec<(CellKey, V)>,
            valid: impl Fn(V) -> bool,
        ) -> Result<HashMap<CellKey, V>, String> {
            let n = cells.len();
            let out: HashMap<CellKey, V> = cells.into_iter().filter(|&(_, v)| valid(v)).collect();
            if out.len() != n {
                return Err(format!("{name} map: a repeated cell or an invalid value"));
            }
            Ok(out)
        }
        let mut maps = Self::new(params);
        maps.visits = map("visit", parts.visits, |n| n > 0)?;
        maps.future = map("future-count", parts.future, |f: f64| {
            f.is_finite() && f > 0.0
        })?;
        maps.potential = map("potential", parts.potential, |p: f64| {
            p.is_finite() && p >= 0.0
        })?;
        maps.episodes_since_future = parts.episodes_since_future;
        maps.n_future_recomputes = parts.n_future_recomputes;
        maps.n_reach_samples = parts.n_reach_samples;
        maps.episodes_stored = parts.episodes_stored;
        Ok(maps)
    }

    /// The parameters.
    pub fn params(&self) -> &HessParams {
        &self.params
    }

    /// Counts one visit in the cell of each of `points`.
    pub fn count(&mut self, points: &[LatentPoint]) {
        for key in points.iter().filter_map(|&p| self.grid.key(p)) {
            *self.visits.entry(key).or_insert(0) += 1;
        }
    }

    /// Counts arriving states `points` as visits when counting has started (more than
    /// `count_after_episodes` closed episodes stored, or always when that is `None`); returns
    /// whether it counted them.
    pub fn count_arrival(&mut self, points: &[LatentPoint]) -> bool {
        let counting = self
            .params
            .count_after_episodes
            .is_none_or(|after| self.episodes_stored > after);
        if counting {
            self.count(points);
        }
        counting
    }

    /// Closed episodes stored so far ([`HessMaps::episode_stored`] calls).
    pub fn episodes_stored(&self) -> u64 {
        self.episodes_stored
    }

    /// n of the cell holding `point` (0 when unvisited or out of range).
    pub fn visits_at(&self, point: LatentPoint) -> u64 {
        self.grid
            .key(point)
            .and_then(|key| self.visits.get(&key).copied())
            .unwrap_or(0)
    }

    /// Notes one more closed episode in `store`; recomputes the future counts when
    /// `future_interval_episodes` have accumulated. Returns whether it recomputed.
    pub fn episode_stored(&mut self, store: &TrajectoryStore) -> bool {
        self.episodes_stored += 1;
        self.episodes_since_future += 1;
        if self.episodes_since_future < self.params.future_interval_episodes {
            return false;
        }
        self.recompute_future(store);
        true
    }

    /// Recomputes the future-count map from every closed trajectory of `store`.
    pub fn recompute_future(&mut self, store: &TrajectoryStore) {
        // Per cell: (K, S) with S the sum of N (Intended) or the last N written (CodeCompatible).
        let mut cells: HashMap<CellKey, (u64, f64)> = HashMap::new();
        for trajectory in store.trajectories().filter(|t| t.is_closed()) {
            let points = decision_states(trajectory, self.params.subgoal_interval);
            let future = self.discounted_future(&points);
            for (point, n_future) in points.iter().zip(future) {
                let Some(key) = self.grid.key(*point) else {
                    continue;
                };
                let (k, s) = cells.entry(key).or_insert((0, 0.0));
                *k += 1;
                *s = match self.params.averaging {
                    FutureCountAveraging::Intended => *s + n_future,
                    FutureCountAveraging::CodeCompatible => n_future,
                };
            }
        }
        self.future = cells
            .into_iter()
            .map(|(key, (k, s))| (key, (s + 1.0) / (k as f64 + 1.0)))
            .collect();
        self.episodes_since_future = 0;
        self.n_future_recomputes += 1;
    }

    /// N_j = n_j + γ·N_{j+1} (N_H = n_H) along one trajectory's decision states.
    fn discounted_future(&self, points: &[LatentPoint]) -> Vec<f64> {
        let mut future = vec![0.0; points.len()];
        let mut next = 0.0;
        for (j, point) in points.iter().enumerate().rev() {
            next = self.visits_at(*point) as f64 + self.params.discount * next;
            future[j] = next;
        }
        future
    }

    /// F of the cell holding `point` (1 for a cell without samples or out of range).
    pub fn future_at(&self, point: LatentPoint) -> f64 {
        self.grid
            .key(point)
            .and_then(|key| self.future.get(&key).copied())
            .unwrap_or(1.0)
    }

    /// Adds each sample's error at the cell of its subgoal. A negative error refuses the
    /// whole batch, changing nothing. Subgoals whose key is out of range are skipped (the
    /// request handler refuses them before).
    pub fn report(&mut self, samples: &[ReachSample]) -> Result<(), NegativeError> {
        if let Some(index) = samples.iter().position(|s| s.error < 0.0) {
            return Err(NegativeError {
                index,
                error: samples[index].error,
            });
        }
        for sample in samples {
            if let Some(key) = self.grid.key(sample.subgoal) {
                *self.potential.entry(key).or_insert(0.0) += f64::from(sample.error);
            }
        }
        self.n_reach_samples += samples.len() as u64;
        Ok(())
    }

    /// P of the cell holding `point` (0 when nothing was reported there).
    pub fn potential_at(&self, point: LatentPoint) -> f64 {
        self.grid
            .key(point)
            .and_then(|key| self.potential.get(&key).copied())
            .unwrap_or(0.0)
    }

    /// The explore subgoal near `from` for training episode `episode`, from
    /// `n_candidates` uniform draws of `store`'s states; `None` when the store is empty.
    pub fn explore<R: Rng>(
        &self,
        store: &TrajectoryStore,
        from: LatentPoint,
        episode: u64,
        rng: &mut R,
    ) -> Option<ExploreChoice> {
        let draws = store.sample_latents(self.params.n_candidates, rng);
        self.select(&draws, from, episode)
    }

    /// The choice among `draws` (see the module doc); `None` for no draws.
    pub fn select(
        &self,
        draws: &[LatentPoint],
        from: LatentPoint,
        episode: u64,
    ) -> Option<ExploreChoice> {
        let late = episode > self.params.potential_start_episode;
        let mut best: Option<(LatentPoint, f64)> = None;
        for &draw in draws {
            let d = distance(draw, from);
            if !(d > 0.0 && d < self.params.candidate_radius) {
                continue;
            }
            let score = self.score(draw, late);
            if best.is_none_or(|(_, lowest)| score < lowest) {
                best = Some((draw, score));
            }
        }
        let (candidate, score) = match best {
            Some((point, score)) => (point, Some(score)),
            None => (*draws.first()?, None),
        };
        let subgoal = if late {
            push(candidate, from, self.params.push_distance)
        } else {
            candidate
        };
        Some(ExploreChoice {
            subgoal,
            candidate,
            score,
        })
    }

    /// F(point) + coeff·P(point), the potential only when `with_potential`.
    fn score(&self, point: LatentPoint, with_potential: bool) -> f64 {
        let potential = if with_potential {
            self.params.potential_coeff * self.potential_at(point)
        } else {
            0.0
        };
        self.future_at(point) + potential
    }

    /// Cells with at least one counted visit.
    pub fn n_visited_cells(&self) -> usize {
        self.visits.len()
    }

    /// Future-count recomputations so far.
    pub fn n_future_recomputes(&self) -> u64 {
        self.n_future_recomputes
    }

    /// Reach samples accepted so far.
    pub fn n_reach_samples(&self) -> u64 {
        self.n_reach_samples
    }
}

/// The latent points of `trajectory`'s states at env steps c, 2c, … (step 0 excluded).
fn decision_states(trajectory: &Trajectory, c: u32) -> Vec<LatentPoint> {
    let c = u64::from(c.max(1));
    let first = trajectory.first_env_step;
    // Local index of the first state whose env step is a positive multiple of c.
    let mut offset = (c - first % c) % c;
    if first + offset == 0 {
        offset += c;
    }
    let offset = usize::try_from(offset).unwrap_or(usize::MAX);
    trajectory
        .latents()
        .iter()
        .skip(offset)
        .step_by(c as usize)
        .copied()
        .collect()
}

/// Euclidean distance in f64.
fn distance(a: LatentPoint, b: LatentPoint) -> f64 {
    let dx = f64::from(a[0]) - f64::from(b[0]);
    let dy = f64::from(a[1]) - f64::from(b[1]);
    dx.hypot(dy)
}

/// `candidate + push · (candidate − from)/‖candidate − from‖`; `candidate` when they coincide.
fn push(candidate: LatentPoint, from: LatentPoint, push: f64) -> LatentPoint {
    let d = distance(candidate, from);
    if d == 0.0 {
        return candidate;
    }
    let along = |axis: usize| {
        let c = f64::from(candidate[axis]);
        (c + push * (c - f64::from(from[axis])) / d) as f32
    };
    [along(0), along(1)]
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use protocol::{ActorId, EpisodeId};

    use super::*;
    use crate::store::ChunkStates;

    fn params(c: u32, discount: f64, averaging: FutureCountAveraging) -> HessParams {
        HessParams {
            cell_size: 3.0,
            n_candidates: 50,
            candidate_radius: 20.0,
            push_distance: 5.0,
            potential_coeff: 10.0,
            potential_start_episode: 400,
            future_interval_episodes: 2,
            discount,
            averaging,
            subgoal_interval: c,
            count_after_episodes: None,
        }
    }

    /// One closed episode of `points` starting at env step `first` (obs = latent, obs_dim 2).
    fn episode(id: u64, first: u64, points: &[LatentPoint], closed: bool) -> ChunkStates {
        ChunkStates {
            actor: ActorId(0),
            episode: EpisodeId(id),
            chunk_index: 0,
            first_env_step: first,
            episode_start: first == 0,
            episode_end: closed,
            obs: points.concat(),
            latents: points.to_vec(),
        }
    }

    /// Stores the episodes and counts their states, as the service does at ingest.
    fn fill(maps: &mut HessMaps, episodes: Vec<ChunkStates>) -> TrajectoryStore {
        let mut store = TrajectoryStore::new(2, 1_000_000);
        for e in episodes {
            maps.count(&e.latents);
            store.append(e);
        }
        store
    }

    #[test]
    fn future_counts_match_hand_computed_discounted_sums_with_negative_coordinates() {
        // Cells of 3: A = (−1, −1) holds (−0.5, −2.9); B = (0, 0) holds (0, 2.9);
        // C = (−2, 1) holds (−3.1, 3.0).
        let (a, b, cc) = ([-0.5, -2.9], [0.0, 2.9], [-3.1, 3.0]);
        // c = 2, γ = 0.5. Episode 1, steps 0..=6: A B A C B A C → decision states (steps 2,
        // 4, 6): A, B, C. Episode 2, steps 0..=4: B B A A B → steps 2, 4: A, B.
        // Visits: A 5, B 5, C 2.
        let e1 = episode(1, 0, &[a, b, a, cc, b, a, cc], true);
        let e2 = episode(2, 0, &[b, b, a, a, b], true);
        for averaging in [
            FutureCountAveraging::Intended,
            FutureCountAveraging::CodeCompatible,
        ] {
            let mut maps = HessMaps::new(params(2, 0.5, averaging));
            let store = fill(&mut maps, vec![e1.clone(), e2.clone()]);
            assert_eq!(
                (maps.visits_at(a), maps.visits_at(b), maps.visits_at(cc)),
                (5, 5, 2)
            );
            maps.recompute_future(&store);
            // Episode 1: N(C) = 2, N(B) = 5 + 1 = 6, N(A) = 5 + 3 = 8.
            // Episode 2: N(B) = 5, N(A) = 5 + 2.5 = 7.5.
            let (fa, fb, fc) = match averaging {
                // A: (8 + 7.5 + 1)/3, B: (6 + 5 + 1)/3, C: (2 + 1)/2.
                FutureCountAveraging::Intended => (16.5 / 3.0, 12.0 / 3.0, 1.5),
                // Last written: A ← 7.5, B ← 5, C ← 2.
                FutureCountAveraging::CodeCompatible => (8.5 / 3.0, 6.0 / 3.0, 1.5),
            };
            assert!((maps.future_at(a) - fa).abs() < 1e-12, "{averaging:?}");
            assert!((maps.future_at(b) - fb).abs() < 1e-12, "{averaging:?}");
            assert!((maps.future_at(cc) - fc).abs() < 1e-12, "{averaging:?}");
            assert_eq!(maps.future_at([30.0, 30.0]), 1.0, "unvisited cell");
        }
    }

    #[test]
    fn decision_states_follow_env_steps_and_skip_open_trajectories() {
        // A trimmed trajectory starting at env step 3 with c = 4: steps 4 and 8 → local 1, 5.
        let points: Vec<LatentPoint> = (0..7).map(|i| [i as f32 * 3.0, 0.0]).collect();
        let mut maps = HessMaps::new(params(4, 0.0, FutureCountAveraging::Intended));
        let store = fill(
            &mut maps,
            vec![
                episode(1, 3, &points, true),
                episode(2, 0, &[[-50.0, 0.0]; 9], false),
            ],
        );
        maps.recompute_future(&store);
        // γ = 0: N = n = 1 in the cells of local 1 and 5; (1 + 1)/(1 + 1) = 1 elsewhere too,
        // so check the keys that were sampled instead.
        let sampled: Vec<CellKey> = {
            let mut keys: Vec<CellKey> = maps.future.keys().copied().collect();
            keys.sort();
            keys
        };
        assert_eq!(sampled, vec![CellKey([1, 0]), CellKey([5, 0])]);
    }

    #[test]
    fn the_future_map_is_recomputed_every_interval_of_stored_episodes() {
        let mut maps = HessMaps::new(params(1, 0.9, FutureCountAveraging::Intended));
        let store = fill(
            &mut maps,
            vec![episode(1, 0, &[[0.0, 0.0], [1.0, 1.0]], true)],
        );
        assert!(!maps.episode_stored(&store));
        assert_eq!(maps.future_at([1.0, 1.0]), 1.0);
        assert!(maps.episode_stored(&store));
        // One sample at step 1, n = 2 (both states share the cell): (2 + 1)/(1 + 1).
        assert_eq!(maps.future_at([1.0, 1.0]), 1.5);
        assert_eq!(maps.n_future_recomputes(), 1);
        assert!(!maps.episode_stored(&store));
    }

    #[test]
    fn the_potential_accumulates_per_cell_and_refuses_negative_errors() {
        let mut maps = HessMaps::new(params(1, 0.9, FutureCountAveraging::Intended));
        let sample = |x: f32, y: f32, error: f32| ReachSample {
            subgoal: [x, y],
            error,
        };
        maps.report(&[sample(-0.1, -0.1, 2.0), sample(-2.9, -3.1, 0.5)])
            .unwrap();
        maps.report(&[sample(-1.5, -1.5, 1.0)]).unwrap();
        assert_eq!(maps.potential_at([-2.0, -2.0]), 3.0, "cell (−1, −1)");
        assert_eq!(maps.potential_at([-2.0, -3.5]), 0.5, "cell (−1, −2)");
        let err = maps
            .report(&[sample(0.0, 0.0, 1.0), sample(0.0, 0.0, -1.0)])
            .unwrap_err();
        assert_eq!(err.index, 1);
        assert_eq!(
            maps.potential_at([0.0, 0.0]),
            0.0,
            "a refused batch adds nothing"
        );
        assert_eq!(maps.n_reach_samples(), 3);
    }

    #[test]
    fn late_subgoals_are_pushed_outward_along_the_candidate_direction() {
        let mut maps = HessMaps::new(params(1, 0.9, FutureCountAveraging::Intended));
        maps.count(&[[-7.0, -4.0]]);
        let from = [-4.0, -8.0];
        // Only one draw within the radius: (−7, −4), 5 away along (−3, 4)/5.
        let draws = [[100.0, 100.0], [-7.0, -4.0], from];
        let early = maps.select(&draws, from, 400).unwrap();
        assert_eq!(
            (early.candidate, early.subgoal),
            ([-7.0, -4.0], [-7.0, -4.0])
        );
        let late = maps.select(&draws, from, 401).unwrap();
        assert_eq!(late.candidate, [-7.0, -4.0]);
        assert_eq!(late.subgoal, [-10.0, 0.0]);
        // Nothing within the radius: the first draw, pushed all the same.
        let far = maps.select(&[[26.0, -8.0]], from, 401).unwrap();
        assert_eq!(
            (far.candidate, far.subgoal, far.score),
            ([26.0, -8.0], [31.0, -8.0], None)
        );
        // The first draw at `from` itself: no direction, no push.
        let same = maps.select(&[from], from, 401).unwrap();
        assert_eq!(same.subgoal, from);
        assert_eq!(maps.select(&[], from, 401), None);
    }

    /// Brute-force reference for the future map: counts by scanning every stored point,
    /// future counts as explicit sums Σ_k γ^(k−j) n_k, decision states by env step.
    fn brute_future(
        episodes: &[(u64, Vec<LatentPoint>, bool)],
        p: &HessParams,
        cell: LatentPoint,
    ) -> f64 {
        let key = |q: LatentPoint| {
            (
                (f64::from(q[0]) / p.cell_size).floor() as i64,
                (f64::from(q[1]) / p.cell_size).floor() as i64,
            )
        };
        let all: Vec<LatentPoint> = episodes.iter().flat_map(|e| e.1.clone()).collect();
        let n = |q: LatentPoint| all.iter().filter(|&&r| key(r) == key(q)).count() as f64;
        let (mut k, mut sum, mut last) = (0u64, 0.0, 0.0);
        for (first, points, closed) in episodes {
            if !closed {
                continue;
            }
            let chosen: Vec<LatentPoint> = points
                .iter()
                .enumerate()
                .filter(|(i, _)| {
                    let t = first + *i as u64;
                    t > 0 && t.is_multiple_of(u64::from(p.subgoal_interval))
                })
                .map(|(_, &q)| q)
                .collect();
            for j in 0..chosen.len() {
                let future: f64 = (j..chosen.len())
                    .map(|m| p.discount.powi((m - j) as i32) * n(chosen[m]))
                    .sum();
                if key(chosen[j]) == key(cell) {
                    k += 1;
                    sum += future;
                    last = future;
                }
            }
        }
        let s = match p.averaging {
            FutureCountAveraging::Intended => sum,
            FutureCountAveraging::CodeCompatible => last,
        };
        (s + 1.0) / (k as f64 + 1.0)
    }

    fn random_episodes() -> impl Strategy<Value = Vec<(u64, Vec<LatentPoint>, bool)>> {
        let point = (-12.0f32..12.0, -12.0f32..12.0).prop_map(|(x, y)| [x, y]);
        let episode = (
            0u64..7,
            proptest::collection::vec(point, 1..25),
            proptest::bool::weighted(0.8),
        );
        proptest::collection::vec(episode, 1..6)
    }

    proptest! {
        #[test]
        fn future_counts_match_brute_force_sums(
            episodes in random_episodes(),
            c in 1u32..5,
            discount in 0.0f64..1.0,
            code_compatible in proptest::bool::ANY,
        ) {
            let averaging = if code_compatible {
                FutureCountAveraging::CodeCompatible
            } else {
                FutureCountAveraging::Intended
            };
            let p = params(c, discount, averaging);
            let mut maps = HessMaps::new(p.clone());
            let chunks = episodes
                .iter()
                .enumerate()
                .map(|(i, (first, points, closed))| episode(i as u64, *first, points, *closed))
                .collect();
            let store = fill(&mut maps, chunks);
            maps.recompute_future(&store);
            for (_, points, _) in &episodes {
                for &q in points {
                    let expected = brute_future(&episodes, &p, q);
                    prop_assert!((maps.future_at(q) - expected).abs() < 1e-9 * expected.max(1.0),
                        "at {:?}: {} vs brute force {}", q, maps.future_at(q), expected);
                }
            }
        }

        #[test]
        fn the_chosen_candidate_has_the_lowest_score_within_the_radius(
            draws in proptest::collection::vec((-30.0f32..30.0, -30.0f32..30.0), 1..60),
            reports in proptest::collection::vec(((-30.0f32..30.0, -30.0f32..30.0), 0.0f32..3.0), 0..30),
            episode in 0u64..800,
        ) {
            let draws: Vec<LatentPoint> = draws.into_iter().map(|(x, y)| [x, y]).collect();
            let mut maps = HessMaps::new(params(1, 0.9, FutureCountAveraging::Intended));
            maps.count(&draws[..draws.len() / 2]);
            let store = fill(&mut maps, vec![episode_of(&draws)]);
            maps.recompute_future(&store);
            let samples: Vec<ReachSample> = reports
                .into_iter()
                .map(|((x, y), error)| ReachSample { subgoal: [x, y], error })
                .collect();
            maps.report(&samples).unwrap();
            let from = [1.0, -2.0];
            let choice = maps.select(&draws, from, episode).unwrap();
            // Brute force: score every draw in the radius, keep the first minimum.
            let late = episode > 400;
            let scored: Vec<(LatentPoint, f64)> = draws
                .iter()
                .filter(|q| {
                    let d = ((q[0] as f64 - 1.0).powi(2) + (q[1] as f64 + 2.0).powi(2)).sqrt();
                    d > 0.0 && d < 20.0
                })
                .map(|&q| {
                    let potential = if late { 10.0 * maps.potential_at(q) } else { 0.0 };
                    (q, maps.future_at(q) + potential)
                })
                .collect();
            let lowest = scored.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
            let expected = scored.iter().find(|s| s.1 == lowest).map_or(draws[0], |s| s.0);
            prop_assert_eq!(choice.candidate, expected);
            if late {
                let (dx, dy) = (
                    f64::from(choice.subgoal[0] - choice.candidate[0]),
                    f64::from(choice.subgoal[1] - choice.candidate[1]),
                );
                let moved = dx.hypot(dy);
                prop_assert!(moved < 1e-3 || (moved - 5.0).abs() < 1e-3, "push of {}", moved);
            } else {
                prop_assert_eq!(choice.subgoal, choice.candidate);
            }
        }
    }

    fn episode_of(points: &[LatentPoint]) -> ChunkStates {
        episode(99, 0, points, true)
    }

    #[test]
    fn explore_draws_only_stored_states_and_needs_some() {
        use rand::SeedableRng;
        let mut maps = HessMaps::new(params(1, 0.9, FutureCountAveraging::Intended));
        let mut rng = rand_pcg::Pcg64::seed_from_u64(2);
        let empty = TrajectoryStore::new(2, 10);
        assert_eq!(maps.explore(&empty, [0.0, 0.0], 10, &mut rng), None);
        // Two stored states 1 and 4 units from `from`, the far one in a never-visited cell
        // of the future map (F = 1) and the near one in a cell with samples (F > 1).
        let store = fill(
            &mut maps,
            vec![episode(1, 0, &[[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]], true)],
        );
        maps.recompute_future(&store);
        let mut other = TrajectoryStore::new(2, 10);
        other.append(episode(1, 0, &[[1.0, 0.0], [4.0, 0.0]], true));
        let choice = maps.explore(&other, [0.0, 0.0], 10, &mut rng).unwrap();
        assert_eq!(choice.candidate, [4.0, 0.0]);
        assert_eq!(choice.score, Some(1.0));
    }
}
