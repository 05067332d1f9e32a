//! Transport round trips over real iceoryx2 shared memory, two nodes in one process.
//! Each test uses a unique service name so parallel tests never see each other.

use std::time::Duration;

use ::protocol::transport::{
    open_node, Backpressure, ChannelShape, SlicePublisher, SliceSubscriber, TransportError,
};
use iceoryx2::prelude::*;

#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("TestHeader")]
#[repr(C)]
struct TestHeader {
    chunk: u64,
    n: u32,
}

fn unique(name: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("asi-test/{}/{nanos}/{name}", std::process::id())
}

const SHAPE: ChannelShape = ChannelShape {
    max_slice_len: 64,
    subscriber_buffer: 16,
    history: 0,
    max_publishers: 2,
    max_subscribers: 2,
};

#[test]
fn slices_and_headers_arrive_intact_and_in_order() {
    let service = unique("order");
    let node_a = open_node("test-pub").unwrap();
    let node_b = open_node("test-sub").unwrap();
    let subscriber = SliceSubscriber::<f32, TestHeader>::open(&node_b, &service, &SHAPE).unwrap();
    let publisher =
        SlicePublisher::<f32, TestHeader>::open(&node_a, &service, &SHAPE, Backpressure::Discard)
            .unwrap();

    for chunk in 0..5u64 {
        let payload: Vec<f32> = (0..(chunk as usize + 1) * 3)
            .map(|i| i as f32 + chunk as f32 * 0.5)
            .collect();
        let delivered = publisher
            .send(
                TestHeader {
                    chunk,
                    n: payload.len() as u32,
                },
                &payload,
            )
            .unwrap();
        assert_eq!(delivered, 1);
    }
    let mut seen = Vec::new();
    subscriber
        .wait_and_drain(Duration::from_secs(5), |h, p| {
            assert_eq!(h.n as usize, p.len());
            assert_eq!(p[0], h.chunk as f32 * 0.5);
            seen.push(h.chunk);
        })
        .unwrap();
    assert_eq!(seen, vec![0, 1, 2, 3, 4]);
}

#[test]
fn a_payload_longer_than_the_channel_is_an_error_not_a_panic() {
    let service = unique("too-long");
    let node = open_node("test-long").unwrap();
    let publisher =
        SlicePublisher::<f32, TestHeader>::open(&node, &service, &SHAPE, Backpressure::Discard)
            .unwrap();
    let err = publisher
        .send(TestHeader::default(), &[0.0; 65])
        .unwrap_err();
    assert!(
        matches!(
            err,
            TransportError::TooLong {
                len: 65,
                max: 64,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn a_full_subscriber_never_blocks_a_discarding_publisher() {
    let service = unique("full");
    let node = open_node("test-full").unwrap();
    let _subscriber = SliceSubscriber::<f32, TestHeader>::open(&node, &service, &SHAPE).unwrap();
    let publisher =
        SlicePublisher::<f32, TestHeader>::open(&node, &service, &SHAPE, Backpressure::Discard)
            .unwrap();
    // Twice the subscriber's buffer, never drained: every send must return.
    for chunk in 0..(2 * SHAPE.subscriber_buffer as u64) {
        publisher.send(TestHeader { chunk, n: 1 }, &[1.0]).unwrap();
    }
}

#[test]
fn fixed_size_values_arrive_and_history_reaches_a_late_subscriber() {
    use ::protocol::transport::{ValuePublisher, ValueSubscriber};
    let service = unique("values");
    let node = open_node("test-values").unwrap();
    let shape = ChannelShape {
        history: 1,
        ..SHAPE
    };
    let publisher = ValuePublisher::<TestHeader>::open(&node, &service, &shape).unwrap();
    publisher.send(TestHeader { chunk: 7, n: 1 }).unwrap();
    let late = ValueSubscriber::<TestHeader>::open(&node, &service, &shape).unwrap();
    publisher.update_connections().unwrap();
    let values = late.drain().unwrap();
    assert_eq!(values, vec![TestHeader { chunk: 7, n: 1 }]);
}

#[test]
fn a_request_gets_its_own_response_across_nodes() {
    use ::protocol::transport::{RpcClient, RpcServer};
    let service = unique("rpc");
    let server_node = open_node("test-server").unwrap();
    let server = RpcServer::<TestHeader, TestHeader>::open(&server_node, &service, 4, 64).unwrap();
    // iceoryx2 ipc ports are not Send: the client lives entirely on its own thread.
    let client_service = service.clone();
    let call = std::thread::spawn(move || {
        let client_node = open_node("test-client").unwrap();
        let client =
            RpcClient::<TestHeader, TestHeader>::open(&client_node, &client_service, 4, 64)
                .unwrap();
        client.call(
            TestHeader { chunk: 3, n: 2 },
            &[1, 2],
            Duration::from_secs(5),
        )
    });
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    let mut served = 0;
    while served == 0 && std::time::Instant::now() < deadline {
        served = server
            .serve(|h, body| {
                (
                    TestHeader {
                        chunk: h.chunk * 10,
                        n: body.len() as u32,
                    },
                    body.iter().rev().copied().collect(),
                )
            })
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    let (header, body) = call.join().unwrap().unwrap();
    assert_eq!(header, TestHeader { chunk: 30, n: 2 });
    assert_eq!(body, vec![2, 1]);
}

#[test]
fn a_call_without_a_server_times_out_with_an_error() {
    use ::protocol::transport::RpcClient;
    let service = unique("no-server");
    let node = open_node("test-lonely").unwrap();
    let client = RpcClient::<TestHeader, TestHeader>::open(&node, &service, 4, 64).unwrap();
    let err = client
        .call(TestHeader::default(), &[0], Duration::from_millis(50))
        .unwrap_err();
    assert!(err.to_string().contains("no response"), "{err}");
}

#[test]
fn a_call_whose_server_went_away_is_answered_by_the_next_server() {
    use ::protocol::transport::{RpcClient, RpcServer};
    let service = unique("rpc-restart");
    let first_node = open_node("test-first-server").unwrap();
    let first = RpcServer::<TestHeader, TestHeader>::open(&first_node, &service, 4, 64).unwrap();
    let client_service = service.clone();
    // Far longer than the test needs: without the re-send the call would end in this timeout.
    let call = std::thread::spawn(move || {
        let client_node = open_node("test-client").unwrap();
        let client =
            RpcClient::<TestHeader, TestHeader>::open(&client_node, &client_service, 4, 64)
                .unwrap();
        client.call(TestHeader { chunk: 4, n: 1 }, &[9], Duration::from_secs(60))
    });
    // The request has been sent once the first server's listener is woken; that server then
    // goes away without answering, and a second one takes its place.
    let mut woken = false;
    while !woken {
        first
            .listener()
            .timed_wait(|_| woken = true, Duration::from_secs(60))
            .unwrap();
    }
    drop(first);
    drop(first_node);
    let second_node = open_node("test-second-server").unwrap();
    let second = RpcServer::<TestHeader, TestHeader>::open(&second_node, &service, 4, 64).unwrap();
    let mut served = 0;
    while !call.is_finished() {
        served += second
            .serve(|h, body| {
                (
                    TestHeader {
                        chunk: h.chunk * 10,
                        n: body.len() as u32,
                    },
                    body.to_vec(),
                )
            })
            .unwrap();
        std::thread::sleep(Duration::from_millis(1));
    }
    let (header, body) = call.join().unwrap().unwrap();
    assert_eq!(header, TestHeader { chunk: 40, n: 1 });
    assert_eq!(body, vec![9]);
    assert!(served >= 1);
}

#[test]
fn opening_a_channel_with_another_payload_type_or_size_names_the_service() {
    let service = unique("mismatch");
    let node = open_node("test-mismatch").unwrap();
    let _creator = SliceSubscriber::<f32, TestHeader>::open(&node, &service, &SHAPE).unwrap();
    let wrong_type = SliceSubscriber::<u8, TestHeader>::open(&node, &service, &SHAPE);
    let more_publishers = ChannelShape {
        max_publishers: SHAPE.max_publishers + 1,
        ..SHAPE
    };
    let too_many = SlicePublisher::<f32, TestHeader>::open(
        &node,
        &service,
        &more_publishers,
        Backpressure::Discard,
    );
    for (what, result) in [
        ("payload type", wrong_type.err()),
        ("publishers", too_many.err()),
    ] {
        match result {
            Some(TransportError::Open { service: named, .. }) => {
                assert_eq!(named, service, "{what}")
            }
            other => panic!("{what}: expected an Open error, got {other:?}"),
        }
    }
}

#[test]
fn a_port_beyond_the_channels_maximum_is_a_port_error() {
    let service = unique("ports");
    let node = open_node("test-ports").unwrap();
    let _kept: Vec<_> = (0..SHAPE.max_subscribers)
        .map(|_| SliceSubscriber::<f32, TestHeader>::open(&node, &service, &SHAPE).unwrap())
        .collect();
    let err = SliceSubscriber::<f32, TestHeader>::open(&node, &service, &SHAPE)
        .err()
        .expect("one subscriber more than max_subscribers");
    assert!(
        matches!(&err, TransportError::Port { service: named, port: "subscriber", .. } if *named == service),
        "{err:?}"
    );
    assert!(err.to_string().contains("subscriber port"), "{err}");
}

#[test]
fn an_invalid_service_name_is_an_error() {
    let node = open_node("test-bad-name").unwrap();
    let err = SliceSubscriber::<f32, TestHeader>::open(&node, "", &SHAPE)
        .err()
        .expect("an empty service name");
    assert!(matches!(err, TransportError::ServiceName { .. }), "{err:?}");
}
