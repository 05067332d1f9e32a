//! [`LearnerError`]: the one error enum of the learner crate.
//!
//! Ingest errors name the chunk (actor, episode, chunk index) so that a refused chunk can be
//! logged and traced back to its sender; training errors name the level and the quantity.

use protocol::{ActorId, ConfigErrors, EpisodeId, ProtocolError, StepLayout};

/// Everything that can go wrong in the learner.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// The run configuration failed validation.
    #[error("invalid configuration:\n{0}")]
    Config(#[from] ConfigErrors),
    /// A setting is valid for the config tree but unusable by this learner.
    #[error("unsupported learner setting `{key}`: {reason}")]
    Unsupported {
        /// Dotted config key.
        key: &'static str,
        /// Why, and what to do instead.
        reason: String,
    },
    /// A chunk whose header or records are malformed (version, flags, dims, length, values).
    #[error("rejected chunk {chunk_index} of episode {episode} from actor {actor}: {source}")]
    Rejected {
        /// Sender.
        actor: ActorId,
        /// Episode.
        episode: EpisodeId,
        /// The chunk's index within its episode.
        chunk_index: u32,
        /// What was wrong.
        #[source]
        source: ProtocolError,
    },
    /// A chunk whose record layout differs from the learner's (another task or φ size).
    #[error(
        "rejected chunk {chunk_index} of episode {episode} from actor {actor}: record layout \
         {found:?} differs from the learner's {expected:?}"
    )]
    LayoutMismatch {
        /// Sender.
        actor: ActorId,
        /// Episode.
        episode: EpisodeId,
        /// The chunk's index within its episode.
        chunk_index: u32,
        /// The learner's layout.
        expected: StepLayout,
        /// The chunk's layout.
        found: StepLayout,
    },
    /// A chunk that was already ingested (a repeat); it is counted and not stored again.
    #[error(
        "duplicate chunk {chunk_index} of episode {episode} from actor {actor} (next expected: \
         {expected}); not stored"
    )]
    DuplicateChunk {
        /// Sender.
        actor: ActorId,
        /// Episode.
        episode: EpisodeId,
        /// The repeated index.
        chunk_index: u32,
        /// The index the learner expected next.
        expected: u32,
    },
    /// A chunk for an episode whose final chunk was already ingested.
    #[error(
        "rejected chunk {chunk_index} of episode {episode} from actor {actor}: the episode \
         already ended at chunk {last}"
    )]
    AfterEpisodeEnd {
        /// Sender.
        actor: ActorId,
        /// Episode.
        episode: EpisodeId,
        /// The chunk's index.
        chunk_index: u32,
        /// Index of the episode's final chunk.
        last: u32,
    },
    /// A tensor handed to a loss has the wrong shape.
    #[error("{what}: expected shape {expected}, got {got:?}")]
    Shape {
        /// Which tensor, e.g. `twin_critic_loss: q`.
        what: &'static str,
        /// The expected shape, e.g. `[batch, 2]`.
        expected: String,
        /// The shape received.
        got: Vec<usize>,
    },
    /// A loss or statistic became NaN or infinite; the update's results are not trusted.
    #[error("{level} level: non-finite {what} = {value}")]
    NonFinite {
        /// `"low"` or `"high"`.
        level: &'static str,
        /// Which quantity.
        what: &'static str,
        /// The value.
        value: f64,
    },
    /// The thread that runs φ rounds in the background (`encoder.background_rounds`) could
    /// not start, panicked, or holds the trainer that was asked for.
    #[error("φ round worker: {0}")]
    PhiWorker(String),
    /// Building, running, saving or loading networks failed.
    #[error(transparent)]
    Nets(#[from] nets::NetsError),
    /// A candle tensor operation failed.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}
