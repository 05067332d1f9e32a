//! Soft actor-critic for both levels (SPEC §6.2): [`losses`] holds the math as pure functions,
//! [`networks`] the networks of one level, [`update`] one gradient update of one level
//! (optimisers, temperature, Polyak).

pub mod losses;
pub mod networks;
pub mod update;

pub use losses::{ActorStats, CriticStats, TargetClip};
pub use networks::{SacNets, SacShape};
pub use update::{SacBatch, SacLevel, SacParams, SacStats};
