//! [`GraphServiceError`]: everything the graph-service refuses or fails at. A refused chunk or
//! weights message leaves the service's state unchanged and is counted by the caller-visible
//! statistics; nothing here is a panic.

use protocol::ProtocolError;

/// Errors of the graph-service state machine.
#[derive(Debug, thiserror::Error)]
pub enum GraphServiceError {
    /// The configuration cannot drive a graph-service (checked once in `GraphService::new`).
    #[error("graph-service configuration: {0}")]
    Config(String),
    /// A message failed the protocol checks (version, flags, lengths, finiteness, codes).
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
    /// A trajectory chunk describes records of another task than this service's.
    #[error("trajectory chunk from actor {actor}: `{field}` is {found}, this service expects {expected}")]
    ChunkDims {
        /// Sending actor.
        actor: u32,
        /// Which header dimension.
        field: &'static str,
        /// This service's dimension.
        expected: usize,
        /// The chunk's dimension.
        found: usize,
    },
    /// The weights' layout hash matches neither the actor-side set nor the encoder alone.
    #[error(
        "weights layout hash {found:#018x} matches neither the actor-side set ({actor_side:#018x}) \
         nor the encoder alone ({encoder_only:#018x}); the learner's networks differ from this config"
    )]
    LayoutHash {
        /// Hash carried by the weights header.
        found: u64,
        /// Hash of this service's actor-side set (encoder + high + low policy).
        actor_side: u64,
        /// Hash of this service's encoder tensors alone.
        encoder_only: u64,
    },
    /// Building, loading or running a network failed.
    #[error(transparent)]
    Nets(#[from] nets::NetsError),
    /// A tensor operation failed while mapping states through φ.
    #[error("mapping states through φ: {0}")]
    Candle(#[from] candle_core::Error),
    /// New φ weights map a stored state to a NaN or infinite latent point; they are refused.
    #[error("φ version {phi_version} maps a stored state to the non-finite point {point:?}; weights refused")]
    NonFiniteLatent {
        /// Version of the refused φ.
        phi_version: u64,
        /// The offending output.
        point: [f32; 2],
    },
    /// An observation buffer is not a whole number of rows.
    #[error("{len} floats of observations are not a whole number of {obs_dim}-float rows")]
    ObsLength {
        /// Floats given.
        len: usize,
        /// Floats per observation row.
        obs_dim: usize,
    },
    /// A broken internal invariant (a bug); the operation changed nothing.
    #[error("internal error: {0}")]
    Internal(String),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_can_cross_threads_into_anyhow() {
        fn assert_error<E: std::error::Error + Send + Sync + 'static>() {}
        assert_error::<GraphServiceError>();
    }
}
