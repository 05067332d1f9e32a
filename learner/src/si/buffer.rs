//! The SI buffer (digest §8): one entry `(s_0, s_t, g)` per env step of every training episode.
//!
//! Layout (structure of arrays, oldest entry first):
//! - per entry: `s_t` (`obs_dim` f32), the goal xy `g` (`goal_dim` f32) and the episode's
//!   [`EpisodeRef`] (u64) — `s_0` is *not* copied per step;
//! - per episode: its start observation `s_0` (`obs_dim` f32), stored once by
//!   [`SiBuffer::begin_episode`] and addressed by the episode's serial number.
//!
//! Memory bound: at most `capacity` entries, i.e. `capacity · (4·(obs_dim + goal_dim) + 8)`
//! bytes, plus `4·obs_dim` bytes per episode that still has an entry (and the open ones). At the
//! defaults (capacity 5·10⁶, Ant: obs 29, goal 2) that is 660 MB of entries and, at 500 steps per
//! episode, 1.2 MB of starts. Storage grows with use, in steps of at most the current size and
//! never beyond the capacity, so a short run holds only what it stored.
//!
//! Eviction (reference code): when a push finds the buffer full, the oldest 25 % of the entries
//! (at least one) are dropped first; then every episode start older than the oldest remaining
//! entry's episode is dropped too. An episode still open while all of its entries and its start
//! were dropped (it would have to outlast a quarter of the capacity) loses its later steps:
//! they are counted in [`SiBuffer::n_orphaned`], not stored.
//!
//! Sampling: uniform, without replacement ([`SiBuffer::sample`]).
//!
//! Checkpoints: [`SiBuffer::parts`] borrows everything a checkpoint must hold;
//! [`SiBuffer::from_parts`] rebuilds the buffer from it and checks its consistency.

use rand::Rng;

/// An episode's handle in the buffer: its serial number (0, 1, 2, … in `begin_episode` order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct EpisodeRef(pub u64);

/// One stored entry, borrowed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SiEntry<'a> {
    /// The episode's start observation s_0.
    pub s0: &'a [f32],
    /// The pre-step observation s_t.
    pub obs: &'a [f32],
    /// The env goal (xy).
    pub goal: &'a [f32],
}

/// Everything an [`SiBuffer`] holds, borrowed (for checkpoints). Entry `i` is
/// `obs[i·obs_dim..]`, `goal[i·goal_dim..]`, `episode[i]`; episode `e`'s start is
/// `starts[(e − first_start)·obs_dim..]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SiBufferParts<'a> {
    /// s_t of every entry, oldest first.
    pub obs: &'a [f32],
    /// Goal of every entry.
    pub goal: &'a [f32],
    /// Episode serial of every entry.
    pub episode: &'a [u64],
    /// Start observations of the episodes `first_start..next_episode`.
    pub starts: &'a [f32],
    /// Serial of the first start held.
    pub first_start: u64,
    /// Serial the next episode gets.
    pub next_episode: u64,
    /// Counters: evicted entries, orphaned steps, refused input.
    pub evicted: u64,
    /// See [`SiBuffer::n_orphaned`].
    pub orphaned: u64,
    /// See [`SiBuffer::n_rejected`].
    pub rejected: u64,
}

/// The SI buffer. See the module doc.
#[derive(Debug, Clone)]
pub struct SiBuffer {
    obs_dim: usize,
    goal_dim: usize,
    capacity: usize,
    obs: Vec<f32>,
    goal: Vec<f32>,
    episode: Vec<u64>,
    starts: Vec<f32>,
    first_start: u64,
    next_episode: u64,
    evicted: u64,
    orphaned: u64,
    rejected: u64,
}

impl SiBuffer {
    /// An empty buffer for `capacity` entries (at least 1) of the given sizes.
    pub fn new(obs_dim: usize, goal_dim: usize, capacity: usize) -> Self {
        Self {
            obs_dim,
            goal_dim,
            capacity: capacity.max(1),
            obs: Vec::new(),
            goal: Vec::new(),
            episode: Vec::new(),
            starts: Vec::new(),
            first_start: 0,
            next_episode: 0,
            evicted: 0,
            orphaned: 0,
            rejected: 0,
        }
    }

    /// Registers a new episode with its start observation `s0`; its steps are then pushed
    /// with the returned reference. `None` (counted in [`Self::n_rejected`]) when `s0` has the
    /// wrong length.
    pub fn begin_episode(&mut self, s0: &[f32]) -> Option<EpisodeRef> {
        if s0.len() != self.obs_dim {
            self.rejected += 1;
            return None;
        }
        self.starts.extend_from_slice(s0);
        let id = EpisodeRef(self.next_episode);
        self.next_episode += 1;
        Some(id)
    }

    /// Stores one step `(s_t = obs, g = goal)` of `episode`, dropping the oldest quarter first
    /// when full. Returns whether it was stored: a step of an episode whose start was already
    /// dropped is counted in [`Self::n_orphaned`], one with wrong lengths in
    /// [`Self::n_rejected`].
    pub fn push(&mut self, episode: EpisodeRef, obs: &[f32], goal: &[f32]) -> bool {
        if obs.len() != self.obs_dim
            || goal.len() != self.goal_dim
            || episode.0 >= self.next_episode
        {
            self.rejected += 1;
            return false;
        }
        if self.len() >= self.capacity {
            self.evict_oldest_quarter();
        }
        if episode.0 < self.first_start {
            self.orphaned += 1;
            return false;
        }
        self.reserve_one();
        self.obs.extend_from_slice(obs);
        self.goal.extend_from_slice(goal);
        self.episode.push(episode.0);
        true
    }

    /// Grows the entry storage when full: by the current size (at least 1024 entries), never
    /// beyond the capacity.
    fn reserve_one(&mut self) {
        if self.episode.len() < self.episode.capacity() {
            return;
        }
        let len = self.episode.len();
        let extra = len.max(1024).min(self.capacity - len).max(1);
        self.episode.reserve_exact(extra);
        self.obs.reserve_exact(extra * self.obs_dim);
        self.goal.reserve_exact(extra * self.goal_dim);
    }

    /// Drops the oldest 25 % of the entries (at least one) and the starts no entry needs.
    fn evict_oldest_quarter(&mut self) {
        let n = (self.len() / 4).max(1).min(self.len());
        self.obs.drain(..n * self.obs_dim);
        self.goal.drain(..n * self.goal_dim);
        self.episode.drain(..n);
        self.evicted += n as u64;
        let oldest_needed = self
            .episode
            .iter()
            .copied()
            .min()
            .unwrap_or(self.next_episode);
        if oldest_needed > self.first_start {
            let drop = (oldest_needed - self.first_start) as usize;
            self.starts.drain(..drop * self.obs_dim);
            self.first_start = oldest_needed;
        }
    }

    /// Entries stored.
    pub fn len(&self) -> usize {
        self.episode.len()
    }

    /// Whether no entry is stored.
    pub fn is_empty(&self) -> bool {
        self.episode.is_empty()
    }

    /// `(obs_dim, goal_dim)`: the sizes of s_t (and s_0) and of g.
    pub fn dims(&self) -> (usize, usize) {
        (self.obs_dim, self.goal_dim)
    }

    /// Most entries held.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Episode starts held.
    pub fn n_starts(&self) -> usize {
        self.starts.len() / self.obs_dim.max(1)
    }

    /// Entries dropped by eviction so far.
    pub fn n_evicted(&self) -> u64 {
        self.evicted
    }

    /// Steps not stored because their episode's start had been dropped.
    pub fn n_orphaned(&self) -> u64 {
        self.orphaned
    }

    /// Steps or starts refused for a wrong length or an unknown episode.
    pub fn n_rejected(&self) -> u64 {
        self.rejected
    }

    /// Entry `i` (0 = oldest), `None` past the end.
    pub fn get(&self, i: usize) -> Option<SiEntry<'_>> {
        let episode = *self.episode.get(i)?;
        let start = (episode.checked_sub(self.first_start)? as usize) * self.obs_dim;
        Some(SiEntry {
            s0: self.starts.get(start..start + self.obs_dim)?,
            obs: &self.obs[i * self.obs_dim..(i + 1) * self.obs_dim],
            goal: &self.goal[i * self.goal_dim..(i + 1) * self.goal_dim],
        })
    }

    /// Everything the buffer holds, borrowed (for checkpoints).
    pub fn parts(&self) -> SiBufferParts<'_> {
        SiBufferParts {
            obs: &self.obs,
            goal: &self.goal,
            episode: &self.episode,
            starts: &self.starts,
            first_start: self.first_start,
            next_episode: self.next_episode,
            evicted: self.evicted,
            orphaned: self.orphaned,
            rejected: self.rejected,
        }
    }

    /// A buffer of the given sizes holding `parts` (from [`Self::parts`]); `Err` names the
    /// first inconsistency (lengths, more entries than `capacity`, an entry whose episode has
    /// no start).
    pub fn from_parts(
        obs_dim: usize,
        goal_dim: usize,
        capacity: usize,
        parts: SiBufferParts<'_>,
    ) -> Result<Self, String> {
        check_parts(obs_dim, goal_dim, capacity, &parts).map_err(|p| format!("SI buffer: {p}"))?;
        Ok(Self {
            obs_dim,
            goal_dim,
            capacity: capacity.max(1),
            obs: parts.obs.to_vec(),
            goal: parts.goal.to_vec(),
            episode: parts.episode.to_vec(),
            starts: parts.starts.to_vec(),
            first_start: parts.first_start,
            next_episode: parts.next_episode,
            evicted: parts.evicted,
            orphaned: parts.orphaned,
            rejected: parts.rejected,
        })
    }

    /// `min(n, len)` distinct entry indices, uniformly at random.
    pub fn sample(&self, rng: &mut impl Rng, n: usize) -> Vec<usize> {
        let amount = n.min(self.len());
        rand::seq::index::sample(rng, self.len(), amount).into_vec()
    }
}

/// The first inconsistency of `parts` for the given sizes, if any.
fn check_parts(
    obs_dim: usize,
    goal_dim: usize,
    capacity: usize,
    parts: &SiBufferParts<'_>,
) -> Result<(), String> {
    let n = parts.episode.len();
    if parts.obs.len() != n * obs_dim || parts.goal.len() != n * goal_dim {
        return Err(format!(
            "{n} entries need {} obs and {} goal values, got {} and {}",
            n * obs_dim,
            n * goal_dim,
            parts.obs.len(),
            parts.goal.len()
        ));
    }
    if n > capacity.max(1) {
        return Err(format!("{n} entries exceed the capacity {capacity}"));
    }
    let n_starts = parts.next_episode.checked_sub(parts.first_start);
    if n_starts.is_none_or(|k| parts.starts.len() as u64 != k * obs_dim as u64) {
        return Err(format!(
            "starts of episodes {}..{} need {} values each, got {} values",
            parts.first_start,
            parts.next_episode,
            obs_dim,
            parts.starts.len()
        ));
    }
    let held = parts.first_start..parts.next_episode;
    match parts.episode.iter().find(|e| !held.contains(e)) {
        Some(e) => Err(format!(
            "an entry of episode {e} has no start (held: {held:?})"
        )),
        None => Ok(()),
    }
}
