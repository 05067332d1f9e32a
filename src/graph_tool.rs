//! `asi graph --run-dir DIR …`: a debug client for the live graph-service of a running
//! training run. It reads the run id from the folder, asks one question, prints the answer.

use std::time::Duration;

use anyhow::{bail, Context};
use protocol::graph::{GraphRequest, GraphRequestHeader, GraphResponse, GraphStatus};
use protocol::transport::open_node;
use protocol::{PhiVersion, Service};

use crate::cli::{GraphArgs, GraphCommand};
use crate::run::{read_run_id, RunContext};

/// How long to wait for the graph-service (it answers between trajectory chunks).
const TIMEOUT: Duration = Duration::from_secs(10);

pub fn run(args: &GraphArgs) -> anyhow::Result<()> {
    let run_id = read_run_id(&args.run_dir)?;
    let ctx = RunContext::open(&args.run_dir, run_id.as_str())?;
    let node = open_node(&run_id.node_name(&format!("graph-tool-{}", std::process::id())))?;
    let layout = crate::proc::common::task_info(&ctx.config)?.layout;
    let client = crate::channels::Channels::new(&ctx.config, &run_id, &layout).graph_client(&node)?;
    let request = match args.command {
        GraphCommand::Stats => GraphRequest::Stats,
    };
    let header = GraphRequestHeader::new(u64::from(std::process::id()), request.kind(), PhiVersion(0));
    let body = protocol::encode(&request)?;
    let (reply, bytes) = client
        .call(header, &body, TIMEOUT)
        .with_context(|| format!("asking the graph-service of run `{run_id}` ({})", run_id.service_name(Service::Graph)))?;
    let status = reply.status()?;
    let response: GraphResponse = protocol::decode(&bytes).context("decoding the graph-service's answer")?;
    println!("graph_version: {}", reply.graph_version);
    println!("phi_version: {}", reply.phi_version);
    match (status, response) {
        (GraphStatus::Ok, GraphResponse::Stats(stats)) => {
            println!("nodes: {}", stats.n_nodes);
            println!("edges: {}", stats.n_edges);
            println!("dropped_cells: {}", stats.n_dropped_cells);
            println!("stored_steps: {}", stats.n_stored_steps);
            println!("stored_episodes: {}", stats.n_stored_episodes);
            Ok(())
        }
        (status, GraphResponse::Error { message }) => bail!("graph-service answered {status:?}: {message}"),
        (status, other) => bail!("unexpected answer ({status:?}): {other:?}"),
    }
}
