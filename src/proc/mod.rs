//! Process entry points spawned by the launcher (`asi learner|actor|graph-service|evaluator`) and the
//! plumbing they share. Each wires one transport-agnostic component to iceoryx2 channels; the
//! component crates hold all the logic, so serial mode drives the very same code.

pub mod actor;
pub mod common;
pub mod evaluator;
pub mod graph_service;
pub mod learner;
