//! The request handler: one [`GraphRequestHeader`] + postcard body in, one
//! [`GraphResponseHeader`] + postcard body out. Never panics.
//!
//! Checks, in order: protocol version (→ `VersionMismatch`), request kind code, body decoding,
//! body kind = header kind, finiteness, and that every point's cell key fits in `i32`
//! (→ `InvalidRequest`); each error body is [`GraphResponse::Error`] with the reason. A request
//! computed with another φ version than the graph's is answered all the same (the response
//! header names the graph's φ version) and counted in `stale_phi_requests`.
//!
//! Answers (every response header carries the graph version and the φ version of the state
//! that answered, whatever the status):
//! - `Stats`: always `Ok`, also before the first graph.
//! - `FrontierRoute`, `Routes`, `Dump`: `NotReady` until a graph is built, with an `Error` body
//!   giving the reason (empty graph: no φ weights yet). `FrontierRoute(Err(reason))` and
//!   `RouteAnswer::NoRoute { direct, fallback }` carry the [`NoRouteReason`] (empty graph,
//!   start cell unknown, end cell unknown, unreachable, nothing reachable); they are counted
//!   (`frontier_not_found`, `routes_not_found`).
//! - `LeastVisited`: the candidate with the lowest score, first on ties, and its score: by
//!   `asi.count_mode_score`, the graph visit count n(v) of its cell (paper Eq. 10; the counts
//!   exist before the graph) or HESS's future count F of its cell ([`crate::hess`]; 1 for a
//!   cell without samples, as the reference code's `future_hash`). An empty candidate list,
//!   or a candidate whose graph cell key is out of range, is `InvalidRequest`.
//! - `ExploreSubgoal`: HESS's count-based subgoal ([`crate::hess`]); `NotReady` with a reason
//!   while no state is stored. Needs no graph.
//! - `ReportReaching`: adds the samples to the potential map, answers `Ack`; a negative error
//!   refuses the whole batch (`InvalidRequest`, nothing added).

use protocol::config::CountModeScore;
use protocol::graph::{
    DumpNode, FrontierRoute, GraphDump, GraphRequestHeader, GraphResponseHeader,
    GraphStats as WireStats, GraphStatus, NoRouteReason, ReachSample, RouteAnswer, RouteQuery,
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
    /// Not answerable yet (no graph, no stored state): `NotReady` with the reason.
    NotReady(String),
}

/// Why graph queries are `NotReady` before the first graph.
const NO_GRAPH_YET: &str = "empty graph: no graph has been built yet (the first is built when \
    the learner's first φ weights arrive)";

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
            Ok(Answer::NotReady(message)) => (
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
                .map_or(Answer::NotReady(NO_GRAPH_YET.to_owned()), |g| self.dump(g)),
            GraphRequest::ExploreSubgoal { from, episode } => self.answer_explore(from, episode),
            GraphRequest::ReportReaching { samples } => self.answer_report(&samples)?,
        })
    }

    fn answer_explore(&mut self, from: LatentPoint, episode: u64) -> Answer {
        match self.explore(from, episode) {
            Some(choice) => Answer::Ok(GraphResponse::ExploreSubgoal {
                subgoal: choice.subgoal,
                candidate: choice.candidate,
            }),
            None => Answer::NotReady(
                "no stored states yet: explore subgoals are drawn from stored trajectories"
                    .to_owned(),
            ),
        }
    }

    fn answer_report(&mut self, samples: &[ReachSample]) -> Result<Answer, Refusal> {
        match self.hess.report(samples) {
            Ok(()) => Ok(Answer::Ok(GraphResponse::Ack)),
            Err(bad) => Err(Refusal::invalid(format!(
                "samples.error[{}] is {}; a reaching error is a distance (≥ 0); no sample of \
                 the batch was added",
                bad.index, bad.error
            ))),
        }
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
            return Answer::NotReady(NO_GRAPH_YET.to_owned());
        };
        let found = frontier::frontier(graph, from, self.frontier_fraction, &mut self.rng);
        self.stats.frontier_not_found += u64::from(found.is_err());
        let answer = found.as_ref().map_err(|why| why.reason()).and_then(|f| {
            Ok(FrontierRoute {
                // A frontier node is a node of this graph, so it has a position.
                frontier: graph
                    .position(f.node)
                    .ok_or(NoRouteReason::NothingReachable)?,
                route: positions(graph, &f.route),
                distance: f.distance as f32,
            })
        });
        if let Ok(f) = &found {
            self.note_frontier(f.node, &f.route);
        }
        Answer::Ok(GraphResponse::FrontierRoute(answer))
    }

    fn answer_routes(&mut self, queries: &[RouteQuery]) -> Answer {
        let Some(graph) = self.graph.as_ref() else {
            return Answer::NotReady(NO_GRAPH_YET.to_owned());
        };
        let fraction = self.frontier_fraction;
        let answers: Vec<RouteAnswer> = queries
            .iter()
            .map(|q| frontier::answer_route_query(graph, q, fraction, &mut self.rng))
            .collect();
        self.stats.routes_not_found += answers
            .iter()
            .filter(|a| matches!(a, RouteAnswer::NoRoute { .. }))
            .count() as u64;
        Answer::Ok(GraphResponse::Routes(answers))
    }

    fn answer_least_visited(&self, candidates: &[LatentPoint]) -> Result<Answer, Refusal> {
        let least = match self.count_mode_score {
            CountModeScore::GraphVisits => self
                .counts
                .least_visited(candidates)
                .map(|best| best.map(|(index, visits)| (index, visits as f64))),
            CountModeScore::FutureCount => self.least_future_count(candidates),
        };
        match least {
            Ok(Some((index, score))) => Ok(Answer::Ok(GraphResponse::LeastVisited {
                index: index as u32,
                visits: score as f32,
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

    /// The candidate whose cell has the lowest HESS future count (first on ties) and that
    /// count; candidates are range-checked against the graph grid as for visit counts.
    fn least_future_count(
        &self,
        candidates: &[LatentPoint],
    ) -> Result<Option<(usize, f64)>, crate::counts::OutOfRange> {
        let mut best: Option<(usize, f64)> = None;
        for (index, &point) in candidates.iter().enumerate() {
            if self.counts.at(point).is_none() {
                return Err(crate::counts::OutOfRange { index, point });
            }
            let score = self.hess.future_at(point);
            if best.is_none_or(|(_, lowest)| score < lowest) {
                best = Some((index, score));
            }
        }
        Ok(best)
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
