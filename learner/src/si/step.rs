//! [`SelfImitation`]: the SI schedule, the high and low imitation steps, and their counters
//! (SPEC §6.7, digest §8).
//!
//! Schedule: every training episode that ends after `asi.si_start_episode` (the run-wide count
//! is `> si_start_episode`, as the code's `epoch > 300`) makes one SI round due; the learner
//! runs due rounds between its SAC updates, never during a φ round. A round is one high-level
//! step and then one low-level step, each on its own uniform batch of `asi.si_batch_size`
//! buffer entries, each its own Adam step on the level's policy optimiser (the same optimiser as
//! the level's SAC actor step), not added to the RL losses.
//!
//! Skips are counted per level step (a round has two): SI switched off (or the level's weight
//! α or β is 0, an ablation of one half of SI), no answer from the route
//! source, a graph with another φ version, no usable route left, an empty buffer, or a loss that
//! is NaN or infinite, or whose gradient is (e.g. states so large that the policy or φ overflows
//! f32; issue #7): then no Adam step is taken, the policy is untouched and the round is done as
//! usual.
//!
//! Low-level policy: the SAC low level's action at `[s_t, φ(s_t), subgoal]` is its deterministic
//! action `scale · tanh(μ)` — the counterpart of the reference code's deterministic actor, which
//! the deterministic low level uses as it is (steps on the actor's Adam, unclipped, as the code).

use candle_core::{Device, Tensor};
use nets::LowPolicy;
use protocol::graph::{LatentPoint, RouteQuery};
use protocol::{Config, PhiVersion};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::error::LearnerError;
use crate::setup::Networks;
use crate::si::buffer::SiBuffer;
use crate::si::indices::{reference_indices, target_index, MIN_HIGH_ROUTE_LEN, MIN_LOW_ROUTE_LEN};
use crate::si::losses::{high_si_loss, low_si_loss, SiLossStats};
use crate::si::routes::{usable_route, RouteKind, RouteSource, RoutesReply};

/// SI settings, from `[asi]` (see `protocol::config::AsiConfig` for defaults and sources).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SiParams {
    /// `asi.self_imitation`.
    pub enabled: bool,
    /// `asi.si_start_episode`: rounds are due for episodes ending after this many.
    pub start_episode: u64,
    /// `asi.si_alpha` (α, Eq. 11).
    pub alpha: f64,
    /// `asi.si_beta` (β, Eq. 12).
    pub beta: f64,
    /// `asi.si_frontier_fallback`: entries without a route to φ(g̃) imitate a route to a
    /// frontier (true) or are dropped (false).
    pub frontier_fallback: bool,
    /// `asi.si_batch_size`, per level step.
    pub batch_size: usize,
    /// `asi.si_k_range`, inclusive.
    pub k_range: [u32; 2],
    /// `asi.si_n_refs` (|u|).
    pub n_refs: u32,
    /// `asi.si_buffer_capacity`, entries.
    pub buffer_capacity: usize,
}

impl SiParams {
    /// The `[asi]` SI fields of `config`.
    pub fn from_config(config: &Config) -> Self {
        let a = &config.asi;
        Self {
            enabled: a.self_imitation,
            start_episode: a.si_start_episode,
            alpha: a.si_alpha,
            beta: a.si_beta,
            frontier_fallback: a.si_frontier_fallback,
            batch_size: a.si_batch_size,
            k_range: a.si_k_range,
            n_refs: a.si_n_refs,
            buffer_capacity: usize::try_from(a.si_buffer_capacity).unwrap_or(usize::MAX),
        }
    }
}

/// Why a level step was skipped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SiSkip {
    /// `asi.self_imitation` is off, or the level's weight (α or β) is 0.
    Disabled,
    /// The route source gave no answer.
    NoAnswer,
    /// The graph uses another φ version.
    PhiMismatch,
    /// No sampled entry had a usable route.
    NoUsableRoute,
    /// The buffer holds no entry.
    EmptyBuffer,
    /// The loss was NaN or infinite: no Adam step, the policy untouched.
    NonFinite,
}

/// SI counters and the latest values (metrics `si/*`, `docs/METRICS.md`).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SiStats {
    /// Latest high-level loss.
    pub high: SiLossStats,
    /// Latest low-level loss.
    pub low: SiLossStats,
    /// Latest high step: global L2 norm of the weighted loss's (α·L) gradient over the high
    /// policy's variables, as its Adam step saw it.
    pub high_grad_norm: f64,
    /// Latest low step: the same for β·L over the low policy's variables.
    pub low_grad_norm: f64,
    /// Latest high batch: fraction of sampled entries with a usable route (`L > 1`).
    pub usable_fraction: f64,
    /// Latest low batch: fraction of sampled entries with a usable route (`L > 2`).
    pub low_usable_fraction: f64,
    /// Latest high batch: fraction of the usable routes that lead to a frontier (fallback).
    pub via_frontier_fraction: f64,
    /// SI rounds that fell due (episodes ending after `si_start_episode`).
    pub rounds_due: u64,
    /// High-level Adam steps taken.
    pub high_steps: u64,
    /// Low-level Adam steps taken.
    pub low_steps: u64,
    /// Level steps skipped because SI is off or the level's weight is 0.
    pub skipped_disabled: u64,
    /// Level steps skipped for want of an answer.
    pub skipped_no_answer: u64,
    /// Level steps skipped because the graph uses another φ version.
    pub skipped_phi_mismatch: u64,
    /// Level steps skipped because no usable route remained.
    pub skipped_no_usable_route: u64,
    /// Level steps skipped because the buffer was empty.
    pub skipped_empty_buffer: u64,
    /// Level steps skipped because their loss was NaN or infinite (no Adam step).
    pub skipped_nonfinite: u64,
}

impl SiStats {
    /// All skipped level steps.
    pub fn skipped(&self) -> u64 {
        self.skipped_disabled
            + self.skipped_no_answer
            + self.skipped_phi_mismatch
            + self.skipped_no_usable_route
            + self.skipped_empty_buffer
            + self.skipped_nonfinite
    }

    fn count_skip(&mut self, skip: SiSkip) {
        match skip {
            SiSkip::Disabled => self.skipped_disabled += 1,
            SiSkip::NoAnswer => self.skipped_no_answer += 1,
            SiSkip::PhiMismatch => self.skipped_phi_mismatch += 1,
            SiSkip::NoUsableRoute => self.skipped_no_usable_route += 1,
            SiSkip::EmptyBuffer => self.skipped_empty_buffer += 1,
            SiSkip::NonFinite => self.skipped_nonfinite += 1,
        }
    }
}

/// Which level an SI step trains.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Level {
    High,
    Low,
}

impl Level {
    fn min_route_len(self) -> usize {
        match self {
            Level::High => MIN_HIGH_ROUTE_LEN,
            Level::Low => MIN_LOW_ROUTE_LEN,
        }
    }
}

/// A sampled batch with its φ values, before routes are known. Rows are back to back.
struct Sampled {
    n: usize,
    obs: Vec<f32>,
    goal: Vec<f32>,
    phi: Vec<LatentPoint>,
    phi_s0: Vec<LatentPoint>,
    phi_goal: Vec<LatentPoint>,
}

/// The entries of a batch with a usable route, and their route points.
struct Usable {
    obs: Vec<f32>,
    goal: Vec<f32>,
    phi: Vec<f32>,
    target: Vec<f32>,
    /// Low level only: `n_refs` route points per row, back to back.
    refs: Vec<f32>,
    n: usize,
    via_frontier: usize,
}

/// The SI state of the learner: buffer, schedule, counters. See the module doc.
#[derive(Debug, Clone)]
pub struct SelfImitation {
    params: SiParams,
    buffer: SiBuffer,
    obs_dim: usize,
    goal_dim: usize,
    pending: u64,
    /// Consecutive attempts of the oldest due round that met a graph with another φ version.
    phi_attempts: u32,
    stats: SiStats,
}

/// How many times a due round whose high-level step met a graph with another φ version (the
/// graph-service re-maps its nodes right after a φ round) is kept pending and tried again on a
/// later call of [`SelfImitation::run_round`] before it is given up and its steps are counted
/// in `skipped_phi_mismatch`. Unit: attempts. Source: this implementation (the reference code
/// runs graph and learner in one process, where the race cannot happen).
pub const SI_PHI_MISMATCH_ATTEMPTS: u32 = 100;

impl SelfImitation {
    /// SI for observations of `obs_dim` and goals of `goal_dim` values.
    pub fn new(params: SiParams, obs_dim: usize, goal_dim: usize) -> Self {
        Self {
            buffer: SiBuffer::new(obs_dim, goal_dim, params.buffer_capacity),
            params,
            obs_dim,
            goal_dim,
            pending: 0,
            phi_attempts: 0,
            stats: SiStats::default(),
        }
    }

    /// The settings.
    pub fn params(&self) -> &SiParams {
        &self.params
    }

    /// The buffer.
    pub fn buffer(&self) -> &SiBuffer {
        &self.buffer
    }

    /// The buffer to fill while ingesting. It is filled whether SI is on or off, as in the
    /// reference code (every step of every episode): filling draws no random number and changes
    /// no policy, so runs with SI on and off stay identical until `si_start_episode`, and a run
    /// with SI off can be resumed with SI on and go on exactly as one with SI on from the start.
    pub fn buffer_mut(&mut self) -> &mut SiBuffer {
        &mut self.buffer
    }

    /// Counters and latest values.
    pub fn stats(&self) -> &SiStats {
        &self.stats
    }

    /// The counters and latest statistics, for a checkpoint restore.
    pub(crate) fn stats_mut(&mut self) -> &mut SiStats {
        &mut self.stats
    }

    /// SI rounds due and not yet run.
    pub fn pending(&self) -> u64 {
        self.pending
    }

    /// Replaces the buffer, the due rounds and the counters (checkpoint restore). `Err` when
    /// the buffer's sizes differ from this learner's.
    pub fn restore(
        &mut self,
        buffer: SiBuffer,
        pending: u64,
        stats: SiStats,
    ) -> Result<(), String> {
        if buffer.dims() != (self.obs_dim, self.goal_dim) {
            return Err(format!(
                "SI buffer sizes {:?} do not match obs_dim {} / goal_dim {}",
                buffer.dims(),
                self.obs_dim,
                self.goal_dim
            ));
        }
        self.buffer = buffer;
        self.pending = pending;
        self.phi_attempts = 0;
        self.stats = stats;
        Ok(())
    }

    /// Notes the end of a training episode; `train_episodes` is the run-wide count including it.
    /// Past `si_start_episode` a round falls due (or, with SI off, its two steps are counted as
    /// skipped).
    pub fn on_episode_end(&mut self, train_episodes: u64) {
        if train_episodes <= self.params.start_episode {
            return;
        }
        self.stats.rounds_due += 1;
        if self.params.enabled {
            self.pending += 1;
        } else {
            self.stats.skipped_disabled += 2;
        }
    }

    /// Runs one due round (high step, then low step) if any; returns the Adam steps taken
    /// (0–2). A round whose high step meets a graph with another φ version stays due and is
    /// tried again on the next call, up to [`SI_PHI_MISMATCH_ATTEMPTS`] attempts in a row; then
    /// it is given up and its skipped steps are counted. Points are computed with the learner's encoder, whose φ version is `phi_version`.
    pub fn run_round(
        &mut self,
        nets: &mut Networks,
        rng: &mut impl Rng,
        source: &mut dyn RouteSource,
        phi_version: PhiVersion,
    ) -> Result<usize, LearnerError> {
        if self.pending == 0 {
            return Ok(0);
        }
        let mut steps = 0;
        for level in [Level::High, Level::Low] {
            match self.level_step(level, nets, rng, source, phi_version)? {
                Ok(()) => steps += 1,
                Err(SiSkip::PhiMismatch)
                    if level == Level::High && self.phi_attempts + 1 < SI_PHI_MISMATCH_ATTEMPTS =>
                {
                    // The graph has not re-mapped to our φ yet: keep the round for later.
                    self.phi_attempts += 1;
                    return Ok(0);
                }
                Err(skip) => self.stats.count_skip(skip),
            }
        }
        self.phi_attempts = 0;
        self.pending -= 1;
        Ok(steps)
    }

    /// One level step: batch, routes, loss, Adam step; `Ok(Err(skip))` when skipped.
    fn level_step(
        &mut self,
        level: Level,
        nets: &mut Networks,
        rng: &mut impl Rng,
        source: &mut dyn RouteSource,
        phi_version: PhiVersion,
    ) -> Result<Result<(), SiSkip>, LearnerError> {
        let rows = self.buffer.sample(rng, self.params.batch_size);
        if rows.is_empty() {
            return Ok(Err(SiSkip::EmptyBuffer));
        }
        let sampled = self.embed(&rows, nets)?;
        let queries = queries(&sampled, self.params.frontier_fallback);
        let answers = match source.routes(&queries, phi_version) {
            RoutesReply::Answered(answers) if answers.len() == sampled.n => answers,
            // An answer of the wrong length is unusable: counted as no answer.
            RoutesReply::Answered(_) | RoutesReply::NoAnswer => return Ok(Err(SiSkip::NoAnswer)),
            RoutesReply::PhiMismatch { .. } => return Ok(Err(SiSkip::PhiMismatch)),
        };
        let usable = self.select(level, &sampled, &answers, rng);
        let fraction = usable.n as f64 / sampled.n as f64;
        match level {
            Level::High => {
                self.stats.usable_fraction = fraction;
                self.stats.via_frontier_fraction = if usable.n > 0 {
                    usable.via_frontier as f64 / usable.n as f64
                } else {
                    0.0
                };
            }
            Level::Low => self.stats.low_usable_fraction = fraction,
        }
        if usable.n == 0 {
            return Ok(Err(SiSkip::NoUsableRoute));
        }
        // A zero weight turns the level's step off. Only the Adam step is left out: the batch
        // and its route figures above are still drawn and reported, and a high step that met
        // another φ version has already kept its round pending.
        let weight = match level {
            Level::High => self.params.alpha,
            Level::Low => self.params.beta,
        };
        if weight == 0.0 {
            return Ok(Err(SiSkip::Disabled));
        }
        match level {
            Level::High => self.high_step(&usable, nets, rng),
            Level::Low => self.low_step(&usable, nets),
        }
    }

    /// The sampled rows and their φ(s_t), φ(s_0), φ(g̃) under the current encoder (one forward
    /// pass, no gradient).
    fn embed(&self, rows: &[usize], nets: &Networks) -> Result<Sampled, LearnerError> {
        let n = rows.len();
        let (d, g) = (self.obs_dim, self.goal_dim);
        let mut obs = Vec::with_capacity(n * d);
        let mut goal = Vec::with_capacity(n * g);
        let mut s0 = Vec::with_capacity(n * d);
        let mut tilde = Vec::with_capacity(n * d);
        for entry in rows.iter().filter_map(|&i| self.buffer.get(i)) {
            obs.extend_from_slice(entry.obs);
            goal.extend_from_slice(entry.goal);
            s0.extend_from_slice(entry.s0);
            // g̃: s_t with its first goal_dim coordinates (xy) replaced by the goal.
            let replaced = g.min(d);
            tilde.extend_from_slice(&entry.goal[..replaced]);
            tilde.extend_from_slice(&entry.obs[replaced..]);
        }
        let n = goal.len() / g.max(1);
        let all = [obs.as_slice(), &s0, &tilde].concat();
        let x = Tensor::from_slice(&all, (3 * n, d), &Device::Cpu)?;
        let latent = nets
            .policies
            .encoder
            .forward(&x)?
            .detach()
            .to_vec2::<f32>()?;
        let points: Vec<LatentPoint> = latent
            .iter()
            .map(|row| {
                [
                    row.first().copied().unwrap_or(f32::NAN),
                    row.get(1).copied().unwrap_or(f32::NAN),
                ]
            })
            .collect();
        Ok(Sampled {
            n,
            obs,
            goal,
            phi: points[..n].to_vec(),
            phi_s0: points[n..2 * n].to_vec(),
            phi_goal: points[2 * n..].to_vec(),
        })
    }

    /// Keeps the rows whose route is long enough for `level`, with their target (and, for the
    /// low level, reference) route points; draws k per kept row.
    fn select(
        &self,
        level: Level,
        sampled: &Sampled,
        answers: &[protocol::graph::RouteAnswer],
        rng: &mut impl Rng,
    ) -> Usable {
        let (d, g) = (self.obs_dim, self.goal_dim);
        let mut out = Usable {
            obs: Vec::new(),
            goal: Vec::new(),
            phi: Vec::new(),
            target: Vec::new(),
            refs: Vec::new(),
            n: 0,
            via_frontier: 0,
        };
        for (i, answer) in answers.iter().enumerate() {
            let Some((route, kind)) = usable_route(answer, level.min_route_len()) else {
                continue;
            };
            let k = rng.random_range(self.params.k_range[0]..=self.params.k_range[1]);
            let Some(idx) = target_index(k, route.len()) else {
                continue;
            };
            out.obs.extend_from_slice(&sampled.obs[i * d..(i + 1) * d]);
            out.goal
                .extend_from_slice(&sampled.goal[i * g..(i + 1) * g]);
            out.phi.extend_from_slice(&sampled.phi[i]);
            out.target.extend_from_slice(&route[idx]);
            if level == Level::Low {
                for u in reference_indices(idx, route.len(), self.params.n_refs) {
                    out.refs.extend_from_slice(&route[u]);
                }
            }
            out.n += 1;
            out.via_frontier += usize::from(kind == RouteKind::ViaFrontier);
        }
        out
    }

    /// The high-level step: L_hi on a reparameterised sample of π_hi([s_t, g]); skipped when
    /// L_hi is not finite.
    fn high_step(
        &mut self,
        usable: &Usable,
        nets: &mut Networks,
        rng: &mut impl Rng,
    ) -> Result<Result<(), SiSkip>, LearnerError> {
        let cpu = Device::Cpu;
        let m = usable.n;
        let obs = Tensor::from_slice(&usable.obs, (m, self.obs_dim), &cpu)?;
        let goal = Tensor::from_slice(&usable.goal, (m, self.goal_dim), &cpu)?;
        let policy = nets.high.policy();
        let latent_dim = policy.action_dim();
        let noise: Vec<f32> = (0..m * latent_dim)
            .map(|_| StandardNormal.sample(rng))
            .collect();
        let eps = Tensor::from_slice(&noise, (m, latent_dim), &cpu)?;
        let (action, _) = policy.sample(&Tensor::cat(&[&obs, &goal], 1)?, &eps)?;
        let target = Tensor::from_slice(&usable.target, (m, 2), &cpu)?;
        let phi = Tensor::from_slice(&usable.phi, (m, 2), &cpu)?;
        let (loss, stats) = high_si_loss(&action, &target, &phi, self.params.alpha)?;
        if !finite_with_gradient(&loss, stats.loss, nets)? {
            return Ok(Err(SiSkip::NonFinite));
        }
        self.stats.high_grad_norm =
            nets.high
                .policy_step(&loss, "self-imitation loss", stats.loss)?;
        self.stats.high = stats;
        self.stats.high_steps += 1;
        Ok(Ok(()))
    }

    /// The low-level step: L_lo between the action at the target and the (detached) actions at
    /// the reference route points; skipped when L_lo is not finite.
    fn low_step(
        &mut self,
        usable: &Usable,
        nets: &mut Networks,
    ) -> Result<Result<(), SiSkip>, LearnerError> {
        let cpu = Device::Cpu;
        let m = usable.n;
        let u = self.params.n_refs as usize;
        let obs = Tensor::from_slice(&usable.obs, (m, self.obs_dim), &cpu)?;
        let phi = Tensor::from_slice(&usable.phi, (m, 2), &cpu)?;
        let base = Tensor::cat(&[&obs, &phi], 1)?;
        let target = Tensor::from_slice(&usable.target, (m, 2), &cpu)?;
        let policy = &nets.policies.low;
        let aligned = low_action(policy, &base, &target)?;
        let refs = Tensor::from_slice(&usable.refs, (m * u, 2), &cpu)?;
        // Row r's references are rows r·U … r·U + U − 1: repeat each base row U times.
        let base_rep = base
            .unsqueeze(1)?
            .repeat((1, u, 1))?
            .reshape((m * u, base.dim(1)?))?;
        let reference = low_action(policy, &base_rep, &refs)?;
        let action_dim = reference.dim(1)?;
        let reference = reference.reshape((m, u, action_dim))?;
        let (loss, stats) = low_si_loss(&aligned, &reference, self.params.beta)?;
        if !finite_with_gradient(&loss, stats.loss, nets)? {
            return Ok(Err(SiSkip::NonFinite));
        }
        self.stats.low_grad_norm =
            nets.low
                .policy_step(&loss, "self-imitation loss", stats.loss)?;
        self.stats.low = stats;
        self.stats.low_steps += 1;
        Ok(Ok(()))
    }
}

/// Whether `loss` (whose value is `value`) and its gradient for every policy variable are
/// finite. A finite loss can still have a non-finite gradient — π_lo's tanh saturated by
/// overflowing pre-activations gives a loss of 0 and a gradient with ∞ · 0 in it — which the
/// Adam step would write into the weights. The gradient is computed here once more than needed
/// (the level's `policy_step` runs its own backward pass); an SI step is rare next to the SAC
/// updates.
fn finite_with_gradient(loss: &Tensor, value: f64, nets: &Networks) -> Result<bool, LearnerError> {
    if !value.is_finite() {
        return Ok(false);
    }
    let grads = loss.backward()?;
    for var in nets.policy_vm.all_vars() {
        if let Some(grad) = grads.get(var.as_tensor()) {
            let values = grad.flatten_all()?.to_vec1::<f32>()?;
            if !values.iter().all(|v| v.is_finite()) {
                return Ok(false);
            }
        }
    }
    Ok(true)
}

/// π_lo's deterministic action at `[base, subgoal]` (`base = [s_t, φ(s_t)]`).
pub fn low_action(
    policy: &LowPolicy,
    base: &Tensor,
    subgoal: &Tensor,
) -> Result<Tensor, LearnerError> {
    Ok(policy.deterministic(&Tensor::cat(&[base, subgoal], 1)?)?)
}

/// One route query per sampled row: φ(s_t) → φ(g̃), with `fallback` falling back to a frontier
/// seen from φ(s_0).
fn queries(sampled: &Sampled, fallback: bool) -> Vec<RouteQuery> {
    (0..sampled.n)
        .map(|i| RouteQuery {
            start: sampled.phi[i],
            end: sampled.phi_goal[i],
            fallback_origin: fallback.then_some(sampled.phi_s0[i]),
        })
        .collect()
}

#[cfg(test)]
mod tests;
