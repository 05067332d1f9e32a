//! Where SI routes come from: a small trait so the learner stays transport-agnostic. The `asi`
//! binary implements [`RouteSource`] over the graph-service client (process mode) or the
//! in-process graph-service (serial mode); [`NoRouteSource`] never answers.
//!
//! The routes must be computed in the φ the learner's points come from: a source is asked with
//! the learner's current φ version and answers [`RoutesReply::PhiMismatch`] when the graph
//! that answered was built with another one (the learner then skips the step and counts it).

use protocol::graph::{LatentPoint, RouteAnswer, RouteQuery};
use protocol::PhiVersion;

/// A source's reply to a batch of route queries.
#[derive(Debug, Clone, PartialEq)]
pub enum RoutesReply {
    /// One answer per query, in order.
    Answered(Vec<RouteAnswer>),
    /// No answer: no graph yet (`NotReady`), refused, timed out or no source at all.
    NoAnswer,
    /// The graph that answered uses another φ version than the one asked for.
    PhiMismatch {
        /// φ version of the graph.
        graph: PhiVersion,
    },
}

/// Batched route queries (SPEC §6.7): `route(start, end)`, or, when there is none, the route
/// from `start` to a random frontier node seen from `fallback_origin`.
pub trait RouteSource {
    /// Answers `queries` (points in the φ of `phi_version`).
    fn routes(&mut self, queries: &[RouteQuery], phi_version: PhiVersion) -> RoutesReply;
}

/// A source that never answers (runs without a graph-service, tests).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoRouteSource;

impl RouteSource for NoRouteSource {
    fn routes(&mut self, _queries: &[RouteQuery], _phi_version: PhiVersion) -> RoutesReply {
        RoutesReply::NoAnswer
    }
}

/// How a usable route was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RouteKind {
    /// start → φ(g̃).
    Direct,
    /// start → a random frontier node (no route to φ(g̃)).
    ViaFrontier,
}

/// The route of an answer with at least `min_len` nodes, and how it was found; `None` for no
/// route or a too-short one.
pub fn usable_route(answer: &RouteAnswer, min_len: usize) -> Option<(&[LatentPoint], RouteKind)> {
    let (route, kind) = match answer {
        RouteAnswer::Direct(route) => (route, RouteKind::Direct),
        RouteAnswer::ViaFrontier(route) => (route, RouteKind::ViaFrontier),
        // Every other answer (NoRoute with its reasons, or variants added later) is "no route".
        #[allow(unreachable_patterns)]
        _ => return None,
    };
    (route.len() >= min_len && route.iter().flatten().all(|v| v.is_finite()))
        .then_some((route.as_slice(), kind))
}
