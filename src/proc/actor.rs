//! `asi actor`: one rollout process. Steps its environment chunk by chunk, publishes each
//! chunk, loads new weights when they arrive, and pauses (sleeping on the progress channel)
//! while the learner's replay-ratio budget is used up (SPEC §6.8). HESS exploration requests and
//! reaching reports go to the graph-service over the run's `graph` request–response service.
//! Running totals of what it published are kept in the run's status folder ([`record_published`]).

use std::time::Duration;

use actor::{Actor, ActorStats, ServiceOracle};
use anyhow::Context;
use protocol::{ActorId, ProcessRole, ProgressMessage};

use super::common::{newest_weights, node, IpcGraph, MetricsOut, StopWatch};
use crate::channels::{Channels, WeightsSubscriber};
use crate::run::RunContext;

/// How long a throttled actor sleeps before re-checking its stop conditions.
const THROTTLE_WAIT: Duration = Duration::from_millis(100);

pub struct ActorArgs {
    pub actor_id: u32,
    /// Earlier starts of this actor in the run folder (all launches); keeps episode ids unique.
    pub incarnation: u32,
    /// Training episodes the run had completed when this actor was started.
    pub run_episodes: u64,
}

pub fn run(ctx: &RunContext, args: &ActorArgs) -> anyhow::Result<()> {
    let config = &ctx.config;
    // Signals are caught from here on: a SIGTERM while the env and networks are built stops
    // the actor at its first check, with its status written.
    let node = node(ctx, &format!("actor-{}", args.actor_id))?;
    let mut stop = StopWatch::new(&node);
    let mut actor = Actor::new(config, ActorId(args.actor_id), config.run.seed)
        .context("building the actor")?;
    let warm_up = actor::warm_up_share(config, args.run_episodes);
    actor.start_at_episode(first_episode(args.incarnation), warm_up)?;
    let channels = Channels::new(config, &ctx.run_id, &actor.layout());
    let trajectories = channels.trajectory_publisher(&node)?;
    let weights = channels.weights_subscriber(&node)?;
    let progress = channels.progress_subscriber(&node)?;
    let timeout = Duration::from_millis(config.transport.graph_request_timeout_ms);
    let mut oracle = ServiceOracle::new(IpcGraph::new(channels.graph_client(&node)?, timeout));
    let mut metrics = MetricsOut::new(
        channels.metrics_publisher(&node)?,
        ProcessRole::Actor,
        args.actor_id,
        config,
    );
    let mut throttle = Throttle::default();
    let mut published_steps = 0u64;
    let mut published_chunks = 0u64;
    let mut reach_means = ReachMeans::default();
    let published_file = ctx.run_dir.join(crate::run::STATUS_DIR).join(format!(
        "actor-{}-{}.published",
        args.actor_id, args.incarnation
    ));
    let reason = loop {
        if let Some(reason) = stop.should_stop(&node) {
            break reason;
        }
        load_new_weights(&mut actor, &weights);
        if let Some(p) = progress.drain()?.last() {
            throttle.observe(*p);
        }
        // Before the learner's first progress message the budget is 0: nobody would store our
        // data yet, so we wait as if throttled.
        if !throttle.allows_more() {
            // An interrupted wait (termination signal) is caught by the stop check above.
            let _ = progress.listener().timed_wait(|_| {}, THROTTLE_WAIT);
            continue;
        }
        let chunk = actor.next_chunk(&mut oracle)?;
        published_steps += u64::from(chunk.header.n_steps);
        published_chunks += 1;
        record_published(&published_file, published_steps, published_chunks)?;
        trajectories.send(chunk.header, &chunk.records)?;
        throttle.published(u64::from(chunk.header.n_steps));
        if metrics.due() {
            let mut values = actor_metrics(&actor.stats(), published_steps);
            values.extend(reach_means.since_last(&actor.stats()));
            values.push((
                "actor/graph_unreachable".to_owned(),
                oracle.transport().n_unreachable as f64,
            ));
            values.push(("actor/incarnation".to_owned(), f64::from(args.incarnation)));
            metrics.publish(published_steps, &values);
        }
    };
    tracing::info!(
        actor = args.actor_id,
        reason,
        published_steps,
        "actor stopping"
    );
    let stats = actor.stats();
    ctx.write_status(
        &format!("actor-{}-{}", args.actor_id, args.incarnation),
        &serde_json::json!({
            "role": "actor", "actor_id": args.actor_id, "incarnation": args.incarnation,
            "published_steps": published_steps, "published_chunks": published_chunks,
            "episodes": stats.episodes, "policy_version": stats.policy_version.0,
            "weights_rejected": stats.n_weights_rejected, "explore_decisions": stats.n_explore_decisions,
            "random_decisions": stats.n_random_decisions,
            "explore_fallbacks": stats.n_explore_fallbacks, "reach_reports": stats.n_reach_reports,
            "fr_episodes": stats.frontier.n_episodes, "fr_no_route": stats.frontier.n_no_route,
            "stop_reason": reason,
        }),
    )
}

/// Writes this incarnation's running totals to `status/actor-<id>-<incarnation>.published`
/// just before each chunk is sent, so that they survive a SIGKILL (the final status file does
/// not): an actor killed between the write and the send counts one chunk that never left.
/// Fault-injection tests compare these totals with what the learner ingested.
fn record_published(path: &std::path::Path, steps: u64, chunks: u64) -> anyhow::Result<()> {
    let totals = serde_json::json!({ "published_steps": steps, "published_chunks": chunks });
    crate::run::write_atomically(path, &totals.to_string())
}

/// The learner's replay-ratio budget as this actor sees it (SPEC §6.8): the latest progress
/// message, plus the steps this actor published since the learner's ingested count last moved.
/// Those are in flight (or waiting in the learner's buffer while it trains) and not yet in
/// `env_steps_ingested`; without counting them an actor keeps publishing against a stale message
/// for as long as the learner is busy, and the run overshoots its budget by far.
#[derive(Default)]
struct Throttle {
    latest: ProgressMessage,
    in_flight_steps: u64,
}

impl Throttle {
    fn observe(&mut self, progress: ProgressMessage) {
        if progress.env_steps_ingested != self.latest.env_steps_ingested {
            // The learner moved on; what it has not taken yet is at most one message's worth,
            // so a lost chunk never blocks this actor for good.
            self.in_flight_steps = 0;
        }
        self.latest = progress;
    }

    fn published(&mut self, steps: u64) {
        self.in_flight_steps += steps;
    }

    fn allows_more(&self) -> bool {
        self.latest
            .env_steps_ingested
            .saturating_add(self.in_flight_steps)
            < self.latest.env_step_budget
    }
}

/// Episodes per incarnation range: an actor starts at `incarnation × 2^28`, so its episode ids
/// (and env seeds and generator, see `Actor::start_at_episode`) never repeat those of its
/// earlier incarnations, in this launch or an earlier one of the run (the launcher numbers
/// starts over all launches, `launcher::starts`).
const EPISODE_RANGE_BITS: u32 = 28;

/// Starts of one actor a run folder can hold: the episode counter has
/// [`actor::seeds::EPISODE_COUNTER_BITS`] bits, the low [`EPISODE_RANGE_BITS`] of them count
/// one incarnation's episodes (2^28: far beyond a week of episodes of one actor).
pub const MAX_INCARNATIONS: u32 = 1 << (actor::seeds::EPISODE_COUNTER_BITS - EPISODE_RANGE_BITS);

/// The index of the first episode of the actor's `incarnation`-th start.
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

/// The actor's counters as metrics (names documented in `docs/METRICS.md`); serial mode
/// writes the same names.
pub fn actor_metrics(s: &ActorStats, published_steps: u64) -> Vec<(String, f64)> {
    let mut values = vec![
        ("actor/env_steps".to_owned(), published_steps as f64),
        ("actor/episodes".to_owned(), s.episodes as f64),
        ("actor/policy_version".to_owned(), s.policy_version.0 as f64),
        (
            "actor/last_episode_return".to_owned(),
            f64::from(s.last_episode_return),
        ),
        (
            "actor/physics_failures".to_owned(),
            s.n_physics_failures as f64,
        ),
        ("actor/decisions".to_owned(), s.n_decisions as f64),
        (
            "actor/explore_decisions".to_owned(),
            s.n_explore_decisions as f64,
        ),
        (
            "actor/explore_fallbacks".to_owned(),
            s.n_explore_fallbacks as f64,
        ),
        (
            "actor/random_decisions".to_owned(),
            s.n_random_decisions as f64,
        ),
        ("actor/reach_reports".to_owned(), s.n_reach_reports as f64),
        (
            "actor/reach_samples_sent".to_owned(),
            s.n_reach_samples_sent as f64,
        ),
        (
            "actor/reach_samples_dropped".to_owned(),
            s.n_reach_samples_dropped as f64,
        ),
        (
            "actor/count_prob".to_owned(),
            f64::from(s.schedule.count_prob),
        ),
        ("actor/fr_prob".to_owned(), f64::from(s.schedule.fr_prob)),
    ];
    let fr = &s.frontier;
    let frontier = [
        ("actor/fr/episodes", fr.n_episodes),
        ("actor/fr/no_route", fr.n_no_route),
        ("actor/fr/goals_forced", fr.n_goals_forced),
        ("actor/fr/waypoint_decisions", fr.n_waypoint_decisions),
        ("actor/fr/count_decisions", fr.n_count_decisions),
        ("actor/fr/count_fallbacks", fr.n_count_fallbacks),
        (
            "actor/fr/near_frontier_switches",
            fr.n_near_frontier_switches,
        ),
        ("actor/fr/stuck_switches", fr.n_stuck_switches),
        (
            "actor/fr/stuck_while_navigating",
            fr.n_stuck_while_navigating,
        ),
        ("actor/fr/ended_by_new_phi", fr.n_ended_by_new_phi),
        (
            "actor/fr/new_phi_while_navigating",
            fr.n_new_phi_while_navigating,
        ),
        ("actor/fr/navigating_at_end", fr.n_navigating_at_end),
        ("actor/fr/waypoints_cut", fr.n_waypoints_cut),
    ];
    values.extend(
        frontier
            .into_iter()
            .map(|(name, v)| (name.to_owned(), v as f64)),
    );
    let [x, y] = s
        .last_episode_xy
        .map_or([None, None], |[x, y]| [Some(x), Some(y)]);
    let optional = [
        ("actor/last_episode_x", x),
        ("actor/last_episode_y", y),
        ("actor/last_episode_reach_error", s.last_episode_reach_error),
        ("actor/last_episode_reach_ratio", s.last_episode_reach_ratio),
        (
            "actor/last_episode_explore_reach_error",
            s.last_episode_explore_reach_error,
        ),
    ];
    values.extend(
        optional
            .into_iter()
            .filter_map(|(name, v)| Some((name.to_owned(), f64::from(v?)))),
    );
    if let Some(end) = s.last_fr_end {
        let last = [
            ("actor/fr/last_episode", s.last_fr_episode as f64),
            ("actor/fr/last_outcome", end.outcome.code()),
            (
                "actor/fr/last_route_progress",
                f64::from(end.route_progress),
            ),
            ("actor/fr/last_off_route", f64::from(end.off_route)),
            (
                "actor/fr/last_frontier_distance",
                f64::from(end.frontier_distance),
            ),
            ("actor/fr/last_x", f64::from(end.xy[0])),
            ("actor/fr/last_y", f64::from(end.xy[1])),
            (
                "actor/fr/last_waypoint_decisions",
                f64::from(end.waypoint_decisions),
            ),
        ];
        // A NaN (no route point, an observation without y) is left out, not written.
        values.extend(
            last.into_iter()
                .filter(|(_, v)| v.is_finite())
                .map(|(name, v)| (name.to_owned(), v)),
        );
    }
    values
}

/// Mean reaching errors over the segments finished since the previous call (the smooth curve of
/// issue #5); a mean over no segment is left out rather than written as NaN.
#[derive(Default)]
pub struct ReachMeans {
    all: (f64, u64),
    explore: (f64, u64),
    ratio: (f64, u64),
}

impl ReachMeans {
    pub fn since_last(&mut self, s: &ActorStats) -> Vec<(String, f64)> {
        let mut values = Vec::new();
        let pairs = [
            (
                "actor/reach_error",
                &mut self.all,
                (s.reach_error_sum, s.n_reach_segments),
            ),
            (
                "actor/explore_reach_error",
                &mut self.explore,
                (s.explore_reach_error_sum, s.n_explore_reach_segments),
            ),
            (
                "actor/reach_ratio",
                &mut self.ratio,
                (s.reach_ratio_sum, s.n_reach_ratio_segments),
            ),
        ];
        for (name, last, now) in pairs {
            if now.1 > last.1 {
                values.push((name.to_owned(), (now.0 - last.0) / (now.1 - last.1) as f64));
            }
            *last = now;
        }
        values
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn progress(ingested: u64, budget: u64) -> ProgressMessage {
        ProgressMessage {
            env_steps_ingested: ingested,
            env_step_budget: budget,
            ..ProgressMessage::default()
        }
    }

    #[test]
    fn the_throttle_counts_own_steps_until_the_learner_ingests_again() {
        let mut throttle = Throttle::default();
        assert!(!throttle.allows_more(), "no progress message yet: budget 0");
        throttle.observe(progress(1000, 1100));
        assert!(throttle.allows_more());
        throttle.published(50);
        assert!(throttle.allows_more(), "1000 + 50 < 1100");
        throttle.published(50);
        assert!(
            !throttle.allows_more(),
            "1000 + 100 in flight reaches the budget"
        );
        throttle.observe(progress(1000, 1100));
        assert!(
            !throttle.allows_more(),
            "a repeated message does not forget what is in flight"
        );
        throttle.observe(progress(1100, 1300));
        assert!(
            throttle.allows_more(),
            "the learner took our steps: 1100 < 1300"
        );
    }
}
