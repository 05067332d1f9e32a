//! Config sections for the method itself: the encoder φ (HESS), HESS exploration, the latent
//! graph and ASI's frontier-reaching (FR) and self-imitation (SI) parts (SPEC §6.3–6.7).

use serde::{Deserialize, Serialize};

use super::error::Checker;

/// How the stable loss (Eq. 6–7) chooses and weights the states it regularizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StableWeighting {
    /// Paper's intent: sample regularized states with probability ∝ 1/√(1 + p), p the stored
    /// per-state triplet loss, so low-loss states weigh more. Default.
    InverseSqrtPriority,
    /// Released code: uniform over the candidates above the `regularization_low_ratio`
    /// quantile of p (drops the lowest-loss states).
    DropLowestLoss,
}

/// `[encoder]`: the subgoal representation φ and its training rounds (SPEC §6.3).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EncoderConfig {
    /// Hidden layer widths of φ (ReLU). Default [100, 100]. Source: code (supplement: [100]).
    pub hidden: Vec<usize>,
    /// Latent dimension. Must be 2 (the graph grid and the high action are 2-D). Default 2.
    /// Source: paper and code.
    pub out_dim: usize,
    /// Adam learning rate. Default 1e-4. Source: paper and code.
    pub lr: f64,
    /// Minibatch size (anchors and regularized states each). Default 100. Source: code.
    pub batch_size: usize,
    /// Gradient steps per training round. Default 50 000. Source: code.
    pub steps_per_round: u64,
    /// A round runs every this many training episodes. Default 100. Unit: episodes.
    /// Source: code (`phi_interval`).
    pub interval_episodes: u64,
    /// Training episode at which the first round runs. Default 100. Unit: episodes.
    /// Source: code.
    pub first_round_episode: u64,
    /// Triplet margin δ on the code's `mean_dims(Δ²)` distance. Default 1. Source: code.
    pub triplet_margin: f64,
    /// Temporal offset of the negative s_{t+k}; absent = `hierarchy.c`.
    /// Unit: env steps. Source: code (k = c).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub negative_offset: Option<u32>,
    /// Stable-loss coefficient before `stable_coeff_switch_episode`. Default 0.001. Source: code.
    pub stable_coeff: f64,
    /// Stable-loss coefficient from `stable_coeff_switch_episode` on. Default 0.1. Source: code.
    pub stable_coeff_late: f64,
    /// Episode at which the stable coefficient switches. Default 500. Unit: episodes.
    /// Source: code.
    pub stable_coeff_switch_episode: u64,
    /// Anchors are drawn from this top fraction of candidates by stored triplet loss.
    /// Default 0.5. Source: code (`hi_ratio`).
    pub anchor_high_ratio: f64,
    /// With `DropLowestLoss`, this lowest fraction is excluded from regularization.
    /// Default 0.3. Source: code (`low_ratio`).
    pub regularization_low_ratio: f64,
    /// How regularized states are chosen: `"inverse_sqrt_priority"` (default, paper's intent)
    /// or `"drop_lowest_loss"` (code).
    pub stable_weighting: StableWeighting,
    /// Process mode only: run each round on a thread of its own while the SAC updates go on
    /// (and the actors with them) on the encoder as it was, which the round's result replaces
    /// when it ends. Default false: the round stops the SAC updates until it ends, as the code
    /// (one process, rounds in line) and serial mode, which refuses `true`. Gains up to the
    /// round's share of the learner's time where a core is free for it; the φ an update or an
    /// actor sees is then up to one round's duration older.
    pub background_rounds: bool,
}

impl Default for EncoderConfig {
    fn default() -> Self {
        Self {
            hidden: vec![100, 100],
            out_dim: 2,
            lr: 1e-4,
            batch_size: 100,
            steps_per_round: 50_000,
            interval_episodes: 100,
            first_round_episode: 100,
            triplet_margin: 1.0,
            negative_offset: None,
            stable_coeff: 0.001,
            stable_coeff_late: 0.1,
            stable_coeff_switch_episode: 500,
            anchor_high_ratio: 0.5,
            regularization_low_ratio: 0.3,
            stable_weighting: StableWeighting::InverseSqrtPriority,
            background_rounds: false,
        }
    }
}

impl EncoderConfig {
    /// The negative offset k in env steps (`negative_offset`, or c when absent).
    pub fn negative_offset_or(&self, subgoal_interval: u32) -> u32 {
        self.negative_offset.unwrap_or(subgoal_interval)
    }

    pub(crate) fn check(&self, c: &mut Checker) {
        c.layer_sizes("encoder.hidden", &self.hidden);
        if self.out_dim != 2 {
            c.issue(
                "encoder.out_dim",
                self.out_dim,
                "must be 2: the latent graph grid and the high-level action are 2-D",
            );
        }
        c.positive("encoder.lr", self.lr);
        c.at_least_one("encoder.batch_size", self.batch_size as u64);
        c.at_least_one("encoder.steps_per_round", self.steps_per_round);
        c.at_least_one("encoder.interval_episodes", self.interval_episodes);
        c.at_least_one("encoder.first_round_episode", self.first_round_episode);
        c.positive("encoder.triplet_margin", self.triplet_margin);
        if let Some(k) = self.negative_offset {
            c.at_least_one("encoder.negative_offset", u64::from(k));
        }
        c.non_negative("encoder.stable_coeff", self.stable_coeff);
        c.non_negative("encoder.stable_coeff_late", self.stable_coeff_late);
        c.fraction("encoder.anchor_high_ratio", self.anchor_high_ratio);
        if !(0.0..1.0).contains(&self.regularization_low_ratio) {
            c.issue(
                "encoder.regularization_low_ratio",
                self.regularization_low_ratio,
                "must be in [0, 1)",
            );
        }
    }
}

/// How the per-cell future count is averaged (digest §5.2, disagreement 17).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FutureCountAveraging {
    /// Per-cell mean of the discounted future counts with +1 smoothing: (ΣN + 1)/(K + 1).
    /// Default (the code's intent).
    Intended,
    /// What the released code computes because of a numpy duplicate-index bug:
    /// (N_last + 1)/(K + 1), N_last the last sample written to the cell.
    CodeCompatible,
}

/// `[exploration]`: HESS novelty/potential subgoal selection for non-FR episodes (SPEC §6.4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExplorationConfig {
    /// Cell side of the visit-count and potential hashes. Default 3.0. Unit: φ units.
    /// Source: code.
    pub count_cell_size: f64,
    /// Stored states sampled as candidates per decision. Default 2000. Source: code.
    pub n_candidates: usize,
    /// Candidates must lie within this φ-distance of φ(s_t) (and not at it). Default 20.
    /// Unit: φ units. Source: code (`max(20, abs_range)`).
    pub candidate_radius: f64,
    /// Outward push of the chosen candidate, after `potential_start_episode`. Default 5.
    /// Unit: φ units. Source: code (`delta_r`).
    pub push_distance: f64,
    /// Weight of the potential (accumulated reaching failure) in the score. Default 10.
    /// Source: code.
    pub potential_coeff: f64,
    /// Potential term and push apply after this episode. Default 400. Unit: episodes.
    /// Source: code (`start_count_success`).
    pub potential_start_episode: u64,
    /// Count-based subgoals are allowed after this episode. Default 100. Unit: episodes.
    /// Source: code (`start_explore`).
    pub explore_start_episode: u64,
    /// Which stored states count as HESS visits n(cell). Default false: only those that
    /// arrive once more than `explore_start_episode` episodes are stored, closed (source:
    /// code, digest §2.3 D: `hash` is incremented only when `epoch > start_explore`, so the
    /// untrained φ of the first episodes leaves no counts). true: every stored state from the
    /// run's first episode on (this project's behaviour before 3 December 2026, which every
    /// run in docs/RESULTS.md used).
    pub visits_from_start: bool,
    /// Future counts are recomputed every this many episodes. Default 10. Unit: episodes.
    /// Source: code.
    pub future_count_interval_episodes: u64,
    /// Discount along stored episodes in the future count N_j = n_j + γ·N_{j+1}. Default 0.99.
    /// Source: code (`args.gamma`).
    pub future_count_discount: f64,
    /// `count_prob` is recomputed every this many episodes. Default 50. Unit: episodes.
    /// Source: code.
    pub count_prob_interval_episodes: u64,
    /// x in `count_prob = 1/(1 + exp(2x − 1))` is far-goal successes per interval divided by
    /// this. Default 5. Unit: episodes. Source: code (`/ 50 · 10`).
    pub count_prob_success_unit: f64,
    /// A goal is "far" when its maze path distance from the start is at least this fraction of
    /// the maximum. Default 2/3. Source: ours (reproduces the code's U-maze rule g_y ≥ 8).
    pub far_goal_fraction: f64,
    /// `"intended"` (default) or `"code_compatible"`; see [`FutureCountAveraging`].
    pub future_count_averaging: FutureCountAveraging,
}

impl Default for ExplorationConfig {
    fn default() -> Self {
        Self {
            count_cell_size: 3.0,
            n_candidates: 2000,
            candidate_radius: 20.0,
            push_distance: 5.0,
            potential_coeff: 10.0,
            potential_start_episode: 400,
            explore_start_episode: 100,
            visits_from_start: false,
            future_count_interval_episodes: 10,
            future_count_discount: 0.99,
            count_prob_interval_episodes: 50,
            count_prob_success_unit: 5.0,
            far_goal_fraction: 2.0 / 3.0,
            future_count_averaging: FutureCountAveraging::Intended,
        }
    }
}

impl ExplorationConfig {
    pub(crate) fn check(&self, c: &mut Checker) {
        c.positive("exploration.count_cell_size", self.count_cell_size);
        c.at_least_one("exploration.n_candidates", self.n_candidates as u64);
        c.positive("exploration.candidate_radius", self.candidate_radius);
        c.non_negative("exploration.push_distance", self.push_distance);
        c.non_negative("exploration.potential_coeff", self.potential_coeff);
        c.at_least_one(
            "exploration.future_count_interval_episodes",
            self.future_count_interval_episodes,
        );
        c.closed_interval(
            "exploration.future_count_discount",
            self.future_count_discount,
            0.0,
            1.0,
        );
        c.at_least_one(
            "exploration.count_prob_interval_episodes",
            self.count_prob_interval_episodes,
        );
        c.positive(
            "exploration.count_prob_success_unit",
            self.count_prob_success_unit,
        );
        c.fraction("exploration.far_goal_fraction", self.far_goal_fraction);
    }
}

/// Where a graph node sits inside its cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NodePosition {
    /// Lower-left corner (key·d), as the released code. Default.
    Corner,
    /// Cell centre ((key + ½)·d).
    Centre,
}

/// `[graph]`: the latent grid graph (SPEC §6.5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GraphConfig {
    /// Cell side d in φ-space. Default 2 (U, cheetah); 4 for S, W, FourRooms.
    /// Unit: φ units. Source: supplement Table 2 (code: 2 everywhere).
    pub cell_size: f64,
    /// Node cap; cells beyond it are not added and the drop is counted. Default 5000.
    /// Source: supplement (code: 3500).
    pub max_nodes: usize,
    /// Edges join states at most this many steps apart in one trajectory, weighted by the gap.
    /// Default 1 (consecutive states, as the code). Unit: env steps. Source: code.
    pub edge_window: u32,
    /// `"corner"` (default, code) or `"centre"`.
    pub node_position: NodePosition,
    /// Trajectory store cap of the graph-service; oldest episodes are evicted beyond it
    /// (the code never evicts). Default 8 000 000. Unit: env steps. Source: ours.
    pub max_stored_steps: u64,
    /// Threads that re-map the trajectory store through a new φ (the rest of the rebuild and
    /// the mapping of arriving chunks stay on one thread). Default 2: the graph-service is
    /// otherwise idle during a rebuild, and the dev machine has 2 cores. In [1, 256]. Unit:
    /// threads. Source: ours.
    pub remap_threads: usize,
    /// Graphs with at most this many nodes get an all-pairs route table after each rebuild
    /// (built on a background thread with `remap_threads` workers; 2·n² bytes, 50 MB at 5,000
    /// nodes), so route queries are lookups; larger graphs are searched per query. 0 disables
    /// the table. In [0, 65535]. Default 10 000. Unit: nodes. Source: ours.
    pub route_table_max_nodes: usize,
}

impl Default for GraphConfig {
    fn default() -> Self {
        Self {
            cell_size: 2.0,
            max_nodes: 5000,
            edge_window: 1,
            node_position: NodePosition::Corner,
            max_stored_steps: 8_000_000,
            remap_threads: 2,
            route_table_max_nodes: 10_000,
        }
    }
}

impl GraphConfig {
    pub(crate) fn check(&self, c: &mut Checker) {
        c.positive("graph.cell_size", self.cell_size);
        if self.max_nodes < 2 || self.max_nodes > u32::MAX as usize {
            c.issue(
                "graph.max_nodes",
                self.max_nodes,
                "must be in [2, 4294967295]",
            );
        }
        c.at_least_one("graph.edge_window", u64::from(self.edge_window));
        c.at_least_one("graph.max_stored_steps", self.max_stored_steps);
        if self.route_table_max_nodes > usize::from(u16::MAX) {
            c.issue(
                "graph.route_table_max_nodes",
                self.route_table_max_nodes,
                "must be in [0, 65535] (node ids are stored as 16-bit numbers)",
            );
        }
        if !(1..=256).contains(&self.remap_threads) {
            c.issue(
                "graph.remap_threads",
                self.remap_threads,
                "must be in [1, 256]",
            );
        }
    }
}

/// One step of the FR probability schedule: from `from_episode` on, p applies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrProbStep {
    /// First training episode this probability applies to. Unit: episodes.
    pub from_episode: u64,
    /// Probability that an eligible episode is frontier-reaching.
    pub p: f64,
}

/// `[asi]`: frontier-reaching exploration and hierarchical self-imitation (SPEC §6.6–6.7).
/// Both switches off gives HESS.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AsiConfig {
    /// Enable frontier-reaching episodes. Default true. Source: paper.
    pub frontier_reaching: bool,
    /// Enable hierarchical self-imitation. Default true. Source: paper.
    pub self_imitation: bool,
    /// FR episodes only after this training episode. Default 200. Unit: episodes. Source: code.
    pub fr_start_episode: u64,
    /// Step schedule of the FR probability, sorted by `from_episode`, first entry at 0.
    /// Default [(0, 0.2), (500, 0.3), (700, 0.4)]; the cheetah uses [(0, 0.1)].
    /// Source: code (paper: "gradually increased"; supplement: 0.1 for the cheetah).
    pub fr_prob_schedule: Vec<FrProbStep>,
    /// The frontier is a uniformly random node whose graph distance from the start node
    /// exceeds this fraction of the maximum. Default 0.9. Source: code.
    pub frontier_fraction: f64,
    /// Inclusive range of the FR waypoint offset k along the route. Default [3, 6] (U);
    /// [2, 5] for the other tasks. Unit: route nodes. Source: supplement Table 2.
    pub fr_k_range: [u32; 2],
    /// Cut the FR waypoint where the route folds. 0 (default; paper and code): the waypoint
    /// is k route points past the nearest. r in (0, 1]: the furthest of those k points up to
    /// which every route point lies at least r times as far from the nearest route point in a
    /// straight line as along the route; a U-turn or corner of the route in φ brings the
    /// straight distance down, so the walk heads for the turn instead of a point across the
    /// wall beyond it (docs/RESULTS.md, "FR with the frontier just past a fold"). The
    /// waypoint is always at least one point past the nearest. An experiment, not in the
    /// paper. Unit: ratio.
    pub fr_waypoint_straightness: f64,
    /// Switch to count mode within this φ-distance of the frontier (ε). Default 8.
    /// Unit: φ units. Source: code.
    pub frontier_epsilon: f64,
    /// "Stuck" when φ(s_t) moved less than this over the last two FR decisions. Default 1.
    /// Unit: φ units. Source: code.
    pub stuck_threshold: f64,
    /// Candidates drawn uniformly in the ±abs_range box in count mode. Default 100.
    /// Source: code.
    pub count_mode_candidates: usize,
    /// How count mode scores candidates (the lowest wins): `"graph_visits"` (default, paper
    /// Eq. 10: the graph visit count n(v) of the candidate's cell, 0 for a cell never visited)
    /// or `"future_count"` (released code: HESS's future count F of the candidate's 3.0-cell,
    /// 1 for a cell without samples, so a visited cell whose states rarely lead on can beat an
    /// unvisited one, e.g. behind a wall).
    pub count_mode_score: CountModeScore,
    /// What an FR episode does once φ(s_t) is within ε of the frontier: `"count_mode"`
    /// (default; paper and code: count mode for the rest of the episode) or `"end_fr"` (an
    /// experiment, not in the paper: that decision is still count mode, then FR mode ends as
    /// after a stuck switch and later decisions come from the episode's normal sources — HESS
    /// exploration subgoals drawn from stored states, or the policy).
    pub near_frontier: NearFrontier,
    /// The low level acts without exploration noise while an FR episode navigates its route.
    /// Default true. Source: code. false is an experiment (not in the paper): navigation
    /// segments keep the low level's exploration noise, as count mode does.
    pub fr_noise_free_low: bool,
    /// Which FR segments (navigation and count mode) report their reaching error to HESS's
    /// potential map, as HESS's explore segments do: `"count_draw"` (default; source: code,
    /// digest §2.3 A.1 and §7: a segment reports when its decision's count draw, probability
    /// `count_prob`, came up, and only while HESS exploration is open), `"every"` (every FR
    /// segment; this project's behaviour before `count_draw` existed, which every earlier ASI
    /// run in docs/RESULTS.md used) or `"off"` (an experiment, not in the paper: only HESS
    /// explore segments feed the potential, so failed FR walks toward the frontier do not
    /// steer the ordinary episodes' explore subgoals away from it).
    pub fr_potential_reports: FrPotentialReports,
    /// The learner stores an FR episode's steps in the low level's replay. Default true
    /// (source: code, every stored step trains the low level). false is an experiment, not in
    /// the paper: the low level then learns only from ordinary episodes (and the noise-free FR
    /// walks do not shape it); `replay/low_size` then trails `ingest/env_steps`.
    pub fr_in_low_replay: bool,
    /// The learner stores an FR episode's segments in the high level's replay. Default true
    /// (source: code, whose high buffer stores `subgoal − ag` for FR decisions too). false is
    /// an experiment, not in the paper: the high level learns only from ordinary episodes, and
    /// makes one update per stored transition, so fewer in all.
    pub fr_in_high_replay: bool,
    /// An FR episode counts in the `count_prob` window (exploration.count_prob_interval_episodes
    /// episodes, far-goal successes / count_prob_success_unit). Default true (source: code:
    /// every training episode counts, and an FR episode always has a far goal although it
    /// walks to the frontier, so it rarely succeeds). false is an experiment, not in the
    /// paper: a window holds that many ordinary episodes and FR episodes are not counted, so
    /// the count schedule follows the ordinary episodes' success rate as it does in HESS.
    pub fr_in_count_window: bool,
    /// SI updates only after this training episode. Default 300. Unit: episodes. Source: code.
    pub si_start_episode: u64,
    /// High-level SI weight α (Eq. 11). Default 0.01. Source: paper and code. 0 turns the
    /// high-level SI step off (no Adam step, counted in `si/skipped_disabled`), so the two
    /// halves of SI can be ablated apart (an experiment, not in the paper).
    pub si_alpha: f64,
    /// Low-level SI weight β (Eq. 12). Default 0.001. Source: paper and code. 0 turns the
    /// low-level SI step off, as α = 0 the high one.
    pub si_beta: f64,
    /// When an SI entry has no route to φ(g̃) (its goal's cell is not in the graph, e.g. an
    /// unexplored far goal), imitate the route to a random frontier seen from φ(s_0) instead.
    /// Default true (source: code). false is an experiment, not in the paper: such entries are
    /// dropped from the batch, so the high level is only taught routes toward its own goal.
    pub si_frontier_fallback: bool,
    /// SI minibatch size (per level). Default 128. Source: supplement and code.
    pub si_batch_size: usize,
    /// Inclusive range of the SI target index k along the route (clamped to its end).
    /// Default [3, 5]. Unit: route nodes. Source: code (`[c//6, c//4]`).
    pub si_k_range: [u32; 2],
    /// Number |u| of nearer route indices used as low-level SI references. Default 3.
    /// Source: supplement and code.
    pub si_n_refs: u32,
    /// SI buffer capacity; the oldest 25 % is dropped when full. Default 5 000 000.
    /// Unit: env steps. Source: code.
    pub si_buffer_capacity: u64,
}

/// Which visit measure FR count mode minimizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CountModeScore {
    /// Visit count n(v) of the candidate's graph node (paper Eq. 10). Default.
    GraphVisits,
    /// HESS future-count hash at the candidate (released code).
    FutureCount,
}

/// What an FR episode does near its frontier (`asi.near_frontier`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NearFrontier {
    /// Count mode for the rest of the episode (paper and code). Default.
    #[default]
    CountMode,
    /// End FR mode after the switching decision; the normal sources decide from then on.
    EndFr,
}

/// Which FR segments report their reaching error to the potential map
/// (`asi.fr_potential_reports`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FrPotentialReports {
    /// Those whose decision's count draw came up, probability `count_prob` (released code).
    /// Default.
    #[default]
    CountDraw,
    /// Every FR segment but an episode's last.
    Every,
    /// None.
    Off,
}

impl Default for AsiConfig {
    fn default() -> Self {
        Self {
            frontier_reaching: true,
            self_imitation: true,
            fr_start_episode: 200,
            fr_prob_schedule: vec![
                FrProbStep {
                    from_episode: 0,
                    p: 0.2,
                },
                FrProbStep {
                    from_episode: 500,
                    p: 0.3,
                },
                FrProbStep {
                    from_episode: 700,
                    p: 0.4,
                },
            ],
            frontier_fraction: 0.9,
            fr_k_range: [3, 6],
            fr_waypoint_straightness: 0.0,
            frontier_epsilon: 8.0,
            stuck_threshold: 1.0,
            count_mode_candidates: 100,
            count_mode_score: CountModeScore::GraphVisits,
            near_frontier: NearFrontier::CountMode,
            fr_noise_free_low: true,
            fr_potential_reports: FrPotentialReports::CountDraw,
            fr_in_low_replay: true,
            fr_in_high_replay: true,
            fr_in_count_window: true,
            si_start_episode: 300,
            si_alpha: 0.01,
            si_beta: 0.001,
            si_frontier_fallback: true,
            si_batch_size: 128,
            si_k_range: [3, 5],
            si_n_refs: 3,
            si_buffer_capacity: 5_000_000,
        }
    }
}

impl AsiConfig {
    /// FR probability for training episode `episode` (0 before `fr_start_episode` is handled
    /// by the caller): the `p` of the last schedule step with `from_episode <= episode`.
    pub fn fr_prob(&self, episode: u64) -> f64 {
        self.fr_prob_schedule
            .iter()
            .take_while(|step| step.from_episode <= episode)
            .last()
            .map_or(0.0, |step| step.p)
    }

    pub(crate) fn check(&self, c: &mut Checker) {
        self.check_schedule(c);
        c.open_interval("asi.frontier_fraction", self.frontier_fraction, 0.0, 1.0);
        c.int_range("asi.fr_k_range", self.fr_k_range);
        c.closed_interval(
            "asi.fr_waypoint_straightness",
            self.fr_waypoint_straightness,
            0.0,
            1.0,
        );
        c.positive("asi.frontier_epsilon", self.frontier_epsilon);
        c.non_negative("asi.stuck_threshold", self.stuck_threshold);
        c.at_least_one(
            "asi.count_mode_candidates",
            self.count_mode_candidates as u64,
        );
        c.non_negative("asi.si_alpha", self.si_alpha);
        c.non_negative("asi.si_beta", self.si_beta);
        c.at_least_one("asi.si_batch_size", self.si_batch_size as u64);
        c.int_range("asi.si_k_range", self.si_k_range);
        c.at_least_one("asi.si_n_refs", u64::from(self.si_n_refs));
        if self.si_buffer_capacity < self.si_batch_size as u64 {
            c.issue(
                "asi.si_buffer_capacity",
                self.si_buffer_capacity,
                "must be at least asi.si_batch_size",
            );
        }
    }

    fn check_schedule(&self, c: &mut Checker) {
        let path = "asi.fr_prob_schedule";
        let shown = || {
            format!(
                "{:?}",
                self.fr_prob_schedule
                    .iter()
                    .map(|s| (s.from_episode, s.p))
                    .collect::<Vec<_>>()
            )
        };
        if self.fr_prob_schedule.first().map(|s| s.from_episode) != Some(0) {
            c.issue(path, shown(), "must be non-empty and start with from_episode = 0, e.g. [{ from_episode = 0, p = 0.2 }]");
        }
        let increasing = self
            .fr_prob_schedule
            .windows(2)
            .all(|w| w[0].from_episode < w[1].from_episode);
        if !increasing {
            c.issue(path, shown(), "from_episode must be strictly increasing");
        }
        for (i, step) in self.fr_prob_schedule.iter().enumerate() {
            c.closed_interval(&format!("{path}[{i}].p"), step.p, 0.0, 1.0);
        }
    }
}
