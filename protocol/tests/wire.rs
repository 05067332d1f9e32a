//! Wire contract: versions, headers, step records, postcard messages, names, layout hash.

use iceoryx2::prelude::ZeroCopySend;
use proptest::prelude::*;
use protocol::graph::{
    FrontierRoute, GraphRequestHeader, GraphRequestKind, GraphResponseHeader, GraphStatus,
    NoRouteReason, RouteAnswer, RouteQuery,
};
use protocol::payload::METRIC_NAME_CAPACITY;
use protocol::*;

#[test]
fn version_mismatch_names_both_versions() {
    let err = check_version(PROTOCOL_VERSION + 6).expect_err("other version");
    assert_eq!(
        err,
        ProtocolError::VersionMismatch {
            expected: PROTOCOL_VERSION,
            found: PROTOCOL_VERSION + 6
        }
    );
    let text = err.to_string();
    assert!(
        text.contains(&format!("version {PROTOCOL_VERSION}")),
        "{text}"
    );
    assert!(
        text.contains(&format!("version {}", PROTOCOL_VERSION + 6)),
        "{text}"
    );
    check_version(PROTOCOL_VERSION).expect("same version");
}

#[test]
fn every_header_refuses_another_protocol_version() {
    let layout = StepLayout::new(4, 2, 2, 2).expect("dims");
    let mut trajectory = TrajectoryHeader::for_layout(&layout).expect("header");
    trajectory.n_steps = 1;
    trajectory.protocol_version += 1;
    assert!(matches!(
        trajectory.check(layout.record_len()),
        Err(ProtocolError::VersionMismatch { .. })
    ));

    let mut weights = WeightsHeader::new(PolicyVersion(1), PhiVersion(1), 7, 10);
    weights.protocol_version = 0;
    assert!(matches!(
        weights.check(7, 10),
        Err(ProtocolError::VersionMismatch { .. })
    ));

    let mut control = ControlMessage::new(1, ControlCommand::Stop);
    control.protocol_version = 99;
    assert!(matches!(
        control.command(),
        Err(ProtocolError::VersionMismatch { found: 99, .. })
    ));

    let mut request = GraphRequestHeader::new(3, GraphRequestKind::Stats, PhiVersion(2));
    request.protocol_version = 0;
    assert!(request.kind().is_err());
}

#[test]
fn payload_types_have_explicit_names_and_no_implicit_padding() {
    // SAFETY (test): type_name is unsafe only because it promises identical layouts across
    // languages; reading it is harmless.
    let names = unsafe {
        [
            TrajectoryHeader::type_name(),
            WeightsHeader::type_name(),
            MetricsSample::type_name(),
            ControlMessage::type_name(),
            GraphRequestHeader::type_name(),
            GraphResponseHeader::type_name(),
            ActorId::type_name(),
            RunSchedule::type_name(),
        ]
    };
    assert_eq!(
        names,
        [
            "asi::TrajectoryHeader",
            "asi::WeightsHeader",
            "asi::MetricsSample",
            "asi::ControlMessage",
            "asi::GraphRequestHeader",
            "asi::GraphResponseHeader",
            "asi::ActorId",
            "asi::RunSchedule",
        ]
    );
    assert_eq!(std::mem::size_of::<TrajectoryHeader>(), 4 * 8 + 10 * 4);
    assert_eq!(std::mem::size_of::<RunSchedule>(), 8 + 2 * 4);
    assert_eq!(
        std::mem::size_of::<WeightsHeader>(),
        4 * 8 + 2 * 4 + (8 + 2 * 4)
    );
    assert_eq!(std::mem::size_of::<GraphRequestHeader>(), 2 * 8 + 2 * 4);
    assert_eq!(std::mem::size_of::<GraphResponseHeader>(), 3 * 8 + 4 * 4);
    assert_eq!(
        std::mem::size_of::<MetricsSample>(),
        3 * 8 + 4 * 4 + METRIC_NAME_CAPACITY
    );
    assert_eq!(std::mem::size_of::<ControlMessage>(), 16);
    assert_eq!(std::mem::size_of::<PolicyVersion>(), 8);
}

#[test]
fn trajectory_header_checks_payload_length_and_flags() {
    let layout = StepLayout::new(29, 8, 2, 2).expect("dims");
    let mut header = TrajectoryHeader::for_layout(&layout).expect("header");
    header.n_steps = 3;
    header
        .flags
        .insert(TrajectoryFlags::EPISODE_START | TrajectoryFlags::FAR_GOAL);
    assert_eq!(header.check(3 * layout.record_len()), Ok(layout));
    assert!(matches!(
        header.check(3 * layout.record_len() - 1),
        Err(ProtocolError::LengthMismatch { .. })
    ));
    header.flags.insert(1 << 20);
    assert!(matches!(
        header.check(3 * layout.record_len()),
        Err(ProtocolError::UnknownFlags { .. })
    ));
    header.flags = TrajectoryFlags::default();
    header.n_steps = 0;
    assert!(header.check(0).is_err());
    header.n_steps = 1;
    header.obs_dim = 0;
    assert!(matches!(
        header.check(0),
        Err(ProtocolError::InvalidDims(_))
    ));
}

#[test]
fn weights_header_checks_layout_hash_and_length() {
    let header = WeightsHeader::new(PolicyVersion(4), PhiVersion(2), 0xabc, 100);
    header.check(0xabc, 100).expect("matching");
    assert_eq!(
        header.check(0xabd, 100),
        Err(ProtocolError::LayoutHashMismatch {
            expected: 0xabd,
            found: 0xabc
        })
    );
    assert!(matches!(
        header.check(0xabc, 99),
        Err(ProtocolError::LengthMismatch { .. })
    ));
}

#[test]
fn metrics_names_round_trip_and_bad_names_are_refused() {
    let sample = MetricsSample::new(ProcessRole::Learner, 0, "losses/high_critic", 1.5, 1000, 42)
        .expect("valid");
    assert_eq!(sample.name(), Ok("losses/high_critic"));
    assert_eq!(sample.role(), Ok(ProcessRole::Learner));
    sample.check_version().expect("current version");
    let long = "x".repeat(METRIC_NAME_CAPACITY + 1);
    for bad in ["", "with space", long.as_str(), "ü"] {
        assert!(
            MetricsSample::new(ProcessRole::Actor, 1, bad, 0.0, 0, 0).is_err(),
            "{bad:?} accepted"
        );
    }
    let mut corrupt = sample;
    corrupt.name_len = 200;
    assert!(corrupt.name().is_err());
}

#[test]
fn control_commands_decode_and_unknown_codes_are_refused() {
    assert_eq!(
        ControlMessage::new(5, ControlCommand::Checkpoint).command(),
        Ok(ControlCommand::Checkpoint)
    );
    let mut message = ControlMessage::new(6, ControlCommand::Stop);
    message.command = 77;
    assert_eq!(
        message.command(),
        Err(ProtocolError::UnknownCode {
            what: "control command",
            code: 77
        })
    );
}

#[test]
fn run_ids_are_validated_and_name_the_services() {
    let id = RunId::new("antmaze-u_seed-0").expect("valid");
    assert_eq!(
        id.service_name(Service::Trajectories),
        "asi/antmaze-u_seed-0/trajectories"
    );
    assert_eq!(
        id.service_name(Service::Control),
        "asi/antmaze-u_seed-0/control"
    );
    assert_eq!(id.node_name("actor-3"), "asi/antmaze-u_seed-0/actor-3");
    assert_eq!(RunId::new(""), Err(RunIdError::Empty));
    assert!(matches!(
        RunId::new("a/b"),
        Err(RunIdError::BadChar {
            found: '/',
            position: 1,
            ..
        })
    ));
    assert!(matches!(RunId::new("-x"), Err(RunIdError::BadStart(_))));
    assert!(matches!(
        RunId::new(&"a".repeat(65)),
        Err(RunIdError::TooLong { len: 65, max: 64 })
    ));
    for service in Service::ALL {
        let name = id.service_name(service);
        iceoryx2::prelude::ServiceName::new(&name).expect("a valid iceoryx2 service name");
    }
}

#[test]
fn layout_hash_is_order_independent_and_pinned() {
    let a: [(&str, &[usize]); 2] = [("w", &[2, 3]), ("b", &[3])];
    let b: [(&str, &[usize]); 2] = [("b", &[3]), ("w", &[2, 3])];
    assert_eq!(layout_hash(a), layout_hash(b));
    assert_ne!(
        layout_hash(a),
        layout_hash([("w", &[3, 2][..]), ("b", &[3][..])])
    );
    // Reference (Python): fnv1a64(b"w:2x3\n") and fnv1a64(b"a:1\nb:\n").
    assert_eq!(layout_hash([("w", &[2, 3][..])]), 0xafa5_a135_71b7_0b77);
    assert_eq!(
        layout_hash([("b", &[][..]), ("a", &[1][..])]),
        0x613b_ef20_4687_fad1
    );
}

#[test]
fn graph_messages_round_trip_through_postcard() {
    let request = GraphRequest::Routes {
        queries: vec![
            RouteQuery {
                start: [0.0, 1.0],
                end: [4.5, -2.0],
                fallback_origin: Some([0.0, 0.0]),
            },
            RouteQuery {
                start: [1.0, 1.0],
                end: [2.0, 2.0],
                fallback_origin: None,
            },
        ],
    };
    let bytes = encode(&request).expect("encodes");
    assert_eq!(decode::<GraphRequest>(&bytes), Ok(request.clone()));
    assert_eq!(request.kind(), GraphRequestKind::Routes);

    let response = GraphResponse::FrontierRoute(Ok(FrontierRoute {
        frontier: [10.0, 12.0],
        route: vec![[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]],
        distance: 2.0,
    }));
    assert_eq!(
        decode::<GraphResponse>(&encode(&response).expect("encodes")),
        Ok(response)
    );
    let routes = GraphResponse::Routes(vec![
        RouteAnswer::Direct(vec![[0.0, 0.0]]),
        RouteAnswer::NoRoute {
            direct: NoRouteReason::Unreachable,
            fallback: Some(NoRouteReason::NothingReachable),
        },
        RouteAnswer::NoRoute {
            direct: NoRouteReason::EndUnknown,
            fallback: None,
        },
    ]);
    assert_eq!(
        decode::<GraphResponse>(&encode(&routes).expect("encodes")),
        Ok(routes)
    );
}

const ALL_NO_ROUTE_REASONS: [NoRouteReason; 5] = [
    NoRouteReason::EmptyGraph,
    NoRouteReason::StartUnknown,
    NoRouteReason::EndUnknown,
    NoRouteReason::Unreachable,
    NoRouteReason::NothingReachable,
];

#[test]
fn every_no_route_reason_survives_the_wire_in_both_answers() {
    for reason in ALL_NO_ROUTE_REASONS {
        let frontier = GraphResponse::FrontierRoute(Err(reason));
        assert_eq!(
            decode::<GraphResponse>(&encode(&frontier).expect("encodes")),
            Ok(frontier)
        );
        let route = GraphResponse::Routes(vec![RouteAnswer::NoRoute {
            direct: reason,
            fallback: Some(reason),
        }]);
        assert_eq!(
            decode::<GraphResponse>(&encode(&route).expect("encodes")),
            Ok(route)
        );
    }
}

#[test]
fn no_route_reasons_have_distinct_messages() {
    let texts: std::collections::HashSet<String> =
        ALL_NO_ROUTE_REASONS.iter().map(|r| r.to_string()).collect();
    assert_eq!(texts.len(), ALL_NO_ROUTE_REASONS.len());
}

#[test]
fn an_unknown_no_route_reason_code_is_a_decode_error() {
    let mut bytes = encode(&NoRouteReason::NothingReachable).expect("encodes");
    assert_eq!(
        bytes,
        [4],
        "postcard writes the variant index as one varint byte"
    );
    bytes[0] = 5;
    assert!(decode::<NoRouteReason>(&bytes).is_err());
}

#[test]
fn malformed_postcard_bytes_are_errors() {
    let mut bytes = encode(&GraphRequest::Stats).expect("encodes");
    bytes.push(0);
    assert!(matches!(
        decode::<GraphRequest>(&bytes),
        Err(ProtocolError::Decode { .. })
    ));
    assert!(matches!(
        decode::<GraphRequest>(&[200, 1, 2]),
        Err(ProtocolError::Decode { .. })
    ));
    assert!(matches!(
        decode::<GraphRequest>(&[]),
        Err(ProtocolError::Decode { .. })
    ));
}

#[test]
fn graph_requests_with_non_finite_points_are_refused() {
    let request = GraphRequest::LeastVisited {
        candidates: vec![[0.0, 0.0], [1.0, f32::NAN]],
    };
    assert!(matches!(
        request.check_finite(),
        Err(ProtocolError::NonFinite {
            field: "candidates",
            index: 1,
            ..
        })
    ));
    GraphRequest::FrontierRoute { from: [1.0, 2.0] }
        .check_finite()
        .expect("finite");
}

#[test]
fn graph_headers_echo_the_request() {
    let request = GraphRequestHeader::new(9, GraphRequestKind::FrontierRoute, PhiVersion(3));
    assert_eq!(request.kind(), Ok(GraphRequestKind::FrontierRoute));
    let response =
        GraphResponseHeader::answering(&request, GraphStatus::NotReady, 0, PhiVersion(3));
    assert_eq!(response.request_id, 9);
    assert_eq!(response.status(), Ok(GraphStatus::NotReady));
}

const DECISIONS: [DecisionKind; 7] = [
    DecisionKind::None,
    DecisionKind::Policy,
    DecisionKind::Random,
    DecisionKind::Explore,
    DecisionKind::FrontierRoute,
    DecisionKind::FrontierCount,
    DecisionKind::Evaluation,
];

/// A layout with small random dims and a matching random record.
fn layout_and_record() -> impl Strategy<Value = (StepLayout, StepRecord)> {
    (1usize..12, 1usize..5, 1usize..3, 1usize..3).prop_flat_map(|(obs, act, goal, latent)| {
        let layout = StepLayout::new(obs, act, goal, latent).expect("dims >= 1");
        let v = |n: usize| proptest::collection::vec(-1e6f32..1e6, n);
        let vectors = (
            v(obs),
            v(obs),
            v(latent),
            v(latent),
            v(latent),
            v(latent),
            v(act),
            v(goal),
            v(goal),
        );
        let scalars = (
            -100f32..1.0,
            0usize..DECISIONS.len(),
            any::<bool>(),
            any::<bool>(),
            any::<bool>(),
        );
        (Just(layout), vectors, scalars).prop_map(
            |(layout, vecs, (reward, d, success, terminated, truncated))| {
                let (
                    obs,
                    next_obs,
                    phi,
                    next_phi,
                    subgoal,
                    high_action,
                    action,
                    goal,
                    achieved_goal,
                ) = vecs;
                let record = StepRecord {
                    obs,
                    next_obs,
                    phi,
                    next_phi,
                    subgoal,
                    high_action,
                    action,
                    goal,
                    achieved_goal,
                    reward,
                    decision: DECISIONS[d],
                    success,
                    terminated,
                    truncated,
                };
                (layout, record)
            },
        )
    })
}

proptest! {
    #[test]
    fn step_records_round_trip((layout, record) in layout_and_record()) {
        let chunk = layout.encode_chunk(&[record.clone(), record.clone()]).expect("encodes");
        prop_assert_eq!(chunk.len(), 2 * layout.record_len());
        let views = layout.view_chunk(&chunk, 2).expect("decodes");
        prop_assert_eq!(views[1].to_record(), record.clone());
        prop_assert_eq!(layout.decode(&chunk[..layout.record_len()]).expect("decodes"), record);
    }

    #[test]
    fn wrong_lengths_are_rejected((layout, record) in layout_and_record(), extra in 1usize..4) {
        let encoded = layout.encode_chunk(std::slice::from_ref(&record)).expect("encodes");
        let mut longer = encoded.clone();
        longer.extend(std::iter::repeat_n(0.0, extra));
        let is_len_err = |r: Result<StepRecord, ProtocolError>| matches!(r, Err(ProtocolError::LengthMismatch { .. }));
        prop_assert!(is_len_err(layout.decode(&longer)));
        prop_assert!(is_len_err(layout.decode(&encoded[..encoded.len() - 1])));
        prop_assert!(layout.view_chunk(&longer, 1).is_err());
        let mut bad = record;
        bad.action.push(0.0);
        let refused = matches!(layout.encode_chunk(&[bad]), Err(ProtocolError::LengthMismatch { .. }));
        prop_assert!(refused);
    }

    #[test]
    fn non_finite_values_are_rejected((layout, record) in layout_and_record(), pick in any::<prop::sample::Index>(), inf in any::<bool>()) {
        let poison = if inf { f32::INFINITY } else { f32::NAN };
        let mut encoded = layout.encode_chunk(std::slice::from_ref(&record)).expect("encodes");
        // Every slot except the four trailing flag/code slots holds data that must be finite.
        let data_slots = layout.record_len() - 4;
        let index = pick.index(data_slots);
        encoded[index] = poison;
        let refused = matches!(layout.decode(&encoded), Err(ProtocolError::NonFinite { .. }));
        prop_assert!(refused);

        let mut bad = record;
        let len = bad.obs.len();
        bad.obs[pick.index(len)] = poison;
        let refused = matches!(layout.encode_chunk(&[bad]), Err(ProtocolError::NonFinite { field: "obs", .. }));
        prop_assert!(refused);
    }
}

#[test]
fn flags_must_be_exactly_zero_or_one() {
    let layout = StepLayout::new(3, 2, 2, 2).expect("dims");
    let record = layout
        .decode(&vec![0.0; layout.record_len()])
        .expect("all zeros is a valid record");
    let mut encoded = layout.encode_chunk(&[record]).expect("encodes");
    let success = layout.field("success").expect("field").start;
    encoded[success] = 0.5;
    assert_eq!(
        layout.decode(&encoded),
        Err(ProtocolError::InvalidFlag {
            field: "success",
            value: 0.5
        })
    );
    encoded[success] = 1.0;
    let decision = layout.field("decision").expect("field").start;
    encoded[decision] = 42.0;
    assert!(matches!(
        layout.decode(&encoded),
        Err(ProtocolError::UnknownCode {
            what: "decision kind",
            code: 42
        })
    ));
    encoded[decision] = f32::NAN;
    assert!(layout.decode(&encoded).is_err());
}

#[test]
fn field_offsets_tile_the_record() {
    let layout = StepLayout::new(29, 8, 2, 2).expect("dims");
    let names = [
        "obs",
        "next_obs",
        "phi",
        "next_phi",
        "subgoal",
        "high_action",
        "action",
        "goal",
        "achieved_goal",
        "reward",
        "decision",
        "success",
        "terminated",
        "truncated",
    ];
    let mut next = 0;
    for name in names {
        let range = layout.field(name).expect("known field");
        assert_eq!(range.start, next, "{name}");
        next = range.end;
    }
    assert_eq!(next, layout.record_len());
    assert_eq!(layout.record_len(), 2 * 29 + 4 * 2 + 8 + 2 * 2 + 5);
    assert!(layout.field("nope").is_none());
    assert!(StepLayout::new(0, 1, 1, 1).is_err());
}
