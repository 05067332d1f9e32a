//! `GraphService::handle`: every request kind, and bad requests answered with errors.

mod common;

use common::*;
use protocol::graph::{
    GraphRequestHeader, GraphRequestKind, GraphStatus, NoRouteReason, ReachSample, RouteAnswer,
    RouteQuery,
};
use protocol::{GraphRequest, GraphResponse, PhiVersion};

/// A plus-shaped maze of unit cells, arms of length 4, plus a far island (10, 10)–(11, 10).
fn plus_service() -> graph_service::GraphService {
    plus_service_with(&config())
}

fn plus_service_with(config: &protocol::Config) -> graph_service::GraphService {
    let config = config.clone();
    let mut service = service(&config);
    let arms = [(1, 0), (-1, 0), (0, 1), (0, -1)];
    for (episode, (dx, dy)) in arms.into_iter().enumerate() {
        let arm: Vec<_> = (0..=4).map(|i| at(i * dx, i * dy)).collect();
        ingest_episode(&mut service, 0, episode as u64, &arm);
    }
    ingest_episode(&mut service, 1, 0, &[at(10, 10), at(11, 10)]);
    load_identity(&mut service, &config, 1);
    service
}

fn assert_error(
    service: &mut graph_service::GraphService,
    header: &GraphRequestHeader,
    body: &[u8],
    expected: GraphStatus,
    words: &str,
) {
    let (response, bytes) = service.handle(header, body);
    assert_eq!(status(&response), expected);
    assert_eq!(response.request_id, header.request_id);
    match decode_body(&bytes) {
        Some(GraphResponse::Error { message }) => {
            assert!(message.contains(words), "{message:?} lacks {words:?}")
        }
        other => panic!("expected an error body, got {other:?}"),
    }
}

fn stats_still_work(service: &mut graph_service::GraphService) {
    let (response, body) = ask(service, &GraphRequest::Stats);
    assert_eq!(status(&response), GraphStatus::Ok);
    assert!(matches!(body, Some(GraphResponse::Stats(_))));
}

#[test]
fn stats_are_answered_before_and_after_the_first_graph() {
    let config = config();
    let mut service = service(&config);
    ingest_episode(&mut service, 0, 0, &[at(0, 0), at(1, 0), at(2, 0)]);
    let (response, body) = ask(&mut service, &GraphRequest::Stats);
    assert_eq!(
        (status(&response), response.graph_version),
        (GraphStatus::Ok, 0)
    );
    let Some(GraphResponse::Stats(stats)) = body else {
        panic!("{body:?}")
    };
    assert_eq!(
        (stats.n_nodes, stats.n_stored_steps, stats.n_stored_episodes),
        (0, 3, 1)
    );
    load_identity(&mut service, &config, 1);
    let (response, body) = ask(&mut service, &GraphRequest::Stats);
    assert_eq!(
        (response.graph_version, response.phi_version),
        (1, PhiVersion(1))
    );
    let Some(GraphResponse::Stats(stats)) = body else {
        panic!("{body:?}")
    };
    assert_eq!(
        (stats.n_nodes, stats.n_edges, stats.n_dropped_cells),
        (3, 2, 0)
    );
}

#[test]
fn graph_requests_before_the_first_graph_are_not_ready() {
    let config = config();
    let mut service = service(&config);
    ingest_episode(&mut service, 0, 0, &[at(0, 0), at(1, 0)]);
    let requests = [
        GraphRequest::FrontierRoute { from: at(0, 0) },
        GraphRequest::Routes {
            queries: vec![RouteQuery {
                start: at(0, 0),
                end: at(1, 0),
                fallback_origin: None,
            }],
        },
        GraphRequest::Dump,
    ];
    for request in requests {
        let (response, body) = ask(&mut service, &request);
        assert_eq!(status(&response), GraphStatus::NotReady, "{request:?}");
        assert_eq!(
            (response.graph_version, response.phi_version),
            (0, PhiVersion(0))
        );
        let Some(GraphResponse::Error { message }) = body else {
            panic!("{body:?}")
        };
        assert!(message.contains("empty graph"), "{message}");
    }
}

#[test]
fn malformed_bytes_wrong_versions_and_nan_points_get_errors_and_the_service_keeps_working() {
    let mut service = plus_service();
    let header = GraphRequestHeader::new(42, GraphRequestKind::FrontierRoute, PhiVersion(1));
    assert_error(
        &mut service,
        &header,
        &[0xff, 0xff, 0xff, 0xff, 0x0f],
        GraphStatus::InvalidRequest,
        "malformed",
    );
    assert_error(
        &mut service,
        &header,
        &[],
        GraphStatus::InvalidRequest,
        "malformed",
    );
    let good = protocol::encode(&GraphRequest::FrontierRoute { from: at(0, 0) }).unwrap();
    let mut trailing = good.clone();
    trailing.push(0);
    assert_error(
        &mut service,
        &header,
        &trailing,
        GraphStatus::InvalidRequest,
        "trailing",
    );
    let mut old = header;
    old.protocol_version += 7;
    assert_error(
        &mut service,
        &old,
        &good,
        GraphStatus::VersionMismatch,
        "version",
    );
    let mut unknown = header;
    unknown.kind = 99;
    assert_error(
        &mut service,
        &unknown,
        &good,
        GraphStatus::InvalidRequest,
        "unknown",
    );
    let stats_header = GraphRequestHeader::new(43, GraphRequestKind::Stats, PhiVersion(1));
    assert_error(
        &mut service,
        &stats_header,
        &good,
        GraphStatus::InvalidRequest,
        "header says",
    );
    let nan = protocol::encode(&GraphRequest::FrontierRoute {
        from: [f32::NAN, 0.0],
    })
    .unwrap();
    assert_error(
        &mut service,
        &header,
        &nan,
        GraphStatus::InvalidRequest,
        "non-finite",
    );
    let inf_query = GraphRequest::Routes {
        queries: vec![RouteQuery {
            start: at(0, 0),
            end: at(1, 0),
            fallback_origin: Some([0.0, f32::INFINITY]),
        }],
    };
    let routes_header = GraphRequestHeader::new(44, GraphRequestKind::Routes, PhiVersion(1));
    assert_error(
        &mut service,
        &routes_header,
        &protocol::encode(&inf_query).unwrap(),
        GraphStatus::InvalidRequest,
        "non-finite",
    );
    let huge = protocol::encode(&GraphRequest::FrontierRoute { from: [3e38, 0.0] }).unwrap();
    assert_error(
        &mut service,
        &header,
        &huge,
        GraphStatus::InvalidRequest,
        "out of range",
    );
    assert_eq!(service.stats().invalid_requests, 9);
    stats_still_work(&mut service);
    let (response, body) = ask(
        &mut service,
        &GraphRequest::FrontierRoute { from: at(0, 0) },
    );
    assert_eq!(status(&response), GraphStatus::Ok);
    assert!(matches!(body, Some(GraphResponse::FrontierRoute(Ok(_)))));
}

#[test]
fn random_bytes_never_panic_the_handler() {
    let mut service = plus_service();
    let mut state = 0x1234_5678_u64;
    for len in 0..300 {
        let bytes: Vec<u8> = (0..len % 40)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 56) as u8
            })
            .collect();
        let kind = [
            GraphRequestKind::FrontierRoute,
            GraphRequestKind::Routes,
            GraphRequestKind::LeastVisited,
        ][len % 3];
        let header = GraphRequestHeader::new(len as u64, kind, PhiVersion(1));
        let (response, _) = service.handle(&header, &bytes);
        assert_eq!(response.request_id, len as u64);
    }
    stats_still_work(&mut service);
}

#[test]
fn frontier_route_goes_from_the_start_cell_to_a_far_node() {
    let mut service = plus_service();
    for _ in 0..20 {
        let (response, body) = ask(
            &mut service,
            &GraphRequest::FrontierRoute { from: [1.2, 0.3] },
        );
        assert_eq!(status(&response), GraphStatus::Ok);
        let Some(GraphResponse::FrontierRoute(Ok(answer))) = body else {
            panic!("{body:?}")
        };
        // From (1, 0): the tips (−4, 0), (0, 4), (0, −4) are 5 hops away, (4, 0) is 3.
        // Beyond 0.9 × 5 = 4.5: exactly the three tips at distance 5.
        assert_eq!(answer.distance, 5.0);
        assert!(
            [[-4.0, 0.0], [0.0, 4.0], [0.0, -4.0]].contains(&answer.frontier),
            "{answer:?}"
        );
        assert_eq!(answer.route.first(), Some(&[1.0, 0.0]));
        assert_eq!(answer.route.last(), Some(&answer.frontier));
        assert_eq!(answer.route.len(), 6);
    }
}

#[test]
fn frontier_route_from_an_unknown_cell_says_the_start_is_unknown() {
    let mut service = plus_service();
    for from in [at(30, 30), at(-7, -7)] {
        let (response, body) = ask(&mut service, &GraphRequest::FrontierRoute { from });
        assert_eq!(status(&response), GraphStatus::Ok);
        assert_eq!(
            body,
            Some(GraphResponse::FrontierRoute(Err(
                NoRouteReason::StartUnknown
            )))
        );
    }
    // The island's two cells: the other one is the frontier.
    let (_, body) = ask(
        &mut service,
        &GraphRequest::FrontierRoute { from: at(10, 10) },
    );
    let Some(GraphResponse::FrontierRoute(Ok(answer))) = body else {
        panic!("{body:?}")
    };
    assert_eq!(answer.frontier, [11.0, 10.0]);
}

#[test]
fn routes_answer_each_query_in_order_with_the_si_fallback() {
    let mut service = plus_service();
    let queries = vec![
        RouteQuery {
            start: at(2, 0),
            end: at(0, -3),
            fallback_origin: None,
        },
        RouteQuery {
            start: at(2, 0),
            end: at(10, 10),
            fallback_origin: Some(at(0, 0)),
        },
        RouteQuery {
            start: at(2, 0),
            end: at(10, 10),
            fallback_origin: None,
        },
        RouteQuery {
            start: at(40, 0),
            end: at(0, 0),
            fallback_origin: Some(at(0, 0)),
        },
        RouteQuery {
            start: at(3, 0),
            end: at(3, 0),
            fallback_origin: None,
        },
    ];
    let (response, body) = ask(&mut service, &GraphRequest::Routes { queries });
    assert_eq!(status(&response), GraphStatus::Ok);
    let Some(GraphResponse::Routes(answers)) = body else {
        panic!("{body:?}")
    };
    assert_eq!(answers.len(), 5);
    assert_eq!(
        answers[0],
        RouteAnswer::Direct(vec![
            [2.0, 0.0],
            [1.0, 0.0],
            [0.0, 0.0],
            [0.0, -1.0],
            [0.0, -2.0],
            [0.0, -3.0]
        ])
    );
    let RouteAnswer::ViaFrontier(route) = &answers[1] else {
        panic!("{:?}", answers[1])
    };
    assert_eq!(route[0], [2.0, 0.0]);
    assert!([[4.0, 0.0], [-4.0, 0.0], [0.0, 4.0], [0.0, -4.0]].contains(route.last().unwrap()));
    assert_eq!(
        answers[2],
        RouteAnswer::NoRoute {
            direct: NoRouteReason::Unreachable,
            fallback: None
        }
    );
    assert_eq!(
        answers[3],
        RouteAnswer::NoRoute {
            direct: NoRouteReason::StartUnknown,
            fallback: Some(NoRouteReason::StartUnknown)
        }
    );
    assert_eq!(answers[4], RouteAnswer::Direct(vec![[3.0, 0.0]]));
}

#[test]
fn least_visited_picks_the_candidate_with_fewest_stored_states() {
    let mut service = plus_service();
    // The origin cell holds the first state of all four arms.
    let candidates = vec![at(0, 0), at(2, 0), at(25, 25), at(3, 0)];
    let (response, body) = ask(&mut service, &GraphRequest::LeastVisited { candidates });
    assert_eq!(status(&response), GraphStatus::Ok);
    assert_eq!(
        body,
        Some(GraphResponse::LeastVisited {
            index: 2,
            visits: 0.0
        })
    );
    let (_, body) = ask(
        &mut service,
        &GraphRequest::LeastVisited {
            candidates: vec![at(0, 0), at(1, 0)],
        },
    );
    assert_eq!(
        body,
        Some(GraphResponse::LeastVisited {
            index: 1,
            visits: 1.0
        })
    );
    let (response, _) = ask(
        &mut service,
        &GraphRequest::LeastVisited { candidates: vec![] },
    );
    assert_eq!(status(&response), GraphStatus::InvalidRequest);
}

#[test]
fn least_visited_scores_by_hess_future_count_when_configured() {
    let mut config = config();
    config.asi.count_mode_score = protocol::config::CountModeScore::FutureCount;
    config.hierarchy.c = 1; // every stored state is a decision state of the future counts
    config.exploration.visits_from_start = true; // a handful of episodes, all counted
    let mut service = plus_service_with(&config);
    assert!(service.hess().n_future_recomputes() > 0);
    // Brute force: the first candidate with the lowest F of its 3.0-cell.
    let brute = |service: &graph_service::GraphService, candidates: &[[f32; 2]]| {
        let scores: Vec<f64> = candidates
            .iter()
            .map(|&p| service.hess().future_at(p))
            .collect();
        let lowest = scores.iter().copied().fold(f64::INFINITY, f64::min);
        let index = scores.iter().position(|&s| s == lowest).unwrap();
        (index as u32, lowest as f32)
    };
    let visited = vec![at(0, 0), at(4, 0), at(0, -4), at(-3, 0), at(0, 2)];
    let unvisited_last = vec![at(0, 0), at(4, 0), at(25, 25)];
    for candidates in [visited, unvisited_last] {
        let (index, score) = brute(&service, &candidates);
        let (response, body) = ask(
            &mut service,
            &GraphRequest::LeastVisited {
                candidates: candidates.clone(),
            },
        );
        assert_eq!(status(&response), GraphStatus::Ok);
        assert_eq!(
            body,
            Some(GraphResponse::LeastVisited {
                index,
                visits: score
            }),
            "{candidates:?}"
        );
    }
    // Visited cells have F ≥ 1 (every sample is a visit), a cell without samples F = 1: the
    // unvisited candidate wins only against visited ones with F > 1.
    assert!(service.hess().future_at(at(0, 0)) > 1.0);
    assert_eq!(service.hess().future_at(at(25, 25)), 1.0);
    let (response, _) = ask(
        &mut service,
        &GraphRequest::LeastVisited {
            candidates: vec![at(0, 0), [1e30, 0.0]],
        },
    );
    assert_eq!(status(&response), GraphStatus::InvalidRequest);
}

#[test]
fn dump_lists_nodes_with_visits_and_edges() {
    let mut service = plus_service();
    let (response, body) = ask(&mut service, &GraphRequest::Dump);
    assert_eq!(status(&response), GraphStatus::Ok);
    let Some(GraphResponse::Dump(dump)) = body else {
        panic!("{body:?}")
    };
    assert_eq!(dump.cell_size, 1.0);
    assert_eq!(
        dump.nodes.len(),
        1 + 4 * 4 + 2,
        "origin, four arms, the island"
    );
    assert_eq!(dump.nodes[0].key, [0, 0]);
    assert_eq!(dump.nodes[0].visits, 4);
    assert_eq!(dump.edges.len(), 4 * 4 + 1);
    assert!(dump.edges.iter().all(|&(a, b, w)| a < b && w == 1.0));
}

#[test]
fn explore_subgoals_come_from_stored_states_near_the_query_point() {
    let mut service = plus_service();
    // Count cells are 3 wide: every stored state within 20 of (0.5, 0.5) except the island
    // ((10.5, 10.5) is 14.1 away, (11.5, 10.5) is 15.0 away: also within).
    let stored: Vec<[f32; 2]> = (0..=4)
        .flat_map(|i| [at(i, 0), at(-i, 0), at(0, i), at(0, -i)])
        .chain([at(10, 10), at(11, 10)])
        .collect();
    for episode in [0, 100, 500] {
        let (response, body) = ask(
            &mut service,
            &GraphRequest::ExploreSubgoal {
                from: at(0, 0),
                episode,
            },
        );
        assert_eq!(status(&response), GraphStatus::Ok);
        assert_eq!(
            (response.graph_version, response.phi_version),
            (1, PhiVersion(1))
        );
        let Some(GraphResponse::ExploreSubgoal { subgoal, candidate }) = body else {
            panic!("{body:?}")
        };
        assert!(stored.contains(&candidate), "{candidate:?}");
        assert_ne!(
            candidate,
            at(0, 0),
            "the query point itself is no candidate"
        );
        let pushed =
            ((subgoal[0] - candidate[0]).powi(2) + (subgoal[1] - candidate[1]).powi(2)).sqrt();
        if episode > config().exploration.potential_start_episode {
            assert!((pushed - 5.0).abs() < 1e-4, "pushed by {pushed}");
        } else {
            assert_eq!(subgoal, candidate);
        }
    }
    assert_eq!(service.stats().explore_answers, 3);
}

#[test]
fn reported_failures_steer_late_explore_subgoals_away() {
    let config = config();
    let mut service = service(&config);
    // Two stored states 3 units either side of the origin, in count cells (1, 0) and (−1, 0)
    // (cells of 3). Equal future counts: without potential the first draw of the lower
    // score wins, so report a large failure at one of them and check the other is chosen.
    ingest_episode(&mut service, 0, 0, &[[3.5, 0.5], [-2.5, 0.5]]);
    let report = GraphRequest::ReportReaching {
        samples: vec![ReachSample {
            subgoal: [4.0, 1.0],
            error: 50.0,
        }],
    };
    let (response, body) = ask(&mut service, &report);
    assert_eq!(
        (status(&response), body),
        (GraphStatus::Ok, Some(GraphResponse::Ack))
    );
    for _ in 0..10 {
        let (_, body) = ask(
            &mut service,
            &GraphRequest::ExploreSubgoal {
                from: [0.5, 0.5],
                episode: 1000,
            },
        );
        let Some(GraphResponse::ExploreSubgoal { candidate, subgoal }) = body else {
            panic!("{body:?}")
        };
        assert_eq!(candidate, [-2.5, 0.5]);
        assert_eq!(subgoal, [-7.5, 0.5], "pushed 5 further from (0.5, 0.5)");
    }
    assert!((service.hess().potential_at([3.0, 0.0]) - 50.0).abs() < 1e-12);
}

#[test]
fn explore_before_any_stored_state_is_not_ready_with_a_reason() {
    let config = config();
    let mut service = service(&config);
    let (response, body) = ask(
        &mut service,
        &GraphRequest::ExploreSubgoal {
            from: [0.0, 0.0],
            episode: 1,
        },
    );
    assert_eq!(status(&response), GraphStatus::NotReady);
    let Some(GraphResponse::Error { message }) = body else {
        panic!("{body:?}")
    };
    assert!(message.contains("no stored states"), "{message}");
}

#[test]
fn negative_or_non_finite_reaching_errors_are_refused_and_add_nothing() {
    let mut service = plus_service();
    let bad = [
        (-1.0, "distance"),
        (f32::NAN, "non-finite"),
        (f32::INFINITY, "non-finite"),
    ];
    for (error, words) in bad {
        let request = GraphRequest::ReportReaching {
            samples: vec![
                ReachSample {
                    subgoal: at(0, 0),
                    error: 1.0,
                },
                ReachSample {
                    subgoal: at(0, 0),
                    error,
                },
            ],
        };
        let header = GraphRequestHeader::new(3, GraphRequestKind::ReportReaching, PhiVersion(1));
        assert_error(
            &mut service,
            &header,
            &protocol::encode(&request).unwrap(),
            GraphStatus::InvalidRequest,
            words,
        );
    }
    assert_eq!(service.hess().potential_at(at(0, 0)), 0.0);
    assert_eq!(service.stats().reach_samples, 0);
    stats_still_work(&mut service);
}

#[test]
fn requests_without_a_route_are_counted() {
    let mut service = plus_service();
    ask(
        &mut service,
        &GraphRequest::FrontierRoute { from: at(30, 30) },
    );
    ask(
        &mut service,
        &GraphRequest::Routes {
            queries: vec![RouteQuery {
                start: at(0, 0),
                end: at(10, 10),
                fallback_origin: None,
            }],
        },
    );
    let stats = service.stats();
    assert_eq!((stats.frontier_not_found, stats.routes_not_found), (1, 1));
}

#[test]
fn requests_with_another_phi_version_are_answered_and_counted() {
    let mut service = plus_service();
    let header = GraphRequestHeader::new(5, GraphRequestKind::FrontierRoute, PhiVersion(0));
    let body = protocol::encode(&GraphRequest::FrontierRoute { from: at(0, 0) }).unwrap();
    let (response, _) = service.handle(&header, &body);
    assert_eq!(
        (status(&response), response.phi_version),
        (GraphStatus::Ok, PhiVersion(1))
    );
    assert_eq!(service.stats().stale_phi_requests, 1);
}

#[test]
fn routes_are_the_same_with_the_route_table_and_without_it() {
    let with_table = plus_service();
    let graph = with_table.graph().expect("built");
    assert!(graph.build_route_table(1), "a 19-node graph gets a table");
    let mut no_table_config = config();
    no_table_config.graph.route_table_max_nodes = 0;
    let without = plus_service_with(&no_table_config);
    assert!(without.graph().expect("built").route_table().is_none());
    let mut cells: Vec<_> = (-4..=4)
        .map(|i| at(i, 0))
        .chain((-4..=4).filter(|&i| i != 0).map(|i| at(0, i)))
        .collect();
    cells.extend([at(10, 10), at(11, 10), at(7, 7)]);
    let mut reachable = 0;
    for &start in &cells {
        for &end in &cells {
            let table_answer = with_table.route(start, end);
            assert_eq!(
                table_answer,
                without.route(start, end),
                "{start:?} -> {end:?}"
            );
            reachable += usize::from(table_answer.is_ok());
        }
    }
    // 17 plus cells reach each other, the 2 island cells each other; (7, 7) is no node.
    assert_eq!(reachable, 17 * 17 + 2 * 2);
}
