//! φ weights: which messages are accepted, re-mapping the store and rebuilding the graph.

mod common;

use common::*;
use graph_service::{CellKey, GraphServiceError};
use nets::prefix;
use protocol::{PhiVersion, ProtocolError};

/// An L-shaped walk 0,0 → 3,0 → 3,2 and a short second episode.
fn fill(service: &mut graph_service::GraphService) {
    ingest_episode(
        service,
        0,
        0,
        &[at(0, 0), at(1, 0), at(2, 0), at(3, 0), at(3, 1), at(3, 2)],
    );
    ingest_episode(service, 1, 0, &[at(-1, 0), at(0, 0)]);
}

#[test]
fn the_first_weights_build_the_graph_from_the_store() {
    let config = config();
    let mut service = service(&config);
    fill(&mut service);
    assert!(service.graph().is_none());
    load_identity(&mut service, &config, 1);
    let stats = service.stats();
    assert_eq!((stats.graph_version, stats.phi_version), (1, PhiVersion(1)));
    assert_eq!((stats.n_nodes, stats.n_edges), (7, 6));
    let graph = service.graph().unwrap();
    assert_eq!(graph.keys()[0], CellKey([0, 0]), "first-seen order");
    assert_eq!(graph.keys()[6], CellKey([-1, 0]));
}

#[test]
fn a_higher_phi_version_re_maps_every_state_and_recounts() {
    let config = config();
    let mut service = service(&config);
    fill(&mut service);
    load_identity(&mut service, &config, 1);
    assert_eq!(service.visits([0.5, 0.5]), Some(2));
    let (header, bytes) = weights(&actor_side_params(&config, 2.0), 2);
    service.load_weights(&header, &bytes).unwrap();
    let graph = service.graph().unwrap();
    // φ doubles every coordinate: (3.5, 2.5) → (7, 5).
    assert!(graph.node_of_key(CellKey([7, 5])).is_some());
    assert!(graph.node_of_key(CellKey([3, 2])).is_none());
    assert_eq!(
        service.visits([1.0, 1.0]),
        Some(2),
        "(0.5, 0.5) maps to (1, 1)"
    );
    assert_eq!(service.visits([0.5, 0.5]), Some(0));
    assert_eq!(service.stats().graph_version, 2);
}

#[test]
fn weights_that_are_not_newer_are_ignored() {
    let config = config();
    let mut service = service(&config);
    fill(&mut service);
    load_identity(&mut service, &config, 3);
    let (header, bytes) = weights(&actor_side_params(&config, 2.0), 3);
    service.load_weights(&header, &bytes).unwrap();
    let (header, bytes) = weights(&actor_side_params(&config, 2.0), 2);
    service.load_weights(&header, &bytes).unwrap();
    assert_eq!(service.stats().graph_version, 1);
    assert_eq!(service.stats().phi_version, PhiVersion(3));
    assert!(service
        .graph()
        .unwrap()
        .node_of_key(CellKey([3, 2]))
        .is_some());
}

#[test]
fn an_encoder_only_payload_is_accepted() {
    let config = config();
    let mut service = service(&config);
    fill(&mut service);
    let params = nets::subset(&actor_side_params(&config, 1.0), &[prefix::ENCODER]).unwrap();
    let (header, bytes) = weights(&params, 1);
    service.load_weights(&header, &bytes).unwrap();
    assert_eq!(service.stats().n_nodes, 7);
}

#[test]
fn bad_weights_are_refused_and_change_nothing() {
    let config = config();
    let mut service = service(&config);
    fill(&mut service);
    let (mut header, bytes) = weights(&actor_side_params(&config, 1.0), 1);
    header.layout_hash ^= 1;
    assert!(matches!(
        service.load_weights(&header, &bytes),
        Err(GraphServiceError::LayoutHash { .. })
    ));
    let (mut header, bytes) = weights(&actor_side_params(&config, 1.0), 1);
    header.byte_len += 1;
    let err = service.load_weights(&header, &bytes).unwrap_err();
    assert!(
        matches!(
            err,
            GraphServiceError::Protocol(ProtocolError::LengthMismatch { .. })
        ),
        "{err}"
    );
    let (mut header, bytes) = weights(&actor_side_params(&config, 1.0), 1);
    header.protocol_version += 1;
    assert!(service.load_weights(&header, &bytes).is_err());
    let (header, mut bytes) = weights(&actor_side_params(&config, 1.0), 1);
    bytes[0] ^= 0xff; // corrupt the safetensors header length
    assert!(service.load_weights(&header, &bytes).is_err());
    let (header, bytes) = weights(&actor_side_params(&config, f32::INFINITY), 1);
    let err = service.load_weights(&header, &bytes).unwrap_err();
    assert!(
        matches!(err, GraphServiceError::NonFiniteLatent { .. }),
        "{err}"
    );
    let stats = service.stats();
    assert_eq!(
        (stats.graph_version, stats.phi_version, stats.n_nodes),
        (0, PhiVersion(0), 0)
    );
    assert_eq!(
        service.visits([0.5, 0.5]),
        Some(2),
        "counts still from the chunks' φ labels"
    );
}

#[test]
fn chunks_labelled_with_an_older_phi_are_mapped_with_the_current_one() {
    let config = config();
    let mut service = service(&config);
    let (header, bytes) = weights(&actor_side_params(&config, 2.0), 4);
    service.load_weights(&header, &bytes).unwrap();
    let old = Chunk {
        phi_version: 3,
        ..Chunk::new(0, 0)
    };
    let (h, p) = old.encode(&[at(1, 1), at(1, 2)]);
    service.ingest(&h, &p).unwrap();
    assert_eq!(
        service.visits([3.0, 3.0]),
        Some(1),
        "(1.5, 1.5) under φ = 2·xy"
    );
    let current = Chunk {
        phi_version: 4,
        ..Chunk::new(0, 1)
    };
    let (h, p) = current.encode(&[at(9, 9), at(9, 9)]);
    service.ingest(&h, &p).unwrap();
    assert_eq!(
        service.visits(at(9, 9)),
        Some(2),
        "labels of the current φ are used as they are"
    );
}
