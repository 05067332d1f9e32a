//! The reference code's deterministic low level (`learner.low.algo = "deterministic"`,
//! SPEC §5, digest §3.2): a deterministic actor and a γ-distance critic trained DDPG-style.
//!
//! - [`losses`]: the target, critic and actor losses as pure functions.
//! - [`update`]: one update in the code's order (actor before critic, both gradient-clipped),
//!   with target actor and critic moved by Polyak 0.99 every third update.

pub mod losses;
pub mod update;

pub use update::{DeterministicLevel, DeterministicNets, DeterministicParams, DeterministicStats};
