//! Candle networks shared by actors (inference) and the learner (training), CPU.
//!
//! Role (SPEC §5): plain MLPs with named parameters, so weights travel as safetensors bytes and
//! receivers can check a layout hash. Actors and learner run the same module code.
//!
//! - [`linear`]: dense layers (`weight [out, in]`, `bias [out]`) and their stacked ensemble form.
//! - [`mlp`]: ReLU MLPs (`l0`, `l1`, …) and ensembles of them.
//! - [`encoder`], [`policy`], [`critic`]: φ, the tanh-Gaussian and deterministic policies, the
//!   twin critic and the γ-distance critic.
//! - [`set`]: [`NetsSpec`] and the actor-side [`PolicySet`].
//! - [`weights`]: safetensors bytes, strict loading, layout hash, subsets.
//! - [`init`]: Xavier / PyTorch-default init and a seeded `VarBuilder`.
//!
//! Invariants: every tensor is f32; inputs are `[batch, features]`; every public operation
//! returns [`NetsError`] with the layer name and dims rather than panicking.

pub mod critic;
pub mod encoder;
pub mod error;
pub mod from_config;
pub mod init;
pub mod linear;
pub mod mlp;
pub mod policy;
pub mod set;
pub mod weights;

pub use critic::{q_from_distance, DistanceCritic, TwinCritic};
pub use encoder::Encoder;
pub use error::{NetsError, Result};
pub use from_config::{spec_from_config, TaskDims};
pub use init::{seeded_var_builder, LinearInit};
pub use linear::{EnsembleLinear, Linear};
pub use mlp::{EnsembleMlp, Mlp};
pub use policy::{DeterministicActor, GaussianPolicy};
pub use set::{prefix, LowCritic, LowPolicy, LowVariant, NetsSpec, PolicySet};
pub use weights::{layout_hash, load_safetensors_bytes, subset, to_safetensors_bytes};
