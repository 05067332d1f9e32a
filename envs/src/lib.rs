//! Goal-conditioned rapier environments for ASI: the Ant in four mazes, HalfCheetahHurdle and a
//! fast point mass in the same mazes.
//!
//! The contract every task follows lives in [`api`]; tasks are built by name through
//! [`registry`]. Geometry and constants follow `shared/reference/asi-reference-code.md` §9; each
//! one is a documented parameter field.

pub mod api;
pub mod maze;

pub use api::{Env, EnvError, EnvSpec, Reset, Robot, StaticBox, Step, StepInfo};
