//! [`GraphOracle`]: the graph-service questions an actor asks while acting (SPEC §6.4), behind a
//! small trait so the actor stays transport-agnostic.
//!
//! - [`NoGraph`] never answers (tests, benchmarks, runs without a graph-service).
//! - [`ServiceOracle`] speaks the graph protocol ([`protocol::graph`]) over any
//!   [`GraphTransport`]: the `asi` binary plugs in the iceoryx2 client (process mode) or the
//!   in-process graph-service's request handler (serial mode), so both modes share the encoding,
//!   the status handling and the checks of the answer.
//!
//! Questions: HESS explore subgoals and reaching reports (SPEC §6.4), and for frontier-reaching
//! episodes (SPEC §6.6) the frontier route at episode start and the least-visited count-mode
//! candidate.
//!
//! Invariant: an oracle that cannot answer (no graph yet, timeout, refused or malformed reply)
//! says so with `Ok(None)` / `Ok(false)`; the actor then falls back to its policy and counts it.
//! `Err` is kept for failures that must abandon the episode.

use protocol::graph::{
    FrontierRoute, GraphRequestHeader, GraphResponseHeader, GraphStatus, ReachSample,
};
use protocol::{GraphRequest, GraphResponse, LatentPoint, PhiVersion};

use crate::error::ActorError;

/// A HESS exploration subgoal chosen by the graph-service (SPEC §6.4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExploreAnswer {
    /// Absolute subgoal for the low level (the candidate pushed outward, when the push applies).
    pub subgoal: LatentPoint,
    /// The chosen candidate before the push: the cell where the segment's reaching error is
    /// accumulated.
    pub candidate: LatentPoint,
}

/// The graph-service's pick among count-mode candidates (SPEC §6.6, paper Eq. 10).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeastVisitedAnswer {
    /// Index of the chosen candidate in the list that was asked about.
    pub index: usize,
    /// Its visit measure n(v) (finite, non-negative).
    pub visits: f32,
}

/// The graph queries of an acting actor. The frontier-reaching questions have default bodies
/// that never answer, so an oracle without FR support makes every FR episode a counted
/// fallback.
pub trait GraphOracle {
    /// A HESS exploration subgoal near `from` = φ(s_t), for training episode `episode` (the
    /// run-wide count, which gates the potential term and the push), with points in the φ of
    /// `phi_version`. `Ok(None)`: no answer (the actor falls back to its policy).
    fn explore(
        &mut self,
        from: LatentPoint,
        episode: u64,
        phi_version: PhiVersion,
    ) -> Result<Option<ExploreAnswer>, ActorError>;

    /// Delivers reaching errors for the potential map. `Ok(true)`: acknowledged; `Ok(false)`:
    /// not delivered (the samples are dropped and counted by the actor).
    fn report_reaching(
        &mut self,
        samples: &[ReachSample],
        phi_version: PhiVersion,
    ) -> Result<bool, ActorError>;

    /// The frontier g_F seen from `from` = φ(s_0) and the route to it (SPEC §6.6), in the φ of
    /// `phi_version`. `Ok(None)`: no frontier (graph not built, start cell unknown, nothing
    /// reachable, no answer); the episode falls back to a normal one.
    fn frontier_route(
        &mut self,
        _from: LatentPoint,
        _phi_version: PhiVersion,
    ) -> Result<Option<FrontierRoute>, ActorError> {
        Ok(None)
    }

    /// The least-visited of `candidates` (count mode of an FR episode). `Ok(None)`: no answer.
    fn least_visited(
        &mut self,
        _candidates: &[LatentPoint],
        _phi_version: PhiVersion,
    ) -> Result<Option<LeastVisitedAnswer>, ActorError> {
        Ok(None)
    }
}

/// An oracle without a graph: never answers, never accepts a report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoGraph;

/// Its frontier and least-visited answers are the trait's defaults: none.
impl GraphOracle for NoGraph {
    fn explore(
        &mut self,
        _from: LatentPoint,
        _episode: u64,
        _phi_version: PhiVersion,
    ) -> Result<Option<ExploreAnswer>, ActorError> {
        Ok(None)
    }

    fn report_reaching(
        &mut self,
        _samples: &[ReachSample],
        _phi_version: PhiVersion,
    ) -> Result<bool, ActorError> {
        Ok(false)
    }
}

/// One request–response round trip to the graph-service: header and postcard body in, header
/// and body out. `Err` carries a human-readable reason (timeout, transport failure).
pub trait GraphTransport {
    /// Sends `body` with `header` and returns the response.
    fn call(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<(GraphResponseHeader, Vec<u8>), String>;
}

/// A [`GraphOracle`] answered by the graph-service through `T`.
#[derive(Debug)]
pub struct ServiceOracle<T> {
    transport: T,
    next_request_id: u64,
}

impl<T: GraphTransport> ServiceOracle<T> {
    /// An oracle over `transport`; request ids count up from 0.
    pub fn new(transport: T) -> Self {
        Self {
            transport,
            next_request_id: 0,
        }
    }

    /// The transport, e.g. to read its own counters.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// Sends `request`; the decoded answer when the status is `Ok`, `None` (logged) otherwise.
    /// Public so other clients of the graph-service (the learner's self-imitation routes) share
    /// the encoding and status handling.
    pub fn ask(
        &mut self,
        request: &GraphRequest,
        phi_version: PhiVersion,
    ) -> Option<GraphResponse> {
        let kind = request.kind();
        let header = GraphRequestHeader::new(self.next_request_id, kind, phi_version);
        self.next_request_id = self.next_request_id.wrapping_add(1);
        let body = match protocol::encode(request) {
            Ok(body) => body,
            Err(err) => {
                tracing::warn!(?kind, %err, "graph request not encoded");
                return None;
            }
        };
        let (reply, bytes) = match self.transport.call(&header, &body) {
            Ok(answer) => answer,
            Err(reason) => {
                tracing::debug!(?kind, %reason, "graph request got no answer");
                return None;
            }
        };
        match reply.status() {
            Ok(GraphStatus::Ok) => match protocol::decode::<GraphResponse>(&bytes) {
                Ok(response) => Some(response),
                Err(err) => {
                    tracing::warn!(?kind, %err, "graph answer not decoded");
                    None
                }
            },
            Ok(GraphStatus::NotReady) => None,
            Ok(status) => {
                let reason = protocol::decode::<GraphResponse>(&bytes)
                    .map_or_else(|e| e.to_string(), |r| format!("{r:?}"));
                tracing::warn!(?kind, ?status, %reason, "graph request refused");
                None
            }
            Err(err) => {
                tracing::warn!(?kind, %err, "graph answer header refused");
                None
            }
        }
    }
}

impl<T: GraphTransport> GraphOracle for ServiceOracle<T> {
    fn explore(
        &mut self,
        from: LatentPoint,
        episode: u64,
        phi_version: PhiVersion,
    ) -> Result<Option<ExploreAnswer>, ActorError> {
        let request = GraphRequest::ExploreSubgoal { from, episode };
        Ok(match self.ask(&request, phi_version) {
            Some(GraphResponse::ExploreSubgoal { subgoal, candidate })
                if subgoal.iter().chain(&candidate).all(|v| v.is_finite()) =>
            {
                Some(ExploreAnswer { subgoal, candidate })
            }
            Some(other) => {
                tracing::warn!(answer = ?other, "unusable answer to an explore request");
                None
            }
            None => None,
        })
    }

    fn report_reaching(
        &mut self,
        samples: &[ReachSample],
        phi_version: PhiVersion,
    ) -> Result<bool, ActorError> {
        let request = GraphRequest::ReportReaching {
            samples: samples.to_vec(),
        };
        Ok(matches!(
            self.ask(&request, phi_version),
            Some(GraphResponse::Ack)
        ))
    }

    fn frontier_route(
        &mut self,
        from: LatentPoint,
        phi_version: PhiVersion,
    ) -> Result<Option<FrontierRoute>, ActorError> {
        let request = GraphRequest::FrontierRoute { from };
        Ok(match self.ask(&request, phi_version) {
            Some(GraphResponse::FrontierRoute(Ok(found))) if frontier_is_finite(&found) => {
                Some(found)
            }
            Some(GraphResponse::FrontierRoute(Err(reason))) => {
                tracing::debug!(%reason, "no frontier route");
                None
            }
            Some(other) => {
                tracing::warn!(answer = ?other, "unusable answer to a frontier request");
                None
            }
            None => None,
        })
    }

    fn least_visited(
        &mut self,
        candidates: &[LatentPoint],
        phi_version: PhiVersion,
    ) -> Result<Option<LeastVisitedAnswer>, ActorError> {
        let request = GraphRequest::LeastVisited {
            candidates: candidates.to_vec(),
        };
        Ok(match self.ask(&request, phi_version) {
            Some(GraphResponse::LeastVisited { index, visits })
                if (index as usize) < candidates.len() && visits.is_finite() && visits >= 0.0 =>
            {
                Some(LeastVisitedAnswer {
                    index: index as usize,
                    visits,
                })
            }
            Some(other) => {
                tracing::warn!(answer = ?other, n_candidates = candidates.len(), "unusable answer to a least-visited request");
                None
            }
            None => None,
        })
    }
}

/// Every point and the distance of a frontier answer are finite.
fn frontier_is_finite(found: &FrontierRoute) -> bool {
    found.distance.is_finite()
        && found
            .route
            .iter()
            .chain(std::iter::once(&found.frontier))
            .all(|p| p.iter().all(|v| v.is_finite()))
}
