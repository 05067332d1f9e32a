//! Graph-service request–response messages (`asi/<run>/graph`, payload `[u8]`).
//!
//! Each request is a [`GraphRequestHeader`] (fixed, zero-copy) plus a postcard-encoded
//! [`GraphRequest`]; each response a [`GraphResponseHeader`] plus a postcard-encoded
//! [`GraphResponse`]. All points are in φ-space ([`LatentPoint`]); the header's φ version says
//! which φ they were computed with. Use [`encode`] / [`decode`]: decoding rejects malformed
//! bytes and trailing garbage, and [`GraphRequest::check_finite`] rejects NaN/inf points before a
//! query touches the graph.

use iceoryx2::prelude::ZeroCopySend;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::error::ProtocolError;
use crate::payload::{PhiVersion, Versioned};
use crate::PROTOCOL_VERSION;

/// A point in the 2-D latent space φ.
pub type LatentPoint = [f32; 2];

/// Encodes `value` with postcard.
pub fn encode<T: Serialize>(value: &T) -> Result<Vec<u8>, ProtocolError> {
    postcard::to_allocvec(value).map_err(|err| ProtocolError::Encode {
        what: std::any::type_name::<T>(),
        message: err.to_string(),
    })
}

/// Decodes a postcard `T` that must span all of `bytes`.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ProtocolError> {
    let what = std::any::type_name::<T>();
    let (value, rest) =
        postcard::take_from_bytes::<T>(bytes).map_err(|err| ProtocolError::Decode {
            what,
            message: err.to_string(),
        })?;
    if rest.is_empty() {
        Ok(value)
    } else {
        Err(ProtocolError::Decode {
            what,
            message: format!("{} trailing bytes after the message", rest.len()),
        })
    }
}

/// Kind of a graph request (and of its response), as a `u32` code in the headers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum GraphRequestKind {
    /// [`GraphRequest::FrontierRoute`].
    FrontierRoute = 1,
    /// [`GraphRequest::Routes`].
    Routes = 2,
    /// [`GraphRequest::ExploreSubgoal`].
    ExploreSubgoal = 3,
    /// [`GraphRequest::LeastVisited`].
    LeastVisited = 4,
    /// [`GraphRequest::ReportReaching`].
    ReportReaching = 5,
    /// [`GraphRequest::Stats`].
    Stats = 6,
    /// [`GraphRequest::Dump`].
    Dump = 7,
}

impl TryFrom<u32> for GraphRequestKind {
    type Error = ProtocolError;
    fn try_from(code: u32) -> Result<Self, Self::Error> {
        Ok(match code {
            1 => GraphRequestKind::FrontierRoute,
            2 => GraphRequestKind::Routes,
            3 => GraphRequestKind::ExploreSubgoal,
            4 => GraphRequestKind::LeastVisited,
            5 => GraphRequestKind::ReportReaching,
            6 => GraphRequestKind::Stats,
            7 => GraphRequestKind::Dump,
            _ => {
                return Err(ProtocolError::UnknownCode {
                    what: "graph request kind",
                    code,
                })
            }
        })
    }
}

/// Outcome of a graph request as a whole (per-item outcomes live in the response body).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u32)]
pub enum GraphStatus {
    /// Answered; the body is the matching [`GraphResponse`].
    Ok = 0,
    /// The request cannot be answered yet (no graph before the first φ weights, or no stored
    /// state for an explore subgoal); the body is a [`GraphResponse::Error`] with the reason.
    NotReady = 1,
    /// The request was malformed or had non-finite points; the body is [`GraphResponse::Error`].
    InvalidRequest = 2,
    /// The request's protocol version differs; the body is [`GraphResponse::Error`].
    VersionMismatch = 3,
    /// The service failed internally; the body is [`GraphResponse::Error`].
    Internal = 4,
}

impl TryFrom<u32> for GraphStatus {
    type Error = ProtocolError;
    fn try_from(code: u32) -> Result<Self, Self::Error> {
        Ok(match code {
            0 => GraphStatus::Ok,
            1 => GraphStatus::NotReady,
            2 => GraphStatus::InvalidRequest,
            3 => GraphStatus::VersionMismatch,
            4 => GraphStatus::Internal,
            _ => {
                return Err(ProtocolError::UnknownCode {
                    what: "graph status",
                    code,
                })
            }
        })
    }
}

/// Request user header.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("asi::GraphRequestHeader")]
pub struct GraphRequestHeader {
    /// Client-chosen id, echoed in the response.
    pub request_id: u64,
    /// φ version the request's points were computed with.
    pub phi_version: PhiVersion,
    /// [`GraphRequestKind`] code; must match the body.
    pub kind: u32,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
}

impl GraphRequestHeader {
    /// A header for `kind`, current protocol version.
    pub fn new(request_id: u64, kind: GraphRequestKind, phi_version: PhiVersion) -> Self {
        Self {
            request_id,
            phi_version,
            kind: kind as u32,
            protocol_version: PROTOCOL_VERSION,
        }
    }

    /// Checks the version and decodes the kind.
    pub fn kind(&self) -> Result<GraphRequestKind, ProtocolError> {
        self.check_version()?;
        GraphRequestKind::try_from(self.kind)
    }
}

impl Versioned for GraphRequestHeader {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// Response user header.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("asi::GraphResponseHeader")]
pub struct GraphResponseHeader {
    /// The request's id.
    pub request_id: u64,
    /// Version of the graph that answered (goes up with every rebuild).
    pub graph_version: u64,
    /// φ version the graph (and the returned points) is built with.
    pub phi_version: PhiVersion,
    /// [`GraphRequestKind`] code of the request answered.
    pub kind: u32,
    /// [`GraphStatus`] code.
    pub status: u32,
    /// [`PROTOCOL_VERSION`] of the sender.
    pub protocol_version: u32,
    /// Zero; keeps the struct free of implicit padding.
    pub reserved: u32,
}

impl GraphResponseHeader {
    /// A header answering `request`, current protocol version.
    pub fn answering(
        request: &GraphRequestHeader,
        status: GraphStatus,
        graph_version: u64,
        phi_version: PhiVersion,
    ) -> Self {
        Self {
            request_id: request.request_id,
            graph_version,
            phi_version,
            kind: request.kind,
            status: status as u32,
            protocol_version: PROTOCOL_VERSION,
            reserved: 0,
        }
    }

    /// Checks the version and decodes the status.
    pub fn status(&self) -> Result<GraphStatus, ProtocolError> {
        self.check_version()?;
        GraphStatus::try_from(self.status)
    }
}

impl Versioned for GraphResponseHeader {
    fn protocol_version(&self) -> u32 {
        self.protocol_version
    }
}

/// One route query of a batch (SI, SPEC §6.7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RouteQuery {
    /// Route start, φ(s_t).
    pub start: LatentPoint,
    /// Route end, φ(g̃).
    pub end: LatentPoint,
    /// If set and there is no route start→end: route start→(random frontier seen from this
    /// origin, typically φ(s_0)) instead.
    pub fallback_origin: Option<LatentPoint>,
}

/// A reaching sample for the HESS potential map (SPEC §6.4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReachSample {
    /// The chosen subgoal before the outward push (the cell that accumulates the error).
    pub subgoal: LatentPoint,
    /// ‖pushed subgoal − φ(s_{t+c})‖ at the end of the segment.
    pub error: f32,
}

/// A request to the graph-service.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum GraphRequest {
    /// FR episode start: a random frontier node seen from `from`, and the route to it.
    FrontierRoute {
        /// φ(s_0).
        from: LatentPoint,
    },
    /// Batched route queries (SI).
    Routes {
        /// The queries, answered in order.
        queries: Vec<RouteQuery>,
    },
    /// HESS exploration subgoal near `from` for training episode `episode`.
    ExploreSubgoal {
        /// φ(s_t).
        from: LatentPoint,
        /// Training episode index (gates the potential term and the push).
        episode: u64,
    },
    /// FR count mode: which candidate has the fewest visits.
    LeastVisited {
        /// Candidates, e.g. 100 uniform in the ±abs_range box around φ(s_t).
        candidates: Vec<LatentPoint>,
    },
    /// Reaching errors for the potential map; answered with [`GraphResponse::Ack`].
    ReportReaching {
        /// The samples.
        samples: Vec<ReachSample>,
    },
    /// Graph statistics.
    Stats,
    /// The whole graph, for debug tools.
    Dump,
}

impl GraphRequest {
    /// The request's kind (for the header).
    pub fn kind(&self) -> GraphRequestKind {
        match self {
            GraphRequest::FrontierRoute { .. } => GraphRequestKind::FrontierRoute,
            GraphRequest::Routes { .. } => GraphRequestKind::Routes,
            GraphRequest::ExploreSubgoal { .. } => GraphRequestKind::ExploreSubgoal,
            GraphRequest::LeastVisited { .. } => GraphRequestKind::LeastVisited,
            GraphRequest::ReportReaching { .. } => GraphRequestKind::ReportReaching,
            GraphRequest::Stats => GraphRequestKind::Stats,
            GraphRequest::Dump => GraphRequestKind::Dump,
        }
    }

    /// `Err(NonFinite)` naming the first NaN/inf point or value (index = position in the list).
    pub fn check_finite(&self) -> Result<(), ProtocolError> {
        match self {
            GraphRequest::FrontierRoute { from } | GraphRequest::ExploreSubgoal { from, .. } => {
                check_points("from", std::iter::once(from))
            }
            GraphRequest::Routes { queries } => check_route_queries(queries),
            GraphRequest::LeastVisited { candidates } => {
                check_points("candidates", candidates.iter())
            }
            GraphRequest::ReportReaching { samples } => check_reach_samples(samples),
            GraphRequest::Stats | GraphRequest::Dump => Ok(()),
        }
    }
}

/// Finiteness of every point of a route batch.
fn check_route_queries(queries: &[RouteQuery]) -> Result<(), ProtocolError> {
    check_points("queries.start", queries.iter().map(|q| &q.start))?;
    check_points("queries.end", queries.iter().map(|q| &q.end))?;
    check_points(
        "queries.fallback_origin",
        queries.iter().filter_map(|q| q.fallback_origin.as_ref()),
    )
}

/// Finiteness of reach samples.
fn check_reach_samples(samples: &[ReachSample]) -> Result<(), ProtocolError> {
    check_points("samples.subgoal", samples.iter().map(|s| &s.subgoal))?;
    match samples.iter().position(|s| !s.error.is_finite()) {
        Some(index) => Err(ProtocolError::NonFinite {
            field: "samples.error",
            index,
            value: samples[index].error,
        }),
        None => Ok(()),
    }
}

/// `Err(NonFinite)` at the first point with a NaN/inf coordinate.
fn check_points<'a>(
    field: &'static str,
    points: impl Iterator<Item = &'a LatentPoint>,
) -> Result<(), ProtocolError> {
    for (index, point) in points.enumerate() {
        if let Some(value) = point.iter().copied().find(|v| !v.is_finite()) {
            return Err(ProtocolError::NonFinite {
                field,
                index,
                value,
            });
        }
    }
    Ok(())
}

/// Why the graph-service found no route or no frontier.
///
/// In a [`RouteAnswer::NoRoute`], `direct` is the reason for the start→end search and
/// `fallback` the reason for the fallback (frontier seen from the fallback origin, then the
/// route start→frontier): there `StartUnknown` means the origin's or the start's cell is not a
/// node, `NothingReachable` that no frontier exists from the origin, and `Unreachable` that the
/// chosen frontier is not reachable from the start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum NoRouteReason {
    /// The graph has no nodes.
    EmptyGraph,
    /// The start point's cell (or the origin's, for a frontier) is not a graph node.
    StartUnknown,
    /// The end point's cell is not a graph node.
    EndUnknown,
    /// Both cells are nodes, but the end is not reachable from the start.
    Unreachable,
    /// No node other than the start node is reachable, so there is no frontier.
    NothingReachable,
}

impl std::fmt::Display for NoRouteReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NoRouteReason::EmptyGraph => "the graph has no nodes",
            NoRouteReason::StartUnknown => "the start point is in no graph node's cell",
            NoRouteReason::EndUnknown => "the end point is in no graph node's cell",
            NoRouteReason::Unreachable => "the end node is not reachable from the start node",
            NoRouteReason::NothingReachable => {
                "no node other than the start node is reachable (no frontier)"
            }
        })
    }
}

/// A route answer of a batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum RouteAnswer {
    /// Route from the start node (index 0) to the end node inclusive, node positions.
    Direct(Vec<LatentPoint>),
    /// No route to the end; route to a random frontier node seen from the fallback origin.
    ViaFrontier(Vec<LatentPoint>),
    /// No route at all, with the reasons (see [`NoRouteReason`]).
    NoRoute {
        /// Why the direct route start→end failed.
        direct: NoRouteReason,
        /// Why the fallback failed; `None` when the query had no fallback origin.
        fallback: Option<NoRouteReason>,
    },
}

/// Frontier and route for an FR episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrontierRoute {
    /// Position of the chosen frontier node g_F.
    pub frontier: LatentPoint,
    /// Route from the start node to the frontier node inclusive.
    pub route: Vec<LatentPoint>,
    /// Graph distance of the frontier from the start node.
    pub distance: f32,
}

/// Graph statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GraphStats {
    /// Nodes in the graph.
    pub n_nodes: u64,
    /// Undirected edges.
    pub n_edges: u64,
    /// New cells not added because of the node cap, since the last rebuild.
    pub n_dropped_cells: u64,
    /// Env steps in the trajectory store.
    pub n_stored_steps: u64,
    /// Episodes in the trajectory store.
    pub n_stored_episodes: u64,
}

/// One node in a dump.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DumpNode {
    /// Integer cell key (⌊φ/d⌋ per axis).
    pub key: [i32; 2],
    /// Node position in φ-space.
    pub position: LatentPoint,
    /// Visit count n(v).
    pub visits: u64,
}

/// The whole graph, for debug tools.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GraphDump {
    /// Cell side d.
    pub cell_size: f32,
    /// Nodes; their index is the node id used in `edges`.
    pub nodes: Vec<DumpNode>,
    /// Undirected edges (a, b, weight), a < b.
    pub edges: Vec<(u32, u32, f32)>,
}

/// A response from the graph-service.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum GraphResponse {
    /// Answer to [`GraphRequest::FrontierRoute`]; `Err` with the reason when the start cell is
    /// unknown or no other node is reachable (the actor falls back to a normal episode and
    /// counts it).
    FrontierRoute(Result<FrontierRoute, NoRouteReason>),
    /// Answers to [`GraphRequest::Routes`], in query order.
    Routes(Vec<RouteAnswer>),
    /// Answer to [`GraphRequest::ExploreSubgoal`]: the absolute subgoal (pushed if applicable)
    /// and the un-pushed candidate (for the potential report).
    ExploreSubgoal {
        /// Subgoal for the low level.
        subgoal: LatentPoint,
        /// The chosen candidate before the push.
        candidate: LatentPoint,
    },
    /// Answer to [`GraphRequest::LeastVisited`]: index of the chosen candidate and its count.
    LeastVisited {
        /// Index into the request's candidates.
        index: u32,
        /// Its visit measure.
        visits: f32,
    },
    /// Acknowledges [`GraphRequest::ReportReaching`].
    Ack,
    /// Answer to [`GraphRequest::Stats`].
    Stats(GraphStats),
    /// Answer to [`GraphRequest::Dump`].
    Dump(GraphDump),
    /// The request could not be answered; see the header status.
    Error {
        /// Human-readable reason.
        message: String,
    },
}
