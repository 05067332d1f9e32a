//! The request handler: one [`GraphRequestHeader`] + postcard body in, one
//! [`GraphResponseHeader`] + postcard body out. Never panics.
//!
//! Checks, in order: protocol version (→ `VersionMismatch`), request kind code, body decoding,
//! body kind = header kind, finiteness, and that every point's cell key fits in `i32`
//! (→ `InvalidRequest`); each error body is [`GraphResponse::Error`] with the reason. A request
//! computed with another φ version than the graph's is answered all the same (the response
//! header names the graph's φ version) and counted in `stale_phi_requests`.
//!
//! Answers:
//! - `Stats`: always `Ok`, also before the first graph.
//! - `FrontierRoute`, `Routes`, `Dump`: `NotReady` with an empty body until a graph is built.
//! - `LeastVisited`: answered from the visit counts (which exist before the graph); an empty
//!   candidate list is `InvalidRequest`.
//! - `ExploreSubgoal`, `ReportReaching` (HESS novelty/potential maps): not implemented yet;
//!   `NotReady` with an `Error` body saying so.

use protocol::graph::{
    DumpNode, FrontierRoute, GraphDump, GraphRequestHeader, GraphResponseHeader,
    GraphStats as WireStats, GraphStatus, RouteQuery,
};
use protocol::{GraphRequest, GraphResponse, LatentPoint, ProtocolError};

use crate::frontier::{self, positions};
use crate::graph::LatentGraph;
use crate::service::GraphService;

/// A refused request: status and reason.
struct Refusal {
    status: GraphStatus,
    message: String,
}

impl Refusal {
    fn invalid(message: impl Into<String>) -> Self {
        Self {
            status: GraphStatus::InvalidRequest,
            message: message.into(),
        }
    }
}

impl From<ProtocolError> for Refusal {
    fn from(err: ProtocolError) -> Self {
        let status = match err {
            ProtocolError::VersionMismatch { .. } => GraphStatus::VersionMismatch,
            _ => GraphStatus::InvalidRequest,
        };
        Self {
            status,
            message: err.to_string(),
        }
    }
}

/// What a request is answered with, before encoding.
enum Answer {
    Ok(GraphResponse),
    /// No graph yet: empty body.
    NotReady,
    /// Not supported by this build: `NotReady` with a reason.
    Unsupported(String),
}

impl GraphService {
    /// Answers one request (see the module doc of [`crate::server`]). Never panics.
    pub fn handle(
        &mut self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> (GraphResponseHeader, Vec<u8>) {
        self.stats.requests += 1;
        let answer = self.checked_request(header, body).and_then(|request| {
            self.note_phi_version(header);
            self.answer(request)
        });
        let (status, body) = match answer {
            Ok(Answer::Ok(response)) => (GraphStatus::Ok, Some(response)),
            Ok(Answer::NotReady) => (GraphStatus::NotReady, None),
            Ok(Answer::Unsupported(message)) => (
                GraphStatus::NotReady,
                Some(GraphResponse::Error { message }),
            ),
            Err(refusal) => {
                self.stats.invalid_requests += 1;
                (
                    refusal.status,
                    Some(GraphResponse::Error {
                        message: refusal.message,
                    }),
                )
            }
        };
        self.respond(header, status, body)
    }

    /// Encodes the response; an encoding failure becomes `Internal` with an empty body.
    fn respond(
        &self,
        header: &GraphRequestHeader,
        status: GraphStatus,
        body: Option<GraphResponse>,
    ) -> (GraphResponseHeader, Vec<u8>) {
        let encoded = body.map_or(Ok(Vec::new()), |b| protocol::encode(&b));
        let (status, bytes) = match encoded {
            Ok(bytes) => (status, bytes),
            Err(_) => (GraphStatus::Internal, Vec::new()),
        };
        let phi_version = self.phi_version();
        let response =
            GraphResponseHeader::answering(header, status, self.graph_version, phi_version);
        (response, bytes)
    }

    /// Version, kind, decoding, kind agreement, finiteness and range checks.
    fn checked_request(
        &self,
        header: &GraphRequestHeader,
        body: &[u8],
    ) -> Result<GraphRequest, Refusal> {
        let kind = header.kind()?;
        let request: GraphRequest = protocol::decode(body)?;
        if request.kind() != kind {
            return Err(Refusal::invalid(format!(
                "the header says {kind:?} but the body is a {:?} request",
                request.kind()
            )));
        }
        request.check_finite()?;
        self.check_in_range(&request)?;
        Ok(request)
    }

    /// `Err` at the first point whose cell key does not fit in `i32`.
    fn check_in_range(&self, request: &GraphRequest) -> Result<(), Refusal> {
        let points: Vec<(&str, &LatentPoint)> = match request {
            GraphRequest::FrontierRoute { from } | GraphRequest::ExploreSubgoal { from, .. } => {
                vec![("from", from)]
            }
            GraphRequest::Routes { queries } => queries.iter().flat_map(query_points).collect(),
            GraphRequest::LeastVisited { candidates } => {
                candidates.iter().map(|c| ("candidates", c)).collect()
            }
            GraphRequest::ReportReaching { samples } => samples
                .iter()
                .map(|s| ("samples.subgoal", &s.subgoal))
                .collect(),
            GraphRequest::Stats | GraphRequest::Dump => Vec::new(),
        };
        match points.into_iter().find(|(_, p)| self.grid.key(**p).is_none()) {
            None => Ok(()),
            Some((field, point)) => Err(Refusal::invalid(format!(
                "point {point:?} in `{field}` is out of range: its cell index (cell size {}) does not fit in i32",
                self.grid.cell_size()
            ))),
        }
    }

    fn note_phi_version(&mut self, header: &GraphRequestHeader) {
        if self.graph.is_some() && header.phi_version != self.phi_version() {
            self.stats.stale_phi_requests += 1;
        }
    }

    /// Dispatches a checked request.
    fn answer(&mut self, request: GraphRequest) -> Result<Answer, Refusal> {
        Ok(match request {
            GraphRequest::Stats => Answer::Ok(GraphResponse::Stats(self.wire_stats())),
            GraphRequest::FrontierRoute { from } => self.answer_frontier(from),
            GraphRequest::Routes { queries } => self.answer_routes(&queries),
            GraphRequest::LeastVisited { candidates } => self.answer_least_visited(&candidates)?,
            GraphRequest::Dump => self
                .graph
                .as_ref()
                .map_or(Answer::NotReady, |g| self.dump(g)),
            GraphRequest::ExploreSubgoal { .. } | GraphRequest::ReportReaching { .. } => {
                Answer::Unsupported(format!(
                    "{:?} (HESS novelty/potential maps) is not supported by this graph-service yet",
                    request.kind()
                ))
            }
        })
    }

    fn wire_stats(&self) -> WireStats {
        let stats = self.stats();
        WireStats {
            n_nodes: stats.n_nodes as u64,
            n_edges: stats.n_edges as u64,
            n_dropped_cells: stats.dropped_nodes,
            n_stored_steps: stats.stored_steps,
            n_stored_episodes: stats.stored_episodes,
        }
    }

    fn answer_frontier(&mut self, from: LatentPoint) -> Answer {
        let Some(graph) = self.graph.as_ref() else {
            return Answer::NotReady;
        };
        let found = frontier::frontier(graph, from, self.frontier_fraction, &mut self.rng).ok();
        let answer = found.and_then(|f| {
            Some(FrontierRoute {
                frontier: graph.position(f.node)?,
                route: positions(graph, &f.route),
                distance: f.distance as f32,
            })
        });
        Answer::Ok(GraphResponse::FrontierRoute(answer))
    }

    fn answer_routes(&mut self, queries: &[RouteQuery]) -> Answer {
        let Some(graph) = self.graph.as_ref() else {
            return Answer::NotReady;
        };
        let fraction = self.frontier_fraction;
        let answers = queries
            .iter()
            .map(|q| frontier::answer_route_query(graph, q, fraction, &mut self.rng))
            .collect();
        Answer::Ok(GraphResponse::Routes(answers))
    }

    fn answer_least_visited(&self, candidates: &[LatentPoint]) -> Result<Answer, Refusal> {
        match self.counts.least_visited(candidates) {
            Ok(Some((index, visits))) => Ok(Answer::Ok(GraphResponse::LeastVisited {
                index: index as u32,
                visits: visits as f32,
            })),
            Ok(None) => Err(Refusal::invalid(
                "LeastVisited needs at least one candidate",
            )),
            Err(out) => Err(Refusal::invalid(format!(
                "candidate {} at {:?} is out of range",
                out.index, out.point
            ))),
        }
    }

    fn dump(&self, graph: &LatentGraph) -> Answer {
        let nodes = graph
            .keys()
            .iter()
            .map(|&key| DumpNode {
                key: key.0,
                position: graph.grid().position(key),
                visits: self.counts.of_key(key),
            })
            .collect();
        let edges = graph
            .edges()
            .iter()
            .map(|&(a, b, w)| (a, b, w as f32))
            .collect();
        Answer::Ok(GraphResponse::Dump(GraphDump {
            cell_size: graph.grid().cell_size() as f32,
            nodes,
            edges,
        }))
    }
}

/// The points of one route query, named.
fn query_points(query: &RouteQuery) -> Vec<(&'static str, &LatentPoint)> {
    let mut points = vec![("queries.start", &query.start), ("queries.end", &query.end)];
    points.extend(
        query
            .fallback_origin
            .as_ref()
            .map(|p| ("queries.fallback_origin", p)),
    );
    points
}
