//! The episode-structured observation store that φ rounds sample triplets from (digest §3.3,
//! §4; SPEC §6.3).
//!
//! What is stored: for every ingested episode, its raw observation sequence `s_0 … s_T` (the
//! `obs` of each step, then the last step's `next_obs`) and one priority `p` per state,
//! initialised to 1 (the code's `p [N, T+1]`). Triplets `(s_t, s_{t+1}, s_{t+k})` are only ever
//! formed inside one stored [`StateRun`], so they are always temporally correct.
//!
//! Broken episodes (rule): a lost chunk splits an episode into *runs* of consecutive states;
//! each run is stored on its own (no triplet spans the gap) and counted in
//! [`StoreStats::fragments`]. A run too short to hold one triplet (fewer than `k + 1` states)
//! is not stored and is counted in [`StoreStats::dropped_short`]. An episode that ended by
//! `PHYSICS_FAILURE` is stored as sent: the failing step is never in a chunk, and every sent
//! step's `next_obs` is a finite state, so its states are all valid; it is counted in
//! [`StoreStats::physics_failures`].
//!
//! Capacity (rule): at most `replay.capacity_steps` states in total, the same bound as the
//! low-level replay (the code keeps `buffer_size // T` episodes of `T + 1` states); the oldest
//! runs are evicted first. Memory: `capacity_steps × obs_dim × 4` bytes for the states plus 4
//! bytes per state for the priorities.
//!
//! Freezing: while a φ round runs the store is frozen ([`PhiStore::freeze`]); runs completed
//! meanwhile are staged and only enter the store (and evict) when it thaws, so the round's
//! candidate indices stay valid and the round sees exactly the episodes ingested before it
//! started — whatever the actors' speed.
//!
//! A run's observations never change once stored, so they are shared (`Arc`): a
//! [`StoreView`] of the stored runs costs one reference per run, and a round run on another
//! thread (`encoder.background_rounds`) reads its triplets from the view while ingest stages
//! new runs here. Priorities stay in the store; only the owner reads and writes them.

use std::collections::VecDeque;
use std::sync::Arc;

/// One stored run of consecutive states of one episode.
#[derive(Debug, Clone, PartialEq)]
pub struct StateRun {
    obs: Arc<[f32]>,
    priority: Vec<f32>,
}

impl StateRun {
    /// Number of states in the run.
    pub fn n_states(&self) -> usize {
        self.priority.len()
    }
}

/// Store counters (see the module doc for the rules they count).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StoreStats {
    /// Runs stored (complete episodes and fragments).
    pub runs_stored: u64,
    /// Runs that are a part of an episode split by lost chunks (stored or dropped).
    pub fragments: u64,
    /// Runs too short for one triplet, not stored.
    pub dropped_short: u64,
    /// Runs evicted by the capacity bound.
    pub evicted: u64,
    /// Episodes that ended by physics failure (their valid states are stored).
    pub physics_failures: u64,
}

/// Where a run being added comes from (for the counters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunKind {
    /// A whole episode, start to end.
    Complete,
    /// A whole episode that ended by physics failure.
    PhysicsFailure,
    /// Part of an episode with lost chunks.
    Fragment,
}

/// A candidate triplet anchor: state `t` of run `run` (an index into the store's current runs,
/// oldest first); valid while the store is frozen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Candidate {
    /// Run index.
    pub run: u32,
    /// Anchor time step within the run.
    pub t: u32,
}

/// The φ observation store; see the module doc.
#[derive(Debug, Clone)]
pub struct PhiStore {
    obs_dim: usize,
    negative_offset: usize,
    capacity_states: usize,
    runs: VecDeque<StateRun>,
    n_states: usize,
    staged: Vec<StateRun>,
    frozen: bool,
    stats: StoreStats,
}

impl PhiStore {
    /// An empty store for observations of `obs_dim` floats, triplets with negative offset
    /// `negative_offset` (k), at most `capacity_states` states.
    pub fn new(obs_dim: usize, negative_offset: usize, capacity_states: usize) -> Self {
        Self {
            obs_dim,
            negative_offset: negative_offset.max(1),
            capacity_states,
            runs: VecDeque::new(),
            n_states: 0,
            staged: Vec::new(),
            frozen: false,
            stats: StoreStats::default(),
        }
    }

    /// Adds a run `obs` (`n × obs_dim` floats, states in time order); priorities start at 1.
    /// A run with fewer than `k + 1` states, or more than the capacity, is counted and dropped.
    /// Panics never; a length that is not a multiple of `obs_dim` drops the partial state.
    pub fn push_run(&mut self, mut obs: Vec<f32>, kind: RunKind) {
        match kind {
            RunKind::Fragment => self.stats.fragments += 1,
            RunKind::PhysicsFailure => self.stats.physics_failures += 1,
            RunKind::Complete => {}
        }
        let n = obs.len() / self.obs_dim.max(1);
        obs.truncate(n * self.obs_dim);
        if n <= self.negative_offset || n > self.capacity_states {
            self.stats.dropped_short += 1;
            return;
        }
        let run = StateRun {
            obs: obs.into(),
            priority: vec![1.0; n],
        };
        if self.frozen {
            self.staged.push(run);
        } else {
            self.insert(run);
        }
    }

    /// Inserts a run, evicting the oldest ones beyond the capacity.
    fn insert(&mut self, run: StateRun) {
        while self.n_states + run.n_states() > self.capacity_states {
            let Some(old) = self.runs.pop_front() else {
                break;
            };
            self.n_states -= old.n_states();
            self.stats.evicted += 1;
        }
        self.n_states += run.n_states();
        self.stats.runs_stored += 1;
        self.runs.push_back(run);
    }

    /// Freezes the store for a round: later runs are staged.
    pub fn freeze(&mut self) {
        self.frozen = true;
    }

    /// Thaws the store and inserts the staged runs in arrival order.
    pub fn thaw(&mut self) {
        self.frozen = false;
        for run in std::mem::take(&mut self.staged) {
            self.insert(run);
        }
    }

    /// Whether a round holds the store.
    pub fn is_frozen(&self) -> bool {
        self.frozen
    }

    /// The stored runs, oldest first, as `(obs, priority)` (checkpoints; staged runs are not
    /// included: a checkpoint is never taken while a round holds the store).
    pub(crate) fn runs(&self) -> impl Iterator<Item = (&[f32], &[f32])> {
        self.runs.iter().map(|r| (&*r.obs, r.priority.as_slice()))
    }

    /// Replaces the contents of an empty, thawed store with `runs` (oldest first, `(obs,
    /// priority)`) and `stats` (checkpoints). Refused, with nothing changed, when a run's
    /// lengths disagree, a run is shorter than k + 1 states, or the total exceeds the capacity.
    pub(crate) fn restore(
        &mut self,
        runs: Vec<(Vec<f32>, Vec<f32>)>,
        stats: StoreStats,
    ) -> Result<(), String> {
        let mut total = 0usize;
        for (index, (obs, priority)) in runs.iter().enumerate() {
            let n = priority.len();
            if obs.len() != n * self.obs_dim || n <= self.negative_offset {
                return Err(format!(
                    "run {index}: {} observation floats and {n} priorities (obs_dim {}, k {})",
                    obs.len(),
                    self.obs_dim,
                    self.negative_offset
                ));
            }
            total += n;
        }
        if total > self.capacity_states {
            return Err(format!(
                "{total} states for a capacity of {}",
                self.capacity_states
            ));
        }
        self.runs = runs
            .into_iter()
            .map(|(obs, priority)| StateRun {
                obs: obs.into(),
                priority,
            })
            .collect();
        self.n_states = total;
        self.staged.clear();
        self.frozen = false;
        self.stats = stats;
        Ok(())
    }

    /// Every anchor position `(run, t)` with `t + k` inside its run, oldest run first.
    pub fn candidates(&self) -> Vec<Candidate> {
        let k = self.negative_offset;
        let mut out = Vec::with_capacity(self.n_states);
        for (run, r) in self.runs.iter().enumerate() {
            let last_anchor = r.n_states().saturating_sub(k + 1);
            out.extend((0..=last_anchor).map(|t| Candidate {
                run: run as u32,
                t: t as u32,
            }));
        }
        out
    }

    /// State `t` of run `run` (`obs_dim` floats); `None` when out of range.
    pub fn state(&self, run: u32, t: u32) -> Option<&[f32]> {
        state_in(&self.runs.get(run as usize)?.obs, t, self.obs_dim)
    }

    /// The stored runs' observations as they are now (staged runs not included), indexed as
    /// [`PhiStore::state`] and [`Candidate`]s: what a round samples from.
    pub fn view(&self) -> StoreView {
        StoreView {
            obs_dim: self.obs_dim,
            negative_offset: self.negative_offset,
            runs: self.runs.iter().map(|r| Arc::clone(&r.obs)).collect(),
        }
    }

    /// Stored priority of state `t` of run `run`.
    pub fn priority(&self, run: u32, t: u32) -> Option<f32> {
        self.runs
            .get(run as usize)?
            .priority
            .get(t as usize)
            .copied()
    }

    /// Overwrites the priority of a candidate's anchor; out-of-range positions are ignored
    /// (cannot happen while the store is frozen).
    pub fn set_priority(&mut self, at: Candidate, value: f32) {
        if let Some(p) = self
            .runs
            .get_mut(at.run as usize)
            .and_then(|r| r.priority.get_mut(at.t as usize))
        {
            *p = value;
        }
    }

    /// Observation length.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// The negative offset k.
    pub fn negative_offset(&self) -> usize {
        self.negative_offset
    }

    /// States stored.
    pub fn n_states(&self) -> usize {
        self.n_states
    }

    /// Runs stored.
    pub fn n_runs(&self) -> usize {
        self.runs.len()
    }

    /// Runs staged while frozen.
    pub fn n_staged(&self) -> usize {
        self.staged.len()
    }

    /// Counters.
    pub fn stats(&self) -> StoreStats {
        self.stats
    }
}

/// The observations of a store's runs at one moment ([`PhiStore::view`]); `Send`, so a round
/// on another thread reads them while the store goes on staging.
#[derive(Debug, Clone)]
pub struct StoreView {
    obs_dim: usize,
    negative_offset: usize,
    runs: Vec<Arc<[f32]>>,
}

impl StoreView {
    /// State `t` of run `run`, as [`PhiStore::state`] gave it when the view was taken.
    pub fn state(&self, run: u32, t: u32) -> Option<&[f32]> {
        state_in(self.runs.get(run as usize)?, t, self.obs_dim)
    }

    /// The negative offset k.
    pub fn negative_offset(&self) -> usize {
        self.negative_offset
    }
}

/// State `t` (`obs_dim` floats) of a run's observations; `None` when out of range.
fn state_in(obs: &[f32], t: u32, obs_dim: usize) -> Option<&[f32]> {
    let start = (t as usize).checked_mul(obs_dim)?;
    obs.get(start..start.checked_add(obs_dim)?)
}

/// The states of one open episode's current run, built chunk by chunk during ingest:
/// `obs` of every step, and the latest step's `next_obs` kept aside until the run closes.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunBuilder {
    obs: Vec<f32>,
    last_next_obs: Vec<f32>,
    broken: bool,
}

impl RunBuilder {
    /// Appends a step's `obs` and remembers its `next_obs`.
    pub fn push_step(&mut self, obs: &[f32], next_obs: &[f32]) {
        self.obs.extend_from_slice(obs);
        self.last_next_obs.clear();
        self.last_next_obs.extend_from_slice(next_obs);
    }

    /// Lost chunks before the next step: closes the current run as a fragment into `store`,
    /// and marks the rest of the episode as fragments too.
    pub fn gap(&mut self, store: &mut PhiStore) {
        if !self.obs.is_empty() {
            self.close_into(store, RunKind::Fragment);
        }
        self.broken = true;
    }

    /// The episode ended: closes the run into `store` (`physics_failure` from the chunk flags).
    pub fn end(mut self, store: &mut PhiStore, physics_failure: bool) {
        let kind = match (self.broken, physics_failure) {
            (true, _) => RunKind::Fragment,
            (false, true) => RunKind::PhysicsFailure,
            (false, false) => RunKind::Complete,
        };
        if !self.obs.is_empty() {
            self.close_into(store, kind);
        }
    }

    fn close_into(&mut self, store: &mut PhiStore, kind: RunKind) {
        let mut obs = std::mem::take(&mut self.obs);
        obs.append(&mut self.last_next_obs);
        store.push_run(obs, kind);
    }
}
