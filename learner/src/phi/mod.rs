//! The representation φ (HESS stable representation; paper Eq. 5–7, SPEC §6.3, digest §4).
//!
//! - [`store`]: the episode-structured observation store triplets are sampled from, with one
//!   priority per state.
//! - [`losses`]: the triplet and stable losses as pure functions.
//! - [`round`]: the round schedule, sampling and Adam steps, run in slices by
//!   [`crate::Learner::train`].
//! - [`worker`]: where rounds run — in line with the SAC updates, or on a thread of their own.

pub mod losses;
pub mod round;
pub mod store;
pub mod worker;

pub use losses::{stable_loss, triplet_loss, TripletStats};
pub use round::{
    phi_objective, phi_optimizer, Advance, PhiObjective, PhiParams, PhiStats, PhiTrainer,
    SliceOutcome,
};
pub use store::{Candidate, PhiStore, RunKind, StoreStats, StoreView};
pub use worker::PhiRunner;
