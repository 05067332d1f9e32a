//! The run's channels, sized once from the config so that every process opens them with the
//! same settings (iceoryx2 refuses to open a service with incompatible ones).

use iceoryx2::prelude::*;
use protocol::graph::{GraphRequestHeader, GraphResponseHeader};
use protocol::transport::{
    Backpressure, ChannelShape, Ipc, RpcClient, RpcServer, SlicePublisher, SliceSubscriber,
    TransportError, ValuePublisher, ValueSubscriber,
};
use protocol::{
    Config, ControlMessage, MetricsSample, ProgressMessage, RunId, Service, StepLayout,
    TrajectoryHeader, WeightsHeader,
};

/// Trajectory chunks buffered per subscriber. The throttle keeps the learner at most
/// `replay_slack_steps` (plus one chunk per actor) behind, so this bound is generous; a full
/// buffer drops the chunk for that subscriber, and the drop shows up as a lost chunk.
const TRAJECTORY_BUFFER: usize = 1024;
/// Metrics samples buffered at the launcher between two wake-ups.
const METRICS_BUFFER: usize = 4096;
/// Processes besides actors that may open a channel (learner, graph-service, launcher, tools).
const EXTRA_PORTS: usize = 4;
/// Largest encoded graph request or response, bytes (a full `Dump` of 5 000 nodes fits).
pub const GRAPH_MAX_BYTES: usize = 1 << 20;

pub type TrajectoryPublisher = SlicePublisher<f32, TrajectoryHeader>;
pub type TrajectorySubscriber = SliceSubscriber<f32, TrajectoryHeader>;
pub type WeightsPublisher = SlicePublisher<u8, WeightsHeader>;
pub type WeightsSubscriber = SliceSubscriber<u8, WeightsHeader>;
pub type GraphServer = RpcServer<GraphRequestHeader, GraphResponseHeader>;
pub type GraphClient = RpcClient<GraphRequestHeader, GraphResponseHeader>;

/// Names and shapes of one run's services.
pub struct Channels {
    run_id: RunId,
    max_actors: usize,
    chunk_floats: usize,
}

impl Channels {
    pub fn new(config: &Config, run_id: &RunId, layout: &StepLayout) -> Self {
        Self {
            run_id: run_id.clone(),
            max_actors: config.transport.max_actors,
            chunk_floats: config.transport.chunk_steps as usize * layout.record_len(),
        }
    }

    fn name(&self, service: Service) -> String {
        self.run_id.service_name(service)
    }

    fn shape(&self, max_slice_len: usize, buffer: usize, history: usize) -> ChannelShape {
        ChannelShape {
            max_slice_len,
            subscriber_buffer: buffer,
            history,
            max_publishers: self.max_actors + EXTRA_PORTS,
            max_subscribers: self.max_actors + EXTRA_PORTS,
        }
    }

    pub fn trajectory_publisher(
        &self,
        node: &Node<Ipc>,
    ) -> Result<TrajectoryPublisher, TransportError> {
        let shape = self.shape(self.chunk_floats, TRAJECTORY_BUFFER, 0);
        SlicePublisher::open(
            node,
            &self.name(Service::Trajectories),
            &shape,
            Backpressure::Discard,
        )
    }

    pub fn trajectory_subscriber(
        &self,
        node: &Node<Ipc>,
    ) -> Result<TrajectorySubscriber, TransportError> {
        SliceSubscriber::open(
            node,
            &self.name(Service::Trajectories),
            &self.shape(self.chunk_floats, TRAJECTORY_BUFFER, 0),
        )
    }

    /// `max_bytes`: the size of one weights message (known to the learner).
    pub fn weights_publisher(
        &self,
        node: &Node<Ipc>,
        max_bytes: usize,
    ) -> Result<WeightsPublisher, TransportError> {
        SlicePublisher::open(
            node,
            &self.name(Service::Weights),
            &self.shape(max_bytes, 2, 1),
            Backpressure::Discard,
        )
    }

    pub fn weights_subscriber(
        &self,
        node: &Node<Ipc>,
    ) -> Result<WeightsSubscriber, TransportError> {
        SliceSubscriber::open(node, &self.name(Service::Weights), &self.shape(0, 2, 1))
    }

    pub fn progress_publisher(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValuePublisher<ProgressMessage>, TransportError> {
        ValuePublisher::open(node, &self.name(Service::Progress), &self.shape(0, 4, 1))
    }

    pub fn progress_subscriber(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValueSubscriber<ProgressMessage>, TransportError> {
        ValueSubscriber::open(node, &self.name(Service::Progress), &self.shape(0, 4, 1))
    }

    pub fn metrics_publisher(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValuePublisher<MetricsSample>, TransportError> {
        ValuePublisher::open(
            node,
            &self.name(Service::Metrics),
            &self.shape(0, METRICS_BUFFER, 0),
        )
    }

    pub fn metrics_subscriber(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValueSubscriber<MetricsSample>, TransportError> {
        ValueSubscriber::open(
            node,
            &self.name(Service::Metrics),
            &self.shape(0, METRICS_BUFFER, 0),
        )
    }

    pub fn control_publisher(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValuePublisher<ControlMessage>, TransportError> {
        ValuePublisher::open(node, &self.name(Service::Control), &self.shape(0, 16, 1))
    }

    pub fn control_subscriber(
        &self,
        node: &Node<Ipc>,
    ) -> Result<ValueSubscriber<ControlMessage>, TransportError> {
        ValueSubscriber::open(node, &self.name(Service::Control), &self.shape(0, 16, 1))
    }

    pub fn graph_server(&self, node: &Node<Ipc>) -> Result<GraphServer, TransportError> {
        RpcServer::open(
            node,
            &self.name(Service::Graph),
            self.max_actors + EXTRA_PORTS,
            GRAPH_MAX_BYTES,
        )
    }

    pub fn graph_client(&self, node: &Node<Ipc>) -> Result<GraphClient, TransportError> {
        RpcClient::open(
            node,
            &self.name(Service::Graph),
            self.max_actors + EXTRA_PORTS,
            GRAPH_MAX_BYTES,
        )
    }
}
