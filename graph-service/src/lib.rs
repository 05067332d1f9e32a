//! The graph-service of ASI as a transport-agnostic state machine (SPEC §3, §6.5–6.7): no I/O
//! and no threads of its own beyond the scoped workers of a φ re-map and the background build of
//! the route table; the `asi graph-service` binary wires [`GraphService`] to iceoryx2, and
//! serial mode and tests call it directly.
//!
//! - [`store`]: trajectory store (per episode, in order), bounded, oldest episodes evicted first.
//! - [`grid`]: cells of side d in φ-space, keys by floor division, node positions.
//! - [`graph`]: the latent graph of Eq. 8 (min temporal distance within `edge_window`).
//! - [`dijkstra`]: shortest paths with path recovery.
//! - [`route_table`]: all-pairs predecessor rows filled after each rebuild (routes by lookup).
//! - [`frontier`]: frontier choice, routes, SI route queries with the frontier fallback.
//! - [`counts`]: visit counts n(v) (Eq. 10) and the least-visited candidate.
//! - [`hess`]: HESS's visit, future-count and potential maps and the explore subgoal (SPEC §6.4).
//! - [`phi`]: the encoder φ loaded from weights messages; re-mapping of the store, its rows
//!   split over scoped worker threads.
//! - [`fused`]: the hand-fused CPU forward of φ's MLP that the mapping runs.
//! - [`bench`]: synthetic stores and timings for `asi bench graph`.
//! - [`checkpoint`]: [`GraphService::save`] / [`GraphService::restore`] (atomic folders).
//! - [`server`]: [`GraphService::handle`], the request handler.
//! - [`service`]: [`GraphService`] itself: ingest, weights, rebuild, queries, stats.
//! - [`xy`]: the graph placed in the world (node xy = mean achieved goal of its stored states)
//!   with the last frontier answered, for the run's maze picture.
//!
//! Invariants: bad input (chunks, weights, requests) is refused with a reason and counted,
//! never a panic, and leaves the state unchanged.

pub mod bench;
pub mod checkpoint;
pub mod counts;
pub mod dijkstra;
pub mod error;
pub mod frontier;
pub mod fused;
pub mod graph;
pub mod grid;
pub mod hess;
pub mod phi;
pub mod route_table;
pub mod server;
pub mod service;
pub mod store;
pub mod xy;

pub use error::GraphServiceError;
pub use frontier::{Frontier, NoRoute};
pub use graph::{LatentGraph, NodeId};
pub use grid::{CellKey, Grid};
pub use hess::{ExploreChoice, HessMaps, HessParams};
pub use service::{GraphService, GraphStats};
