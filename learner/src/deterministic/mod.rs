//! The reference code's deterministic low level (`learner.low.algo = "deterministic"`,
//! SPEC §5, digest §3.2): a deterministic actor and a γ-distance critic trained DDPG-style.
//!
//! - [`losses`]: the target, critic and actor losses as pure functions.
//!
//! Not yet wired into [`crate::Learner`] (which still refuses the setting, see
//! [`crate::setup::deterministic_unsupported`]): the update step, target networks with the
//! code's Polyak 0.99 every third batch, gradient clipping and the `not_done` labels in the
//! low replay remain to be built on these losses.

pub mod losses;
