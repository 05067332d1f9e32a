//! `asi graph-service`: stores every trajectory chunk, follows φ as the learner publishes it,
//! and answers graph requests. Sleeps on its channels' events.

use std::time::Duration;

use anyhow::Context;
use graph_service::GraphService;
use iceoryx2::prelude::*;
use protocol::transport::Ipc;
use protocol::{ControlCommand, ProcessRole};

use super::common::{newest_weights, node, task_info, MetricsOut, StopWatch};
use crate::channels::{Channels, TrajectorySubscriber, WeightsSubscriber};
use crate::run::RunContext;

/// Sleep when idle; chunks, weights, requests and control messages wake the service earlier.
const IDLE_WAIT: Duration = Duration::from_millis(100);

pub fn run(ctx: &RunContext) -> anyhow::Result<()> {
    let config = &ctx.config;
    let task = task_info(config)?;
    let (dims, layout) = (task.dims, task.layout);
    let mut service = GraphService::new(config, dims, config.run.seed).context("building the graph-service")?;
    let node = node(ctx, "graph-service")?;
    let channels = Channels::new(config, &ctx.run_id, &layout);
    let trajectories = channels.trajectory_subscriber(&node)?;
    let weights = channels.weights_subscriber(&node)?;
    let control = channels.control_subscriber(&node)?;
    let server = channels.graph_server(&node)?;
    let mut metrics = MetricsOut::new(channels.metrics_publisher(&node)?, ProcessRole::GraphService, 0, config);
    let waitset = WaitSetBuilder::new().create::<Ipc>().map_err(|e| anyhow::anyhow!("creating a wait set: {e:?}"))?;
    let _g = [trajectories.listener(), weights.listener(), control.listener(), server.listener()]
        .into_iter()
        .map(|l| waitset.attach_notification(l).map_err(|e| anyhow::anyhow!("{e:?}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let stop = StopWatch::new();
    ctx.mark_ready("graph-service")?;
    let reason = loop {
        let _ = waitset.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, IDLE_WAIT);
        if let Some(reason) = stop.should_stop(&node) {
            break reason;
        }
        if control.drain()?.iter().any(|m| m.command() == Ok(ControlCommand::Stop)) {
            break "stop requested";
        }
        ingest_all(&mut service, &trajectories);
        load_new_weights(&mut service, &weights);
        server.serve(|header, body| service.handle(header, body))?;
        if metrics.due() {
            let stats = service.stats();
            metrics.publish(stats.stored_steps, &graph_metrics(&stats));
        }
    };
    ingest_all(&mut service, &trajectories);
    tracing::info!(reason, "graph-service stopping");
    let stats = service.stats();
    let per_actor: serde_json::Map<String, serde_json::Value> =
        stats.per_actor_steps.iter().map(|(k, v)| (k.to_string(), serde_json::json!(v))).collect();
    ctx.write_status(
        "graph-service",
        &serde_json::json!({
            "role": "graph-service", "env_steps": stats.per_actor_steps.values().sum::<u64>(),
            "stored_steps": stats.stored_steps, "chunks": stats.chunks,
            "rejected_chunks": stats.rejected_chunks, "per_actor_steps": per_actor,
            "nodes": stats.n_nodes, "graph_version": stats.graph_version, "stop_reason": reason,
        }),
    )
}

fn ingest_all(service: &mut GraphService, trajectories: &TrajectorySubscriber) {
    let drained = trajectories.drain(|header, payload| {
        if let Err(err) = service.ingest(header, payload) {
            tracing::warn!("rejected a trajectory chunk: {err:#}");
        }
    });
    if let Err(err) = drained {
        tracing::warn!("receiving trajectories failed: {err:#}");
    }
}

fn load_new_weights(service: &mut GraphService, weights: &WeightsSubscriber) {
    if let Some((header, bytes)) = newest_weights(weights) {
        if let Err(err) = service.load_weights(&header, &bytes) {
            tracing::error!("refused weights: {err:#}");
        }
    }
}

fn graph_metrics(stats: &graph_service::GraphStats) -> Vec<(String, f64)> {
    vec![
        ("graph/stored_steps".to_owned(), stats.stored_steps as f64),
        ("graph/chunks".to_owned(), stats.chunks as f64),
        ("graph/rejected_chunks".to_owned(), stats.rejected_chunks as f64),
        ("graph/nodes".to_owned(), stats.n_nodes as f64),
        ("graph/edges".to_owned(), stats.n_edges as f64),
        ("graph/version".to_owned(), stats.graph_version as f64),
        ("graph/requests".to_owned(), stats.requests as f64),
        ("graph/invalid_requests".to_owned(), stats.invalid_requests as f64),
        ("graph/frontier_not_found".to_owned(), stats.frontier_not_found as f64),
        ("graph/routes_not_found".to_owned(), stats.routes_not_found as f64),
        ("graph/explore_answers".to_owned(), stats.explore_answers as f64),
        ("graph/hess_visited_cells".to_owned(), stats.hess_visited_cells as f64),
        ("graph/future_count_recomputes".to_owned(), stats.future_count_recomputes as f64),
        ("graph/reach_samples".to_owned(), stats.reach_samples as f64),
    ]
}
