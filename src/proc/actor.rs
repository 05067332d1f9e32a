//! `asi actor`: one rollout process. Steps its environment chunk by chunk, publishes each
//! chunk, loads new weights when they arrive, and pauses (sleeping on the progress channel)
//! while the learner's replay-ratio budget is used up (SPEC §6.8).

use std::time::Duration;

use actor::Actor;
use anyhow::Context;
use protocol::{ActorId, ProcessRole, ProgressMessage};

use super::common::{newest_weights, node, MetricsOut, StopWatch};
use crate::channels::{Channels, WeightsSubscriber};
use crate::run::RunContext;

/// How long a throttled actor sleeps before re-checking its stop conditions.
const THROTTLE_WAIT: Duration = Duration::from_millis(100);

pub struct ActorArgs {
    pub actor_id: u32,
    /// How many times the launcher has (re)started this actor; keeps episode ids unique.
    pub incarnation: u32,
}

pub fn run(ctx: &RunContext, args: &ActorArgs) -> anyhow::Result<()> {
    let config = &ctx.config;
    let mut actor = Actor::new(config, ActorId(args.actor_id), config.run.seed).context("building the actor")?;
    actor.start_at_episode(first_episode(args.incarnation))?;
    let node = node(ctx, &format!("actor-{}", args.actor_id))?;
    let channels = Channels::new(config, &ctx.run_id, &actor.layout());
    let trajectories = channels.trajectory_publisher(&node)?;
    let weights = channels.weights_subscriber(&node)?;
    let progress = channels.progress_subscriber(&node)?;
    let mut metrics = MetricsOut::new(channels.metrics_publisher(&node)?, ProcessRole::Actor, args.actor_id, config);
    let stop = StopWatch::new();
    let mut latest = ProgressMessage::default();
    let mut published_steps = 0u64;
    let mut published_chunks = 0u64;
    let reason = loop {
        if let Some(reason) = stop.should_stop(&node) {
            break reason;
        }
        load_new_weights(&mut actor, &weights);
        if let Some(p) = progress.drain()?.last() {
            latest = *p;
        }
        // Before the learner's first progress message the budget is 0: nobody would store our
        // data yet, so we wait as if throttled.
        if !latest.allows_more() {
            // An interrupted wait (termination signal) is caught by the stop check above.
            let _ = progress.listener().timed_wait(|_| {}, THROTTLE_WAIT);
            continue;
        }
        let chunk = actor.next_chunk()?;
        trajectories.send(chunk.header, &chunk.records)?;
        published_steps += u64::from(chunk.header.n_steps);
        published_chunks += 1;
        if metrics.due() {
            metrics.publish(published_steps, &actor_metrics(&actor, published_steps));
        }
    };
    tracing::info!(actor = args.actor_id, reason, published_steps, "actor stopping");
    let stats = actor.stats();
    ctx.write_status(
        &format!("actor-{}-{}", args.actor_id, args.incarnation),
        &serde_json::json!({
            "role": "actor", "actor_id": args.actor_id, "incarnation": args.incarnation,
            "published_steps": published_steps, "published_chunks": published_chunks,
            "episodes": stats.episodes, "policy_version": stats.policy_version.0,
            "weights_rejected": stats.n_weights_rejected, "stop_reason": reason,
        }),
    )
}

/// Episodes per incarnation range: a restarted actor starts at `incarnation × 2^28`, so its
/// episode ids (and env seeds) never repeat those of its earlier incarnations.
const EPISODE_RANGE_BITS: u32 = 28;

pub fn first_episode(incarnation: u32) -> u64 {
    u64::from(incarnation) << EPISODE_RANGE_BITS
}

/// Loads the newest weights message, if any; a rejected one is logged and counted by the actor.
fn load_new_weights(actor: &mut Actor, weights: &WeightsSubscriber) {
    if let Some((header, bytes)) = newest_weights(weights) {
        if let Err(err) = actor.load_weights(&header, &bytes) {
            tracing::error!("refused weights: {err:#}");
        }
    }
}

fn actor_metrics(actor: &Actor, published_steps: u64) -> Vec<(String, f64)> {
    let s = actor.stats();
    vec![
        ("actor/env_steps".to_owned(), published_steps as f64),
        ("actor/episodes".to_owned(), s.episodes as f64),
        ("actor/policy_version".to_owned(), s.policy_version.0 as f64),
        ("actor/last_episode_return".to_owned(), f64::from(s.last_episode_return)),
        ("actor/physics_failures".to_owned(), s.n_physics_failures as f64),
    ]
}
