//! iceoryx2 plumbing shared by every process: typed slice channels with wake-up events.
//!
//! A *channel* is an iceoryx2 publish–subscribe service carrying a slice payload (`[f32]` for
//! trajectories, `[u8]` for weights and encoded messages) with a typed user header, paired with
//! an event service of the same name. A publisher notifies the event after every send, so a
//! receiving process sleeps in a [`WaitSet`] on the listener instead of spinning: with two cores, a
//! spinning process starves the others.
//!
//! Invariants:
//! - `send` never blocks: services are created with iceoryx2's default *safe overflow*, so a
//!   subscriber whose buffer is full loses its **oldest** buffered sample to the new one, and the
//!   configured [`Backpressure`] strategy never comes into play (iceoryx2 applies it only with
//!   safe overflow off). Data channels are therefore sized so that a full buffer cannot happen
//!   in normal operation (trajectories: 1,024 chunks per subscriber, far above what the
//!   learner's replay-ratio throttle lets the actors put in flight), and receivers detect any
//!   loss from chunk-index gaps (`ingest/lost_chunks`). A bounded blocking mode (safe overflow
//!   off, retry with a deadline) is issue #7's work.
//! - Payload lengths are checked against the channel's maximum before loaning memory, and a
//!   too-long payload is an error value, not a panic.

use core::fmt::Debug;
use core::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
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
    Port {
        service: String,
        port: &'static str,
        reason: String,
    },
    #[error("payload of {len} elements exceeds the maximum {max} of `{service}`")]
    TooLong {
        service: String,
        len: usize,
        max: usize,
    },
    #[error("send on `{service}` failed: {reason}")]
    Send { service: String, reason: String },
    #[error("receive on `{service}` failed: {reason}")]
    Receive { service: String, reason: String },
}

/// What a publisher does when a subscriber's buffer is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backpressure {
    /// Deliver to everyone who has room. With safe overflow (the default of every service
    /// here) a full subscriber instead drops its oldest sample; see the module invariants.
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
    let failed = |e: &dyn Debug| TransportError::Node {
        name: node_name.to_owned(),
        reason: format!("{e:?}"),
    };
    let name = NodeName::new(node_name).map_err(|e| failed(&e))?;
    NodeBuilder::new()
        .name(&name)
        .create::<Ipc>()
        .map_err(|e| failed(&e))
}

fn service_name(name: &str) -> Result<ServiceName, TransportError> {
    ServiceName::new(name).map_err(|e| TransportError::ServiceName {
        name: name.to_owned(),
        reason: format!("{e:?}"),
    })
}

// `map_err` adapters: each turns an iceoryx2 error into the [`TransportError`] of its step,
// naming the service (and the port).

fn open_failed<E: Debug>(service: &str) -> impl Fn(E) -> TransportError + '_ {
    move |e| TransportError::Open {
        service: service.to_owned(),
        reason: format!("{e:?}"),
    }
}

fn port_failed<'a, E: Debug>(
    service: &'a str,
    port: &'static str,
) -> impl Fn(E) -> TransportError + 'a {
    move |e| TransportError::Port {
        service: service.to_owned(),
        port,
        reason: format!("{e:?}"),
    }
}

fn send_failed<E: Debug>(service: &str) -> impl Fn(E) -> TransportError + '_ {
    move |e| TransportError::Send {
        service: service.to_owned(),
        reason: format!("{e:?}"),
    }
}

fn receive_failed<E: Debug>(service: &str) -> impl Fn(E) -> TransportError + '_ {
    move |e| TransportError::Receive {
        service: service.to_owned(),
        reason: format!("{e:?}"),
    }
}

type PubSubService<P, H> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, P, H>;
type EventService = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

/// Opens (or creates) the wake-up event service `name`, with room for `notifiers` + 1
/// notifiers and `listeners` + 1 listeners (one spare of each).
fn open_events(
    node: &Node<Ipc>,
    name: &str,
    notifiers: usize,
    listeners: usize,
) -> Result<EventService, TransportError> {
    node.service_builder(&service_name(name)?)
        .event()
        .max_notifiers(notifiers + 1)
        .max_listeners(listeners + 1)
        .open_or_create()
        .map_err(open_failed(name))
}

/// What travels in shared memory as a slice element or a fixed-size value: plain, printable
/// data with no references. Every `Copy` type deriving `ZeroCopySend` is one.
pub trait Plain: Debug + Copy + ZeroCopySend + 'static {}
impl<T: Debug + Copy + ZeroCopySend + 'static> Plain for T {}

/// A sample's user header; a freshly loaned sample starts from its default.
pub trait UserHeader: Debug + Default + ZeroCopySend + 'static {}
impl<T: Debug + Default + ZeroCopySend + 'static> UserHeader for T {}

type PubSubBuilder<P, H> = iceoryx2::service::builder::publish_subscribe::Builder<P, H, Ipc>;

/// Gives a channel's publish–subscribe service the sizes of `shape`.
fn sized<P, H>(builder: PubSubBuilder<P, H>, shape: &ChannelShape) -> PubSubBuilder<P, H>
where
    P: Debug + IceoryxSend + ?Sized,
    H: Debug + ZeroCopySend,
{
    builder
        .history_size(shape.history)
        .subscriber_max_buffer_size(shape.subscriber_buffer.max(shape.history))
        .max_publishers(shape.max_publishers)
        .max_subscribers(shape.max_subscribers)
}

/// A notifier port on the event service `events` of channel `name`.
fn notifier_port(name: &str, events: &EventService) -> Result<Notifier<Ipc>, TransportError> {
    events
        .notifier_builder()
        .create()
        .map_err(port_failed(name, "notifier"))
}

/// A listener port on the event service `events` of channel `name`.
fn listener_port(name: &str, events: &EventService) -> Result<Listener<Ipc>, TransportError> {
    events
        .listener_builder()
        .create()
        .map_err(port_failed(name, "listener"))
}

/// Opens a slice channel's publish–subscribe service and its event. (iceoryx2 opens slice and
/// fixed-size payloads with different methods, hence two openers.)
fn open_slice_services<T, H>(
    node: &Node<Ipc>,
    name: &str,
    shape: &ChannelShape,
) -> Result<(PubSubService<[T], H>, EventService), TransportError>
where
    T: Plain,
    H: UserHeader,
{
    let builder = node
        .service_builder(&service_name(name)?)
        .publish_subscribe::<[T]>()
        .user_header::<H>();
    let data = sized(builder, shape)
        .open_or_create()
        .map_err(open_failed(name))?;
    let events = open_events(node, name, shape.max_publishers, shape.max_subscribers)?;
    Ok((data, events))
}

/// Opens a fixed-size value channel's publish–subscribe service and its event.
fn open_value_services<T>(
    node: &Node<Ipc>,
    name: &str,
    shape: &ChannelShape,
) -> Result<(PubSubService<T, ()>, EventService), TransportError>
where
    T: Plain,
{
    let builder = node
        .service_builder(&service_name(name)?)
        .publish_subscribe::<T>();
    let data = sized(builder, shape)
        .open_or_create()
        .map_err(open_failed(name))?;
    let events = open_events(node, name, shape.max_publishers, shape.max_subscribers)?;
    Ok((data, events))
}

/// A channel's receiving ports: the subscriber and the listener of its wake-ups.
type SubscriberPorts<P, H> = (Subscriber<Ipc, P, H>, Listener<Ipc>);

/// Creates the subscriber and listener ports of an opened channel.
fn subscriber_ports<P, H>(
    name: &str,
    shape: &ChannelShape,
    data: &PubSubService<P, H>,
    events: &EventService,
) -> Result<SubscriberPorts<P, H>, TransportError>
where
    P: Debug + IceoryxSend + ?Sized + 'static,
    H: UserHeader,
{
    let subscriber = data
        .subscriber_builder()
        .buffer_size(shape.subscriber_buffer.max(shape.history))
        .create()
        .map_err(port_failed(name, "subscriber"))?;
    let listener = listener_port(name, events)?;
    Ok((subscriber, listener))
}

/// Connects subscribers that appeared since the last send, hands them the history and wakes
/// them.
fn update_publisher<P, H>(
    name: &str,
    publisher: &Publisher<Ipc, P, H>,
    notifier: &Notifier<Ipc>,
) -> Result<(), TransportError>
where
    P: Debug + IceoryxSend + ?Sized + 'static,
    H: Debug + ZeroCopySend + 'static,
{
    publisher.update_connections().map_err(send_failed(name))?;
    notifier.notify().map_err(send_failed(name))?;
    Ok(())
}

/// Clears the pending wake-ups of `listener`, after waiting up to `timeout` for one if given.
fn take_wakeups(
    name: &str,
    listener: &Listener<Ipc>,
    timeout: Option<Duration>,
) -> Result<(), TransportError> {
    match timeout {
        Some(timeout) => listener.timed_wait(|_| {}, timeout),
        None => listener.try_wait(|_| {}),
    }
    .map(|_| ())
    .map_err(receive_failed(name))
}

/// Sending end of a channel: loans shared memory, writes header and slice, sends, notifies.
pub struct SlicePublisher<T, H>
where
    T: Plain,
    H: UserHeader,
{
    name: String,
    max_slice_len: usize,
    publisher: Publisher<Ipc, [T], H>,
    notifier: Notifier<Ipc>,
}

impl<T, H> SlicePublisher<T, H>
where
    T: Plain,
    H: UserHeader,
{
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        shape: &ChannelShape,
        backpressure: Backpressure,
    ) -> Result<Self, TransportError> {
        let (data, events) = open_slice_services::<T, H>(node, name, shape)?;
        let strategy = match backpressure {
            Backpressure::Discard => BackpressureStrategy::DiscardData,
            Backpressure::Retry => BackpressureStrategy::RetryUntilDelivered,
        };
        let publisher = data
            .publisher_builder()
            .initial_max_slice_len(shape.max_slice_len)
            .backpressure_strategy(strategy)
            .create()
            .map_err(port_failed(name, "publisher"))?;
        let notifier = notifier_port(name, &events)?;
        Ok(Self {
            name: name.to_owned(),
            max_slice_len: shape.max_slice_len,
            publisher,
            notifier,
        })
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
        let mut sample = self
            .publisher
            .loan_slice_uninit(payload.len())
            .map_err(send_failed(&self.name))?;
        *sample.user_header_mut() = header;
        let delivered = sample
            .write_from_slice(payload)
            .send()
            .map_err(send_failed(&self.name))?;
        self.notifier.notify().map_err(send_failed(&self.name))?;
        Ok(delivered)
    }

    /// Connects subscribers that appeared since the last send and hands them the history
    /// (e.g. the latest weights to a restarted actor). Call it on a timer.
    pub fn update_connections(&self) -> Result<(), TransportError> {
        update_publisher(&self.name, &self.publisher, &self.notifier)
    }
}

/// Receiving end of a channel; its listener can be attached to a [`WaitSet`].
pub struct SliceSubscriber<T, H>
where
    T: Plain,
    H: UserHeader,
{
    name: String,
    subscriber: Subscriber<Ipc, [T], H>,
    listener: Listener<Ipc>,
}

impl<T, H> SliceSubscriber<T, H>
where
    T: Plain,
    H: UserHeader,
{
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        shape: &ChannelShape,
    ) -> Result<Self, TransportError> {
        let (data, events) = open_slice_services::<T, H>(node, name, shape)?;
        let (subscriber, listener) = subscriber_ports(name, shape, &data, &events)?;
        Ok(Self {
            name: name.to_owned(),
            subscriber,
            listener,
        })
    }

    /// The event listener to attach to a [`WaitSet`].
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Clears pending wake-ups, then hands every available sample to `on_sample` in arrival
    /// order. Returns how many samples were handled.
    pub fn drain(&self, mut on_sample: impl FnMut(&H, &[T])) -> Result<usize, TransportError> {
        take_wakeups(&self.name, &self.listener, None)?;
        let mut n = 0;
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(receive_failed(&self.name))?
        {
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
        take_wakeups(&self.name, &self.listener, Some(timeout))?;
        self.drain(on_sample)
    }
}

/// Sending end of a fixed-size message channel (metrics, control, progress).
pub struct ValuePublisher<T: Plain> {
    name: String,
    publisher: Publisher<Ipc, T, ()>,
    notifier: Notifier<Ipc>,
}

impl<T: Plain> ValuePublisher<T> {
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        shape: &ChannelShape,
    ) -> Result<Self, TransportError> {
        let (data, events) = open_value_services::<T>(node, name, shape)?;
        let publisher = data
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(port_failed(name, "publisher"))?;
        let notifier = notifier_port(name, &events)?;
        Ok(Self {
            name: name.to_owned(),
            publisher,
            notifier,
        })
    }

    /// Sends a copy of `value` and wakes the subscribers; a full subscriber misses it.
    pub fn send(&self, value: T) -> Result<usize, TransportError> {
        let delivered = self
            .publisher
            .send_copy(value)
            .map_err(send_failed(&self.name))?;
        self.notifier.notify().map_err(send_failed(&self.name))?;
        Ok(delivered)
    }

    /// Connects new subscribers and hands them the history; call it on a timer.
    pub fn update_connections(&self) -> Result<(), TransportError> {
        update_publisher(&self.name, &self.publisher, &self.notifier)
    }
}

/// Receiving end of a fixed-size message channel.
pub struct ValueSubscriber<T: Plain> {
    name: String,
    subscriber: Subscriber<Ipc, T, ()>,
    listener: Listener<Ipc>,
}

impl<T: Plain> ValueSubscriber<T> {
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        shape: &ChannelShape,
    ) -> Result<Self, TransportError> {
        let (data, events) = open_value_services::<T>(node, name, shape)?;
        let (subscriber, listener) = subscriber_ports(name, shape, &data, &events)?;
        Ok(Self {
            name: name.to_owned(),
            subscriber,
            listener,
        })
    }

    /// The event listener to attach to a [`WaitSet`].
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Clears pending wake-ups and returns every available message in arrival order.
    pub fn drain(&self) -> Result<Vec<T>, TransportError> {
        take_wakeups(&self.name, &self.listener, None)?;
        let mut values = Vec::new();
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(receive_failed(&self.name))?
        {
            values.push(*sample.payload());
        }
        Ok(values)
    }

    /// Blocks up to `timeout` for a wake-up, then drains.
    pub fn wait_and_drain(&self, timeout: Duration) -> Result<Vec<T>, TransportError> {
        take_wakeups(&self.name, &self.listener, Some(timeout))?;
        self.drain()
    }
}

type RpcService<Q, R> =
    iceoryx2::service::port_factory::request_response::PortFactory<Ipc, [u8], Q, [u8], R>;

/// Opens the request–response service and its two wake-up events (`…/requests`, `…/responses`).
fn open_rpc_services<Q, R>(
    node: &Node<Ipc>,
    name: &str,
    max_clients: usize,
) -> Result<(RpcService<Q, R>, EventService, EventService), TransportError>
where
    Q: Plain + Default,
    R: Plain + Default,
{
    let rpc = node
        .service_builder(&service_name(name)?)
        .request_response::<[u8], [u8]>()
        .request_user_header::<Q>()
        .response_user_header::<R>()
        .max_clients(max_clients)
        .max_servers(1)
        .open_or_create()
        .map_err(open_failed(name))?;
    let event =
        |suffix: &str| open_events(node, &format!("{name}/{suffix}"), max_clients, max_clients);
    Ok((rpc, event("requests")?, event("responses")?))
}

/// The answering side of a request–response channel whose bodies are bytes (postcard).
pub struct RpcServer<Q, R>
where
    Q: Plain + Default,
    R: Plain + Default,
{
    name: String,
    server: iceoryx2::port::server::Server<Ipc, [u8], Q, [u8], R>,
    listener: Listener<Ipc>,
    notifier: Notifier<Ipc>,
}

impl<Q, R> RpcServer<Q, R>
where
    Q: Plain + Default,
    R: Plain + Default,
{
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        max_clients: usize,
        max_len: usize,
    ) -> Result<Self, TransportError> {
        let (rpc, requests, responses) = open_rpc_services::<Q, R>(node, name, max_clients)?;
        let server = rpc
            .server_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(port_failed(name, "server"))?;
        let listener = listener_port(name, &requests)?;
        let notifier = notifier_port(name, &responses)?;
        Ok(Self {
            name: name.to_owned(),
            server,
            listener,
            notifier,
        })
    }

    /// The request wake-up listener to attach to a [`WaitSet`].
    pub fn listener(&self) -> &Listener<Ipc> {
        &self.listener
    }

    /// Answers every pending request with `handler(header, body) -> (header, body)`, then wakes
    /// the clients once. Returns how many requests were answered.
    pub fn serve(
        &self,
        mut handler: impl FnMut(&Q, &[u8]) -> (R, Vec<u8>),
    ) -> Result<usize, TransportError> {
        take_wakeups(&self.name, &self.listener, None)?;
        let mut n = 0;
        while let Some(request) = self.server.receive().map_err(receive_failed(&self.name))? {
            let (header, body) = handler(request.user_header(), request.payload());
            let mut response = request
                .loan_slice_uninit(body.len())
                .map_err(receive_failed(&self.name))?;
            *response.user_header_mut() = header;
            response
                .write_from_slice(&body)
                .send()
                .map_err(receive_failed(&self.name))?;
            n += 1;
        }
        if n > 0 {
            self.notifier.notify().map_err(receive_failed(&self.name))?;
        }
        Ok(n)
    }
}

/// How often a waiting [`RpcClient::call`] checks that a server still holds its request.
pub const SERVER_CHECK_INTERVAL: Duration = Duration::from_millis(100);

/// A sent request awaiting its response.
type Pending<Q, R> = iceoryx2::pending_response::PendingResponse<Ipc, [u8], Q, [u8], R>;

/// The asking side of a request–response channel.
pub struct RpcClient<Q, R>
where
    Q: Plain + Default,
    R: Plain + Default,
{
    name: String,
    client: iceoryx2::port::client::Client<Ipc, [u8], Q, [u8], R>,
    notifier: Notifier<Ipc>,
    listener: Listener<Ipc>,
}

impl<Q, R> RpcClient<Q, R>
where
    Q: Plain + Default,
    R: Plain + Default,
{
    pub fn open(
        node: &Node<Ipc>,
        name: &str,
        max_clients: usize,
        max_len: usize,
    ) -> Result<Self, TransportError> {
        let (rpc, requests, responses) = open_rpc_services::<Q, R>(node, name, max_clients)?;
        let client = rpc
            .client_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(port_failed(name, "client"))?;
        let notifier = notifier_port(name, &requests)?;
        let listener = listener_port(name, &responses)?;
        Ok(Self {
            name: name.to_owned(),
            client,
            notifier,
            listener,
        })
    }

    /// Sends one request and waits up to `timeout` for its response. A server that does not
    /// answer in time is a [`TransportError::Receive`] naming the timeout.
    ///
    /// Every [`SERVER_CHECK_INTERVAL`] the wait checks that a server still holds the request;
    /// when none does (there was no server, or the one that got it died and its port was
    /// cleaned up, e.g. by the launcher after a crash), the request is sent again to whichever
    /// server is connected now. So a client waiting on a killed graph-service is answered by
    /// its restarted successor instead of waiting out the whole timeout.
    pub fn call(
        &self,
        header: Q,
        body: &[u8],
        timeout: Duration,
    ) -> Result<(R, Vec<u8>), TransportError> {
        let deadline = std::time::Instant::now() + timeout;
        let mut pending = self.send_request(header, body)?;
        loop {
            if let Some(response) = pending.receive().map_err(receive_failed(&self.name))? {
                return Ok((*response.user_header(), response.payload().to_vec()));
            }
            if !pending.is_connected() {
                // A response sent just before its server let go of the request is kept.
                if let Some(response) = pending.receive().map_err(receive_failed(&self.name))? {
                    return Ok((*response.user_header(), response.payload().to_vec()));
                }
                // Dropped first: it counts against the client's active requests.
                drop(pending);
                pending = self.send_request(header, body)?;
            }
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            if left.is_zero() {
                return Err(receive_failed(&self.name)(format!(
                    "no response within {timeout:?}"
                )));
            }
            self.listener
                .timed_wait(|_| {}, left.min(SERVER_CHECK_INTERVAL))
                .map_err(receive_failed(&self.name))?;
        }
    }

    /// Loans, writes, sends and notifies one request.
    fn send_request(&self, header: Q, body: &[u8]) -> Result<Pending<Q, R>, TransportError> {
        let mut request = self
            .client
            .loan_slice_uninit(body.len())
            .map_err(send_failed(&self.name))?;
        *request.user_header_mut() = header;
        let pending = request
            .write_from_slice(body)
            .send()
            .map_err(send_failed(&self.name))?;
        self.notifier.notify().map_err(send_failed(&self.name))?;
        Ok(pending)
    }
}
