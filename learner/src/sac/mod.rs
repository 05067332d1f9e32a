//! Soft actor-critic for both levels (SPEC §6.2): [`losses`] holds the math as pure functions,
//! [`update`] one gradient update of one level (networks, optimisers, temperature, Polyak).

pub mod losses;
pub mod update;

pub use losses::{ActorStats, CriticStats, TargetClip};
pub use update::{SacBatch, SacLevel, SacNets, SacParams, SacStats};
