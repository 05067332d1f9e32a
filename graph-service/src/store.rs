//! The trajectory store: every stored state s_t (raw observation) of every stored trajectory,
//! in time order, with its latent point under the current φ.
//!
//! A *trajectory* is one episode of one actor, or a piece of it: chunks of an episode arrive in
//! order from one actor (`chunk_index` 0, 1, …, `first_env_step` continuing the previous chunk).
//! A chunk that does not continue its episode's open trajectory (a lost chunk, or an episode
//! whose start was evicted) starts a new trajectory and is counted as a gap, so no graph edge
//! ever joins states that were not consecutive in the environment.
//!
//! States: each record contributes its `obs` (s_t); the chunk that ends the episode
//! (`EPISODE_END`) also contributes the last record's `next_obs` (s_T). A complete episode of T
//! steps is therefore T + 1 stored states. "Stored steps" below counts stored states.
//!
//! Eviction (memory bound `graph.max_stored_steps`): after every append, while more states are
//! stored than the cap, the oldest whole trajectory (by arrival of its first chunk) is dropped;
//! if a single trajectory alone exceeds the cap, its oldest states are dropped instead. Every
//! evicted state is counted and handed back so visit counts can forget it.
//!
//! Invariant: `obs.len() == latents.len() × obs_dim` for every trajectory, and
//! `n_states` equals the sum of their lengths.

use std::collections::{HashMap, VecDeque};

use protocol::{ActorId, EpisodeId, LatentPoint};
use rand::Rng;

/// A validated chunk, ready to append.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkStates {
    /// Sending actor.
    pub actor: ActorId,
    /// Episode within the actor.
    pub episode: EpisodeId,
    /// Index of the chunk within its episode.
    pub chunk_index: u32,
    /// Env step of the first state.
    pub first_env_step: u64,
    /// The chunk starts its episode.
    pub episode_start: bool,
    /// The chunk ends its episode (its last state is s_T).
    pub episode_end: bool,
    /// States, `n × obs_dim` floats.
    pub obs: Vec<f32>,
    /// Their latent points, `n`.
    pub latents: Vec<LatentPoint>,
}

/// One stored trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Sending actor.
    pub actor: ActorId,
    /// Episode within the actor.
    pub episode: EpisodeId,
    /// Env step of `latents[0]`.
    pub first_env_step: u64,
    obs: Vec<f32>,
    latents: Vec<LatentPoint>,
    next_chunk: u32,
    closed: bool,
}

impl Trajectory {
    /// States as raw observations, `len × obs_dim` floats.
    pub fn obs(&self) -> &[f32] {
        &self.obs
    }

    /// Latent points under the current φ, in time order.
    pub fn latents(&self) -> &[LatentPoint] {
        &self.latents
    }

    /// Number of stored states.
    pub fn len(&self) -> usize {
        self.latents.len()
    }

    /// Whether no state is stored.
    pub fn is_empty(&self) -> bool {
        self.latents.is_empty()
    }

    /// Whether the trajectory reached its episode's end (`EPISODE_END`); a trajectory cut
    /// short by a lost chunk, or still receiving chunks, is not closed.
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// Index the next chunk of this trajectory must have.
    pub fn next_chunk(&self) -> u32 {
        self.next_chunk
    }

    /// A trajectory from its saved parts (checkpoints); `None` unless `obs` holds
    /// `latents.len()` rows of `obs_dim` floats.
    pub fn from_parts(
        head: TrajectoryHead,
        obs_dim: usize,
        obs: Vec<f32>,
        latents: Vec<LatentPoint>,
    ) -> Option<Self> {
        (obs.len() == latents.len() * obs_dim).then_some(Self {
            actor: head.actor,
            episode: head.episode,
            first_env_step: head.first_env_step,
            obs,
            latents,
            next_chunk: head.next_chunk,
            closed: head.closed,
        })
    }

    /// Its bookkeeping, without the states.
    pub fn head(&self) -> TrajectoryHead {
        TrajectoryHead {
            actor: self.actor,
            episode: self.episode,
            first_env_step: self.first_env_step,
            next_chunk: self.next_chunk,
            closed: self.closed,
        }
    }

    /// Whether `chunk` continues this trajectory.
    fn continues_with(&self, chunk: &ChunkStates) -> bool {
        !self.closed
            && !chunk.episode_start
            && chunk.chunk_index == self.next_chunk
            && chunk.first_env_step == self.first_env_step + self.len() as u64
    }
}

/// A trajectory's bookkeeping (what a checkpoint saves beside its states).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrajectoryHead {
    /// Sending actor.
    pub actor: ActorId,
    /// Episode within the actor.
    pub episode: EpisodeId,
    /// Env step of the first state.
    pub first_env_step: u64,
    /// Index the next chunk must have.
    pub next_chunk: u32,
    /// Whether the episode's end was stored.
    pub closed: bool,
}

/// A store's bookkeeping beside its trajectories (checkpoints).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoreCounters {
    /// Serial number of the oldest stored trajectory.
    pub front_serial: u64,
    /// Open trajectory of each (actor, episode) by serial, sorted by serial.
    pub open: Vec<(ActorId, EpisodeId, u64)>,
    /// States evicted so far.
    pub n_evicted: u64,
    /// Chunks that started a new trajectory without continuing their episode.
    pub n_gaps: u64,
}

/// Stored trajectories, oldest first, bounded by a state cap.
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryStore {
    obs_dim: usize,
    max_states: u64,
    trajectories: VecDeque<Trajectory>,
    /// Serial number of `trajectories[0]`; serials are consecutive.
    front_serial: u64,
    /// Open trajectory of each (actor, episode), by serial.
    open: HashMap<(ActorId, EpisodeId), u64>,
    n_states: u64,
    n_evicted: u64,
    n_gaps: u64,
}

impl TrajectoryStore {
    /// An empty store of `obs_dim`-float states, at most `max_states` states (≥ 1).
    pub fn new(obs_dim: usize, max_states: u64) -> Self {
        Self {
            obs_dim,
            max_states: max_states.max(1),
            trajectories: VecDeque::new(),
            front_serial: 0,
            open: HashMap::new(),
            n_states: 0,
            n_evicted: 0,
            n_gaps: 0,
        }
    }

    /// Floats per stored state.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// The state cap (`graph.max_stored_steps`).
    pub fn max_states(&self) -> u64 {
        self.max_states
    }

    /// The bookkeeping a checkpoint saves beside the trajectories.
    pub fn counters(&self) -> StoreCounters {
        let mut open: Vec<_> = self
            .open
            .iter()
            .map(|(&(actor, episode), &serial)| (actor, episode, serial))
            .collect();
        open.sort_by_key(|&(_, _, serial)| serial);
        StoreCounters {
            front_serial: self.front_serial,
            open,
            n_evicted: self.n_evicted,
            n_gaps: self.n_gaps,
        }
    }

    /// A store restored from its trajectories (oldest first) and counters, for `obs_dim` and
    /// `max_states`; the error says which invariant the parts break (states over the cap, a
    /// trajectory of another width, an open entry that is not an open trajectory of its
    /// episode).
    pub fn from_parts(
        obs_dim: usize,
        max_states: u64,
        trajectories: Vec<Trajectory>,
        counters: StoreCounters,
    ) -> Result<Self, String> {
        let mut store = Self::new(obs_dim, max_states);
        if let Some(t) = trajectories
            .iter()
            .find(|t| t.obs.len() != t.len() * obs_dim)
        {
            return Err(format!(
                "trajectory of actor {} episode {} holds {} floats for {} states of {obs_dim}",
                t.actor.0,
                t.episode.0,
                t.obs.len(),
                t.len()
            ));
        }
        store.n_states = trajectories.iter().map(|t| t.len() as u64).sum();
        if store.n_states > store.max_states {
            return Err(format!(
                "{} stored states exceed the cap of {}",
                store.n_states, store.max_states
            ));
        }
        store.trajectories = trajectories.into();
        store.front_serial = counters.front_serial;
        for (actor, episode, serial) in counters.open {
            let fits = store
                .get(serial)
                .is_some_and(|t| t.actor == actor && t.episode == episode && !t.closed);
            if !fits || store.open.insert((actor, episode), serial).is_some() {
                return Err(format!(
                    "open entry (actor {}, episode {}, serial {serial}) is not an open trajectory of that episode",
                    actor.0, episode.0
                ));
            }
        }
        store.n_evicted = counters.n_evicted;
        store.n_gaps = counters.n_gaps;
        Ok(store)
    }

    /// Stored states.
    pub fn n_states(&self) -> u64 {
        self.n_states
    }

    /// Stored trajectories.
    pub fn n_trajectories(&self) -> usize {
        self.trajectories.len()
    }

    /// States evicted so far.
    pub fn n_evicted(&self) -> u64 {
        self.n_evicted
    }

    /// Chunks that did not continue their episode and started a new trajectory.
    pub fn n_gaps(&self) -> u64 {
        self.n_gaps
    }

    /// Stored trajectories, oldest first.
    pub fn trajectories(&self) -> impl Iterator<Item = &Trajectory> {
        self.trajectories.iter()
    }

    /// `n` latent points drawn uniformly, with replacement, from every stored state (empty
    /// when the store is). `O(n_trajectories + n log n_trajectories)`.
    pub fn sample_latents<R: Rng>(&self, n: usize, rng: &mut R) -> Vec<LatentPoint> {
        if self.n_states == 0 {
            return Vec::new();
        }
        // ends[i] = states in trajectories 0..=i.
        let ends: Vec<u64> = self
            .trajectories
            .iter()
            .scan(0u64, |total, t| {
                *total += t.len() as u64;
                Some(*total)
            })
            .collect();
        (0..n)
            .filter_map(|_| {
                let flat = rng.random_range(0..self.n_states);
                let i = ends.partition_point(|&end| end <= flat);
                let start = if i == 0 { 0 } else { ends[i - 1] };
                let t = self.trajectories.get(i)?;
                t.latents.get(usize::try_from(flat - start).ok()?).copied()
            })
            .collect()
    }

    /// Appends a validated chunk (`obs.len() == latents.len() × obs_dim`, checked by the
    /// caller), evicts beyond the cap, and returns the latent points of the evicted states.
    pub fn append(&mut self, chunk: ChunkStates) -> Vec<LatentPoint> {
        let key = (chunk.actor, chunk.episode);
        let serial = match self.open_trajectory(key) {
            Some(serial) if self.get(serial).is_some_and(|t| t.continues_with(&chunk)) => serial,
            open => {
                if open.is_some() || !chunk.episode_start {
                    self.n_gaps += 1;
                }
                self.start_trajectory(&chunk)
            }
        };
        self.extend(serial, chunk);
        self.evict()
    }

    /// Replaces every latent point (after a φ update); `latents[i]` belongs to the i-th
    /// trajectory and must have its length. Returns `false` and changes nothing otherwise.
    pub fn replace_latents(&mut self, latents: Vec<Vec<LatentPoint>>) -> bool {
        let fits = latents.len() == self.trajectories.len()
            && self
                .trajectories
                .iter()
                .zip(&latents)
                .all(|(t, l)| t.len() == l.len());
        if fits {
            for (trajectory, new) in self.trajectories.iter_mut().zip(latents) {
                trajectory.latents = new;
            }
        }
        fits
    }

    fn open_trajectory(&self, key: (ActorId, EpisodeId)) -> Option<u64> {
        self.open.get(&key).copied()
    }

    fn get(&self, serial: u64) -> Option<&Trajectory> {
        let index = serial.checked_sub(self.front_serial)?;
        self.trajectories.get(usize::try_from(index).ok()?)
    }

    fn get_mut(&mut self, serial: u64) -> Option<&mut Trajectory> {
        let index = serial.checked_sub(self.front_serial)?;
        self.trajectories.get_mut(usize::try_from(index).ok()?)
    }

    /// Opens a new, empty trajectory for `chunk`'s episode and returns its serial.
    fn start_trajectory(&mut self, chunk: &ChunkStates) -> u64 {
        let serial = self.front_serial + self.trajectories.len() as u64;
        self.trajectories.push_back(Trajectory {
            actor: chunk.actor,
            episode: chunk.episode,
            first_env_step: chunk.first_env_step,
            obs: Vec::new(),
            latents: Vec::new(),
            next_chunk: chunk.chunk_index,
            closed: false,
        });
        self.open.insert((chunk.actor, chunk.episode), serial);
        serial
    }

    /// Appends `chunk`'s states to trajectory `serial` and closes it at the episode's end.
    fn extend(&mut self, serial: u64, chunk: ChunkStates) {
        let n_new = chunk.latents.len() as u64;
        let Some(trajectory) = self.get_mut(serial) else {
            return; // unreachable: `serial` was just looked up or created
        };
        trajectory.obs.extend_from_slice(&chunk.obs);
        trajectory.latents.extend_from_slice(&chunk.latents);
        trajectory.next_chunk = chunk.chunk_index.wrapping_add(1);
        trajectory.closed = chunk.episode_end;
        if chunk.episode_end {
            self.open.remove(&(chunk.actor, chunk.episode));
        }
        self.n_states += n_new;
    }

    /// Drops oldest trajectories (or, for a lone trajectory, its oldest states) beyond the cap.
    fn evict(&mut self) -> Vec<LatentPoint> {
        let mut evicted = Vec::new();
        while self.n_states > self.max_states {
            if self.trajectories.len() > 1 {
                self.evict_front(&mut evicted);
            } else {
                self.trim_front(&mut evicted);
            }
        }
        self.n_evicted += evicted.len() as u64;
        evicted
    }

    fn evict_front(&mut self, evicted: &mut Vec<LatentPoint>) {
        if let Some(oldest) = self.trajectories.pop_front() {
            let key = (oldest.actor, oldest.episode);
            if self.open.get(&key) == Some(&self.front_serial) {
                self.open.remove(&key);
            }
            self.front_serial += 1;
            self.n_states -= oldest.len() as u64;
            evicted.extend(oldest.latents);
        }
    }

    fn trim_front(&mut self, evicted: &mut Vec<LatentPoint>) {
        let excess = self.n_states.saturating_sub(self.max_states) as usize;
        let obs_dim = self.obs_dim;
        let Some(only) = self.trajectories.front_mut() else {
            return; // unreachable: n_states > 0 implies a trajectory
        };
        let excess = excess.min(only.len());
        evicted.extend(only.latents.drain(..excess));
        only.obs.drain(..excess * obs_dim);
        only.first_env_step += excess as u64;
        self.n_states -= excess as u64;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chunk of 1-D states `values` (latent = (value, 0)).
    fn chunk(
        actor: u32,
        episode: u64,
        index: u32,
        first: u64,
        values: &[f32],
        end: bool,
    ) -> ChunkStates {
        ChunkStates {
            actor: ActorId(actor),
            episode: EpisodeId(episode),
            chunk_index: index,
            first_env_step: first,
            episode_start: index == 0,
            episode_end: end,
            obs: values.to_vec(),
            latents: values.iter().map(|&v| [v, 0.0]).collect(),
        }
    }

    fn xs(store: &TrajectoryStore) -> Vec<Vec<f32>> {
        store.trajectories().map(|t| t.obs().to_vec()).collect()
    }

    #[test]
    fn samples_are_stored_states_and_cover_every_one() {
        use rand::SeedableRng;
        let mut store = TrajectoryStore::new(1, 100);
        let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
        assert!(store.sample_latents(5, &mut rng).is_empty());
        store.append(chunk(0, 1, 0, 0, &[0.0, 1.0, 2.0], true));
        store.append(chunk(0, 2, 0, 0, &[3.0], true));
        store.append(chunk(1, 1, 0, 0, &[4.0, 5.0], false));
        let samples = store.sample_latents(3000, &mut rng);
        assert_eq!(samples.len(), 3000);
        for value in 0..6 {
            let hits = samples.iter().filter(|p| p[0] == value as f32).count();
            // Uniform over 6 states: 500 expected; 5 standard deviations is about ±100.
            assert!((400..=600).contains(&hits), "state {value}: {hits} hits");
        }
        assert!(samples.iter().all(|p| (0.0..=5.0).contains(&p[0])));
    }

    #[test]
    fn chunks_of_one_episode_join_in_order() {
        let mut store = TrajectoryStore::new(1, 100);
        store.append(chunk(0, 7, 0, 0, &[0.0, 1.0], false));
        store.append(chunk(1, 7, 0, 0, &[10.0], false));
        store.append(chunk(0, 7, 1, 2, &[2.0, 3.0], true));
        assert_eq!(xs(&store), vec![vec![0.0, 1.0, 2.0, 3.0], vec![10.0]]);
        assert_eq!(store.n_states(), 5);
        assert_eq!(store.n_gaps(), 0);
    }

    #[test]
    fn a_lost_chunk_starts_a_new_trajectory_and_counts_a_gap() {
        let mut store = TrajectoryStore::new(1, 100);
        store.append(chunk(0, 1, 0, 0, &[0.0, 1.0], false));
        store.append(chunk(0, 1, 2, 4, &[4.0], true));
        assert_eq!(xs(&store), vec![vec![0.0, 1.0], vec![4.0]]);
        assert_eq!(store.n_gaps(), 1);
    }

    #[test]
    fn eviction_drops_oldest_whole_trajectories_first() {
        let mut store = TrajectoryStore::new(1, 5);
        store.append(chunk(0, 1, 0, 0, &[1.0, 1.0], true));
        store.append(chunk(0, 2, 0, 0, &[2.0, 2.0], true));
        let evicted = store.append(chunk(0, 3, 0, 0, &[3.0, 3.0], true));
        assert_eq!(evicted, vec![[1.0, 0.0], [1.0, 0.0]]);
        assert_eq!(xs(&store), vec![vec![2.0, 2.0], vec![3.0, 3.0]]);
        assert_eq!((store.n_states(), store.n_evicted()), (4, 2));
    }

    #[test]
    fn a_lone_trajectory_over_the_cap_loses_its_oldest_states() {
        let mut store = TrajectoryStore::new(1, 3);
        store.append(chunk(0, 1, 0, 0, &[0.0, 1.0], false));
        let evicted = store.append(chunk(0, 1, 1, 2, &[2.0, 3.0, 4.0], false));
        assert_eq!(evicted.len(), 2);
        assert_eq!(xs(&store), vec![vec![2.0, 3.0, 4.0]]);
        // The trimmed trajectory still continues with the next chunk.
        store.append(chunk(0, 1, 2, 5, &[5.0], true));
        assert_eq!(xs(&store), vec![vec![3.0, 4.0, 5.0]]);
        assert_eq!(store.n_gaps(), 0);
    }
}
