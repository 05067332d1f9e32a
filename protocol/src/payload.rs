//! Fixed-layout iceoryx2 payloads and user headers.
//!
//! Every type here is `#[repr(C)]` (ids `#[repr(transparent)]`), implements `ZeroCopySend` with
//! an explicit `asi::…` type name, and every header or message carries
//! [`PROTOCOL_VERSION`](crate::PROTOCOL_VERSION); receivers call [`Versioned::check_version`]
//! first. Enums travel as `u32` codes (never as Rust enums, whose invalid bit patterns would be
//! undefined behaviour when read from shared memory) and are converted with `TryFrom`.

use std::fmt;

use iceoryx2::prelude::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::error::ProtocolError;
use crate::step::{check_len, StepLayout};
use crate::PROTOCOL_VERSION;

/// Returns `Ok` if `found` equals [`PROTOCOL_VERSION`], else an error naming both versions.
pub fn check_version(found: u32) -> Result<(), ProtocolError> {
    if found == PROTOCOL_VERSION {
        Ok(())
    } else {
        Err(ProtocolError::VersionMismatch {
            expected: PROTOCOL_VERSION,
            found,
        })
    }
}

/// A message that carries the protocol version it was written with.
pub trait Versioned {
    /// The version stored in the message.
    fn protocol_version(&self) -> u32;

    /// [`check_version`] on the stored version.
    fn check_version(&self) -> Result<(), ProtocolError> {
        check_version(self.protocol_version())
    }
}

/// Declares a `#[repr(transparent)]` id newtype that can cross processes.
macro_rules! wire_id {
    ($(#[$doc:meta])* $name:ident($inner:ty)) => {
        $(#[$doc])*
        #[repr(transparent)]
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default, Serialize, Deserialize)]
        pub struct $name(pub $inner);

        // SAFETY: a transparent wrapper of one plain integer: self-contained, no pointers, every
        // bit pattern valid, same layout in every process.
        unsafe impl ZeroCopySend for $name {
            unsafe fn type_name() -> &'static str {
                concat!("asi::", stringify!($name))
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                self.0.fmt(f)
            }
        }
    };
}

wire_id!(
    /// Identifies an actor process within a run (the evaluator included).
    ActorId(u32)
);
wire_id!(
    /// Version of the published policy weights; only goes up. 0 = initial weights.
    PolicyVersion(u64)
);
wire_id!(
    /// Version of the encoder φ; goes up after every φ round. 0 = initial φ.
    PhiVersion(u64)
);
wire_id!(
    /// An episode, unique within a run: `(actor_id << 40) | episode index`, where a restarted
    /// actor starts its index at `incarnation << 28` (see the actor crate's `seeds`).
    EpisodeId(u64)
);

/// Bit set of [`TrajectoryHeader::flags`].
#[repr(transparent)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct TrajectoryFlags(pub u32);

// SAFETY: a transparent wrapper of a u32; unknown bits are rejected by `check`.
unsafe impl ZeroCopySend for TrajectoryFlags {
    unsafe fn type_name() -> &'static str {
        "asi::TrajectoryFlags"
    }
}

impl TrajectoryFlags {
    /// The chunk's first step is the episode's first step.
    pub const EPISODE_START: u32 = 1 << 0;
    /// The chunk's last step is the episode's last step.
    pub const EPISODE_END: u32 = 1 << 1;
    /// The episode ended by termination.
    pub const TERMINATED: u32 = 1 << 2;
    /// The episode ended by truncation (time limit).
    pub const TRUNCATED: u32 = 1 << 3;
    /// The episode ended because the physics state became non-finite; the failing step is not
    /// in the chunk.
    pub const PHYSICS_FAILURE: u32 = 1 << 4;
    /// The episode is a frontier-reaching episode.
    pub const FRONTIER: u32 = 1 << 5;
    /// The episode's goal is a "far" goal (counts towards `count_prob`).
    pub const FAR_GOAL: u32 = 1 << 6;
    /// All bits defined by this protocol version.
    pub const ALL: u32 = (1 << 7) - 1;

    /// Whether every bit of `bits` is set.
    pub fn contains(self, bits: u32) -> bool {
        self.0 & bits == bits
    }

    /// Sets `bits`.
    pub fn insert(&mut self, bits: u32) {
        self.0 |= bits;
    }

    /// `Err` if bits outside [`Self::ALL`] are set.
    pub fn check(self) -> Result<(), ProtocolError> {
        match self.0 & !Self::ALL {
            0 => Ok(()),
            bits => Err(ProtocolError::UnknownFlags {
                what: "trajectory flag",
                bits,
            }),
        }
    }
}

/// User header of a trajectory chunk (`asi/<run>/trajectories`, payload `[f32]` of
/// `n_steps × record_len` floats laid out as in [`crate::step`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("asi::TrajectoryHeader")]
pub struct TrajectoryHeader {
    /// The episode this chunk belongs to.
    pub episode_id: EpisodeId,
    /// Index within the episode of the chunk's first step (t of its first record).
    pub first_env_step: u64,
    /// Policy version the actor acted with.
    pub policy_version: PolicyVersion,
    /// φ version of the `phi`/`next_phi`/`subgoal` values in the records.
    pub phi_version: PhiVersion,
    /// The sending actor.
    pub actor_id: ActorId,
    /// Index of this chunk within its episode (0, 1, …); gaps reveal lost chunks.
    pub chunk_index: u32,
    /// Steps (records) in the payload.
    pub n_steps: u32,
    /// Observation length.
    pub obs_dim: u32,
    /// Low-level action length.
    pub action_dim: u32,
    /// Env goal length.
    pub goal_dim: u32,
    /// Latent length.
    pub latent_dim: u32,
    /// [`TrajectoryFlags`] bits.
    pub flags: TrajectoryFlags,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
    /// Zero; keeps the struct free of implicit padding.
    pub reserved: u32,
}

impl TrajectoryHeader {
    /// A header for records of `layout`, all other fields zero, current protocol version.
    pub fn for_layout(layout: &StepLayout) -> Result<Self, ProtocolError> {
        let dim = |name: &str, value: usize| {
            u32::try_from(value)
                .map_err(|_| ProtocolError::InvalidDims(format!("{name} = {value} exceeds u32")))
        };
        Ok(Self {
            episode_id: EpisodeId(0),
            first_env_step: 0,
            policy_version: PolicyVersion(0),
            phi_version: PhiVersion(0),
            actor_id: ActorId(0),
            chunk_index: 0,
            n_steps: 0,
            obs_dim: dim("obs_dim", layout.obs_dim)?,
            action_dim: dim("action_dim", layout.action_dim)?,
            goal_dim: dim("goal_dim", layout.goal_dim)?,
            latent_dim: dim("latent_dim", layout.latent_dim)?,
            flags: TrajectoryFlags::default(),
            protocol_version: PROTOCOL_VERSION,
            reserved: 0,
        })
    }

    /// The record layout the header describes.
    pub fn step_layout(&self) -> Result<StepLayout, ProtocolError> {
        StepLayout::new(
            self.obs_dim as usize,
            self.action_dim as usize,
            self.goal_dim as usize,
            self.latent_dim as usize,
        )
    }

    /// Checks version, flags, dims and that `payload_len` floats hold exactly `n_steps` records;
    /// returns the layout to decode them with.
    pub fn check(&self, payload_len: usize) -> Result<StepLayout, ProtocolError> {
        self.check_version()?;
        self.flags.check()?;
        let layout = self.step_layout()?;
        if self.n_steps == 0 {
            return Err(ProtocolError::InvalidDims(
                "a trajectory chunk must hold at least one step".to_owned(),
            ));
        }
        check_len(
            "trajectory chunk payload",
            self.n_steps as usize * layout.record_len(),
            payload_len,
        )?;
        Ok(layout)
    }
}

impl Versioned for TrajectoryHeader {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// User header of a weights message (`asi/<run>/weights`, payload `[u8]` safetensors bytes of
/// the policy and φ networks, history 1).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("asi::WeightsHeader")]
pub struct WeightsHeader {
    /// Version of the policy tensors in the payload.
    pub policy_version: PolicyVersion,
    /// Version of the φ tensors in the payload.
    pub phi_version: PhiVersion,
    /// [`crate::layout_hash`] of the tensors' names and shapes.
    pub layout_hash: u64,
    /// Payload length in bytes.
    pub byte_len: u64,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
    /// Zero; keeps the struct free of implicit padding.
    pub reserved: u32,
    /// The run-wide schedules at publication time (the learner is their single source).
    pub schedule: RunSchedule,
}

/// Run-wide schedule values the learner computes from every actor's episodes and broadcasts
/// with each weights message, so that all actors (and serial mode) gate on the same global
/// counts instead of their own share of the episodes (SPEC §6.4, §6.6).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("asi::RunSchedule")]
pub struct RunSchedule {
    /// Training episodes completed and ingested by the learner, over all actors ("epoch" of the
    /// reference code: gates HESS exploration, the potential term and the push).
    pub train_episodes: u64,
    /// Probability that a high-level decision uses the HESS count-based subgoal (SPEC §6.4).
    pub count_prob: f32,
    /// Probability that a training episode is a frontier-reaching episode (SPEC §6.6).
    pub fr_prob: f32,
}

impl RunSchedule {
    /// The schedule before any episode: count exploration certain, no FR episodes.
    pub const START: RunSchedule = RunSchedule {
        train_episodes: 0,
        count_prob: 1.0,
        fr_prob: 0.0,
    };
}

impl WeightsHeader {
    /// A header for `byte_len` bytes of weights, current protocol version.
    pub fn new(
        policy_version: PolicyVersion,
        phi_version: PhiVersion,
        layout_hash: u64,
        byte_len: usize,
    ) -> Self {
        Self {
            policy_version,
            phi_version,
            layout_hash,
            byte_len: byte_len as u64,
            protocol_version: PROTOCOL_VERSION,
            reserved: 0,
            schedule: RunSchedule::START,
        }
    }

    /// The same header carrying `schedule`.
    pub fn with_schedule(mut self, schedule: RunSchedule) -> Self {
        self.schedule = schedule;
        self
    }

    /// Checks version, the receiver's `expected_layout_hash` and the payload length.
    pub fn check(
        &self,
        expected_layout_hash: u64,
        payload_len: usize,
    ) -> Result<(), ProtocolError> {
        self.check_version()?;
        if self.layout_hash != expected_layout_hash {
            return Err(ProtocolError::LayoutHashMismatch {
                expected: expected_layout_hash,
                found: self.layout_hash,
            });
        }
        check_len("weights payload", self.byte_len as usize, payload_len)
    }
}

impl Versioned for WeightsHeader {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// Which process published a metric.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u32)]
pub enum ProcessRole {
    /// `asi train` (launcher/supervisor).
    Launcher = 0,
    /// `asi learner`.
    Learner = 1,
    /// `asi actor` (training).
    Actor = 2,
    /// `asi actor` running evaluation episodes.
    Evaluator = 3,
    /// `asi graph-service`.
    GraphService = 4,
}

impl TryFrom<u32> for ProcessRole {
    type Error = ProtocolError;
    fn try_from(code: u32) -> Result<Self, Self::Error> {
        Ok(match code {
            0 => ProcessRole::Launcher,
            1 => ProcessRole::Learner,
            2 => ProcessRole::Actor,
            3 => ProcessRole::Evaluator,
            4 => ProcessRole::GraphService,
            _ => {
                return Err(ProtocolError::UnknownCode {
                    what: "process role",
                    code,
                })
            }
        })
    }
}

/// Bytes available for a metric name in [`MetricsSample`].
pub const METRIC_NAME_CAPACITY: usize = 48;

/// One scalar metric (`asi/<run>/metrics`), e.g. `losses/high_critic`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("asi::MetricsSample")]
pub struct MetricsSample {
    /// Training env steps (all actors) when the value was taken, as the sender knows it.
    pub env_step: u64,
    /// Sender's wall clock, milliseconds since the Unix epoch.
    pub wall_time_ms: u64,
    /// The value.
    pub value: f64,
    /// [`ProcessRole`] code of the sender.
    pub role: u32,
    /// Sender index within its role (actor id; 0 otherwise).
    pub source_id: u32,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
    /// Bytes of `name` in use.
    pub name_len: u32,
    /// Metric name, ASCII, `name_len` bytes, rest zero.
    pub name: [u8; METRIC_NAME_CAPACITY],
}

impl MetricsSample {
    /// A sample; `name` must be 1–48 printable ASCII characters.
    pub fn new(
        role: ProcessRole,
        source_id: u32,
        name: &str,
        value: f64,
        env_step: u64,
        wall_time_ms: u64,
    ) -> Result<Self, ProtocolError> {
        validate_metric_name(name.as_bytes())?;
        let mut bytes = [0u8; METRIC_NAME_CAPACITY];
        bytes[..name.len()].copy_from_slice(name.as_bytes());
        Ok(Self {
            env_step,
            wall_time_ms,
            value,
            role: role as u32,
            source_id,
            protocol_version: PROTOCOL_VERSION,
            name_len: name.len() as u32,
            name: bytes,
        })
    }

    /// The metric name, checked (the bytes came from another process).
    pub fn name(&self) -> Result<&str, ProtocolError> {
        let bytes = self.name.get(..self.name_len as usize).ok_or_else(|| {
            ProtocolError::InvalidMetricName {
                name: String::from_utf8_lossy(&self.name).into_owned(),
                reason: format!("name_len {} exceeds {METRIC_NAME_CAPACITY}", self.name_len),
            }
        })?;
        validate_metric_name(bytes)?;
        std::str::from_utf8(bytes).map_err(|err| ProtocolError::InvalidMetricName {
            name: String::from_utf8_lossy(bytes).into_owned(),
            reason: err.to_string(),
        })
    }

    /// The sender's role.
    pub fn role(&self) -> Result<ProcessRole, ProtocolError> {
        ProcessRole::try_from(self.role)
    }
}

impl Versioned for MetricsSample {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// Rejects empty, too long, or non-printable-ASCII metric names.
fn validate_metric_name(bytes: &[u8]) -> Result<(), ProtocolError> {
    let reason = if bytes.is_empty() {
        Some("must not be empty".to_owned())
    } else if bytes.len() > METRIC_NAME_CAPACITY {
        Some(format!(
            "is {} bytes long; at most {METRIC_NAME_CAPACITY} fit",
            bytes.len()
        ))
    } else if !bytes.iter().all(|b| b.is_ascii_graphic()) {
        Some("must be printable ASCII without spaces, e.g. \"losses/high_critic\"".to_owned())
    } else {
        None
    };
    match reason {
        None => Ok(()),
        Some(reason) => Err(ProtocolError::InvalidMetricName {
            name: String::from_utf8_lossy(bytes).into_owned(),
            reason,
        }),
    }
}

/// A command from the launcher to every process of the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum ControlCommand {
    /// Finish the current unit of work, write state (learner: checkpoint), exit cleanly.
    Stop = 1,
    /// Write a checkpoint now and continue.
    Checkpoint = 2,
}

impl TryFrom<u32> for ControlCommand {
    type Error = ProtocolError;
    fn try_from(code: u32) -> Result<Self, Self::Error> {
        match code {
            1 => Ok(ControlCommand::Stop),
            2 => Ok(ControlCommand::Checkpoint),
            _ => Err(ProtocolError::UnknownCode {
                what: "control command",
                code,
            }),
        }
    }
}

/// A control message (`asi/<run>/control`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("asi::ControlMessage")]
pub struct ControlMessage {
    /// Launcher's message counter; only goes up (receivers ignore repeats).
    pub sequence: u64,
    /// [`ControlCommand`] code.
    pub command: u32,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
}

impl ControlMessage {
    /// A message with the current protocol version.
    pub fn new(sequence: u64, command: ControlCommand) -> Self {
        Self {
            sequence,
            command: command as u32,
            protocol_version: PROTOCOL_VERSION,
        }
    }

    /// Checks the version and decodes the command.
    pub fn command(&self) -> Result<ControlCommand, ProtocolError> {
        self.check_version()?;
        ControlCommand::try_from(self.command)
    }
}

impl Versioned for ControlMessage {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// Learner → actors (`asi/<run>/progress`, history 1): the state of the replay-ratio throttle
/// (SPEC §6.8). Actors pause while `env_steps_ingested >= env_step_budget`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("asi::ProgressMessage")]
pub struct ProgressMessage {
    /// Env steps the learner has stored so far, over all actors.
    pub env_steps_ingested: u64,
    /// Env steps the learner accepts before actors must wait (consumed by updates + slack).
    pub env_step_budget: u64,
    /// Latest published policy version.
    pub policy_version: PolicyVersion,
    /// Latest published φ version.
    pub phi_version: PhiVersion,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
    /// Zero; keeps the struct free of implicit padding.
    pub reserved: u32,
}

impl ProgressMessage {
    /// Whether actors may produce more env steps now.
    pub fn allows_more(&self) -> bool {
        self.env_steps_ingested < self.env_step_budget
    }
}

impl Versioned for ProgressMessage {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}
