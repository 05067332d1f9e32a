//! `asi learner`: ingests trajectory chunks from every actor, trains at the configured replay
//! ratio, runs the due self-imitation rounds with routes from the graph-service (SPEC §6.7),
//! publishes versioned weights and the throttle state. Sleeps on its channels' events when it
//! has nothing to do.
//!
//! Crash recovery: a learner restarted by the launcher starts from the newest checkpoint
//! ([`crate::run::open_learner`]). Before each weights message it records the versions in
//! `run_dir/learner_published.json` ([`PUBLISHED_FILE`], kept across launches of the run); a
//! restarted or resumed learner continues its versions above those
//! ([`learner::Learner::continue_versions_after`]), so the versions every other process sees
//! only go up although the checkpoint is older — also for a graph-service that restored a φ
//! newer than the learner's checkpoint after a crash of the whole run. Each start appends a line to
//! `status/learner.starts.jsonl` ([`STARTS_FILE`]: pid, env steps restored, versions), written
//! once its trajectory subscriber exists.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use iceoryx2::prelude::*;
use learner::Learner;
use protocol::transport::{Ipc, ValuePublisher};
use protocol::{
    ControlCommand, PhiVersion, PolicyVersion, ProcessRole, ProgressMessage, PROTOCOL_VERSION,
};

use super::common::{
    node, task_info, wait_set, wake_on, CoverageTracker, GraphRoutes, IpcGraph, MetricsOut,
    StopWatch,
};
use crate::channels::{Channels, WeightsPublisher};
use crate::run::RunContext;

/// Sleep when idle; events (chunks, control) wake the learner earlier.
const IDLE_WAIT: Duration = Duration::from_millis(50);
/// Updates per loop iteration, so new chunks are ingested between bursts of training.
const UPDATES_PER_TICK: usize = 8;
/// How often publishers hand their history (latest weights, progress) to new subscribers.
const RECONNECT_INTERVAL: Duration = Duration::from_millis(500);
/// File in the run folder: the versions of the newest weights message the run's learners
/// published (all launches; `--restart` moves it aside with the folder).
pub const PUBLISHED_FILE: &str = "learner_published.json";
/// Status file: one JSON line per learner start of this launch.
pub const STARTS_FILE: &str = "learner.starts.jsonl";

pub fn run(ctx: &RunContext) -> anyhow::Result<()> {
    let config = &ctx.config;
    let task = task_info(config)?;
    let layout = task.layout;
    let mut coverage = CoverageTracker::new(config, layout)?;
    let (mut learner, restored) = crate::run::open_learner(ctx, task.dims, task.episode_length)?;
    if let Some(checkpoint) = restored {
        restore_coverage(&mut coverage, &checkpoint);
    }
    continue_published_versions(ctx, &mut learner)?;
    let mut checkpoints = crate::run::CheckpointTimer::new(config);
    let node = node(ctx, "learner")?;
    let channels = Channels::new(config, &ctx.run_id, &layout);
    let trajectories = channels.trajectory_subscriber(&node)?;
    let control = channels.control_subscriber(&node)?;
    let progress = channels.progress_publisher(&node)?;
    let mut weights: Option<WeightsPublisher> = None;
    let mut si_routes = si_route_source(config, &channels, &node)?;
    let mut metrics = MetricsOut::new(
        channels.metrics_publisher(&node)?,
        ProcessRole::Learner,
        0,
        config,
    );
    let waitset = wait_set()?;
    let _wake = wake_on(&waitset, &[trajectories.listener(), control.listener()])?;
    let mut stop = StopWatch::new(&node);
    publish_weights(ctx, &mut learner, &channels, &node, &mut weights)?;
    send_progress(&progress, &learner)?;
    ctx.mark_ready("learner")?;
    record_start(ctx, &learner)?;
    let mut last_reconnect = Instant::now();
    let mut busy = false;
    let reason = loop {
        let timeout = if busy { Duration::ZERO } else { IDLE_WAIT };
        let _ =
            waitset.wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, timeout);
        if let Some(reason) = stop.should_stop(&node).or_else(|| stop_requested(&control)) {
            break reason;
        }
        ingest_all(&mut learner, &mut coverage, &trajectories);
        busy = learner.train(UPDATES_PER_TICK)? > 0;
        if let Some(routes) = si_routes.as_mut() {
            busy |= learner.train_self_imitation(routes)? > 0;
        }
        publish_weights(ctx, &mut learner, &channels, &node, &mut weights)?;
        send_progress(&progress, &learner)?;
        if last_reconnect.elapsed() >= RECONNECT_INTERVAL {
            reconnect(&progress, weights.as_ref());
            last_reconnect = Instant::now();
        }
        if metrics.due() {
            metrics.publish(
                learner.progress().env_steps_ingested,
                &learner_metrics(&learner, &coverage),
            );
        }
        if let Some(checkpoint) = checkpoints.tick(ctx, &learner) {
            save_coverage(&coverage, &checkpoint.path);
        }
    };
    // Actors are stopped first; whatever they sent is in our buffer: take it before leaving.
    ingest_all(&mut learner, &mut coverage, &trajectories);
    metrics.publish(
        learner.progress().env_steps_ingested,
        &learner_metrics(&learner, &coverage),
    );
    tracing::info!(reason, "learner stopping");
    if let Some(checkpoint) = crate::run::final_checkpoint(ctx, &mut learner)? {
        save_coverage(&coverage, &checkpoint.path);
    }
    write_final_status(ctx, &learner, reason)
}

/// The coverage grid of the learner checkpoint just restored from, so `charts/coverage` goes
/// on from where the run was instead of from 0. A missing or unreadable grid is logged and
/// coverage counts from this start's data only: a metric, not a reason to stop training.
fn restore_coverage(coverage: &mut CoverageTracker, checkpoint: &Path) {
    match coverage.restore_beside(checkpoint) {
        Ok(true) => {}
        Ok(false) => tracing::warn!(
            "no coverage grid beside {}: charts/coverage counts from this start's data only",
            checkpoint.display()
        ),
        Err(err) => tracing::warn!("{err:#}: charts/coverage counts from this start's data only"),
    }
}

/// Writes the coverage grid beside the learner checkpoint at `checkpoint`; a failure is
/// logged (the checkpoint stands; a resume from it counts coverage anew).
fn save_coverage(coverage: &CoverageTracker, checkpoint: &Path) {
    if let Err(err) = coverage.save_beside(checkpoint) {
        tracing::error!(
            "writing the coverage grid beside {} failed: {err:#}",
            checkpoint.display()
        );
    }
}

/// The graph-service client for self-imitation routes; `None` when `asi.self_imitation` is off
/// (no graph port is taken then).
fn si_route_source(
    config: &protocol::Config,
    channels: &Channels,
    node: &Node<Ipc>,
) -> anyhow::Result<Option<GraphRoutes<IpcGraph>>> {
    if !config.asi.self_imitation {
        return Ok(None);
    }
    let timeout = Duration::from_millis(config.transport.graph_request_timeout_ms);
    Ok(Some(GraphRoutes::new(IpcGraph::new(
        channels.graph_client(node)?,
        timeout,
    ))))
}

fn ingest_all(
    learner: &mut Learner,
    coverage: &mut CoverageTracker,
    trajectories: &crate::channels::TrajectorySubscriber,
) {
    let drained = trajectories.drain(|header, payload| match learner.ingest(header, payload) {
        Ok(_) => coverage.observe(payload),
        Err(err) => tracing::warn!("rejected a trajectory chunk: {err:#}"),
    });
    if let Err(err) = drained {
        tracing::warn!("receiving trajectories failed: {err:#}");
    }
}

fn stop_requested(
    control: &protocol::transport::ValueSubscriber<protocol::ControlMessage>,
) -> Option<&'static str> {
    let messages = control.drain().ok()?;
    messages
        .iter()
        .any(|m| m.command() == Ok(ControlCommand::Stop))
        .then_some("stop requested")
}

fn publish_weights(
    ctx: &RunContext,
    learner: &mut Learner,
    channels: &Channels,
    node: &Node<Ipc>,
    weights: &mut Option<WeightsPublisher>,
) -> anyhow::Result<()> {
    let Some((header, bytes)) = learner.publish_due()? else {
        return Ok(());
    };
    // Recorded before the send: a learner killed in between only skips one version number.
    let versions = serde_json::json!({ "policy_version": header.policy_version.0, "phi_version": header.phi_version.0 });
    crate::run::write_atomically(&ctx.run_dir.join(PUBLISHED_FILE), &versions.to_string())?;
    if weights.is_none() {
        *weights = Some(channels.weights_publisher(node, bytes.len())?);
    }
    if let Some(publisher) = weights {
        publisher.send(header, &bytes)?;
    }
    Ok(())
}

/// `(policy_version, phi_version)` of a [`PUBLISHED_FILE`].
fn published_versions(text: &str) -> Option<(PolicyVersion, PhiVersion)> {
    let value: serde_json::Value = serde_json::from_str(text).ok()?;
    let policy = value.get("policy_version")?.as_u64()?;
    let phi = value.get("phi_version")?.as_u64()?;
    Some((PolicyVersion(policy), PhiVersion(phi)))
}

fn status_file(ctx: &RunContext, name: &str) -> std::path::PathBuf {
    ctx.run_dir.join(crate::run::STATUS_DIR).join(name)
}

/// A restarted or resumed learner continues its versions above what its predecessors
/// published (see the module doc); a first start finds no file and changes nothing. An
/// unreadable file is reported and ignored (versions then continue from the checkpoint).
fn continue_published_versions(ctx: &RunContext, learner: &mut Learner) -> anyhow::Result<()> {
    let path = ctx.run_dir.join(PUBLISHED_FILE);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(err) => return Err(err).with_context(|| format!("reading {}", path.display())),
    };
    let Some((policy, phi)) = published_versions(&text) else {
        tracing::error!(
            "{} is unreadable ({text:?}); weights versions continue from the checkpoint",
            path.display()
        );
        return Ok(());
    };
    let restored = learner.progress();
    learner.continue_versions_after(policy, phi);
    let now = learner.progress();
    tracing::info!(
        published_policy = policy.0,
        published_phi = phi.0,
        restored_policy = restored.policy_version.0,
        restored_phi = restored.phi_version.0,
        policy = now.policy_version.0,
        phi = now.phi_version.0,
        "restarted learner continues the weights versions of its predecessor"
    );
    Ok(())
}

/// Appends this start to [`STARTS_FILE`] (one `write` of one line, so concurrent readers see
/// whole lines).
fn record_start(ctx: &RunContext, learner: &Learner) -> anyhow::Result<()> {
    use std::io::Write;
    let p = learner.progress();
    let line = serde_json::json!({
        "pid": std::process::id(), "env_steps": p.env_steps_ingested, "updates_low": p.updates_low,
        "policy_version": p.policy_version.0, "phi_version": p.phi_version.0,
    });
    let path = status_file(ctx, STARTS_FILE);
    let mut file = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("opening {}", path.display()))?;
    file.write_all(format!("{line}\n").as_bytes())
        .with_context(|| format!("writing {}", path.display()))
}

fn send_progress(
    progress: &ValuePublisher<ProgressMessage>,
    learner: &Learner,
) -> anyhow::Result<()> {
    let p = learner.progress();
    progress.send(ProgressMessage {
        env_steps_ingested: p.env_steps_ingested,
        env_step_budget: p.env_step_budget,
        policy_version: p.policy_version,
        phi_version: p.phi_version,
        protocol_version: PROTOCOL_VERSION,
        reserved: 0,
    })?;
    Ok(())
}

fn reconnect(progress: &ValuePublisher<ProgressMessage>, weights: Option<&WeightsPublisher>) {
    if let Err(err) = progress.update_connections() {
        tracing::warn!("progress channel: {err:#}");
    }
    if let Some(Err(err)) = weights.map(WeightsPublisher::update_connections) {
        tracing::warn!("weights channel: {err:#}");
    }
}

fn learner_metrics(learner: &Learner, coverage: &CoverageTracker) -> Vec<(String, f64)> {
    let mut values: Vec<(String, f64)> = learner
        .metrics()
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect();
    values.extend(coverage.metrics());
    values
}

fn write_final_status(ctx: &RunContext, learner: &Learner, reason: &str) -> anyhow::Result<()> {
    let p = learner.progress();
    let s = learner.ingest_stats();
    let per_actor: serde_json::Map<String, serde_json::Value> = s
        .per_actor_steps
        .iter()
        .map(|(k, v)| (k.to_string(), serde_json::json!(v)))
        .collect();
    ctx.write_status(
        "learner",
        &serde_json::json!({
            "role": "learner", "env_steps": p.env_steps_ingested, "chunks": s.chunks,
            "episodes": s.episodes_completed, "lost_chunks": s.lost_chunks,
            "duplicate_chunks": s.duplicate_chunks, "rejected_chunks": s.rejected_chunks,
            "per_actor_steps": per_actor, "updates_low": p.updates_low, "updates_high": p.updates_high,
            "policy_version": p.policy_version.0, "stop_reason": reason,
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_published_versions_file_is_read_back_and_a_damaged_one_is_refused() {
        let text = serde_json::json!({ "policy_version": 12, "phi_version": 3 }).to_string();
        assert_eq!(
            published_versions(&text),
            Some((PolicyVersion(12), PhiVersion(3)))
        );
        assert_eq!(
            published_versions(&text[..text.len() - 2]),
            None,
            "truncated"
        );
        assert_eq!(
            published_versions(r#"{"policy_version": 12}"#),
            None,
            "φ version missing"
        );
        assert_eq!(
            published_versions(r#"{"policy_version": -1, "phi_version": 3}"#),
            None
        );
    }
}
