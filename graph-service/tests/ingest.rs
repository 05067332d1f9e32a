//! Trajectory chunks: what is stored, what is refused, what is counted.

mod common;

use common::*;
use graph_service::{GraphService, GraphServiceError};
use protocol::Config;
use protocol::{ActorId, EpisodeId, ProtocolError};

#[test]
fn stats_count_env_steps_per_actor_and_stored_states() {
    let config = config();
    let mut service = service(&config);
    ingest_episode(&mut service, 3, 0, &[at(0, 0), at(1, 0), at(2, 0)]);
    ingest_episode(&mut service, 5, 0, &[at(0, 0), at(0, 1)]);
    ingest_episode(
        &mut service,
        3,
        1,
        &[at(0, 0), at(0, 1), at(0, 2), at(0, 3)],
    );
    let stats = service.stats();
    assert_eq!(
        stats.per_actor_steps.into_iter().collect::<Vec<_>>(),
        vec![(3, 5), (5, 1)]
    );
    assert_eq!(stats.chunks, 3);
    assert_eq!(stats.stored_episodes, 3);
    assert_eq!(
        stats.stored_steps,
        3 + 2 + 4,
        "a T-step episode stores T + 1 states"
    );
    assert_eq!(stats.rejected_chunks, 0);
}

#[test]
fn chunks_of_one_episode_join_into_one_trajectory() {
    let config = config();
    let mut service = service(&config);
    let first = Chunk {
        end: false,
        ..Chunk::new(1, 9)
    };
    let (h, p) = first.encode(&[at(0, 0), at(1, 0), at(2, 0)]);
    service.ingest(&h, &p).unwrap();
    let second = Chunk {
        chunk_index: 1,
        first_env_step: 2,
        ..Chunk::new(1, 9)
    };
    let (h, p) = second.encode(&[at(2, 0), at(3, 0)]);
    service.ingest(&h, &p).unwrap();
    let stats = service.stats();
    assert_eq!(
        (stats.stored_episodes, stats.stored_steps, stats.chunk_gaps),
        (1, 4, 0)
    );
    assert_eq!(service.stored_episodes(), vec![(ActorId(1), EpisodeId(9))]);
}

#[test]
fn a_wrong_length_chunk_is_refused_and_changes_nothing() {
    let config = config();
    let mut service = service(&config);
    ingest_episode(&mut service, 0, 0, &[at(0, 0), at(1, 0)]);
    let before = service.stats();
    let (header, payload) = Chunk::new(0, 1).encode(&[at(0, 0), at(1, 0), at(2, 0)]);
    let err = service
        .ingest(&header, &payload[..payload.len() - 1])
        .unwrap_err();
    assert!(
        matches!(
            err,
            GraphServiceError::Protocol(ProtocolError::LengthMismatch { .. })
        ),
        "{err}"
    );
    let mut longer = payload.clone();
    longer.push(0.0);
    assert!(service.ingest(&header, &longer).is_err());
    let after = service.stats();
    assert_eq!(after.rejected_chunks, 2);
    assert_eq!(
        (
            after.stored_steps,
            after.stored_episodes,
            after.chunks,
            after.per_actor_steps.clone()
        ),
        (
            before.stored_steps,
            before.stored_episodes,
            before.chunks,
            before.per_actor_steps.clone()
        )
    );
    assert_eq!(service.visits(at(2, 0)), Some(0));
}

#[test]
fn a_wrong_version_chunk_is_refused_naming_both_versions() {
    let config = config();
    let mut service = service(&config);
    let (mut header, payload) = Chunk::new(0, 0).encode(&[at(0, 0), at(1, 0)]);
    header.protocol_version = protocol::PROTOCOL_VERSION + 1;
    let err = service.ingest(&header, &payload).unwrap_err();
    let message = err.to_string();
    assert!(
        message.contains(&protocol::PROTOCOL_VERSION.to_string()) && message.contains("mismatch"),
        "{message}"
    );
    assert_eq!(service.stats().stored_steps, 0);
    assert_eq!(service.stats().rejected_chunks, 1);
}

#[test]
fn chunks_of_another_task_or_with_nan_are_refused() {
    let config = config();
    let mut service = service(&config);
    let (mut header, payload) = Chunk::new(0, 0).encode(&[at(0, 0), at(1, 0)]);
    header.obs_dim += 1;
    header.goal_dim -= 1; // same record length (obs and goal both appear twice), another layout
    let err = service.ingest(&header, &payload).unwrap_err();
    assert!(
        matches!(
            err,
            GraphServiceError::ChunkDims {
                field: "obs_dim",
                ..
            }
        ),
        "{err}"
    );
    let (header, mut payload) = Chunk::new(0, 0).encode(&[at(0, 0), at(1, 0)]);
    payload[0] = f32::NAN;
    let err = service.ingest(&header, &payload).unwrap_err();
    assert!(
        matches!(
            err,
            GraphServiceError::Protocol(ProtocolError::NonFinite { .. })
        ),
        "{err}"
    );
    let stats = service.stats();
    assert_eq!(
        (stats.rejected_chunks, stats.stored_steps, stats.chunks),
        (2, 0, 0)
    );
}

#[test]
fn the_store_evicts_oldest_episodes_and_counts_follow() {
    let mut config = config();
    config.graph.max_stored_steps = 6;
    let mut service = service(&config);
    ingest_episode(&mut service, 0, 0, &[at(5, 5), at(5, 5), at(5, 6)]);
    ingest_episode(&mut service, 0, 1, &[at(0, 0), at(1, 0), at(2, 0)]);
    assert_eq!(service.visits(at(5, 5)), Some(2));
    ingest_episode(&mut service, 1, 0, &[at(0, 0), at(0, 1)]);
    let stats = service.stats();
    assert_eq!(
        (
            stats.stored_steps,
            stats.stored_episodes,
            stats.evicted_steps
        ),
        (5, 2, 3)
    );
    assert_eq!(
        service.visits(at(5, 5)),
        Some(0),
        "evicted states leave the counts"
    );
    assert_eq!(service.visits(at(0, 0)), Some(2));
    assert_eq!(
        service.stored_episodes(),
        vec![(ActorId(0), EpisodeId(1)), (ActorId(1), EpisodeId(0))]
    );
}

/// HESS visit counts (digest §2.3 D) of a service whose config stores `episodes` one-state-
/// per-cell episodes: the i-th visits cells (i, 0) and (i, 1) (unit φ = xy; HESS cells of 3.0
/// hold x in [0, 3), [3, 6), …).
fn hess_visits_after(config: &Config, episodes: u64) -> (GraphService, Vec<u64>) {
    let mut service = service(config);
    for e in 0..episodes {
        let x = 3 * e as i32;
        ingest_episode(&mut service, 0, e, &[at(x, 0), at(x, 1)]);
    }
    let visits = (0..episodes)
        .map(|e| service.hess().visits_at(at(3 * e as i32, 0)))
        .collect();
    (service, visits)
}

#[test]
fn hess_visits_count_only_after_explore_start_episodes_are_stored_unless_from_start() {
    let mut config = config();
    config.exploration.explore_start_episode = 2;
    // Episodes 0, 1, 2 arrive with 0, 1, 2 closed episodes stored: not counted (the code's
    // `epoch > start_explore`); 3 and 4 are, both of their states in one 3.0-cell.
    let (service, visits) = hess_visits_after(&config, 5);
    assert_eq!(visits, vec![0, 0, 0, 2, 2]);
    assert_eq!(service.hess().episodes_stored(), 5);
    assert_eq!(service.stats().hess_visited_cells, 2);
    // The graph's own visit counts n(v) are not gated: every stored state counts.
    assert_eq!(service.stats().stored_steps, 10);
    config.exploration.visits_from_start = true;
    let (_, visits) = hess_visits_after(&config, 5);
    assert_eq!(visits, vec![2; 5]);
}
