//! Bounded fuzzing of every decoder a peer's bytes reach (issue #7, "hostile input"): arbitrary
//! and mutated bytes, headers with arbitrary fields, and float payloads with arbitrary bit
//! patterns must give a value or an error — never a panic, never an out-of-bounds read — and
//! whatever decodes must re-encode to an equal value.
//!
//! The number of cases per property is `FUZZ_CASES` (default 2,000; CI runs the default).

use proptest::prelude::*;
use protocol::graph::{
    FrontierRoute, GraphRequestHeader, GraphRequestKind, GraphResponseHeader, GraphStatus,
    NoRouteReason, ReachSample, RouteAnswer, RouteQuery,
};
use protocol::*;

fn cases() -> u32 {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2_000)
}

/// Valid requests of every kind, to mutate.
fn seed_requests() -> Vec<GraphRequest> {
    vec![
        GraphRequest::FrontierRoute { from: [1.5, -2.0] },
        GraphRequest::Routes {
            queries: vec![
                RouteQuery {
                    start: [0.0, 0.0],
                    end: [4.0, 4.0],
                    fallback_origin: None,
                },
                RouteQuery {
                    start: [1.0, 2.0],
                    end: [-3.0, 8.0],
                    fallback_origin: Some([0.5, 0.5]),
                },
            ],
        },
        GraphRequest::ExploreSubgoal {
            from: [3.0, 3.0],
            episode: 412,
        },
        GraphRequest::LeastVisited {
            candidates: vec![[0.0, 1.0], [2.0, -1.0], [9.0, 9.0]],
        },
        GraphRequest::ReportReaching {
            samples: vec![ReachSample {
                subgoal: [1.0, 1.0],
                error: 0.25,
            }],
        },
        GraphRequest::Stats,
        GraphRequest::Dump,
    ]
}

/// Valid responses carrying routes and no-route reasons, to mutate.
fn seed_responses() -> Vec<GraphResponse> {
    vec![
        GraphResponse::FrontierRoute(Ok(FrontierRoute {
            frontier: [4.0, 2.0],
            route: vec![[0.0, 0.0], [2.0, 2.0], [4.0, 2.0]],
            distance: 31.0,
        })),
        GraphResponse::FrontierRoute(Err(NoRouteReason::NothingReachable)),
        GraphResponse::Routes(vec![
            RouteAnswer::Direct(vec![[0.0, 0.0], [1.0, 1.0]]),
            RouteAnswer::ViaFrontier(vec![[0.0, 0.0]]),
            RouteAnswer::NoRoute {
                direct: NoRouteReason::Unreachable,
                fallback: Some(NoRouteReason::StartUnknown),
            },
            RouteAnswer::NoRoute {
                direct: NoRouteReason::EmptyGraph,
                fallback: None,
            },
        ]),
    ]
}

/// A decoded request must survive a round trip, and its finiteness check must not panic.
fn check_decoded_request(request: &GraphRequest) {
    let _ = request.check_finite();
    let bytes = encode(request).expect("a decoded request encodes");
    let again: GraphRequest = decode(&bytes).expect("re-encoded bytes decode");
    // NaN breaks PartialEq; compare the encodings instead.
    assert_eq!(encode(&again).unwrap(), bytes);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_panic_the_graph_decoders(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        if let Ok(request) = decode::<GraphRequest>(&bytes) {
            check_decoded_request(&request);
        }
        if let Ok(response) = decode::<GraphResponse>(&bytes) {
            let again = encode(&response).expect("a decoded response encodes");
            prop_assert_eq!(encode(&decode::<GraphResponse>(&again).unwrap()).unwrap(), again);
        }
    }

    #[test]
    fn mutated_route_responses_decode_or_fail_cleanly(
        which in 0usize..3,
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let mut bytes = encode(&seed_responses()[which]).unwrap();
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] = value;
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        if let Ok(response) = decode::<GraphResponse>(&bytes) {
            let again = encode(&response).expect("a decoded response encodes");
            prop_assert_eq!(encode(&decode::<GraphResponse>(&again).unwrap()).unwrap(), again);
        }
    }

    #[test]
    fn mutated_requests_decode_or_fail_cleanly(
        which in 0usize..7,
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let mut bytes = encode(&seed_requests()[which]).unwrap();
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] = value;
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        if let Ok(request) = decode::<GraphRequest>(&bytes) {
            check_decoded_request(&request);
        }
    }

    #[test]
    fn trajectory_headers_with_arbitrary_fields_are_checked_without_panic(
        words in prop::array::uniform8(any::<u32>()),
        big in prop::array::uniform4(any::<u64>()),
        payload_len in any::<usize>(),
    ) {
        let header = TrajectoryHeader {
            episode_id: EpisodeId(big[0]),
            first_env_step: big[1],
            policy_version: PolicyVersion(big[2]),
            phi_version: PhiVersion(big[3]),
            actor_id: ActorId(words[0]),
            chunk_index: words[1],
            n_steps: words[2],
            obs_dim: words[3] % 4096,
            action_dim: words[4] % 64,
            goal_dim: words[5] % 8,
            latent_dim: words[6] % 8,
            flags: TrajectoryFlags(words[7]),
            protocol_version: if words[7] % 3 == 0 { words[0] } else { PROTOCOL_VERSION },
            reserved: 0,
        };
        if let Ok(layout) = header.check(payload_len) {
            // Accepted ⇒ the payload holds exactly n_steps records of the layout.
            prop_assert_eq!(header.n_steps as usize * layout.record_len(), payload_len);
            prop_assert!(header.n_steps > 0);
            prop_assert_eq!(header.protocol_version, PROTOCOL_VERSION);
            prop_assert_eq!(header.flags.0 & !TrajectoryFlags::ALL, 0);
        }
    }

    #[test]
    fn chunk_payloads_with_arbitrary_bit_patterns_never_panic(
        dims in (1usize..40, 1usize..10, 1usize..4, 1usize..4),
        n_steps in 1usize..4,
        bits in prop::collection::vec(any::<u32>(), 0..600),
        claimed_steps in 0usize..6,
    ) {
        let (obs, action, goal, latent) = dims;
        let layout = StepLayout::new(obs, action, goal, latent).unwrap();
        let mut payload: Vec<f32> = bits.iter().map(|b| f32::from_bits(*b)).collect();
        payload.resize(payload.len().max(n_steps * layout.record_len()).min(n_steps * layout.record_len() + 3), 0.0);
        if let Ok(views) = layout.view_chunk(&payload, claimed_steps) {
            prop_assert_eq!(views.len(), claimed_steps);
            for view in &views {
                // Accepted records are finite and their flags are booleans.
                prop_assert!(view.obs.iter().chain(view.next_obs).chain(view.phi).all(|v| v.is_finite()));
                prop_assert!(view.reward.is_finite());
                let record = view.to_record();
                let mut out = vec![0.0; layout.record_len()];
                layout.encode_into(&record, &mut out).unwrap();
                prop_assert_eq!(layout.decode(&out).unwrap(), record);
            }
        }
    }

    #[test]
    fn graph_headers_and_small_messages_with_arbitrary_fields_never_panic(
        words in prop::array::uniform6(any::<u32>()),
        value in any::<f64>(),
        name in prop::array::uniform32(any::<u8>()),
    ) {
        let mut request = GraphRequestHeader::new(1, GraphRequestKind::Stats, PhiVersion(2));
        request.kind = words[0];
        request.protocol_version = words[1];
        let _ = request.check_version();
        let _ = request.kind();
        let mut response = GraphResponseHeader::answering(&GraphRequestHeader::new(3, GraphRequestKind::Dump, PhiVersion(4)), GraphStatus::Ok, 7, PhiVersion(1));
        response.status = words[2];
        let _ = response.status();
        let _ = response.check_version();
        let mut control = ControlMessage::new(1, ControlCommand::Stop);
        control.command = words[3];
        let _ = control.command();
        let mut sample = MetricsSample::new(ProcessRole::Learner, 0, "a", value, 0, 0).unwrap();
        sample.role = words[4];
        sample.name_len = words[5] % 64;
        sample.name[..32].copy_from_slice(&name);
        if let Ok(decoded) = sample.name() {
            prop_assert!(decoded.len() <= sample.name.len());
        }
        let _ = sample.role();
    }
}
