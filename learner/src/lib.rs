//! The ASI learner as a transport-agnostic state machine (SPEC §3, §6.1, §6.2, §6.8).
//!
//! The `asi` binary wires [`Learner`] to iceoryx2 (process mode) or to in-process queues
//! (serial mode); this crate does no I/O and starts no threads.
//!
//! - [`replay`]: structure-of-arrays replay buffers for both levels, grown in blocks, ring
//!   overwrite, uniform sampling into reusable staging.
//! - [`ingest`]: per-episode chunk continuity (lost / duplicate chunks) and the building of
//!   high-level transitions from decision steps across chunk boundaries.
//! - [`ratio`]: the replay-ratio accounting and the actor throttle budget.
//! - [`adam`]: PyTorch's Adam with exportable state (moments, step count) for checkpoints.
//! - [`sac`]: SAC losses (pure functions, one module for both levels) and the update.
//! - [`phi`]: the φ observation store, the triplet and stable losses, the training rounds.
//! - [`schedule`]: the run-wide schedule (training episodes, `count_prob`, `fr_prob`).
//! - [`si`]: hierarchical self-imitation: the (s₀, s_t, g) buffer, route indices, the two
//!   losses, the [`si::RouteSource`] the binary implements, and the SI steps.
//! - [`deterministic`]: the reference code's deterministic low level: losses and update.
//! - [`setup`]: the networks (published policy set, online and target critics) and the
//!   [`setup::LowLevel`] of either algorithm.
//! - [`learner`]: the [`Learner`] itself: ingest, train, publish, progress, metrics.
//!
//! Dependencies: `protocol` (wire types, config) and `nets` (networks) only.

pub mod adam;
pub mod deterministic;
pub mod error;
pub mod ingest;
pub mod learner;
pub mod phi;
pub mod ratio;
pub mod replay;
pub mod sac;
pub mod schedule;
pub mod setup;
pub mod si;

pub use error::LearnerError;
pub use learner::{IngestStats, Learner, LearnerProgress, PHI_STEPS_PER_CALL};
pub use nets::TaskDims;
pub use ratio::ReplayRatio;
pub use si::{NoRouteSource, RouteSource, RoutesReply};
