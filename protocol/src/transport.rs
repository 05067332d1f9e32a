//! iceoryx2 plumbing shared by every process: typed slice channels with wake-up events.
//!
//! A *channel* is an iceoryx2 publish–subscribe service carrying a slice payload (`[f32]` for
//! trajectories, `[u8]` for weights and encoded messages) with a typed user header, paired with
//! an event service of the same name. A publisher notifies the event after every send, so a
//! receiving process sleeps in a [`WaitSet`] on the listener instead of spinning: with two cores, a
//! spinning process starves the others.
//!
//! Invariants:
//! - `send` never blocks forever: subscribers with full buffers are handled by the configured
//!   [`Backpressure`] (drop the sample for that subscriber, counted by iceoryx2, or retry until
//!   a deadline), never by an unbounded retry.
//! - Payload lengths are checked against the channel's maximum before loaning memory, and a
//!   too-long payload is an error value, not a panic.

use core::fmt::Debug;
use core::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;

/// The service variant of every channel: inter-process shared memory.
pub type Ipc = ipc::Service;

/// Errors of the transport layer; each names the service it happened on.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("invalid service name `{name}`: {reason}")]
    ServiceName { name: String, reason: String },
    #[error("cannot create the iceoryx2 node `{name}`: {reason}")]
    Node { name: String, reason: String },
    #[error("cannot open service `{service}`: {reason}")]
    Open { service: String, reason: String },
    #[error("cannot create a {port} port on `{service}`: {reason}")]
    Port { service: String, port: &'static str, reason: String },
    #[error("payload of {len} elements exceeds the maximum {max} of `{service}`")]
    TooLong { service: String, len: usize, max: usize },
    #[error("send on `{service}` failed: {reason}")]
    Send { service: String, reason: String },
    #[error("receive on `{service}` failed: {reason}")]
    Receive { service: String, reason: String },
}

/// What a publisher does when a subscriber's buffer is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backpressure {
    /// Deliver to everyone who has room; a full subscriber misses this sample.
    Discard,
    /// Keep retrying until the subscriber makes room (bounded by the caller's own deadline
    /// through the subscriber buffer size; use only where the consumer is known to be alive).
    Retry,
}

/// Sizing of a channel, decided by whoever creates it; openers must ask for the same.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelShape {
    /// Largest slice length a sample may carry.
    pub max_slice_len: usize,
    /// Samples buffered per subscriber before backpressure applies.
    pub subscriber_buffer: usize,
    /// Samples a late subscriber receives on connect (1 for "latest weights").
    pub history: usize,
    /// Upper bound on publishers (actors) and subscribers.
    pub max_publishers: usize,
    pub max_subscribers: usize,
}

/// Creates a node whose name identifies the run and role (shown by iceoryx2 tooling).
pub fn open_node(node_name: &str) -> Result<Node<Ipc>, TransportError> {
    let name = NodeName::new(node_name).map_err(|e| TransportError::Node {
        name: node_name.to_owned(),
        reason: format!("{e:?}"),
    })?;
    NodeBuilder::new()
        .name(&name)
        .create::<Ipc>()
        .map_err(|e| TransportError::Node { name: node_name.to_owned(), reason: format!("{e:?}") })
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(|e| TransportError::ServiceName {
        name: name.to_owned(),
        reason: format!("{e:?}"),
    })
}

type SliceService<T, H> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [T], H>;
type EventService = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

fn open_services<T, H>(
    node: &Node<Ipc>,
    name: &str,
    shape: &ChannelShape,
) -> Result<(SliceService<T, H>, EventService), TransportError>
where
    T: Debug + Copy + ZeroCopySend + 'static,
    H: Debug + Default + ZeroCopySend + 'static,
{
    let sn = service_name(name)?;
    let open_err = |e: &dyn Debug| TransportError::Open { service: name.to_owned(), reason: format!("{e:?}") };
    let data = node
        .service_builder(&sn)
        .publish_subscribe::<[T]>()
        .user_header::<H>()
        .history_size(shape.history)
        .subscriber_max_buffer_size(shape.subscriber_buffer.max(shape.history))
        .max_publishers(shape.max_publishers)
        .max_subscribers(shape.max_subscribers)
        .open_or_create()
        .map_err(|e| open_err(&e))?;
    let events = node
        .service_builder(&sn)
        .event()
        .max_notifiers(shape.max_publishers + 1)
        .max_listeners(shape.max_subscribers + 1)
        .open_or_create()
        .map_err(|e| open_err(&e))?;
    Ok((data, events))
}

/// Sending end of a channel: loans shared memory, writes header and slice, sends, notifies.
pub struct SlicePublisher<T, H>
where
    T: Debug + Copy + ZeroCopySend + 'static,
    H: Debug + Default + ZeroCopySend + 'static,
{
    name: String,
    max_slice_len: usize,
    publisher: Publisher<Ipc, [T], H>,
    notifier: Notifier<Ipc>,
}

impl<T, H> SlicePublisher<T, H>
where
    T: Debug + Copy + ZeroCopySend + 'static,
    H: Debug + Default + ZeroCopySend + 'static,
{
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        shape: &ChannelShape,
        backpressure: Backpressure,
    ) -> Result<Self, TransportError> {
        let (data, events) = open_services::<T, H>(node, name, shape)?;
        let port_err = |port, e: &dyn Debug| TransportError::Port {
            service: name.to_owned(),
            port,
            reason: format!("{e:?}"),
        };
        let strategy = match backpressure {
            Backpressure::Discard => BackpressureStrategy::DiscardData,
            Backpressure::Retry => BackpressureStrategy::RetryUntilDelivered,
        };
        let publisher = data
            .publisher_builder()
            .initial_max_slice_len(shape.max_slice_len)
            .backpressure_strategy(strategy)
            .create()
            .map_err(|e| port_err("publisher", &e))?;
        let notifier = events.notifier_builder().create().map_err(|e| port_err("notifier", &e))?;
        Ok(Self { name: name.to_owned(), max_slice_len: shape.max_slice_len, publisher, notifier })
    }

    /// Sends `payload` with `header` and wakes the subscribers. Returns how many received it.
    pub fn send(&self, header: H, payload: &[T]) -> Result<usize, TransportError> {
        if payload.len() > self.max_slice_len {
            return Err(TransportError::TooLong {
                service: self.name.clone(),
                len: payload.len(),
                max: self.max_slice_len,
            });
        }
        let send_err = |e: &dyn Debug| TransportError::Send { service: self.name.clone(), reason: format!("{e:?}") };
        let mut sample = self.publisher.loan_slice_uninit(payload.len()).map_err(|e| send_err(&e))?;
        *sample.user_header_mut() = header;
        let delivered = sample.write_from_slice(payload).send().map_err(|e| send_err(&e))?;
        self.notifier.notify().map_err(|e| send_err(&e))?;
        Ok(delivered)
    }
}

/// Receiving end of a channel; its listener can be attached to a [`WaitSet`].
pub struct SliceSubscriber<T, H>
where
    T: Debug + Copy + ZeroCopySend + 'static,
    H: Debug + Default + ZeroCopySend + 'static,
{
    name: String,
    subscriber: Subscriber<Ipc, [T], H>,
    listener: Listener<Ipc>,
}

impl<T, H> SliceSubscriber<T, H>
where
    T: Debug + Copy + ZeroCopySend + 'static,
    H: Debug + Default + ZeroCopySend + 'static,
{
    pub fn open(node: &Node<Ipc>, name: &str, shape: &ChannelShape) -> Result<Self, TransportError> {
        let (data, events) = open_services::<T, H>(node, name, shape)?;
        let port_err = |port, e: &dyn Debug| TransportError::Port {
            service: name.to_owned(),
            port,
            reason: format!("{e:?}"),
        };
        let subscriber = data
            .subscriber_builder()
            .buffer_size(shape.subscriber_buffer.max(shape.history))
            .create()
            .map_err(|e| port_err("subscriber", &e))?;
        let listener = events.listener_builder().create().map_err(|e| port_err("listener", &e))?;
        Ok(Self { name: name.to_owned(), subscriber, listener })
    }

    /// The event listener to attach to a [`WaitSet`].
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Clears pending wake-ups, then hands every available sample to `on_sample` in arrival
    /// order. Returns how many samples were handled.
    pub fn drain(&self, mut on_sample: impl FnMut(&H, &[T])) -> Result<usize, TransportError> {
        let recv_err = |e: &dyn Debug| TransportError::Receive { service: self.name.clone(), reason: format!("{e:?}") };
        self.listener.try_wait(|_| {}).map_err(|e| recv_err(&e))?;
        let mut n = 0;
        while let Some(sample) = self.subscriber.receive().map_err(|e| recv_err(&e))? {
            on_sample(sample.user_header(), sample.payload());
            n += 1;
        }
        Ok(n)
    }

    /// Blocks up to `timeout` for a wake-up, then drains. Used by single-channel loops and tests.
    pub fn wait_and_drain(
        &self,
        timeout: Duration,
        on_sample: impl FnMut(&H, &[T]),
    ) -> Result<usize, TransportError> {
        let recv_err = |e: &dyn Debug| TransportError::Receive { service: self.name.clone(), reason: format!("{e:?}") };
        self.listener.timed_wait(|_| {}, timeout).map_err(|e| recv_err(&e))?;
        self.drain(on_sample)
    }
}
