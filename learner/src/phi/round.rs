//! φ training rounds (SPEC §6.3, digest §4): schedule, sampling, Adam steps, priorities.
//!
//! Schedule: round `j` (0, 1, …) is due once `first_round_episode + j · interval_episodes`
//! training episodes have been ingested (the code's "epoch 100, 200, …"; the code's epoch
//! counts from 0, so its round at epoch 100 follows the 101st episode — one episode apart).
//! Rounds never overlap. Overdue rounds coalesce (rule): when a round starts, every schedule
//! point already reached is consumed by it, so a learner that fell behind (actors that ran on
//! while it was busy) runs one round, not a burst that would starve the SAC updates; the
//! skipped points are counted ([`PhiStats::coalesced_rounds`]). Serial mode checks after
//! every chunk, so there no point is ever skipped.
//!
//! A round: freeze the store and list its candidates `(run, t)`, `t + k` inside the run;
//! snapshot `φ_old ← φ`; then `steps_per_round` Adam steps (lr `encoder.lr`, batch
//! `encoder.batch_size`) on `L_tri + L_s`:
//! - anchors uniform (with replacement) from the `anchor_high_ratio` fraction of candidates
//!   with the highest stored priority p (the code's `high_p`; in round 0 all p = 1 and the
//!   split is an arbitrary but deterministic partition, as the code's argsort);
//! - regularised states s per `encoder.stable_weighting`: `inverse_sqrt_priority` samples
//!   candidates with probability ∝ 1/√(1 + p) (the paper's intent: smaller triplet loss →
//!   larger λ; the code's unused `prioritized_collect`), `drop_lowest_loss` samples uniformly
//!   above the `regularization_low_ratio` quantile of p (the code's `low_p`); the loss weight
//!   λ itself is 1 in both (the weighting is in the sampling);
//! - the stable term from the second round started on (code: `epoch > 100`), with
//!   `stable_coeff`, or `stable_coeff_late` for rounds whose schedule point lies after
//!   `stable_coeff_switch_episode` episodes (code: `epoch > 500`);
//! - every sampled anchor's per-sample triplet loss (from the step's forward pass) is kept
//!   and written back as its priority when the round ends; later samples overwrite earlier
//!   ones, never-sampled states keep theirs.
//!
//! A step whose loss is NaN or infinite (e.g. states so large that φ overflows f32) is skipped:
//! no Adam step, φ and the priorities untouched, counted
//! ([`PhiStats::skipped_nonfinite_steps`]); it still uses up one of the round's steps, so a
//! round always ends. A round whose every step was skipped ends without changing φ and is
//! counted ([`PhiStats::nonfinite_rounds`]), not published.
//!
//! The Adam state (moments, step count) persists across rounds; φ is never re-initialised.
//! Work is done in slices ([`PhiTrainer::run_slice`]) so that the owner stays responsive.
//!
//! Where the steps run: a round reads its triplets from a [`StoreView`] taken at its start, so
//! its steps ([`PhiTrainer::advance`]) need no access to the store and can run on another
//! thread; only the start (priorities, freeze) and the end ([`PhiTrainer::conclude`]:
//! priorities written back, thaw) touch the store. A trainer made with
//! [`PhiTrainer::with_private_copy`] trains a copy of the encoder, set from the published
//! one when a round starts and copied into it when the round ends, so nothing reading the
//! published encoder sees a round half done (`encoder.background_rounds`,
//! [`crate::phi::worker`]); the steps are the same arithmetic either way.

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use nets::{prefix, Encoder, NetsSpec};
use protocol::config::StableWeighting;
use protocol::Config;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use crate::adam::{Adam, AdamParams};
use crate::error::LearnerError;
use crate::phi::losses::{stable_loss, triplet_loss, TripletStats};
use crate::phi::store::{Candidate, PhiStore, StoreView};

/// `[encoder]` round parameters, resolved (k from `hierarchy.c` when absent).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhiParams {
    /// Adam learning rate.
    pub lr: f64,
    /// Anchors (and regularised states) per step.
    pub batch_size: usize,
    /// Adam steps per round.
    pub steps_per_round: u64,
    /// Episodes between rounds.
    pub interval_episodes: u64,
    /// Episodes before the first round.
    pub first_round_episode: u64,
    /// Triplet margin δ.
    pub margin: f64,
    /// Negative offset k (env steps).
    pub negative_offset: usize,
    /// Stable coefficient, early.
    pub stable_coeff: f64,
    /// Stable coefficient, late.
    pub stable_coeff_late: f64,
    /// Rounds at more than this many episodes use the late coefficient.
    pub stable_coeff_switch_episode: u64,
    /// Top fraction of candidates (by p) that anchors come from.
    pub anchor_high_ratio: f64,
    /// Lowest fraction excluded from regularisation with `DropLowestLoss`.
    pub regularization_low_ratio: f64,
    /// How regularised states are chosen.
    pub weighting: StableWeighting,
}

impl PhiParams {
    /// The parameters of `config`.
    pub fn from_config(config: &Config) -> Self {
        let e = &config.encoder;
        Self {
            lr: e.lr,
            batch_size: e.batch_size,
            steps_per_round: e.steps_per_round,
            interval_episodes: e.interval_episodes.max(1),
            first_round_episode: e.first_round_episode,
            margin: e.triplet_margin,
            negative_offset: e.negative_offset_or(config.hierarchy.c) as usize,
            stable_coeff: e.stable_coeff,
            stable_coeff_late: e.stable_coeff_late,
            stable_coeff_switch_episode: e.stable_coeff_switch_episode,
            anchor_high_ratio: e.anchor_high_ratio,
            regularization_low_ratio: e.regularization_low_ratio,
            weighting: e.stable_weighting,
        }
    }

    /// Training episodes after which round `index` is due.
    pub fn round_episode(&self, index: u64) -> u64 {
        self.first_round_episode
            .saturating_add(index.saturating_mul(self.interval_episodes))
    }

    /// The stable coefficient of round `index` (0 for the first round).
    pub fn stable_coeff_for(&self, index: u64) -> f64 {
        if index == 0 {
            0.0
        } else if self.round_episode(index) > self.stable_coeff_switch_episode {
            self.stable_coeff_late
        } else {
            self.stable_coeff
        }
    }
}

/// Statistics of φ training, for metrics.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PhiStats {
    /// The latest step's triplet statistics.
    pub triplet: TripletStats,
    /// The latest step's stable loss (0 in round 0).
    pub stable_loss: f64,
    /// Rounds completed.
    pub rounds: u64,
    /// Rounds skipped because the store held no candidate.
    pub skipped_rounds: u64,
    /// Schedule points consumed by a later round because the learner was behind.
    pub coalesced_rounds: u64,
    /// Adam steps run in total.
    pub steps: u64,
    /// Steps skipped because their loss was NaN or infinite (no Adam step, φ unchanged).
    pub skipped_nonfinite_steps: u64,
    /// Rounds whose every step was skipped as non-finite: ended with φ unchanged, not
    /// counted in `rounds`, nothing to publish.
    pub nonfinite_rounds: u64,
    /// Seconds spent in φ steps (metrics only).
    pub secs: f64,
    /// Mean per-sample triplet loss over the first slice of the latest round.
    pub round_start_loss: f64,
    /// Mean per-sample triplet loss over the last slice of the latest completed round.
    pub round_end_loss: f64,
}

/// How regularised states are drawn.
#[derive(Debug, Clone)]
enum RegSampler {
    /// Uniform over these candidate indices.
    Uniform(Vec<u32>),
    /// ∝ weights, as a cumulative sum over all candidates.
    Cumulative(Vec<f64>),
}

impl RegSampler {
    fn draw(&self, rng: &mut Pcg64Mcg) -> usize {
        match self {
            Self::Uniform(pool) => pool[rng.random_range(0..pool.len())] as usize,
            Self::Cumulative(cum) => {
                let total = cum.last().copied().unwrap_or(0.0);
                let u = rng.random::<f64>() * total;
                cum.partition_point(|&c| c <= u).min(cum.len() - 1)
            }
        }
    }
}

/// A round in progress.
struct ActiveRound {
    index: u64,
    coeff: f64,
    old: Encoder,
    /// The store's observations at the round's start: the candidates index into it.
    view: StoreView,
    candidates: Vec<Candidate>,
    anchors: Vec<u32>,
    reg: RegSampler,
    new_priority: Vec<f32>,
    steps_done: u64,
    /// Of `steps_done`, those skipped for a non-finite loss.
    skipped_steps: u64,
    slice_loss_sum: f64,
    slice_samples: u64,
}

/// What a slice of work did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SliceOutcome {
    /// Steps of the round used up: Adam steps run plus steps skipped for a non-finite loss.
    pub steps: u64,
    /// Of `steps`, those skipped for a non-finite loss (no Adam step).
    pub skipped_nonfinite: u64,
    /// The round ended in this slice and φ changed (publish it). A round whose every step
    /// was skipped ends with this `false`: the trainer is idle again, φ is unchanged.
    pub round_finished: bool,
}

/// What [`PhiTrainer::advance`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Advance {
    /// Steps of the round used up (Adam steps plus skipped non-finite ones).
    pub steps: u64,
    /// Of `steps`, those skipped for a non-finite loss.
    pub skipped_nonfinite: u64,
    /// Every step of the round has run: [`PhiTrainer::conclude`] ends it.
    pub done: bool,
}

/// The φ trainer: the encoder's parameters (the published ones, or a private copy of them),
/// their Adam, the round state.
pub struct PhiTrainer {
    params: PhiParams,
    spec_hidden: Vec<usize>,
    obs_dim: usize,
    latent_dim: usize,
    encoder: Encoder,
    vars: Vec<Var>,
    /// With a private copy: the published encoder's variables (same order as `vars`), set
    /// from `vars` when a round ends. `None`: `vars` are the published ones.
    published: Option<Vec<Var>>,
    names: Vec<String>,
    opt: Adam,
    rng: Pcg64Mcg,
    next_round: u64,
    active: Option<ActiveRound>,
    stats: PhiStats,
    staging: Vec<f32>,
}

impl PhiTrainer {
    /// A trainer of the `encoder.*` parameters of `policy_vm` (shared storage: the published
    /// φ is the trained one); `seed` seeds the triplet sampling.
    pub fn new(
        params: PhiParams,
        spec: &NetsSpec,
        policy_vm: &VarMap,
        seed: u64,
    ) -> Result<Self, LearnerError> {
        Self::build(params, spec, policy_vm, None, seed)
    }

    /// A trainer of a private copy of the `encoder.*` parameters of `policy_vm`: a round
    /// starts from the published values and writes its result into them when it ends
    /// ([`PhiTrainer::conclude`]); meanwhile the published encoder does not change. Same
    /// steps, same results as [`PhiTrainer::new`].
    pub fn with_private_copy(
        params: PhiParams,
        spec: &NetsSpec,
        policy_vm: &VarMap,
        seed: u64,
    ) -> Result<Self, LearnerError> {
        let (names, published) = encoder_vars(policy_vm);
        let private = VarMap::new();
        {
            let mut data = private.data().lock().unwrap_or_else(|p| p.into_inner());
            for (name, var) in names.iter().zip(&published) {
                data.insert(name.clone(), Var::from_tensor(&var.as_tensor().copy()?)?);
            }
        }
        Self::build(params, spec, &private, Some(published), seed)
    }

    fn build(
        params: PhiParams,
        spec: &NetsSpec,
        policy_vm: &VarMap,
        published: Option<Vec<Var>>,
        seed: u64,
    ) -> Result<Self, LearnerError> {
        let (names, vars) = encoder_vars(policy_vm);
        if vars.is_empty() {
            return Err(LearnerError::Nets(nets::NetsError::Spec(
                "the policy set has no `encoder.*` parameter".to_owned(),
            )));
        }
        let vb = VarBuilder::from_varmap(policy_vm, DType::F32, &Device::Cpu);
        let encoder = Encoder::new(
            &vb.pp(prefix::ENCODER),
            spec.obs_dim,
            &spec.encoder_hidden,
            spec.latent_dim,
        )?;
        let opt = phi_optimizer(vars.clone(), params.lr)?;
        Ok(Self {
            params,
            spec_hidden: spec.encoder_hidden.clone(),
            obs_dim: spec.obs_dim,
            latent_dim: spec.latent_dim,
            encoder,
            vars,
            published,
            names,
            opt,
            rng: Pcg64Mcg::seed_from_u64(seed),
            next_round: 0,
            active: None,
            stats: PhiStats::default(),
            staging: Vec::new(),
        })
    }

    /// Whether a round is in progress.
    pub fn is_active(&self) -> bool {
        self.active.is_some()
    }

    /// The state a checkpoint carries between rounds: the optimiser, the sampling generator,
    /// the next round index and the statistics.
    pub(crate) fn checkpoint_parts(&self) -> (&Adam, &Pcg64Mcg, u64, PhiStats) {
        (&self.opt, &self.rng, self.next_round, self.stats)
    }

    /// The optimiser, generator, next round and statistics, for a restore (no round runs).
    pub(crate) fn restore_parts(&mut self) -> (&mut Adam, &mut Pcg64Mcg, &mut u64, &mut PhiStats) {
        (
            &mut self.opt,
            &mut self.rng,
            &mut self.next_round,
            &mut self.stats,
        )
    }

    /// Index of the next round to start (= rounds started so far).
    pub fn next_round(&self) -> u64 {
        self.next_round
    }

    /// Training episodes at which the next round is due.
    pub fn next_round_episode(&self) -> u64 {
        self.params.round_episode(self.next_round)
    }

    /// Statistics.
    pub fn stats(&self) -> PhiStats {
        self.stats
    }

    /// The parameters in use.
    pub fn params(&self) -> &PhiParams {
        &self.params
    }

    /// Starts the next round if `train_episodes` reached it and none is running; freezes
    /// `store`. Returns whether a round is now active. A round with no candidate is skipped
    /// (counted) and leaves φ unchanged.
    pub fn start_if_due(
        &mut self,
        train_episodes: u64,
        store: &mut PhiStore,
    ) -> Result<bool, LearnerError> {
        if self.active.is_some() {
            return Ok(true);
        }
        if train_episodes < self.next_round_episode() {
            return Ok(false);
        }
        let mut index = self.next_round;
        while self.params.round_episode(index + 1) <= train_episodes {
            index += 1;
            self.stats.coalesced_rounds += 1;
        }
        self.next_round = index + 1;
        let candidates = store.candidates();
        if candidates.is_empty() {
            self.stats.skipped_rounds += 1;
            return Ok(false);
        }
        let priorities: Vec<f32> = candidates
            .iter()
            .map(|c| store.priority(c.run, c.t).unwrap_or(1.0))
            .collect();
        let anchors = top_fraction(&priorities, self.params.anchor_high_ratio);
        let reg = match self.params.weighting {
            StableWeighting::InverseSqrtPriority => RegSampler::Cumulative(cumulative(
                priorities
                    .iter()
                    .map(|&p| 1.0 / (1.0 + f64::from(p).max(0.0)).sqrt()),
            )),
            StableWeighting::DropLowestLoss => RegSampler::Uniform(top_fraction(
                &priorities,
                1.0 - self.params.regularization_low_ratio,
            )),
        };
        if let Some(published) = &self.published {
            for (private, var) in self.vars.iter().zip(published) {
                private.set(var.as_tensor())?;
            }
        }
        store.freeze();
        self.active = Some(ActiveRound {
            index,
            // The first round completed has no stable term (there is no earlier φ to keep).
            coeff: if self.stats.rounds == 0 {
                0.0
            } else {
                self.params.stable_coeff_for(index.max(1))
            },
            old: self.snapshot()?,
            view: store.view(),
            new_priority: vec![f32::NAN; candidates.len()],
            candidates,
            anchors,
            reg,
            steps_done: 0,
            skipped_steps: 0,
            slice_loss_sum: 0.0,
            slice_samples: 0,
        });
        Ok(true)
    }

    /// φ_old: a detached copy of the current encoder.
    fn snapshot(&self) -> Result<Encoder, LearnerError> {
        let tensors = self
            .names
            .iter()
            .zip(&self.vars)
            .map(|(n, v)| Ok((n.clone(), v.as_tensor().copy()?.detach())))
            .collect::<Result<std::collections::HashMap<_, _>, LearnerError>>()?;
        let vb = VarBuilder::from_tensors(tensors, DType::F32, &Device::Cpu);
        Ok(Encoder::new(
            &vb.pp(prefix::ENCODER),
            self.obs_dim,
            &self.spec_hidden,
            self.latent_dim,
        )?)
    }

    /// Runs at most `max_steps` steps of the active round; at its end writes the priorities
    /// back, thaws `store` and reports `round_finished` (unless every step of the round was
    /// skipped as non-finite). No-op without an active round. A non-finite step is skipped and
    /// counted, not an error; an error ends the round (thawed, priorities not written).
    pub fn run_slice(
        &mut self,
        store: &mut PhiStore,
        max_steps: u64,
    ) -> Result<SliceOutcome, LearnerError> {
        let advance = match self.advance(max_steps) {
            Ok(advance) => advance,
            Err(err) => {
                self.abandon(store);
                return Err(err);
            }
        };
        let round_finished = advance.done && self.conclude(store)?;
        Ok(SliceOutcome {
            steps: advance.steps,
            skipped_nonfinite: advance.skipped_nonfinite,
            round_finished,
        })
    }

    /// Runs at most `max_steps` steps of the active round, reading only the round's
    /// [`StoreView`] (so it may run away from the store's owner). No-op without an active
    /// round. After an error the round stays active: [`PhiTrainer::abandon`] ends it.
    pub fn advance(&mut self, max_steps: u64) -> Result<Advance, LearnerError> {
        let Some(mut round) = self.active.take() else {
            return Ok(Advance::default());
        };
        let start = std::time::Instant::now();
        let n = max_steps.min(self.params.steps_per_round - round.steps_done);
        round.slice_loss_sum = 0.0;
        round.slice_samples = 0;
        let skipped_before = round.skipped_steps;
        let result = (0..n).try_for_each(|_| self.step(&mut round));
        self.stats.secs += start.elapsed().as_secs_f64();
        let advance = Advance {
            steps: n,
            skipped_nonfinite: round.skipped_steps - skipped_before,
            done: round.steps_done >= self.params.steps_per_round,
        };
        // A slice of skipped steps only has no loss to report; the previous value stays.
        let slice_mean =
            (round.slice_samples > 0).then(|| round.slice_loss_sum / round.slice_samples as f64);
        if let (Ok(()), Some(mean)) = (&result, slice_mean) {
            if round.steps_done == n {
                self.stats.round_start_loss = mean;
            }
            if advance.done {
                self.stats.round_end_loss = mean;
            }
        }
        self.active = Some(round);
        result.map(|()| advance)
    }

    /// Ends the active round once all its steps have run: the trained encoder copied into
    /// the published one (with a private copy), the priorities written back, `store` thawed;
    /// returns whether φ changed. A round whose every step was skipped as non-finite ends
    /// with φ and the priorities unchanged (`false`, counted). A round with steps left, or
    /// none, is left as it is (`false`).
    pub fn conclude(&mut self, store: &mut PhiStore) -> Result<bool, LearnerError> {
        let Some(round) = self.active.take() else {
            return Ok(false);
        };
        if round.steps_done < self.params.steps_per_round {
            self.active = Some(round);
            return Ok(false);
        }
        if round.skipped_steps == round.steps_done {
            self.stats.nonfinite_rounds += 1;
            store.thaw();
            return Ok(false);
        }
        if let Some(published) = &self.published {
            let copied = published
                .iter()
                .zip(&self.vars)
                .try_for_each(|(var, private)| var.set(private.as_tensor()));
            if let Err(err) = copied {
                store.thaw();
                return Err(err.into());
            }
        }
        self.finish(round, store);
        Ok(true)
    }

    /// Ends the active round, if any, without its result (after an error): priorities not
    /// written, the published encoder as it was (with a private copy; in place, the steps
    /// taken stay), `store` thawed so ingest goes on.
    pub fn abandon(&mut self, store: &mut PhiStore) {
        if self.active.take().is_some() {
            store.thaw();
        }
    }

    /// One Adam step of `round`, or none when the loss is not finite (counted; φ and the
    /// priorities untouched).
    fn step(&mut self, round: &mut ActiveRound) -> Result<(), LearnerError> {
        let b = self.params.batch_size;
        let with_stable = round.coeff > 0.0;
        let drawn: Vec<usize> = (0..b)
            .map(|_| round.anchors[self.rng.random_range(0..round.anchors.len())] as usize)
            .collect();
        let reg: Vec<usize> = if with_stable {
            (0..b).map(|_| round.reg.draw(&mut self.rng)).collect()
        } else {
            Vec::new()
        };
        let input = self.gather(round, &drawn, &reg)?;
        let stable_term = with_stable.then_some((&round.old, round.coeff));
        let objective = phi_objective(&self.encoder, &input, b, self.params.margin, stable_term)?;
        let PhiObjective {
            loss,
            per_sample,
            triplet,
            stable,
        } = objective;
        round.steps_done += 1;
        if !triplet.loss.is_finite() || !stable.is_finite() {
            round.skipped_steps += 1;
            // Counted in the metrics (`phi/skipped_nonfinite_steps`); this library does not log.
            self.stats.skipped_nonfinite_steps += 1;
            return Ok(());
        }
        self.opt.backward_step(&loss)?;
        for (&c, l) in drawn.iter().zip(per_sample.to_vec1::<f32>()?) {
            round.new_priority[c] = l;
        }
        round.slice_loss_sum += triplet.loss * b as f64;
        round.slice_samples += b as u64;
        self.stats.triplet = triplet;
        self.stats.stable_loss = stable;
        self.stats.steps += 1;
        Ok(())
    }

    /// `[anchors; positives; negatives; regularised]` as one `[3B (+B), obs]` tensor.
    fn gather(
        &mut self,
        round: &ActiveRound,
        drawn: &[usize],
        reg: &[usize],
    ) -> Result<Tensor, LearnerError> {
        let store = &round.view;
        let k = store.negative_offset() as u32;
        self.staging.clear();
        for offset in [0, 1, k] {
            for &i in drawn {
                let c = round.candidates[i];
                self.staging
                    .extend_from_slice(state(store, c.run, c.t + offset)?);
            }
        }
        for &i in reg {
            let c = round.candidates[i];
            self.staging.extend_from_slice(state(store, c.run, c.t)?);
        }
        let rows = self.staging.len() / self.obs_dim;
        Ok(Tensor::from_slice(
            &self.staging,
            (rows, self.obs_dim),
            &Device::Cpu,
        )?)
    }

    /// Ends `round`: priorities written back, store thawed, counters.
    fn finish(&mut self, round: ActiveRound, store: &mut PhiStore) {
        for (c, p) in round.candidates.iter().zip(&round.new_priority) {
            if p.is_finite() {
                store.set_priority(*c, *p);
            }
        }
        store.thaw();
        self.stats.rounds += 1;
        debug_assert!(round.index < self.next_round);
    }
}

/// One step's objective (Eq. 7): the loss to minimise and what it measured.
#[derive(Debug)]
pub struct PhiObjective {
    /// `L_tri + L_s` (scalar, on the graph of the encoder's parameters).
    pub loss: Tensor,
    /// Per-sample triplet losses `[B]` (the anchors' new priorities).
    pub per_sample: Tensor,
    /// Triplet statistics.
    pub triplet: TripletStats,
    /// `L_s` (0 without a stable term).
    pub stable: f64,
}

/// The φ objective on `input` = `[anchors; positives; negatives]` (`3B` rows of observations)
/// or, with `stable = Some((φ_old, coeff))`, `[anchors; positives; negatives; regularised]`
/// (`4B` rows): one forward pass of `encoder`, the triplet loss (margin δ) and the stable loss
/// with λ = 1 against `φ_old` (see [`crate::phi::losses`]).
pub fn phi_objective(
    encoder: &Encoder,
    input: &Tensor,
    b: usize,
    margin: f64,
    stable: Option<(&Encoder, f64)>,
) -> Result<PhiObjective, LearnerError> {
    let rows = if stable.is_some() { 4 * b } else { 3 * b };
    if input.dims().first() != Some(&rows) || b == 0 {
        return Err(LearnerError::Shape {
            what: "phi_objective: input",
            expected: format!("[{rows}, obs] with batch {b} ≥ 1"),
            got: input.dims().to_vec(),
        });
    }
    let out = encoder.forward(input)?;
    let (tri, per_sample, triplet) = triplet_loss(
        &out.narrow(0, 0, b)?,
        &out.narrow(0, b, b)?,
        &out.narrow(0, 2 * b, b)?,
        margin,
    )?;
    let (loss, stable) = match stable {
        Some((old, coeff)) => {
            let old_phi = old.forward(&input.narrow(0, 3 * b, b)?)?;
            let (s, value) = stable_loss(&out.narrow(0, 3 * b, b)?, &old_phi, None, coeff)?;
            ((tri + s)?, value)
        }
        None => (tri, 0.0),
    };
    Ok(PhiObjective {
        loss,
        per_sample,
        triplet,
        stable,
    })
}

/// φ's optimiser: PyTorch's Adam ([`crate::adam::Adam`], defaults β = (0.9, 0.999),
/// ε = 1e-8) at learning rate `lr`.
pub fn phi_optimizer(vars: Vec<Var>, lr: f64) -> Result<Adam, LearnerError> {
    Ok(Adam::new(vars, AdamParams::with_lr(lr))?)
}

/// The state at `(run, t)` or an error (cannot happen: the view is the store at the round's
/// start, which the candidates index).
fn state(store: &StoreView, run: u32, t: u32) -> Result<&[f32], LearnerError> {
    store.state(run, t).ok_or(LearnerError::Unsupported {
        key: "encoder",
        reason: format!("φ store has no state {t} in run {run} (store changed during a round)"),
    })
}

/// `encoder.*` names and variables of `vm`, sorted by name.
fn encoder_vars(vm: &VarMap) -> (Vec<String>, Vec<Var>) {
    let data = vm.data().lock().unwrap_or_else(|p| p.into_inner());
    let mut named: Vec<(String, Var)> = data
        .iter()
        .filter(|(n, _)| nets::weights::is_under(n, prefix::ENCODER))
        .map(|(n, v)| (n.clone(), v.clone()))
        .collect();
    named.sort_unstable_by(|a, b| a.0.cmp(&b.0));
    named.into_iter().unzip()
}

/// Indices of the top `fraction` of `priorities` (at least one when non-empty): the code's
/// `argsort(p)[int(n · (1 − fraction)):]`, as a deterministic partition.
pub fn top_fraction(priorities: &[f32], fraction: f64) -> Vec<u32> {
    let n = priorities.len();
    if n == 0 {
        return Vec::new();
    }
    let cut = ((n as f64 * (1.0 - fraction)).floor() as usize).min(n - 1);
    let mut idx: Vec<u32> = (0..n as u32).collect();
    if cut > 0 {
        idx.select_nth_unstable_by(cut, |&a, &b| {
            priorities[a as usize].total_cmp(&priorities[b as usize])
        });
    }
    idx.split_off(cut)
}

/// Running sum of `weights`.
fn cumulative(weights: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut total = 0.0;
    weights
        .map(|w| {
            total += w;
            total
        })
        .collect()
}
