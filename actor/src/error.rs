//! [`ActorError`]: everything that can go wrong while building an actor, stepping it, or loading
//! weights into it.
//!
//! Invariant: a rejected weights message ([`ActorError::WeightsRejected`]) leaves the actor
//! exactly as it was; the other stepping errors abandon the current episode (its chunks sent so
//! far stay valid, the episode simply has no `EPISODE_END` chunk) and the next
//! [`crate::Actor::next_chunk`] starts a fresh one.

use protocol::{ConfigErrors, ProtocolError};

/// Errors of the `actor` crate.
#[derive(Debug, thiserror::Error)]
pub enum ActorError {
    /// The configuration handed to [`crate::Actor::new`] is invalid.
    #[error(transparent)]
    Config(#[from] ConfigErrors),
    /// The configuration and the task do not fit together (e.g. an episode length the task
    /// cannot run, asymmetric action bounds).
    #[error("task `{task}` cannot run with this configuration: {reason}")]
    TaskMismatch {
        /// Registry name of the task.
        task: String,
        /// What does not fit and how to fix it.
        reason: String,
    },
    /// A method was called in a state that does not allow it (e.g. `start_at_episode` after
    /// stepping began).
    #[error("actor misuse: {0}")]
    Misuse(String),
    /// The environment could not be built or refused an action.
    #[error("environment error: {0}")]
    Env(#[from] envs::api::EnvError),
    /// Building or running a network failed (shapes, candle errors).
    #[error("network error: {0}")]
    Nets(#[from] nets::NetsError),
    /// A candle tensor operation outside the `nets` modules failed.
    #[error("tensor error: {0}")]
    Tensor(#[from] candle_core::Error),
    /// The step record layout or a header could not be built.
    #[error("protocol error: {0}")]
    Protocol(#[from] ProtocolError),
    /// A network produced a NaN or infinite value while acting; the episode is abandoned.
    #[error("non-finite value {value} in `{field}` at index {index}; episode abandoned")]
    NonFinite {
        /// Which record field or network output.
        field: &'static str,
        /// Index inside the field.
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A weights message was refused; nothing changed (counted in
    /// [`crate::ActorStats::n_weights_rejected`]).
    #[error(
        "weights (policy version {policy_version}, φ version {phi_version}) rejected: {reason}"
    )]
    WeightsRejected {
        /// Policy version carried by the refused message.
        policy_version: u64,
        /// φ version carried by the refused message.
        phi_version: u64,
        /// Why: protocol version, layout hash, length, safetensors content or non-finite values.
        reason: WeightsRejection,
    },
    /// Episode after episode ended before its first step could be recorded (physics failure
    /// on every first step): the environment is broken.
    #[error("actor {actor_id}: {n_episodes} episodes in a row ended before recording a step (physics failure on the first step); check the task's parameters")]
    NoProgress {
        /// The actor.
        actor_id: u32,
        /// Consecutive empty episodes.
        n_episodes: u32,
    },
    /// The per-actor episode counter no longer fits in an [`protocol::EpisodeId`].
    #[error("actor {actor_id} ran out of episode ids after {n_episodes} episodes")]
    EpisodeIdsExhausted {
        /// The actor.
        actor_id: u32,
        /// Episodes started so far.
        n_episodes: u64,
    },
}

/// Why a weights message was refused.
#[derive(Debug, thiserror::Error)]
pub enum WeightsRejection {
    /// Header check failed: protocol version, layout hash or payload length.
    #[error(transparent)]
    Header(#[from] ProtocolError),
    /// The safetensors payload does not fit the actor's networks (names, shapes, dtypes).
    #[error(transparent)]
    Payload(#[from] nets::NetsError),
    /// A tensor holds NaN or infinity.
    #[error("tensor `{name}` holds a non-finite value")]
    NonFinite {
        /// Parameter name.
        name: String,
    },
    /// Reading the loaded tensors back failed.
    #[error("cannot inspect loaded tensor: {0}")]
    Inspect(#[from] candle_core::Error),
}
