//! Replay buffers (structure of arrays) for both levels, and uniform batch sampling.
//!
//! - [`LowReplay`]: one row per env step: `obs`, `phi` = φ(obs) at collection, `action`,
//!   `subgoal`, `next_obs`, `next_phi` = φ(next_obs) at collection, `terminated`, `truncated`.
//!   The low reward and "reached" are derived at sampling time from stored values (SPEC §6.1,
//!   Eq. 2): `r = −scale·‖next_phi − subgoal‖`, `reached = ‖next_phi − subgoal‖ ≤ threshold`.
//! - [`HighReplay`]: one row per completed high-level segment: `obs`, `goal`, `action` (the
//!   stored delta), `reward` R = Σ of the segment's env rewards (Eq. 1), `next_obs` (at the next
//!   decision or the episode end), `mask` (0 if the env reported success inside the segment),
//!   `terminated`, `truncated`.
//!
//! Memory: a full Ant buffer is 8e6 rows × 29 floats ≈ 0.9 GB for `obs` alone, so no column is
//! allocated up front. Each [`Column`] holds fixed-size blocks of rows, allocated when the first
//! row of a block is written; existing blocks are never moved or reallocated, and memory grows
//! with the data actually stored. Once `capacity` rows are stored the buffer becomes a ring and
//! overwrites the oldest row first.
//!
//! Sampling draws batch indices uniformly with replacement and writes the rows into reusable
//! staging vectors ([`BatchStage`]); no allocation happens per sample. Rows are laid out in the
//! input order the networks expect ([`nets::NetsSpec`]): `head` = `[obs, φ(obs)]` (low) or
//! `[obs, goal]` (high), `tail` = the subgoal (low) or empty (high), so the policy sees
//! `[head, tail]` and the critic `[head, action, tail]`.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// Rows per allocation block (before capping at the capacity). 65 536 rows of a 29-wide field
/// are 7.6 MB: small enough to keep the over-allocation low, large enough to keep the block
/// table tiny.
pub const BLOCK_ROWS: usize = 1 << 16;

/// One field of a buffer: `capacity` rows of `width` floats, stored in lazily allocated blocks.
#[derive(Debug, Clone)]
pub struct Column {
    width: usize,
    block_rows: usize,
    capacity: usize,
    blocks: Vec<Box<[f32]>>,
}

impl Column {
    /// An empty column; nothing is allocated until the first write.
    pub fn new(width: usize, capacity: usize) -> Self {
        Self {
            width,
            block_rows: BLOCK_ROWS.min(capacity).max(1),
            capacity,
            blocks: Vec::new(),
        }
    }

    /// Writes row `index` (< capacity). Rows are first written in order 0, 1, 2, …, so a new
    /// block is needed exactly when `index` is the first row past the allocated blocks.
    /// Invariant: `values.len() == width` (the caller copies fields of a checked layout).
    pub fn write(&mut self, index: usize, values: &[f32]) {
        let (block, row) = (index / self.block_rows, index % self.block_rows);
        if block == self.blocks.len() {
            let rows = self.block_rows.min(self.capacity - block * self.block_rows);
            self.blocks
                .push(vec![0.0; rows * self.width].into_boxed_slice());
        }
        let start = row * self.width;
        self.blocks[block][start..start + self.width].copy_from_slice(values);
    }

    /// Row `index` (must have been written).
    pub fn row(&self, index: usize) -> &[f32] {
        let (block, row) = (index / self.block_rows, index % self.block_rows);
        let start = row * self.width;
        &self.blocks[block][start..start + self.width]
    }

    /// The single value of row `index` of a width-1 column.
    pub fn scalar(&self, index: usize) -> f32 {
        self.row(index)[0]
    }

    /// Floats allocated so far.
    pub fn allocated(&self) -> usize {
        self.blocks.iter().map(|b| b.len()).sum()
    }
    /// Floats per row.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows `0..n` (all written), concatenated row-major (checkpoints).
    pub(crate) fn export_rows(&self, n: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(n * self.width);
        for block in &self.blocks {
            let want = n * self.width - out.len();
            out.extend_from_slice(&block[..want.min(block.len())]);
        }
        out
    }

    /// Rows `0..k` of a fresh column from `data` (`k × width` floats, `k ≤ capacity`;
    /// checkpoints). The caller checks both bounds.
    pub(crate) fn import_rows(&mut self, data: &[f32]) {
        for (index, row) in data.chunks_exact(self.width.max(1)).enumerate() {
            self.write(index, row);
        }
    }
}

/// Ring bookkeeping shared by the buffers: where the next row goes and how many are valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ring {
    capacity: usize,
    len: usize,
    next: usize,
    total: u64,
}

impl Ring {
    /// An empty ring of `capacity` (≥ 1) rows.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            len: 0,
            next: 0,
            total: 0,
        }
    }

    /// Claims the slot for the next row (overwriting the oldest when full).
    pub fn claim(&mut self) -> usize {
        let slot = self.next;
        self.next = (self.next + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
        self.total += 1;
        slot
    }

    /// Valid rows.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no row is stored.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Maximum rows.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Rows ever written (including overwritten ones).
    pub fn total(&self) -> u64 {
        self.total
    }
    /// The slot the next row goes to.
    pub fn next(&self) -> usize {
        self.next
    }

    /// A ring with this bookkeeping (checkpoints), or `None` unless it is one a ring of
    /// `capacity` can reach: `len ≤ capacity`, `next < capacity`, `total ≥ len`, and
    /// `next = len` before the first wrap.
    pub(crate) fn restored(capacity: usize, len: usize, next: usize, total: u64) -> Option<Ring> {
        let ring = Ring::new(capacity);
        let reachable = len <= ring.capacity
            && next < ring.capacity
            && total >= len as u64
            && (len == ring.capacity || (next == len && total == len as u64));
        reachable.then_some(Ring {
            len,
            next,
            total,
            ..ring
        })
    }
}

/// Reusable host staging vectors of one batch, row-major `[batch, width]` each.
#[derive(Debug, Clone, Default)]
pub struct BatchStage {
    /// Rows of the batch.
    pub batch: usize,
    /// State part before the action in the critic input (`[obs, φ]` or `[obs, goal]`).
    pub head: Vec<f32>,
    /// The same for the next state.
    pub next_head: Vec<f32>,
    /// State part after the action (`subgoal`, shared by s and s'); empty for the high level.
    pub tail: Vec<f32>,
    /// Stored action.
    pub action: Vec<f32>,
    /// Reward, `[batch]`.
    pub reward: Vec<f32>,
    /// 1 where bootstrapping stops, `[batch]` (see the level's `fill`).
    pub terminal: Vec<f32>,
}

impl BatchStage {
    /// Staging for `batch` rows of the given widths, allocated once.
    pub fn new(batch: usize, head: usize, tail: usize, action: usize) -> Self {
        Self {
            batch,
            head: vec![0.0; batch * head],
            next_head: vec![0.0; batch * head],
            tail: vec![0.0; batch * tail],
            action: vec![0.0; batch * action],
            reward: vec![0.0; batch],
            terminal: vec![0.0; batch],
        }
    }
}

/// Copies `parts` back to back into row `i` of a row-major staging vector of `width` columns.
fn put_row(dst: &mut [f32], i: usize, width: usize, parts: &[&[f32]]) {
    let mut at = i * width;
    for part in parts {
        dst[at..at + part.len()].copy_from_slice(part);
        at += part.len();
    }
}

/// Euclidean distance between two equally long vectors.
pub fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

/// How the low reward and "reached" are derived from stored φ values (SPEC §6.1, Eq. 2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LowRewardSpec {
    /// `r = −scale·‖next_phi − subgoal‖` (`hierarchy.low_reward_scale`).
    pub scale: f32,
    /// Reached when `‖next_phi − subgoal‖ ≤ threshold` (`hierarchy.low_reach_threshold`).
    pub threshold: f32,
}

impl LowRewardSpec {
    /// `(reward, reached)` of a transition.
    pub fn eval(&self, next_phi: &[f32], subgoal: &[f32]) -> (f32, bool) {
        let d = distance(next_phi, subgoal);
        (-self.scale * d, d <= self.threshold)
    }
}

/// One low-level transition, borrowed (from a decoded step record).
#[derive(Debug, Clone, Copy)]
pub struct LowTransition<'a> {
    /// s_t.
    pub obs: &'a [f32],
    /// φ(s_t) at collection.
    pub phi: &'a [f32],
    /// Low action.
    pub action: &'a [f32],
    /// Absolute subgoal held during the step.
    pub subgoal: &'a [f32],
    /// s_{t+1}.
    pub next_obs: &'a [f32],
    /// φ(s_{t+1}) at collection.
    pub next_phi: &'a [f32],
    /// The env terminated at this step.
    pub terminated: bool,
    /// The env truncated at this step.
    pub truncated: bool,
}

/// The low-level buffer (one row per env step).
#[derive(Debug, Clone)]
pub struct LowReplay {
    ring: Ring,
    obs: Column,
    phi: Column,
    action: Column,
    subgoal: Column,
    next_obs: Column,
    next_phi: Column,
    terminated: Column,
    truncated: Column,
    reward: LowRewardSpec,
}

impl LowReplay {
    /// An empty buffer of `capacity` transitions.
    pub fn new(
        capacity: usize,
        obs_dim: usize,
        latent_dim: usize,
        action_dim: usize,
        reward: LowRewardSpec,
    ) -> Self {
        let col = |w| Column::new(w, capacity.max(1));
        Self {
            ring: Ring::new(capacity),
            obs: col(obs_dim),
            phi: col(latent_dim),
            action: col(action_dim),
            subgoal: col(latent_dim),
            next_obs: col(obs_dim),
            next_phi: col(latent_dim),
            terminated: col(1),
            truncated: col(1),
            reward,
        }
    }

    /// The columns by name, in a fixed order (checkpoints).
    pub(crate) fn columns(&self) -> [(&'static str, &Column); 8] {
        [
            ("obs", &self.obs),
            ("phi", &self.phi),
            ("action", &self.action),
            ("subgoal", &self.subgoal),
            ("next_obs", &self.next_obs),
            ("next_phi", &self.next_phi),
            ("terminated", &self.terminated),
            ("truncated", &self.truncated),
        ]
    }

    /// As [`LowReplay::columns`], mutable, with the ring (checkpoints).
    pub(crate) fn parts_mut(&mut self) -> (&mut Ring, [(&'static str, &mut Column); 8]) {
        (
            &mut self.ring,
            [
                ("obs", &mut self.obs),
                ("phi", &mut self.phi),
                ("action", &mut self.action),
                ("subgoal", &mut self.subgoal),
                ("next_obs", &mut self.next_obs),
                ("next_phi", &mut self.next_phi),
                ("terminated", &mut self.terminated),
                ("truncated", &mut self.truncated),
            ],
        )
    }

    /// Appends one transition (overwrites the oldest when full).
    pub fn push(&mut self, t: &LowTransition) {
        let i = self.ring.claim();
        self.obs.write(i, t.obs);
        self.phi.write(i, t.phi);
        self.action.write(i, t.action);
        self.subgoal.write(i, t.subgoal);
        self.next_obs.write(i, t.next_obs);
        self.next_phi.write(i, t.next_phi);
        self.terminated
            .write(i, &[f32::from(u8::from(t.terminated))]);
        self.truncated.write(i, &[f32::from(u8::from(t.truncated))]);
    }

    /// Ring state (length, capacity, total written).
    pub fn ring(&self) -> &Ring {
        &self.ring
    }

    /// Row `i` as a transition (for tests and debugging).
    pub fn get(&self, i: usize) -> LowTransition<'_> {
        LowTransition {
            obs: self.obs.row(i),
            phi: self.phi.row(i),
            action: self.action.row(i),
            subgoal: self.subgoal.row(i),
            next_obs: self.next_obs.row(i),
            next_phi: self.next_phi.row(i),
            terminated: self.terminated.scalar(i) != 0.0,
            truncated: self.truncated.scalar(i) != 0.0,
        }
    }

    /// `(reward, reached)` of row `i` (Eq. 2, from the stored collection-time φ).
    pub fn reward_of(&self, i: usize) -> (f32, bool) {
        self.reward.eval(self.next_phi.row(i), self.subgoal.row(i))
    }

    /// Staging sized for this buffer: head `[obs, φ]`, tail `subgoal`.
    pub fn stage(&self, batch: usize) -> BatchStage {
        BatchStage::new(
            batch,
            self.obs.width + self.phi.width,
            self.subgoal.width,
            self.action.width,
        )
    }

    /// Writes row `idx` into slot `k` of `stage`. `terminal` = env `terminated` or subgoal
    /// reached (SPEC §6.1: low "done" when ‖φ(s') − sg‖ ≤ threshold); `truncated` never stops
    /// bootstrapping.
    pub fn fill(&self, stage: &mut BatchStage, k: usize, idx: usize) {
        let head_w = self.obs.width + self.phi.width;
        put_row(
            &mut stage.head,
            k,
            head_w,
            &[self.obs.row(idx), self.phi.row(idx)],
        );
        put_row(
            &mut stage.next_head,
            k,
            head_w,
            &[self.next_obs.row(idx), self.next_phi.row(idx)],
        );
        put_row(
            &mut stage.tail,
            k,
            self.subgoal.width,
            &[self.subgoal.row(idx)],
        );
        put_row(
            &mut stage.action,
            k,
            self.action.width,
            &[self.action.row(idx)],
        );
        let (reward, reached) = self.reward_of(idx);
        stage.reward[k] = reward;
        stage.terminal[k] = f32::from(u8::from(reached || self.terminated.scalar(idx) != 0.0));
    }

    /// Floats allocated by all columns.
    pub fn allocated_floats(&self) -> usize {
        [
            &self.obs,
            &self.phi,
            &self.action,
            &self.subgoal,
            &self.next_obs,
            &self.next_phi,
            &self.terminated,
            &self.truncated,
        ]
        .iter()
        .map(|c| c.allocated())
        .sum()
    }
}

/// One high-level transition, borrowed.
#[derive(Debug, Clone, Copy)]
pub struct HighTransition<'a> {
    /// s at the decision step.
    pub obs: &'a [f32],
    /// Env goal g.
    pub goal: &'a [f32],
    /// Stored high action (delta in φ-space).
    pub action: &'a [f32],
    /// R = sum of the segment's env rewards (Eq. 1).
    pub reward: f32,
    /// s at the next decision step, or the last next_obs of the episode.
    pub next_obs: &'a [f32],
    /// 0 if the env reported success inside the segment, else 1.
    pub mask: f32,
    /// The segment ended by env termination.
    pub terminated: bool,
    /// The segment ended by truncation (time limit, or the episode ended without a flag).
    pub truncated: bool,
}

/// The high-level buffer (one row per completed segment).
#[derive(Debug, Clone)]
pub struct HighReplay {
    ring: Ring,
    obs: Column,
    goal: Column,
    action: Column,
    reward: Column,
    next_obs: Column,
    mask: Column,
    terminated: Column,
    truncated: Column,
}

impl HighReplay {
    /// An empty buffer of `capacity` transitions.
    pub fn new(capacity: usize, obs_dim: usize, goal_dim: usize, latent_dim: usize) -> Self {
        let col = |w| Column::new(w, capacity.max(1));
        Self {
            ring: Ring::new(capacity),
            obs: col(obs_dim),
            goal: col(goal_dim),
            action: col(latent_dim),
            reward: col(1),
            next_obs: col(obs_dim),
            mask: col(1),
            terminated: col(1),
            truncated: col(1),
        }
    }

    /// The columns by name, in a fixed order (checkpoints).
    pub(crate) fn columns(&self) -> [(&'static str, &Column); 8] {
        [
            ("obs", &self.obs),
            ("goal", &self.goal),
            ("action", &self.action),
            ("reward", &self.reward),
            ("next_obs", &self.next_obs),
            ("mask", &self.mask),
            ("terminated", &self.terminated),
            ("truncated", &self.truncated),
        ]
    }

    /// As [`HighReplay::columns`], mutable, with the ring (checkpoints).
    pub(crate) fn parts_mut(&mut self) -> (&mut Ring, [(&'static str, &mut Column); 8]) {
        (
            &mut self.ring,
            [
                ("obs", &mut self.obs),
                ("goal", &mut self.goal),
                ("action", &mut self.action),
                ("reward", &mut self.reward),
                ("next_obs", &mut self.next_obs),
                ("mask", &mut self.mask),
                ("terminated", &mut self.terminated),
                ("truncated", &mut self.truncated),
            ],
        )
    }

    /// Appends one transition (overwrites the oldest when full).
    pub fn push(&mut self, t: &HighTransition) {
        let i = self.ring.claim();
        self.obs.write(i, t.obs);
        self.goal.write(i, t.goal);
        self.action.write(i, t.action);
        self.reward.write(i, &[t.reward]);
        self.next_obs.write(i, t.next_obs);
        self.mask.write(i, &[t.mask]);
        self.terminated
            .write(i, &[f32::from(u8::from(t.terminated))]);
        self.truncated.write(i, &[f32::from(u8::from(t.truncated))]);
    }

    /// Ring state (length, capacity, total written).
    pub fn ring(&self) -> &Ring {
        &self.ring
    }

    /// Row `i` as a transition (for tests and debugging).
    pub fn get(&self, i: usize) -> HighTransition<'_> {
        HighTransition {
            obs: self.obs.row(i),
            goal: self.goal.row(i),
            action: self.action.row(i),
            reward: self.reward.scalar(i),
            next_obs: self.next_obs.row(i),
            mask: self.mask.scalar(i),
            terminated: self.terminated.scalar(i) != 0.0,
            truncated: self.truncated.scalar(i) != 0.0,
        }
    }

    /// Staging sized for this buffer: head `[obs, goal]`, no tail.
    pub fn stage(&self, batch: usize) -> BatchStage {
        BatchStage::new(
            batch,
            self.obs.width + self.goal.width,
            0,
            self.action.width,
        )
    }

    /// Writes row `idx` into slot `k` of `stage`. `terminal` = env `terminated` or `mask = 0`
    /// (success inside the segment); `truncated` never stops bootstrapping. The goal is fixed
    /// within an episode, so s' carries the same goal.
    pub fn fill(&self, stage: &mut BatchStage, k: usize, idx: usize) {
        let head_w = self.obs.width + self.goal.width;
        let goal = self.goal.row(idx);
        put_row(&mut stage.head, k, head_w, &[self.obs.row(idx), goal]);
        put_row(
            &mut stage.next_head,
            k,
            head_w,
            &[self.next_obs.row(idx), goal],
        );
        put_row(
            &mut stage.action,
            k,
            self.action.width,
            &[self.action.row(idx)],
        );
        stage.reward[k] = self.reward.scalar(idx);
        let stop = self.terminated.scalar(idx) != 0.0 || self.mask.scalar(idx) == 0.0;
        stage.terminal[k] = f32::from(u8::from(stop));
    }
}

/// Samples `stage.batch` indices uniformly (with replacement) from `0..len` and fills `stage`
/// through `fill`. Invariant: `len ≥ 1` (callers sample only once a batch is stored).
pub fn sample_into(
    rng: &mut Pcg64Mcg,
    len: usize,
    stage: &mut BatchStage,
    fill: impl Fn(&mut BatchStage, usize, usize),
) {
    for k in 0..stage.batch {
        let idx = rng.random_range(0..len);
        fill(stage, k, idx);
    }
}
