//! Trajectory chunks: the unit an actor hands to the transport, and the buffer it is cut from.
//!
//! Invariants:
//! - A [`Chunk`] holds `header.n_steps ≥ 1` records, `records.len() = n_steps × record_len`,
//!   all from one episode, in step order starting at `header.first_env_step`.
//! - Between two calls of [`crate::Actor::next_chunk`] the [`ChunkBuffer`] holds at most one
//!   record: a full chunk is only cut once the following step has been taken, so that an episode
//!   that ends on that step (including a physics failure, whose step is not recorded) still ends
//!   in a non-empty chunk carrying `EPISODE_END`.

use protocol::{PolicyVersion, TrajectoryHeader};

/// One trajectory chunk ready to publish: header and `n_steps × record_len` floats.
#[derive(Debug, Clone, PartialEq)]
pub struct Chunk {
    /// Ids, versions, dims and flags ([`protocol::TrajectoryHeader`]).
    pub header: TrajectoryHeader,
    /// Step records back to back, layout [`protocol::step`].
    pub records: Vec<f32>,
}

/// Records of the current episode not yet handed out.
#[derive(Debug)]
pub(crate) struct ChunkBuffer {
    records: Vec<f32>,
    record_len: usize,
    /// Episode step index of the first buffered record.
    first_env_step: u64,
    /// Policy version that acted the first buffered record (the oldest in the buffer).
    policy_version: PolicyVersion,
}

/// Records cut from the buffer, with what the header needs to know about them.
pub(crate) struct Cut {
    pub records: Vec<f32>,
    pub n_steps: usize,
    pub first_env_step: u64,
    pub policy_version: PolicyVersion,
}

impl ChunkBuffer {
    /// An empty buffer for records of `record_len` floats, sized for `chunk_steps + 1` records.
    pub fn new(record_len: usize, chunk_steps: usize) -> Self {
        Self {
            records: Vec::with_capacity((chunk_steps + 1) * record_len),
            record_len,
            first_env_step: 0,
            policy_version: PolicyVersion(0),
        }
    }

    /// Records held.
    pub fn n_records(&self) -> usize {
        self.records.len() / self.record_len
    }

    /// Appends one record, taken at episode step `env_step` with `policy_version`.
    pub fn push(&mut self, record: &[f32], env_step: u64, policy_version: PolicyVersion) {
        if self.records.is_empty() {
            self.first_env_step = env_step;
            self.policy_version = policy_version;
        }
        self.records.extend_from_slice(record);
    }

    /// Cuts the first `n` records (at most all of them); the rest stays, now acted (as far as
    /// the caller knows) with `remainder_policy_version`.
    pub fn cut(&mut self, n: usize, remainder_policy_version: PolicyVersion) -> Cut {
        let n = n.min(self.n_records());
        let rest = self.records[n * self.record_len..].to_vec();
        let mut records = std::mem::replace(&mut self.records, rest);
        records.truncate(n * self.record_len);
        self.records
            .reserve(records.capacity().saturating_sub(self.records.len()));
        let cut = Cut {
            records,
            n_steps: n,
            first_env_step: self.first_env_step,
            policy_version: self.policy_version,
        };
        self.first_env_step += n as u64;
        self.policy_version = remainder_policy_version;
        cut
    }

    /// Every buffered record, mutable (for relabelling φ fields).
    pub fn records_mut(&mut self) -> std::slice::ChunksExactMut<'_, f32> {
        self.records.chunks_exact_mut(self.record_len)
    }

    /// Drops everything (an abandoned episode).
    pub fn clear(&mut self) {
        self.records.clear();
    }
}

/// A header from `template` (dims, actor id, protocol version) filled in for one cut.
pub(crate) fn header_for(
    template: &TrajectoryHeader,
    cut: &Cut,
    chunk_index: u32,
    flags: u32,
) -> TrajectoryHeader {
    let mut header = *template;
    header.first_env_step = cut.first_env_step;
    header.n_steps = cut.n_steps as u32;
    header.chunk_index = chunk_index;
    header.policy_version = cut.policy_version;
    header.flags.insert(flags);
    header
}
