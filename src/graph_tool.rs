//! `asi graph --run-dir DIR …`: a debug client for the live graph-service of a running
//! training run. It reads the run id from the folder, checks that the run's graph-service is
//! alive, asks one question over the run's `graph` request–response service, and prints the
//! answer as `key: value` lines (points as `x,y`, routes as JSON arrays of `[x, y]`).
//!
//! - `stats`: graph size and trajectory store counts.
//! - `frontier --from X,Y`: a random frontier node seen from the cell of (X, Y) and the route.
//! - `route --from X,Y --to X,Y`: the shortest route between two cells.
//! - `explore --from X,Y [--episode N]`: HESS's count-based subgoal near (X, Y).
//! - `dump --png FILE [--from X,Y]`: a picture of the graph (see [`crate::graph_png`]), with a
//!   frontier and its route computed for the picture from `--from` (default: node 0, the
//!   oldest cell, which is where the first episodes started).
//!
//! When the service answers "no frontier" or "no route", the tool prints the reason the answer
//! carries (`reason: <code> (<meaning>)`, the code a [`NoRouteReason`] variant: `EmptyGraph`,
//! `StartUnknown`, `EndUnknown`, `Unreachable`, `NothingReachable`).

use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context};
use protocol::graph::{
    FrontierRoute, GraphRequest, GraphRequestHeader, GraphResponse, GraphStatus, NoRouteReason,
    RouteAnswer, RouteQuery,
};
use protocol::transport::open_node;
use protocol::{LatentPoint, PhiVersion, RunId, Service};

use crate::channels::GraphClient;
use crate::cli::{GraphArgs, GraphCommand};
use crate::run::{read_run_id, RunContext, STATUS_DIR};

/// Name of the graph-service process in the run folder's `status/`.
const PROCESS: &str = "graph-service";

/// A connection to one run's graph-service.
struct Session {
    run_id: RunId,
    client: GraphClient,
    timeout: Duration,
    next_id: u64,
}

/// A successful answer with the versions it was computed with.
struct Reply {
    graph_version: u64,
    phi_version: PhiVersion,
    response: GraphResponse,
}

pub fn run(args: &GraphArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.timeout_secs.is_finite() && args.timeout_secs > 0.0,
        "--timeout-secs must be a positive number of seconds, got {}",
        args.timeout_secs
    );
    let run_id = read_run_id(&args.run_dir)?;
    check_running(&args.run_dir, &run_id)?;
    let ctx = RunContext::open(&args.run_dir, run_id.as_str())?;
    let node = open_node(&run_id.node_name(&format!("graph-tool-{}", std::process::id())))?;
    let layout = crate::proc::common::task_info(&ctx.config)?.layout;
    let client =
        crate::channels::Channels::new(&ctx.config, &run_id, &layout).graph_client(&node)?;
    let mut session = Session {
        run_id,
        client,
        timeout: Duration::from_secs_f64(args.timeout_secs),
        next_id: 0,
    };
    match &args.command {
        GraphCommand::Stats => stats(&mut session),
        GraphCommand::Frontier { from } => frontier(&mut session, *from),
        GraphCommand::Route { from, to } => route(&mut session, *from, *to),
        GraphCommand::Explore { from, episode } => explore(&mut session, *from, *episode),
        GraphCommand::Dump { png, from } => dump(&mut session, png, *from),
    }
}

/// `Err` with a clear message when the run's graph-service has stopped or its process is gone.
fn check_running(run_dir: &Path, run_id: &RunId) -> anyhow::Result<()> {
    let status = run_dir.join(STATUS_DIR);
    if status.join(format!("{PROCESS}.json")).exists() {
        bail!("run `{run_id}` in {} is not running: its graph-service has stopped (status/{PROCESS}.json exists)", run_dir.display());
    }
    let pid_path = status.join(format!("{PROCESS}.pid"));
    let pid: i32 = std::fs::read_to_string(&pid_path)
        .with_context(|| {
            format!(
                "run `{run_id}` has no graph-service: reading {}",
                pid_path.display()
            )
        })?
        .trim()
        .parse()
        .with_context(|| format!("{} holds no pid", pid_path.display()))?;
    // SAFETY: signal 0 only checks that the process exists; nothing is delivered.
    let alive = unsafe { libc::kill(pid, 0) } == 0;
    if !alive {
        bail!(
            "run `{run_id}` in {} is not running: its graph-service (pid {pid}) is gone",
            run_dir.display()
        );
    }
    Ok(())
}

impl Session {
    /// Sends `request`; `Err` unless the status is `Ok` (the service's reason is in the error).
    fn ask(&mut self, request: &GraphRequest) -> anyhow::Result<Reply> {
        self.next_id += 1;
        let header = GraphRequestHeader::new(self.next_id, request.kind(), PhiVersion(0));
        let body = protocol::encode(request)?;
        let (reply, bytes) = self
            .client
            .call(header, &body, self.timeout)
            .with_context(|| {
                format!(
                    "asking the graph-service of run `{}` ({}); it did not answer within {:?}",
                    self.run_id,
                    self.run_id.service_name(Service::Graph),
                    self.timeout
                )
            })?;
        let status = reply.status()?;
        let response: Option<GraphResponse> = if bytes.is_empty() {
            None
        } else {
            Some(protocol::decode(&bytes).context("decoding the graph-service's answer")?)
        };
        match (status, response) {
            (GraphStatus::Ok, Some(response)) => Ok(Reply {
                graph_version: reply.graph_version,
                phi_version: reply.phi_version,
                response,
            }),
            (status, Some(GraphResponse::Error { message })) => {
                bail!("graph-service answered {status:?}: {message}")
            }
            (status, other) => bail!("unexpected answer ({status:?}): {other:?}"),
        }
    }
}

fn print_versions(reply: &Reply) {
    println!("graph_version: {}", reply.graph_version);
    println!("phi_version: {}", reply.phi_version);
}

fn stats(session: &mut Session) -> anyhow::Result<()> {
    let reply = session.ask(&GraphRequest::Stats)?;
    print_versions(&reply);
    let GraphResponse::Stats(stats) = reply.response else {
        bail!("unexpected answer: {:?}", reply.response)
    };
    println!("nodes: {}", stats.n_nodes);
    println!("edges: {}", stats.n_edges);
    println!("dropped_cells: {}", stats.n_dropped_cells);
    println!("stored_steps: {}", stats.n_stored_steps);
    println!("stored_episodes: {}", stats.n_stored_episodes);
    Ok(())
}

/// Asks for a frontier from `from`; no frontier comes with its reason.
fn ask_frontier(
    session: &mut Session,
    from: LatentPoint,
) -> anyhow::Result<(Reply, Result<FrontierRoute, String>)> {
    let reply = session.ask(&GraphRequest::FrontierRoute { from })?;
    let answer = match &reply.response {
        GraphResponse::FrontierRoute(Ok(found)) => Ok(found.clone()),
        GraphResponse::FrontierRoute(Err(reason)) => Err(describe(*reason)),
        other => bail!("unexpected answer: {other:?}"),
    };
    Ok((reply, answer))
}

fn frontier(session: &mut Session, from: LatentPoint) -> anyhow::Result<()> {
    let (reply, answer) = ask_frontier(session, from)?;
    print_versions(&reply);
    match answer {
        Ok(found) => {
            println!("frontier: {}", point(found.frontier));
            println!("distance: {}", found.distance);
            println!("route: {}", route_json(&found.route));
        }
        Err(reason) => {
            println!("frontier: none");
            println!("reason: {reason}");
        }
    }
    Ok(())
}

fn route(session: &mut Session, from: LatentPoint, to: LatentPoint) -> anyhow::Result<()> {
    let query = RouteQuery {
        start: from,
        end: to,
        fallback_origin: None,
    };
    let reply = session.ask(&GraphRequest::Routes {
        queries: vec![query],
    })?;
    print_versions(&reply);
    match &reply.response {
        GraphResponse::Routes(answers) => match answers.first() {
            Some(RouteAnswer::Direct(nodes) | RouteAnswer::ViaFrontier(nodes)) => {
                println!("route: {}", route_json(nodes));
            }
            Some(RouteAnswer::NoRoute { direct, .. }) => {
                println!("route: none");
                println!("reason: {}", describe(*direct));
            }
            None => bail!("the graph-service answered no route query"),
        },
        other => bail!("unexpected answer: {other:?}"),
    }
    Ok(())
}

fn explore(session: &mut Session, from: LatentPoint, episode: u64) -> anyhow::Result<()> {
    let reply = session.ask(&GraphRequest::ExploreSubgoal { from, episode })?;
    print_versions(&reply);
    let GraphResponse::ExploreSubgoal { subgoal, candidate } = reply.response else {
        bail!("unexpected answer: {:?}", reply.response)
    };
    println!("subgoal: {}", point(subgoal));
    println!("candidate: {}", point(candidate));
    Ok(())
}

fn dump(session: &mut Session, png: &Path, from: Option<LatentPoint>) -> anyhow::Result<()> {
    let reply = session.ask(&GraphRequest::Dump)?;
    let GraphResponse::Dump(graph) = &reply.response else {
        bail!("unexpected answer: {:?}", reply.response)
    };
    print_versions(&reply);
    println!("nodes: {}", graph.nodes.len());
    println!("edges: {}", graph.edges.len());
    println!(
        "max_visits: {}",
        graph.nodes.iter().map(|n| n.visits).max().unwrap_or(0)
    );
    let origin = from.or_else(|| graph.nodes.first().map(|n| n.position));
    let found = match origin {
        Some(origin) => {
            println!("frontier_from: {}", point(origin));
            match ask_frontier(session, origin)?.1 {
                Ok(found) => {
                    println!("frontier: {}", point(found.frontier));
                    println!("route: {}", route_json(&found.route));
                    Some(found)
                }
                Err(reason) => {
                    println!("frontier: none");
                    println!("reason: {reason}");
                    None
                }
            }
        }
        None => None,
    };
    crate::graph_png::render(graph, origin, found.as_ref(), png)?;
    println!("png: {}", png.display());
    Ok(())
}

/// A no-route reason as printed: the wire code, then its meaning.
fn describe(reason: NoRouteReason) -> String {
    format!("{reason:?} ({reason})")
}

/// `x,y`, the form `--from` takes.
fn point(p: LatentPoint) -> String {
    format!("{},{}", p[0], p[1])
}

/// A route as a JSON array of `[x, y]` pairs.
fn route_json(route: &[LatentPoint]) -> String {
    serde_json::to_string(route).unwrap_or_else(|_| "[]".to_owned())
}

/// Parses `X,Y` (finite numbers) for `--from` / `--to`.
pub fn parse_point(text: &str) -> Result<LatentPoint, String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let [x, y] = parts[..] else {
        return Err(format!(
            "expected X,Y (two numbers separated by a comma), got `{text}`"
        ));
    };
    let parse = |s: &str| -> Result<f32, String> {
        let v: f32 = s
            .parse()
            .map_err(|e| format!("`{s}` in `{text}` is not a number: {e}"))?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("`{s}` in `{text}` is not finite"))
        }
    };
    Ok([parse(x)?, parse(y)?])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_parse_with_signs_and_spaces_and_refuse_garbage() {
        assert_eq!(parse_point("-3.5, 4"), Ok([-3.5, 4.0]));
        assert!(parse_point("1").is_err());
        assert!(parse_point("1,2,3").is_err());
        assert!(parse_point("x,2").is_err());
        assert!(parse_point("inf,2").is_err());
    }

    #[test]
    fn a_reason_prints_its_wire_code_and_its_meaning() {
        let text = describe(NoRouteReason::EndUnknown);
        assert!(text.starts_with("EndUnknown ("), "{text}");
        assert!(text.contains("end point"), "{text}");
    }
}
