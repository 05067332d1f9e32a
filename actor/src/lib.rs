//! The ASI actor: rollouts of one environment with the hierarchical policy, cut into trajectory
//! chunks (SPEC §3, §6.1; `docs/ARCHITECTURE.md`).
//!
//! - [`actor`]: [`Actor`], the transport-agnostic state machine (`next_chunk`, `load_weights`,
//!   `stats`), [`ActorStats`].
//! - [`chunk`]: [`Chunk`] and the buffer chunks are cut from.
//! - `episode`: one episode's stepping: high-level decisions every c steps, low-level actions,
//!   φ labels, records.
//! - [`subgoal`]: [`SubgoalSource`], how the high level decides (random warm-up, policy, HESS
//!   exploration through the graph-service).
//! - [`frontier`]: frontier-reaching episodes (SPEC §6.6): the FR draw, route waypoints, the
//!   ε and stuck switches, count mode; [`FrontierStats`].
//! - [`oracle`]: [`GraphOracle`], the graph-service questions of an acting actor, with
//!   [`NoGraph`] and [`ServiceOracle`] (the protocol over any [`GraphTransport`]).
//! - [`eval`]: [`eval::Evaluator`], deterministic evaluation episodes on the test goal.
//! - `exploration`: sampling and noise for both levels, clipping.
//! - `networks`: φ, π_hi, π_lo inference with double-buffered weights.
//! - `record`: writing records into the `[f32]` payload.
//! - [`seeds`]: episode ids and per-episode env seeds.
//! - [`resume`]: [`resume::ActorState`], an actor's state between episodes (serial-mode
//!   checkpoints).
//!
//! Invariants: no I/O and no threads here (the `asi` binary wires transport); every random
//! choice comes from generators seeded from `(seed, actor_id)`, so runs replay exactly; errors are
//! [`ActorError`], never panics.

pub mod actor;
pub mod chunk;
mod episode;
pub mod error;
pub mod eval;
mod exploration;
pub mod frontier;
mod networks;
pub mod oracle;
mod record;
pub mod resume;
pub mod seeds;
pub mod subgoal;

pub use actor::{warm_up_share, Actor, ActorStats};
pub use chunk::Chunk;
pub use error::{ActorError, WeightsRejection};
pub use frontier::{FrontierParams, FrontierStats};
pub use oracle::{
    ExploreAnswer, GraphOracle, GraphTransport, LeastVisitedAnswer, NoGraph, ServiceOracle,
};
pub use subgoal::{ExploreGate, SubgoalSource};
