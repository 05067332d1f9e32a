//! Chunk continuity per episode and the building of transitions from decoded step records.
//!
//! Chunks of one episode come from one actor, in order (`chunk_index` 0, 1, 2, …). For every
//! open episode, keyed by `(actor, episode)` (episode ids are unique only within an actor), the
//! learner keeps the next expected chunk index and the open high-level segment:
//! - the next index: the chunk is stored;
//! - a larger index: the chunks in between are lost (counted); the chunk is stored, but the open
//!   segment is dropped (its reward sum would miss steps) and counted;
//! - a smaller index, or any chunk of a recently finished episode up to its last index: a
//!   duplicate, counted and not stored;
//! - a larger index on a finished episode: refused (nothing follows an episode's end).
//!
//! High-level segments (SPEC §6.1): a segment opens at a decision step (obs, goal, stored
//! action), sums the env rewards of its steps and notes any success, and closes at the next
//! decision step (next_obs = that step's obs) or at the step that terminates or truncates the
//! episode (next_obs = its next_obs, with its flags). An episode that ends without either flag
//! (physics failure: the failing step is not sent) closes its segment as truncated, so the
//! value still bootstraps from the last valid state.
//!
//! φ store and schedule: each open episode also collects its raw states (`obs` of every step,
//! then the last `next_obs`) for [`crate::phi::store`] — a gap closes the states so far as a
//! fragment — and notes whether any chunk carried `FAR_GOAL` and any step reported success;
//! [`ChunkOutcome::far_goal_success`] reports both at the episode's end (see
//! [`crate::schedule`]).
//!
//! SI buffer ([`crate::si::buffer`]): every stored step also adds an entry
//! `(s_0, s_t = obs, g = goal)`, SI on or off (so a run can switch SI on later, see
//! [`crate::si::SelfImitation::buffer_mut`]); the episode's s_0 is the obs of the first step the
//! learner stored for it (the true s_0 unless chunk 0 was lost), registered once per episode.
//!
//! Memory bound: at most [`MAX_OPEN_EPISODES`] open episodes (a killed actor never sends its
//! last chunk); beyond that the least recently touched one is abandoned and counted. Finished
//! episodes are remembered ([`MAX_FINISHED_EPISODES`], oldest forgotten first) to recognise
//! late repeats.

use std::collections::{HashMap, VecDeque};

use protocol::{ActorId, EpisodeId, StepView, TrajectoryFlags, TrajectoryHeader};

use crate::error::LearnerError;
use crate::phi::store::{PhiStore, RunBuilder};
use crate::replay::{HighReplay, HighTransition, LowReplay, LowTransition};
use crate::si::{EpisodeRef, SiBuffer};

/// Most episodes kept open at once (ours: far above actors × envs per actor).
pub const MAX_OPEN_EPISODES: usize = 4096;
/// Finished episodes remembered for duplicate detection (ours).
pub const MAX_FINISHED_EPISODES: usize = 4096;

type Key = (ActorId, EpisodeId);

/// Where a chunk falls in its episode's sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Continuity {
    /// The next expected chunk (or chunk 0 of a new episode).
    InOrder,
    /// `lost` chunks were skipped before this one.
    Gap {
        /// Number of missing chunks.
        lost: u64,
    },
}

/// A high-level segment in progress.
#[derive(Debug, Clone)]
struct OpenSegment {
    obs: Vec<f32>,
    goal: Vec<f32>,
    action: Vec<f32>,
    reward: f64,
    success: bool,
}

impl OpenSegment {
    /// Opens a segment at decision step `step`.
    fn start(step: &StepView) -> Self {
        Self {
            obs: step.obs.to_vec(),
            goal: step.goal.to_vec(),
            action: step.high_action.to_vec(),
            reward: 0.0,
            success: false,
        }
    }

    /// Closes the segment into the high buffer.
    fn close(&self, high: &mut HighReplay, next_obs: &[f32], terminated: bool, truncated: bool) {
        high.push(&HighTransition {
            obs: &self.obs,
            goal: &self.goal,
            action: &self.action,
            reward: self.reward as f32,
            next_obs,
            mask: if self.success { 0.0 } else { 1.0 },
            terminated,
            truncated,
        });
    }
}

/// State of one open episode.
#[derive(Debug, Clone, Default)]
struct OpenEpisode {
    next_chunk: u32,
    segment: Option<OpenSegment>,
    touched: u64,
    /// Raw states for the φ store ([`crate::phi::store`]).
    states: RunBuilder,
    /// Some chunk carried `FAR_GOAL`.
    far_goal: bool,
    /// Some step reported success.
    success: bool,
    /// The episode's handle in the SI buffer, once its first step was stored there.
    si_episode: Option<EpisodeRef>,
}

/// What one stored chunk produced.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChunkOutcome {
    /// High-level transitions completed by this chunk.
    pub high_added: u64,
    /// The chunk ended its episode.
    pub episode_ended: bool,
    /// Open segments dropped because of a gap.
    pub segments_dropped: u64,
    /// The chunk ended an episode that carried `FAR_GOAL` and reported success at some step
    /// (counts towards `count_prob`, see [`crate::schedule`]).
    pub far_goal_success: bool,
}

/// The buffers a stored chunk feeds.
pub struct Buffers<'a> {
    /// Low-level replay (every step); `None` keeps the chunk's steps out of it (an FR episode's
    /// chunk with `asi.fr_in_low_replay = false`).
    pub low: Option<&'a mut LowReplay>,
    /// High-level replay (completed segments); `None` keeps the episode's segments out of it
    /// (an FR episode's chunk with `asi.fr_in_high_replay = false`). The choice must be the same
    /// for every chunk of an episode, as the FR flag is.
    pub high: Option<&'a mut HighReplay>,
    /// φ observation store (an episode's states when it ends).
    pub phi: &'a mut PhiStore,
    /// SI buffer (every step, SI on or off).
    pub si: &'a mut SiBuffer,
}

/// Per-episode continuity and open segments.
#[derive(Debug, Clone, Default)]
pub struct Episodes {
    open: HashMap<Key, OpenEpisode>,
    finished: HashMap<Key, u32>,
    finished_order: VecDeque<Key>,
    clock: u64,
    abandoned: u64,
}

impl Episodes {
    /// Classifies `header`'s chunk without changing anything; duplicates and chunks after an
    /// episode's end are errors.
    pub fn check(&self, header: &TrajectoryHeader) -> Result<Continuity, LearnerError> {
        let key = (header.actor_id, header.episode_id);
        let index = header.chunk_index;
        if let Some(&last) = self.finished.get(&key) {
            return Err(if index <= last {
                duplicate(header, last.saturating_add(1))
            } else {
                LearnerError::AfterEpisodeEnd {
                    actor: key.0,
                    episode: key.1,
                    chunk_index: index,
                    last,
                }
            });
        }
        let next = self.open.get(&key).map_or(0, |e| e.next_chunk);
        match index.cmp(&next) {
            std::cmp::Ordering::Less => Err(duplicate(header, next)),
            std::cmp::Ordering::Equal => Ok(Continuity::InOrder),
            std::cmp::Ordering::Greater => Ok(Continuity::Gap {
                lost: u64::from(index - next),
            }),
        }
    }

    /// Stores a checked chunk: every step into `low`, completed segments into `high` (each when
    /// given), the episode's raw states into `phi` once it ends (or a run of them at a gap).
    pub fn store(
        &mut self,
        header: &TrajectoryHeader,
        continuity: Continuity,
        steps: &[StepView],
        buffers: Buffers<'_>,
    ) -> ChunkOutcome {
        let Buffers {
            mut low,
            mut high,
            phi,
            si,
        } = buffers;
        self.clock += 1;
        let key = (header.actor_id, header.episode_id);
        let entry = self.open.entry(key).or_default();
        let mut outcome = ChunkOutcome::default();
        if matches!(continuity, Continuity::Gap { .. }) {
            if entry.segment.take().is_some() {
                outcome.segments_dropped += 1;
            }
            entry.states.gap(phi);
        }
        entry.next_chunk = header.chunk_index.saturating_add(1);
        entry.touched = self.clock;
        entry.far_goal |= header.flags.contains(TrajectoryFlags::FAR_GOAL);
        for step in steps {
            if let Some(low) = low.as_deref_mut() {
                low.push(&low_transition(step));
            }
            if let Some(high) = high.as_deref_mut() {
                outcome.high_added += advance_segment(&mut entry.segment, step, high);
            }
            entry.states.push_step(step.obs, step.next_obs);
            entry.success |= step.success;
            push_si(si, &mut entry.si_episode, step);
        }
        if header.flags.contains(TrajectoryFlags::EPISODE_END) {
            if let Some(high) = high {
                outcome.high_added += close_at_end(&mut entry.segment, steps, high);
            }
            outcome.far_goal_success = entry.far_goal && entry.success;
            let states = std::mem::take(&mut entry.states);
            states.end(phi, header.flags.contains(TrajectoryFlags::PHYSICS_FAILURE));
            self.finish(key, header.chunk_index);
            outcome.episode_ended = true;
        }
        outcome.segments_dropped += self.evict_if_full();
        outcome
    }

    /// Episodes currently open.
    pub fn n_open(&self) -> usize {
        self.open.len()
    }

    /// Open episodes abandoned because the table was full.
    pub fn n_abandoned(&self) -> u64 {
        self.abandoned
    }

    /// Moves `key` from the open table to the finished memory.
    fn finish(&mut self, key: Key, last_chunk: u32) {
        self.open.remove(&key);
        self.finished.insert(key, last_chunk);
        self.finished_order.push_back(key);
        if self.finished_order.len() > MAX_FINISHED_EPISODES {
            if let Some(old) = self.finished_order.pop_front() {
                self.finished.remove(&old);
            }
        }
    }

    /// Abandons the least recently touched open episode when over the cap; returns the number
    /// of open segments lost with it.
    fn evict_if_full(&mut self) -> u64 {
        if self.open.len() <= MAX_OPEN_EPISODES {
            return 0;
        }
        let oldest = self
            .open
            .iter()
            .min_by_key(|(_, e)| e.touched)
            .map(|(k, _)| *k);
        let Some(key) = oldest else { return 0 };
        self.abandoned += 1;
        self.open
            .remove(&key)
            .map_or(0, |e| u64::from(e.segment.is_some()))
    }
}

/// The duplicate error for `header`.
fn duplicate(header: &TrajectoryHeader, expected: u32) -> LearnerError {
    LearnerError::DuplicateChunk {
        actor: header.actor_id,
        episode: header.episode_id,
        chunk_index: header.chunk_index,
        expected,
    }
}

/// Adds `step` to the SI buffer, registering the episode's start at its first stored step.
/// Refused steps are counted by the buffer itself.
fn push_si(si: &mut SiBuffer, episode: &mut Option<EpisodeRef>, step: &StepView) {
    if episode.is_none() {
        *episode = si.begin_episode(step.obs);
    }
    if let Some(id) = *episode {
        si.push(id, step.obs, step.goal);
    }
}

/// The low-level transition of one step record.
fn low_transition<'a>(step: &StepView<'a>) -> LowTransition<'a> {
    LowTransition {
        obs: step.obs,
        phi: step.phi,
        action: step.action,
        subgoal: step.subgoal,
        next_obs: step.next_obs,
        next_phi: step.next_phi,
        terminated: step.terminated,
        truncated: step.truncated,
    }
}

/// Feeds one step to the segment state; returns the number of segments it closed (0–2).
fn advance_segment(
    segment: &mut Option<OpenSegment>,
    step: &StepView,
    high: &mut HighReplay,
) -> u64 {
    let mut closed = 0;
    if step.decision.is_decision() {
        if let Some(done) = segment.take() {
            done.close(high, step.obs, false, false);
            closed += 1;
        }
        *segment = Some(OpenSegment::start(step));
    }
    if let Some(open) = segment.as_mut() {
        open.reward += f64::from(step.reward);
        open.success |= step.success;
    }
    if step.terminated || step.truncated {
        if let Some(done) = segment.take() {
            done.close(high, step.next_obs, step.terminated, step.truncated);
            closed += 1;
        }
    }
    closed
}

/// Closes a segment left open at the episode's end (no terminated/truncated flag: physics
/// failure) as truncated at the last stored state.
fn close_at_end(
    segment: &mut Option<OpenSegment>,
    steps: &[StepView],
    high: &mut HighReplay,
) -> u64 {
    match (segment.take(), steps.last()) {
        (Some(done), Some(last)) => {
            done.close(high, last.next_obs, false, true);
            1
        }
        _ => 0,
    }
}
