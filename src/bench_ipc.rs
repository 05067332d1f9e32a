//! `asi bench ipc`: the transport between real processes, iceoryx2 beside a Unix domain socket.
//!
//! Three measurements, each run once over iceoryx2 (the run's own channels from
//! [`crate::channels`], same shapes and back-pressure as in training) and once over a Unix
//! domain socket carrying the same header and payload bytes, with the same process layout:
//!
//! - **trajectory chunks**: 2 publisher processes (actor-like) send chunks of the real step
//!   record layout of a task as fast as they can for `--seconds`, to 2 subscriber processes
//!   (learner-like and graph-service-like) that read every float. Reported: delivered chunks/s
//!   and MB/s per subscriber, chunks lost (sent − received; iceoryx2 drops a chunk for a
//!   subscriber whose buffer is full, a socket blocks the sender instead), and the sender's
//!   time per chunk.
//! - **weights broadcast**: 1 publisher sends the real policy set (safetensors bytes of the
//!   default config's actor-side networks) every [`WEIGHTS_PERIOD`] to 2 subscribers, which copy
//!   it out; latency = receive time − send time, both `CLOCK_MONOTONIC` (one clock for all
//!   processes of the machine), carried in the payload's first 8 bytes.
//! - **request–response**: 1 client calls 1 server (graph-service-like) in a loop with a small
//!   postcard `GraphRequest::FrontierRoute`, answered by a pre-encoded 8-waypoint route.
//!
//! Each measurement gets its own service namespace (`asi/ipc-<pid>-<hex>-<k>/…`) and socket
//! folder; every worker exits cleanly before the next starts, and at the end the bench checks
//! that no iceoryx2 service of its namespaces is left.
//!
//! Workers are `asi bench ipc-worker --spec <json>` processes. They talk to the bench over
//! pipes: a worker prints `ready` when its ports are open and `result <json>` when done; the
//! bench writes `go` to start senders and closes a worker's stdin to stop it.

use std::cell::Cell;
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context};
use iceoryx2::prelude::*;
use protocol::graph::{
    FrontierRoute, GraphRequestHeader, GraphRequestKind, GraphResponseHeader, GraphStatus,
};
use protocol::{
    ActorId, Config, DecisionKind, GraphRequest, GraphResponse, PhiVersion, PolicyVersion, RunId,
    StepLayout, StepRecord, TrajectoryHeader, WeightsHeader,
};
use serde::{Deserialize, Serialize};

use super::{percentile, services_containing, Table};
use crate::channels::Channels;
use crate::cli::BenchIpcArgs;

/// Interval between two weights messages: far slower than delivery, so every message is
/// measured alone (the learner publishes a few times per second at most).
const WEIGHTS_PERIOD: Duration = Duration::from_millis(20);
/// How long a receiving loop sleeps on its wake-up event before it looks at the stop flag.
const POLL: Duration = Duration::from_millis(50);
/// How long a worker may take to start and open its ports (a debug build on a loaded machine).
const READY_TIMEOUT: Duration = Duration::from_secs(60);
/// Grace period past a measurement's duration for results and exits.
const FINISH_GRACE: Duration = Duration::from_secs(60);
/// An RPC call without an answer within this is an error.
const CALL_TIMEOUT: Duration = Duration::from_secs(5);
/// Longest accepted `--seconds`.
const MAX_SECONDS: f64 = 3600.0;
/// Publisher and subscriber processes of the chunk measurement (as in a 2-actor run).
const N_CHUNK_PUBLISHERS: usize = 2;
const N_CHUNK_SUBSCRIBERS: usize = 2;
/// Subscribers of the weights broadcast (actors and graph-service stand-ins).
const N_WEIGHTS_SUBSCRIBERS: usize = 2;
/// Waypoints of the route in the RPC response.
const RPC_ROUTE_LEN: usize = 8;
/// Seed of the synthetic step values and of the networks whose weights are broadcast.
const SEED: u64 = 0;

/// The two transports compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
enum Transport {
    Iceoryx2,
    Uds,
}

impl Transport {
    const BOTH: [Transport; 2] = [Transport::Iceoryx2, Transport::Uds];

    fn label(self) -> &'static str {
        match self {
            Transport::Iceoryx2 => "iceoryx2",
            Transport::Uds => "UDS",
        }
    }
}

/// How a chunk measurement runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ChunkSetup {
    /// iceoryx2, publishers retry until a full subscriber has room: lossless, like a socket.
    Iceoryx2,
    /// Unix domain socket (blocking writes).
    Uds,
    /// iceoryx2 exactly as in training: a full subscriber misses the chunk (counted as lost).
    Iceoryx2Discard,
}

impl ChunkSetup {
    const ALL: [ChunkSetup; 3] = [
        ChunkSetup::Iceoryx2,
        ChunkSetup::Uds,
        ChunkSetup::Iceoryx2Discard,
    ];

    fn transport(self) -> Transport {
        match self {
            ChunkSetup::Iceoryx2 | ChunkSetup::Iceoryx2Discard => Transport::Iceoryx2,
            ChunkSetup::Uds => Transport::Uds,
        }
    }

    fn label(self) -> &'static str {
        match self {
            ChunkSetup::Iceoryx2 => "iceoryx2 (lossless)",
            ChunkSetup::Uds => "UDS",
            ChunkSetup::Iceoryx2Discard => "iceoryx2 (discard, as in training)",
        }
    }

    /// Prefix of its `name: value` lines.
    fn key(self) -> &'static str {
        match self {
            ChunkSetup::Iceoryx2 => "iceoryx2",
            ChunkSetup::Uds => "uds",
            ChunkSetup::Iceoryx2Discard => "iceoryx2_discard",
        }
    }
}

/// What a worker process does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
enum Role {
    ChunkPublisher,
    ChunkSubscriber,
    WeightsPublisher,
    WeightsSubscriber,
    RpcServer,
    RpcClient,
}

/// A worker's job, passed as JSON on its command line.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct WorkerSpec {
    role: Role,
    transport: Transport,
    /// Index among the workers of its role (the actor id of a chunk publisher).
    index: u32,
    /// The measurement's own run id: names the iceoryx2 services and nodes.
    run_id: String,
    /// Folder of the measurement's sockets.
    socket_dir: PathBuf,
    /// Sending window of publishers and clients, seconds.
    seconds: f64,
    /// Step record dims `[obs, action, goal, latent]` of the chunks.
    dims: [usize; 4],
    /// Steps per chunk.
    chunk_steps: u32,
    /// Length of one weights message, bytes.
    weights_len: usize,
    /// Workers on the other side: subscribers a publisher sends to, publishers a subscriber hears.
    n_peers: usize,
    /// iceoryx2 chunk publishers wait for room in a full subscriber buffer (as a socket
    /// blocks) instead of discarding the chunk for that subscriber (the training setting).
    lossless: bool,
}

impl WorkerSpec {
    fn layout(&self) -> anyhow::Result<StepLayout> {
        let [obs, action, goal, latent] = self.dims;
        Ok(StepLayout::new(obs, action, goal, latent)?)
    }

    /// The run's channels, sized as the default config sizes them for this chunk length.
    fn channels(&self) -> anyhow::Result<Channels> {
        let mut config = Config::default();
        config.transport.chunk_steps = self.chunk_steps;
        Ok(Channels::new(
            &config,
            &RunId::new(&self.run_id)?,
            &self.layout()?,
        ))
    }

    fn node(&self) -> anyhow::Result<Node<protocol::transport::Ipc>> {
        let role = format!("{:?}-{}", self.role, self.index).to_lowercase();
        Ok(protocol::transport::open_node(
            &RunId::new(&self.run_id)?.node_name(&role),
        )?)
    }

    fn socket(&self, what: &str, index: usize) -> PathBuf {
        self.socket_dir.join(format!("{what}-{index}.sock"))
    }
}

/// What a worker reports.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct WorkerResult {
    /// Messages sent (chunks, weights messages, calls).
    sent: u64,
    /// Sending window actually used, seconds.
    elapsed_secs: f64,
    /// Messages received, per sender index (subscribers).
    received: Vec<u64>,
    /// Latencies or round trips, nanoseconds.
    latencies_ns: Vec<u64>,
    /// Sum of every float read (proves the data was touched; not compared).
    checksum: f64,
}

// ---------------------------------------------------------------------------------------------
// The bench: measurements, report.
// ---------------------------------------------------------------------------------------------

/// Runs every measurement and prints the side-by-side table, then `name: value` lines.
pub fn run(args: &BenchIpcArgs) -> anyhow::Result<()> {
    ensure!(
        args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= MAX_SECONDS,
        "--seconds must be in (0, {MAX_SECONDS}], got {}",
        args.seconds
    );
    ensure!(args.chunk_steps >= 1, "--chunk-steps must be at least 1");
    let tasks = if args.tasks.is_empty() {
        vec!["pointmaze-u".to_owned(), "antmaze-u".to_owned()]
    } else {
        args.tasks.clone()
    };
    let layouts = tasks
        .iter()
        .map(|t| task_layout(t).map(|l| (t.clone(), l)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let weights_len = policy_set_bytes()?;
    let mut bench = BenchRun::create(args)?;
    let n_steps = ChunkSetup::ALL.len() * layouts.len() + 4;
    let mut report = Report::default();
    for (task, layout) in &layouts {
        for setup in ChunkSetup::ALL {
            bench.progress(
                n_steps,
                &format!(
                    "{} chunks, {task} ({} floats/chunk)",
                    setup.label(),
                    layout.record_len() * args.chunk_steps as usize
                ),
            );
            let m = bench.chunks(setup, layout)?;
            report.chunks.push((task.clone(), setup, m));
        }
    }
    for transport in Transport::BOTH {
        bench.progress(
            n_steps,
            &format!(
                "{} weights broadcast ({weights_len} bytes)",
                transport.label()
            ),
        );
        report
            .weights
            .push((transport, bench.weights(transport, weights_len)?));
    }
    for transport in Transport::BOTH {
        bench.progress(n_steps, &format!("{} request–response", transport.label()));
        report.rpc.push((transport, bench.rpc(transport)?));
    }
    let leftovers = bench.leftovers();
    report.print(args, weights_len, leftovers.len());
    ensure!(
        leftovers.is_empty(),
        "iceoryx2 services left behind: {}",
        leftovers.join(", ")
    );
    Ok(())
}

/// The step layout of `task` under the default config's latent size.
fn task_layout(task: &str) -> anyhow::Result<StepLayout> {
    let mut config = Config::default();
    config.env.task = task.to_owned();
    Ok(crate::proc::common::task_info(&config)?.layout)
}

/// Bytes of one weights message of the default config: the actor-side networks
/// (encoder, high policy, low policy) as safetensors, exactly what the learner publishes.
fn policy_set_bytes() -> anyhow::Result<usize> {
    let config = Config::default();
    let dims = crate::proc::common::task_info(&config)?.dims;
    let spec = nets::spec_from_config(&config, dims)?;
    let networks = learner::setup::build_networks(&config, &spec, SEED)?;
    Ok(nets::to_safetensors_bytes(&networks.policy_vm)?.len())
}

/// One chunk measurement, both sides.
struct ChunkMeasurement {
    chunk_bytes: usize,
    publishers: Vec<WorkerResult>,
    subscribers: Vec<WorkerResult>,
}

impl ChunkMeasurement {
    fn window_secs(&self) -> f64 {
        self.publishers
            .iter()
            .map(|p| p.elapsed_secs)
            .fold(0.0, f64::max)
    }

    fn sent(&self) -> u64 {
        self.publishers.iter().map(|p| p.sent).sum()
    }

    /// Mean over subscribers of the chunks each received per second of the sending window.
    fn delivered_per_sec(&self) -> f64 {
        let received: u64 = self
            .subscribers
            .iter()
            .map(|s| s.received.iter().sum::<u64>())
            .sum();
        received as f64
            / self.subscribers.len().max(1) as f64
            / self.window_secs().max(f64::MIN_POSITIVE)
    }

    /// Chunks sent but not received, summed over subscribers.
    fn lost(&self) -> u64 {
        let received: u64 = self
            .subscribers
            .iter()
            .map(|s| s.received.iter().sum::<u64>())
            .sum();
        (self.sent() * self.subscribers.len() as u64).saturating_sub(received)
    }

    /// Publisher wall time per chunk sent, microseconds: Σ sending windows / Σ chunks sent.
    /// For a publisher that never waits (discard) this is its cost of sending one chunk on
    /// this machine; for a blocking one it is the inverse of its delivered rate.
    fn send_us_per_chunk(&self) -> f64 {
        let secs: f64 = self.publishers.iter().map(|p| p.elapsed_secs).sum();
        secs * 1e6 / self.sent().max(1) as f64
    }
}

/// p50, p99 and count of a set of latencies, microseconds.
#[derive(Debug, Clone, Copy, Default)]
struct LatencySummary {
    p50_us: f64,
    p99_us: f64,
    count: usize,
}

impl LatencySummary {
    fn of(results: &[WorkerResult]) -> Self {
        let mut all: Vec<u64> = results
            .iter()
            .flat_map(|r| r.latencies_ns.iter().copied())
            .collect();
        all.sort_unstable();
        let us = |p| percentile(&all, p).map_or(f64::NAN, |ns| ns as f64 / 1e3);
        Self {
            p50_us: us(50.0),
            p99_us: us(99.0),
            count: all.len(),
        }
    }
}

/// Everything measured, printed at the end.
#[derive(Default)]
struct Report {
    chunks: Vec<(String, ChunkSetup, ChunkMeasurement)>,
    weights: Vec<(Transport, LatencySummary)>,
    rpc: Vec<(Transport, LatencySummary)>,
}

impl Report {
    fn chunk(&self, task: &str, setup: ChunkSetup) -> Option<&ChunkMeasurement> {
        self.chunks
            .iter()
            .find(|(t, s, _)| t == task && *s == setup)
            .map(|(_, _, m)| m)
    }

    fn latency(list: &[(Transport, LatencySummary)], transport: Transport) -> LatencySummary {
        list.iter()
            .find(|(t, _)| *t == transport)
            .map(|(_, s)| *s)
            .unwrap_or_default()
    }

    fn print(&self, args: &BenchIpcArgs, weights_len: usize, n_leftovers: usize) {
        println!("{}", self.table(weights_len).render());
        println!("ratio = iceoryx2 / UDS (rates: above 1 is better; latencies: below 1 is better)");
        println!("seconds_per_measurement: {}", args.seconds);
        println!("chunk_steps: {}", args.chunk_steps);
        println!("weights_bytes: {weights_len}");
        for (task, setup, m) in &self.chunks {
            let key = format!("{}_{task}", setup.key());
            println!("{key}_chunk_bytes: {}", m.chunk_bytes);
            println!("{key}_chunks_per_sec: {:.0}", m.delivered_per_sec());
            println!(
                "{key}_mb_per_sec: {:.1}",
                m.delivered_per_sec() * m.chunk_bytes as f64 / 1e6
            );
            println!("{key}_lost_chunks: {}", m.lost());
            println!("{key}_sent_chunks: {}", m.sent());
            println!("{key}_send_us_per_chunk: {:.2}", m.send_us_per_chunk());
        }
        for (name, list) in [("weights", &self.weights), ("rpc", &self.rpc)] {
            for (transport, s) in list {
                let key = format!("{}_{name}", key_of(*transport));
                println!("{key}_p50_us: {:.1}", s.p50_us);
                println!("{key}_p99_us: {:.1}", s.p99_us);
                println!("{key}_samples: {}", s.count);
            }
        }
        println!("leftover_services: {n_leftovers}");
    }

    fn table(&self, weights_len: usize) -> Table {
        let mut table = Table::new(&["measurement", "iceoryx2", "UDS", "ratio"]);
        let mut tasks: Vec<&str> = self.chunks.iter().map(|(t, _, _)| t.as_str()).collect();
        tasks.dedup();
        for task in tasks {
            let chunk = |setup| self.chunk(task, setup);
            let (Some(iox), Some(uds), Some(discard)) = (
                chunk(ChunkSetup::Iceoryx2),
                chunk(ChunkSetup::Uds),
                chunk(ChunkSetup::Iceoryx2Discard),
            ) else {
                continue;
            };
            let kb = iox.chunk_bytes as f64 / 1e3;
            let rate = |m: &ChunkMeasurement| m.delivered_per_sec();
            let mbs = |m: &ChunkMeasurement| m.delivered_per_sec() * m.chunk_bytes as f64 / 1e6;
            table.push(&row(
                &format!("{task} chunks/s per subscriber ({kb:.1} kB)"),
                rate(iox),
                rate(uds),
                0,
            ));
            table.push(&row(
                &format!("{task} MB/s per subscriber"),
                mbs(iox),
                mbs(uds),
                1,
            ));
            table.push(&[
                format!("{task} lost chunks"),
                lost_text(iox),
                lost_text(uds),
                String::new(),
            ]);
            let training = format!("{task} discard (training setting):");
            table.push(&[
                format!("{training} chunks/s"),
                format!("{:.0}", rate(discard)),
                String::new(),
                String::new(),
            ]);
            table.push(&[
                format!("{training} lost chunks"),
                lost_text(discard),
                String::new(),
                String::new(),
            ]);
            table.push(&[
                format!("{training} sender µs per chunk"),
                format!("{:.2}", discard.send_us_per_chunk()),
                String::new(),
                String::new(),
            ]);
        }
        let kb = weights_len as f64 / 1e3;
        for (name, list) in [
            (format!("weights broadcast ({kb:.0} kB)"), &self.weights),
            ("request–response round trip".to_owned(), &self.rpc),
        ] {
            let (iox, uds) = (
                Self::latency(list, Transport::Iceoryx2),
                Self::latency(list, Transport::Uds),
            );
            table.push(&row(&format!("{name} p50 µs"), iox.p50_us, uds.p50_us, 1));
            table.push(&row(&format!("{name} p99 µs"), iox.p99_us, uds.p99_us, 1));
            table.push(&[
                format!("{name} samples"),
                iox.count.to_string(),
                uds.count.to_string(),
                String::new(),
            ]);
        }
        table
    }
}

/// `lost of expected (percent)`, expected = chunks sent × subscribers.
fn lost_text(m: &ChunkMeasurement) -> String {
    let expected = m.sent() * m.subscribers.len() as u64;
    format!(
        "{} of {expected} ({:.1} %)",
        m.lost(),
        100.0 * m.lost() as f64 / expected.max(1) as f64
    )
}

/// A table row `label, iox, uds, iox/uds` with `decimals` digits.
fn row(label: &str, iox: f64, uds: f64, decimals: usize) -> [String; 4] {
    [
        label.to_owned(),
        format!("{iox:.decimals$}"),
        format!("{uds:.decimals$}"),
        format!("{:.2}", iox / uds),
    ]
}

fn key_of(transport: Transport) -> &'static str {
    match transport {
        Transport::Iceoryx2 => "iceoryx2",
        Transport::Uds => "uds",
    }
}

/// One `asi bench ipc` invocation: its id, socket folder and measurement counter.
struct BenchRun {
    base_id: String,
    socket_root: PathBuf,
    seconds: f64,
    chunk_steps: u32,
    n_done: usize,
    node: Node<protocol::transport::Ipc>,
}

impl BenchRun {
    fn create(args: &BenchIpcArgs) -> anyhow::Result<Self> {
        let base_id = format!("ipc-{}-{:08x}", std::process::id(), rand::random::<u32>());
        let socket_root = std::env::temp_dir().join(format!("asi-bench-{base_id}"));
        std::fs::create_dir_all(&socket_root)
            .with_context(|| format!("creating {}", socket_root.display()))?;
        let node = protocol::transport::open_node(&RunId::new(&base_id)?.node_name("bench"))?;
        Ok(Self {
            base_id,
            socket_root,
            seconds: args.seconds,
            chunk_steps: args.chunk_steps,
            n_done: 0,
            node,
        })
    }

    fn progress(&self, n_steps: usize, what: &str) {
        eprintln!(
            "[{}/{n_steps}] {what}: {:.1} s …",
            self.n_done + 1,
            self.seconds
        );
    }

    /// A fresh spec for the next measurement's workers (own run id and socket folder).
    fn next_spec(
        &mut self,
        transport: Transport,
        layout: &StepLayout,
        weights_len: usize,
    ) -> anyhow::Result<WorkerSpec> {
        self.n_done += 1;
        let socket_dir = self.socket_root.join(format!("m{}", self.n_done));
        std::fs::create_dir_all(&socket_dir)
            .with_context(|| format!("creating {}", socket_dir.display()))?;
        Ok(WorkerSpec {
            role: Role::ChunkPublisher,
            transport,
            index: 0,
            run_id: format!("{}-{}", self.base_id, self.n_done),
            socket_dir,
            seconds: self.seconds,
            dims: [
                layout.obs_dim,
                layout.action_dim,
                layout.goal_dim,
                layout.latent_dim,
            ],
            chunk_steps: self.chunk_steps,
            weights_len,
            n_peers: 0,
            lossless: true,
        })
    }

    fn chunks(
        &mut self,
        setup: ChunkSetup,
        layout: &StepLayout,
    ) -> anyhow::Result<ChunkMeasurement> {
        let mut spec = self.next_spec(setup.transport(), layout, 0)?;
        spec.lossless = setup != ChunkSetup::Iceoryx2Discard;
        let receivers = workers_of(
            &spec,
            Role::ChunkSubscriber,
            N_CHUNK_SUBSCRIBERS,
            N_CHUNK_PUBLISHERS,
        );
        let senders = workers_of(
            &spec,
            Role::ChunkPublisher,
            N_CHUNK_PUBLISHERS,
            N_CHUNK_SUBSCRIBERS,
        );
        // iceoryx2: publishers first. A subscriber attaches its end of a publisher's connection
        // when it is created or next receives; a publisher whose subscriber has not attached
        // yet fills that subscriber's buffer and then, with safe overflow off, *skips* it (no
        // error: the receiver counts as not connected). Subscribers created after the
        // publishers attach at creation, so nothing is skipped. Sockets need the listener
        // first.
        let order = match setup.transport() {
            Transport::Iceoryx2 => StartOrder::SendersFirst,
            Transport::Uds => StartOrder::ReceiversFirst,
        };
        let (publishers, subscribers) = run_measurement(&receivers, &senders, order, self.seconds)?;
        let floats = layout.record_len() * self.chunk_steps as usize;
        let chunk_bytes =
            std::mem::size_of::<TrajectoryHeader>() + floats * std::mem::size_of::<f32>();
        Ok(ChunkMeasurement {
            chunk_bytes,
            publishers,
            subscribers,
        })
    }

    fn weights(
        &mut self,
        transport: Transport,
        weights_len: usize,
    ) -> anyhow::Result<LatencySummary> {
        let layout = task_layout("pointmaze-u")?;
        let spec = self.next_spec(transport, &layout, weights_len)?;
        let receivers = workers_of(&spec, Role::WeightsSubscriber, N_WEIGHTS_SUBSCRIBERS, 1);
        let senders = workers_of(&spec, Role::WeightsPublisher, 1, N_WEIGHTS_SUBSCRIBERS);
        let (_, subscribers) = run_measurement(
            &receivers,
            &senders,
            StartOrder::ReceiversFirst,
            self.seconds,
        )?;
        Ok(LatencySummary::of(&subscribers))
    }

    fn rpc(&mut self, transport: Transport) -> anyhow::Result<LatencySummary> {
        let layout = task_layout("pointmaze-u")?;
        let spec = self.next_spec(transport, &layout, 0)?;
        let receivers = workers_of(&spec, Role::RpcServer, 1, 1);
        let senders = workers_of(&spec, Role::RpcClient, 1, 1);
        let (clients, _) = run_measurement(
            &receivers,
            &senders,
            StartOrder::ReceiversFirst,
            self.seconds,
        )?;
        Ok(LatencySummary::of(&clients))
    }

    /// Removes what dead nodes left and lists the services of this bench still present.
    fn leftovers(&self) -> Vec<String> {
        let _ = self.node.try_cleanup_dead_nodes();
        services_containing(&self.base_id)
    }
}

impl Drop for BenchRun {
    /// Also on errors: removes iceoryx2 resources of killed workers and the socket folder.
    fn drop(&mut self) {
        let _ = self.node.try_cleanup_dead_nodes();
        if let Err(err) = std::fs::remove_dir_all(&self.socket_root) {
            tracing::warn!("could not remove {}: {err}", self.socket_root.display());
        }
    }
}

/// `n` specs of `role`, indices 0…n−1, each with `n_peers` on the other side.
fn workers_of(template: &WorkerSpec, role: Role, n: usize, n_peers: usize) -> Vec<WorkerSpec> {
    (0..n)
        .map(|index| WorkerSpec {
            role,
            index: index as u32,
            n_peers,
            ..template.clone()
        })
        .collect()
}

/// Which side of a measurement opens its ports first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StartOrder {
    ReceiversFirst,
    SendersFirst,
}

/// Starts the workers of both sides in `order`, each side ready before the other starts; lets
/// the senders go together; collects the senders' results, stops the receivers and collects
/// theirs, then lets the senders exit.
fn run_measurement(
    receivers: &[WorkerSpec],
    senders: &[WorkerSpec],
    order: StartOrder,
    seconds: f64,
) -> anyhow::Result<(Vec<WorkerResult>, Vec<WorkerResult>)> {
    let finish = Duration::from_secs_f64(seconds) + FINISH_GRACE;
    let start = |specs: &[WorkerSpec]| -> anyhow::Result<Vec<Worker>> {
        let mut workers: Vec<Worker> = specs
            .iter()
            .map(Worker::spawn)
            .collect::<anyhow::Result<_>>()?;
        for worker in &mut workers {
            worker.expect("ready", READY_TIMEOUT)?;
        }
        Ok(workers)
    };
    let (mut rx, mut tx) = match order {
        StartOrder::ReceiversFirst => {
            let rx = start(receivers)?;
            (rx, start(senders)?)
        }
        StartOrder::SendersFirst => {
            let tx = start(senders)?;
            (start(receivers)?, tx)
        }
    };
    for worker in &mut tx {
        worker.tell("go")?;
    }
    let sent = tx
        .iter_mut()
        .map(|w| w.result(finish))
        .collect::<anyhow::Result<Vec<_>>>()?;
    rx.iter_mut().for_each(Worker::stop);
    let received = rx
        .iter_mut()
        .map(|w| w.result(finish))
        .collect::<anyhow::Result<Vec<_>>>()?;
    tx.iter_mut().for_each(Worker::stop);
    for worker in rx.iter_mut().chain(tx.iter_mut()) {
        worker.wait_exit(FINISH_GRACE)?;
    }
    Ok((sent, received))
}

/// A running worker process: its stdin (commands) and a channel of its stdout lines.
struct Worker {
    label: String,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: mpsc::Receiver<String>,
}

impl Worker {
    fn spawn(spec: &WorkerSpec) -> anyhow::Result<Self> {
        let label = format!("{:?} {} of {}", spec.role, spec.index, spec.run_id);
        let exe = std::env::current_exe().context("locating the asi executable")?;
        let mut child = Command::new(exe)
            .args([
                "bench",
                "ipc-worker",
                "--spec",
                &serde_json::to_string(spec)?,
            ])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting worker {label}"))?;
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().context("worker stdout")?;
        let (send, lines) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if send.send(line).is_err() {
                    break;
                }
            }
        });
        Ok(Self {
            label,
            child,
            stdin,
            lines,
        })
    }

    /// Waits for a line starting with `prefix` and returns the rest of it.
    fn expect(&mut self, prefix: &str, timeout: Duration) -> anyhow::Result<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    if let Some(rest) = line.strip_prefix(prefix) {
                        return Ok(rest.trim().to_owned());
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => bail!(
                    "worker {} sent no `{prefix}` within {timeout:?}",
                    self.label
                ),
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    let status = self.child.wait().ok();
                    bail!(
                        "worker {} exited ({status:?}) before `{prefix}`; its error is above",
                        self.label
                    )
                }
            }
        }
    }

    fn result(&mut self, timeout: Duration) -> anyhow::Result<WorkerResult> {
        let json = self.expect("result", timeout)?;
        serde_json::from_str(&json)
            .with_context(|| format!("result of worker {}: {json}", self.label))
    }

    fn tell(&mut self, command: &str) -> anyhow::Result<()> {
        let stdin = self.stdin.as_mut().context("worker stdin already closed")?;
        writeln!(stdin, "{command}")
            .with_context(|| format!("telling worker {} `{command}`", self.label))
    }

    /// Closes the worker's stdin: its signal to finish.
    fn stop(&mut self) {
        self.stdin = None;
    }

    fn wait_exit(&mut self, timeout: Duration) -> anyhow::Result<()> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(status) = self.child.try_wait()? {
                ensure!(
                    status.success(),
                    "worker {} exited with {status}",
                    self.label
                );
                return Ok(());
            }
            ensure!(
                Instant::now() < deadline,
                "worker {} did not exit within {timeout:?}",
                self.label
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

impl Drop for Worker {
    /// A worker still running here means the measurement failed: end it.
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The worker side.
// ---------------------------------------------------------------------------------------------

/// `asi bench ipc-worker --spec <json>`: runs one role and prints its result.
pub fn run_worker(spec_json: &str) -> anyhow::Result<()> {
    let spec: WorkerSpec = serde_json::from_str(spec_json)
        .context("parsing the worker spec (this command is started by `asi bench ipc`)")?;
    let control = Control::watch_stdin();
    let result = match (spec.role, spec.transport) {
        (Role::ChunkPublisher, Transport::Iceoryx2) => iox::chunk_publisher(&spec, &control),
        (Role::ChunkSubscriber, Transport::Iceoryx2) => iox::chunk_subscriber(&spec, &control),
        (Role::WeightsPublisher, Transport::Iceoryx2) => iox::weights_publisher(&spec, &control),
        (Role::WeightsSubscriber, Transport::Iceoryx2) => iox::weights_subscriber(&spec, &control),
        (Role::RpcServer, Transport::Iceoryx2) => iox::rpc_server(&spec, &control),
        (Role::RpcClient, Transport::Iceoryx2) => iox::rpc_client(&spec, &control),
        (Role::ChunkPublisher, Transport::Uds) => uds::chunk_publisher(&spec, &control),
        (Role::ChunkSubscriber, Transport::Uds) => uds::chunk_subscriber(&spec),
        (Role::WeightsPublisher, Transport::Uds) => uds::weights_publisher(&spec, &control),
        (Role::WeightsSubscriber, Transport::Uds) => uds::weights_subscriber(&spec),
        (Role::RpcServer, Transport::Uds) => uds::rpc_server(&spec),
        (Role::RpcClient, Transport::Uds) => uds::rpc_client(&spec, &control),
    }
    .with_context(|| format!("{:?} over {}", spec.role, spec.transport.label()))?;
    if !control.reported() {
        control.report(&result)?;
    }
    control.wait_stop();
    Ok(())
}

/// The bench's commands on stdin: `go` starts sending; end of input means stop.
struct Control {
    go: mpsc::Receiver<()>,
    stopped: Arc<AtomicBool>,
    /// The `result` line has been printed (only the worker's main thread reads or sets it).
    reported: Cell<bool>,
}

impl Control {
    fn watch_stdin() -> Self {
        let (send, go) = mpsc::channel();
        let stopped = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stopped);
        std::thread::spawn(move || {
            for line in std::io::stdin().lock().lines().map_while(Result::ok) {
                if line.trim() == "go" {
                    let _ = send.send(());
                }
            }
            flag.store(true, Ordering::SeqCst);
        });
        Self {
            go,
            stopped,
            reported: Cell::new(false),
        }
    }

    fn ready(&self) {
        println!("ready");
    }

    /// Blocks until `go` (an error if the bench went away first).
    fn wait_go(&self) -> anyhow::Result<()> {
        self.go.recv().context("the bench closed stdin before `go`")
    }

    fn stopped(&self) -> bool {
        self.stopped.load(Ordering::SeqCst)
    }

    /// Prints the worker's `result` line for the bench.
    fn report(&self, result: &WorkerResult) -> anyhow::Result<()> {
        println!("result {}", serde_json::to_string(result)?);
        self.reported.set(true);
        Ok(())
    }

    fn reported(&self) -> bool {
        self.reported.get()
    }

    /// A sender's end: reports `result`, then waits for the bench's stop *while the caller
    /// still holds its ports*. The bench stops senders only after every receiver has drained
    /// and reported; a publisher dropped before that disconnects from subscribers that may
    /// still hold its chunks, and some of those were seen lost (a few hundred chunks in one
    /// run of several, on a loaded machine).
    fn report_and_hold(&self, result: WorkerResult) -> anyhow::Result<WorkerResult> {
        self.report(&result)?;
        self.wait_stop();
        Ok(result)
    }

    fn wait_stop(&self) {
        while !self.stopped() {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// `CLOCK_MONOTONIC` in nanoseconds: one clock shared by every process of the machine.
fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec into the valid pointer given.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A chunk payload of `spec.chunk_steps` real step records with seeded random values.
fn chunk_payload(spec: &WorkerSpec) -> anyhow::Result<(StepLayout, Vec<f32>)> {
    use rand::{Rng, SeedableRng};
    let layout = spec.layout()?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(SEED + u64::from(spec.index));
    let mut v = |n: usize| {
        (0..n)
            .map(|_| rng.random_range(-1.0f32..1.0))
            .collect::<Vec<f32>>()
    };
    let records: Vec<StepRecord> = (0..spec.chunk_steps)
        .map(|t| StepRecord {
            obs: v(layout.obs_dim),
            next_obs: v(layout.obs_dim),
            phi: v(layout.latent_dim),
            next_phi: v(layout.latent_dim),
            subgoal: v(layout.latent_dim),
            high_action: v(layout.latent_dim),
            action: v(layout.action_dim),
            goal: v(layout.goal_dim),
            achieved_goal: v(layout.goal_dim),
            reward: -1.0,
            decision: if t % 10 == 0 {
                DecisionKind::Policy
            } else {
                DecisionKind::None
            },
            success: false,
            terminated: false,
            truncated: false,
        })
        .collect();
    let payload = layout.encode_chunk(&records)?;
    Ok((layout, payload))
}

fn chunk_header(spec: &WorkerSpec, layout: &StepLayout) -> anyhow::Result<TrajectoryHeader> {
    let mut header = TrajectoryHeader::for_layout(layout)?;
    header.actor_id = ActorId(spec.index);
    header.n_steps = spec.chunk_steps;
    Ok(header)
}

/// A weights payload of the right length (its content does not matter to the transport).
fn weights_header(len: usize, version: u64) -> WeightsHeader {
    WeightsHeader {
        policy_version: PolicyVersion(version),
        byte_len: len as u64,
        ..WeightsHeader::default()
    }
}

/// The small request and the route answer of the RPC measurement, postcard-encoded.
fn rpc_bodies() -> anyhow::Result<(Vec<u8>, Vec<u8>)> {
    let request = protocol::encode(&GraphRequest::FrontierRoute { from: [0.25, -1.5] })?;
    let route: Vec<[f32; 2]> = (0..RPC_ROUTE_LEN)
        .map(|i| [i as f32 * 0.5, 1.0 - i as f32 * 0.25])
        .collect();
    let answer = GraphResponse::FrontierRoute(Ok(FrontierRoute {
        frontier: route[RPC_ROUTE_LEN - 1],
        route,
        distance: 3.5,
    }));
    Ok((request, protocol::encode(&answer)?))
}

/// The server's answer to one request: decodes it as the graph-service would.
fn answer(
    header: &GraphRequestHeader,
    body: &[u8],
    response: &[u8],
) -> anyhow::Result<(GraphResponseHeader, Vec<u8>)> {
    ensure!(
        header.kind()? == GraphRequestKind::FrontierRoute,
        "unexpected request kind"
    );
    let request: GraphRequest = protocol::decode(body)?;
    request.check_finite()?;
    Ok((
        GraphResponseHeader::answering(header, GraphStatus::Ok, 1, PhiVersion(0)),
        response.to_vec(),
    ))
}

/// Sends until the window closes or the bench stops the worker; returns (sent, seconds).
fn send_for(
    spec: &WorkerSpec,
    control: &Control,
    mut send_one: impl FnMut(u64) -> anyhow::Result<()>,
) -> anyhow::Result<(u64, f64)> {
    control.wait_go()?;
    let window = Duration::from_secs_f64(spec.seconds);
    let start = Instant::now();
    let mut sent = 0;
    while start.elapsed() < window && !control.stopped() {
        send_one(sent)?;
        sent += 1;
    }
    Ok((sent, start.elapsed().as_secs_f64()))
}

mod iox {
    //! The iceoryx2 side of each role, over the run's own channel types.

    use super::*;

    pub(super) fn chunk_publisher(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let (layout, payload) = chunk_payload(spec)?;
        let node = spec.node()?;
        if spec.lossless {
            return lossless::chunk_publisher(spec, control, &node, &layout, &payload);
        }
        let publisher = spec.channels()?.trajectory_publisher(&node)?;
        let mut header = chunk_header(spec, &layout)?;
        control.ready();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            header.first_env_step = seq;
            header.chunk_index = seq as u32;
            publisher.send(header, &payload)?;
            Ok(())
        })?;
        control.report_and_hold(WorkerResult {
            sent,
            elapsed_secs,
            ..WorkerResult::default()
        })
    }

    pub(super) fn chunk_subscriber(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let node = spec.node()?;
        if spec.lossless {
            return lossless::chunk_subscriber(spec, control, &node);
        }
        let subscriber = spec.channels()?.trajectory_subscriber(&node)?;
        control.ready();
        let mut result = WorkerResult {
            received: vec![0; spec.n_peers],
            ..WorkerResult::default()
        };
        loop {
            let stopping = control.stopped();
            subscriber.wait_and_drain(POLL, |header, payload| {
                count_chunk(&mut result, header, payload);
            })?;
            if stopping {
                return Ok(result);
            }
        }
    }

    pub(super) fn weights_publisher(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let node = spec.node()?;
        let publisher = spec
            .channels()?
            .weights_publisher(&node, spec.weights_len)?;
        let mut payload = vec![0u8; spec.weights_len];
        control.ready();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            payload[..8].copy_from_slice(&monotonic_ns().to_ne_bytes());
            publisher.send(weights_header(payload.len(), seq), &payload)?;
            std::thread::sleep(WEIGHTS_PERIOD);
            Ok(())
        })?;
        control.report_and_hold(WorkerResult {
            sent,
            elapsed_secs,
            ..WorkerResult::default()
        })
    }

    pub(super) fn weights_subscriber(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let node = spec.node()?;
        let subscriber = spec.channels()?.weights_subscriber(&node)?;
        control.ready();
        let mut result = WorkerResult {
            received: vec![0; 1],
            ..WorkerResult::default()
        };
        loop {
            let stopping = control.stopped();
            subscriber.wait_and_drain(POLL, |_, bytes| {
                let copy = bytes.to_vec();
                record_weights(&mut result, &copy);
            })?;
            if stopping {
                return Ok(result);
            }
        }
    }

    pub(super) fn rpc_server(spec: &WorkerSpec, control: &Control) -> anyhow::Result<WorkerResult> {
        let (_, response) = rpc_bodies()?;
        let node = spec.node()?;
        let server = spec.channels()?.graph_server(&node)?;
        control.ready();
        let mut result = WorkerResult {
            received: vec![0; 1],
            ..WorkerResult::default()
        };
        let mut failure = None;
        loop {
            let stopping = control.stopped();
            server
                .listener()
                .timed_wait(|_| {}, POLL)
                .map_err(|e| anyhow::anyhow!("waiting for requests: {e:?}"))?;
            let n = server.serve(|header, body| {
                answer(header, body, &response).unwrap_or_else(|err| {
                    failure = Some(err);
                    (
                        GraphResponseHeader::answering(
                            header,
                            GraphStatus::InvalidRequest,
                            1,
                            PhiVersion(0),
                        ),
                        Vec::new(),
                    )
                })
            })?;
            result.received[0] += n as u64;
            if let Some(err) = failure.take() {
                return Err(err);
            }
            if stopping {
                return Ok(result);
            }
        }
    }

    pub(super) fn rpc_client(spec: &WorkerSpec, control: &Control) -> anyhow::Result<WorkerResult> {
        let (request, _) = rpc_bodies()?;
        let node = spec.node()?;
        let client = spec.channels()?.graph_client(&node)?;
        control.ready();
        let mut latencies_ns = Vec::new();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            let header =
                GraphRequestHeader::new(seq, GraphRequestKind::FrontierRoute, PhiVersion(0));
            let start = Instant::now();
            let (reply, body) = client.call(header, &request, CALL_TIMEOUT)?;
            latencies_ns.push(start.elapsed().as_nanos() as u64);
            check_reply(&reply, &body, seq)
        })?;
        Ok(WorkerResult {
            sent,
            elapsed_secs,
            latencies_ns,
            ..WorkerResult::default()
        })
    }
}

mod lossless {
    //! The trajectory channel with iceoryx2's safe overflow off and publishers that retry
    //! until a full subscriber has room: nothing is lost, a slow subscriber slows the senders
    //! (as a socket does). The run's channels keep iceoryx2's default, safe overflow on: a full
    //! subscriber buffer drops its *oldest* chunk, whatever the port's back-pressure strategy.
    //! Raw iceoryx2 here, because `protocol::transport` does not expose that service setting.

    use iceoryx2::port::listener::Listener;
    use iceoryx2::port::notifier::Notifier;
    use iceoryx2::port::publisher::Publisher;
    use iceoryx2::service::port_factory::{event, publish_subscribe};
    use protocol::transport::Ipc;
    use protocol::Service;

    use super::*;

    /// Chunks buffered per subscriber, as on the run's trajectory channel.
    const BUFFER: usize = 1024;

    type Services = (
        publish_subscribe::PortFactory<Ipc, [f32], TrajectoryHeader>,
        event::PortFactory<Ipc>,
    );

    fn services(spec: &WorkerSpec, node: &Node<Ipc>) -> anyhow::Result<Services> {
        let name = RunId::new(&spec.run_id)?.service_name(Service::Trajectories);
        let service =
            ServiceName::new(&name).map_err(|e| anyhow::anyhow!("service name {name}: {e:?}"))?;
        let n = N_CHUNK_PUBLISHERS.max(N_CHUNK_SUBSCRIBERS);
        let data = node
            .service_builder(&service)
            .publish_subscribe::<[f32]>()
            .user_header::<TrajectoryHeader>()
            .enable_safe_overflow(false)
            .history_size(0)
            .subscriber_max_buffer_size(BUFFER)
            .max_publishers(n)
            .max_subscribers(n)
            .open_or_create()
            .map_err(|e| anyhow::anyhow!("opening {name}: {e:?}"))?;
        let events = node
            .service_builder(&service)
            .event()
            .max_notifiers(n + 1)
            .max_listeners(n + 1)
            .open_or_create()
            .map_err(|e| anyhow::anyhow!("opening the events of {name}: {e:?}"))?;
        Ok((data, events))
    }

    fn send(
        publisher: &Publisher<Ipc, [f32], TrajectoryHeader>,
        notifier: &Notifier<Ipc>,
        header: TrajectoryHeader,
        payload: &[f32],
    ) -> anyhow::Result<()> {
        let mut sample = publisher
            .loan_slice_uninit(payload.len())
            .map_err(|e| anyhow::anyhow!("loan: {e:?}"))?;
        *sample.user_header_mut() = header;
        sample
            .write_from_slice(payload)
            .send()
            .map_err(|e| anyhow::anyhow!("send: {e:?}"))?;
        notifier
            .notify()
            .map_err(|e| anyhow::anyhow!("notify: {e:?}"))?;
        Ok(())
    }

    pub(super) fn chunk_publisher(
        spec: &WorkerSpec,
        control: &Control,
        node: &Node<Ipc>,
        layout: &StepLayout,
        payload: &[f32],
    ) -> anyhow::Result<WorkerResult> {
        let (data, events) = services(spec, node)?;
        let publisher = data
            .publisher_builder()
            .initial_max_slice_len(payload.len())
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .create()
            .map_err(|e| anyhow::anyhow!("publisher: {e:?}"))?;
        let notifier = events
            .notifier_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("notifier: {e:?}"))?;
        let mut header = chunk_header(spec, layout)?;
        control.ready();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            header.first_env_step = seq;
            header.chunk_index = seq as u32;
            send(&publisher, &notifier, header, payload)
        })?;
        control.report_and_hold(WorkerResult {
            sent,
            elapsed_secs,
            ..WorkerResult::default()
        })
    }

    pub(super) fn chunk_subscriber(
        spec: &WorkerSpec,
        control: &Control,
        node: &Node<Ipc>,
    ) -> anyhow::Result<WorkerResult> {
        let (data, events) = services(spec, node)?;
        let subscriber = data
            .subscriber_builder()
            .buffer_size(BUFFER)
            .create()
            .map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
        let listener: Listener<Ipc> = events
            .listener_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("listener: {e:?}"))?;
        control.ready();
        let mut result = WorkerResult {
            received: vec![0; spec.n_peers],
            ..WorkerResult::default()
        };
        loop {
            let stopping = control.stopped();
            listener
                .timed_wait(|_| {}, POLL)
                .map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
            while let Some(sample) = subscriber
                .receive()
                .map_err(|e| anyhow::anyhow!("receive: {e:?}"))?
            {
                count_chunk(&mut result, sample.user_header(), sample.payload());
            }
            if stopping {
                return Ok(result);
            }
        }
    }
}

/// Counts a chunk for its sender and reads every float.
fn count_chunk(result: &mut WorkerResult, header: &TrajectoryHeader, payload: &[f32]) {
    if let Some(count) = result.received.get_mut(header.actor_id.0 as usize) {
        *count += 1;
    }
    result.checksum += payload.iter().map(|&x| f64::from(x)).sum::<f64>();
}

/// Records the latency of a weights message whose first 8 bytes hold its send time.
fn record_weights(result: &mut WorkerResult, bytes: &[u8]) {
    let now = monotonic_ns();
    if let Some(stamp) = bytes.get(..8).and_then(|b| <[u8; 8]>::try_from(b).ok()) {
        result
            .latencies_ns
            .push(now.saturating_sub(u64::from_ne_bytes(stamp)));
        result.received[0] += 1;
    }
}

fn check_reply(reply: &GraphResponseHeader, body: &[u8], seq: u64) -> anyhow::Result<()> {
    ensure!(
        reply.request_id == seq,
        "response to request {} arrived for request {seq}",
        reply.request_id
    );
    ensure!(
        reply.status()? == GraphStatus::Ok,
        "the server refused the request"
    );
    let _: GraphResponse = protocol::decode(body)?;
    Ok(())
}

mod uds {
    //! The Unix-domain-socket side of each role. A message is a frame
    //! `[u32 header length][u32 payload length][header bytes][payload bytes]`, the header the
    //! same `#[repr(C)]` struct iceoryx2 carries as user header. Receivers listen, senders
    //! connect; a sender shuts its write side down when done, which ends the receiver's reads.

    use std::net::Shutdown;

    use super::*;

    pub(super) fn chunk_publisher(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let (layout, payload) = chunk_payload(spec)?;
        let mut streams = connect_all(spec, "chunks")?;
        let mut header = chunk_header(spec, &layout)?;
        let mut frame = Vec::new();
        control.ready();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            header.first_env_step = seq;
            header.chunk_index = seq as u32;
            // The sender's one copy into a transport buffer, as iceoryx2's write into its loan.
            encode_frame(
                &mut frame,
                wire::bytes_of(&header),
                wire::f32_bytes(&payload),
            );
            for stream in &mut streams {
                stream.write_all(&frame)?;
            }
            Ok(())
        })?;
        shutdown_all(&streams);
        Ok(WorkerResult {
            sent,
            elapsed_secs,
            ..WorkerResult::default()
        })
    }

    pub(super) fn chunk_subscriber(spec: &WorkerSpec) -> anyhow::Result<WorkerResult> {
        let listener = bind(&spec.socket("chunks", spec.index as usize))?;
        println!("ready");
        let readers: Vec<_> = (0..spec.n_peers)
            .map(|_| {
                let (stream, _) = listener.accept()?;
                let n_peers = spec.n_peers;
                Ok(std::thread::spawn(move || read_chunks(stream, n_peers)))
            })
            .collect::<std::io::Result<_>>()?;
        let mut result = WorkerResult {
            received: vec![0; spec.n_peers],
            ..WorkerResult::default()
        };
        for reader in readers {
            let part = reader
                .join()
                .map_err(|_| anyhow::anyhow!("a reader thread panicked"))??;
            result
                .received
                .iter_mut()
                .zip(&part.received)
                .for_each(|(a, b)| *a += b);
            result.checksum += part.checksum;
        }
        Ok(result)
    }

    /// Reads chunk frames from one sender until it shuts down.
    fn read_chunks(mut stream: UnixStream, n_peers: usize) -> anyhow::Result<WorkerResult> {
        let mut result = WorkerResult {
            received: vec![0; n_peers],
            ..WorkerResult::default()
        };
        let mut header = TrajectoryHeader::default();
        let mut payload: Vec<f32> = Vec::new();
        while let Some(payload_len) = read_header(&mut stream, &mut header)? {
            ensure!(
                payload_len % 4 == 0,
                "chunk payload of {payload_len} bytes is not whole floats"
            );
            payload.resize(payload_len / 4, 0.0);
            stream.read_exact(wire::f32_bytes_mut(&mut payload))?;
            count_chunk(&mut result, &header, &payload);
        }
        Ok(result)
    }

    pub(super) fn weights_publisher(
        spec: &WorkerSpec,
        control: &Control,
    ) -> anyhow::Result<WorkerResult> {
        let mut streams = connect_all(spec, "weights")?;
        let mut payload = vec![0u8; spec.weights_len];
        let mut frame = Vec::new();
        control.ready();
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            payload[..8].copy_from_slice(&monotonic_ns().to_ne_bytes());
            encode_frame(
                &mut frame,
                wire::bytes_of(&weights_header(payload.len(), seq)),
                &payload,
            );
            for stream in &mut streams {
                stream.write_all(&frame)?;
            }
            std::thread::sleep(WEIGHTS_PERIOD);
            Ok(())
        })?;
        shutdown_all(&streams);
        Ok(WorkerResult {
            sent,
            elapsed_secs,
            ..WorkerResult::default()
        })
    }

    pub(super) fn weights_subscriber(spec: &WorkerSpec) -> anyhow::Result<WorkerResult> {
        let listener = bind(&spec.socket("weights", spec.index as usize))?;
        println!("ready");
        let (mut stream, _) = listener.accept()?;
        let mut result = WorkerResult {
            received: vec![0; 1],
            ..WorkerResult::default()
        };
        let mut header = WeightsHeader::default();
        while let Some(len) = read_header(&mut stream, &mut header)? {
            let mut bytes = vec![0u8; len];
            stream.read_exact(&mut bytes)?;
            record_weights(&mut result, &bytes);
        }
        Ok(result)
    }

    pub(super) fn rpc_server(spec: &WorkerSpec) -> anyhow::Result<WorkerResult> {
        let (_, response) = rpc_bodies()?;
        let listener = bind(&spec.socket("rpc", 0))?;
        println!("ready");
        let (mut stream, _) = listener.accept()?;
        let mut result = WorkerResult {
            received: vec![0; 1],
            ..WorkerResult::default()
        };
        let mut header = GraphRequestHeader::default();
        let (mut body, mut frame) = (Vec::new(), Vec::new());
        while let Some(len) = read_header(&mut stream, &mut header)? {
            body.resize(len, 0);
            stream.read_exact(&mut body)?;
            let (reply, answer_body) = answer(&header, &body, &response)?;
            encode_frame(&mut frame, wire::bytes_of(&reply), &answer_body);
            stream.write_all(&frame)?;
            result.received[0] += 1;
        }
        Ok(result)
    }

    pub(super) fn rpc_client(spec: &WorkerSpec, control: &Control) -> anyhow::Result<WorkerResult> {
        let (request, _) = rpc_bodies()?;
        let mut stream = connect(&spec.socket("rpc", 0))?;
        control.ready();
        let mut latencies_ns = Vec::new();
        let mut reply = GraphResponseHeader::default();
        let (mut frame, mut body) = (Vec::new(), Vec::new());
        let (sent, elapsed_secs) = send_for(spec, control, |seq| {
            let header =
                GraphRequestHeader::new(seq, GraphRequestKind::FrontierRoute, PhiVersion(0));
            let start = Instant::now();
            encode_frame(&mut frame, wire::bytes_of(&header), &request);
            stream.write_all(&frame)?;
            let len =
                read_header(&mut stream, &mut reply)?.context("the server closed the socket")?;
            body.resize(len, 0);
            stream.read_exact(&mut body)?;
            latencies_ns.push(start.elapsed().as_nanos() as u64);
            check_reply(&reply, &body, seq)
        })?;
        stream.shutdown(Shutdown::Write)?;
        Ok(WorkerResult {
            sent,
            elapsed_secs,
            latencies_ns,
            ..WorkerResult::default()
        })
    }

    fn bind(path: &Path) -> anyhow::Result<UnixListener> {
        UnixListener::bind(path).with_context(|| format!("binding {}", path.display()))
    }

    fn connect(path: &Path) -> anyhow::Result<UnixStream> {
        UnixStream::connect(path).with_context(|| format!("connecting to {}", path.display()))
    }

    /// One connection to each of the `n_peers` receivers of `what`.
    fn connect_all(spec: &WorkerSpec, what: &str) -> anyhow::Result<Vec<UnixStream>> {
        (0..spec.n_peers)
            .map(|i| connect(&spec.socket(what, i)))
            .collect()
    }

    fn shutdown_all(streams: &[UnixStream]) {
        for stream in streams {
            if let Err(err) = stream.shutdown(Shutdown::Write) {
                tracing::warn!("closing a bench socket: {err}");
            }
        }
    }

    /// Writes `[u32 header len][u32 payload len][header][payload]` into `frame`.
    fn encode_frame(frame: &mut Vec<u8>, header: &[u8], payload: &[u8]) {
        frame.clear();
        frame.extend_from_slice(&(header.len() as u32).to_ne_bytes());
        frame.extend_from_slice(&(payload.len() as u32).to_ne_bytes());
        frame.extend_from_slice(header);
        frame.extend_from_slice(payload);
    }

    /// Reads a frame's lengths and header into `header`; returns the payload length, or `None`
    /// at a clean end of stream.
    fn read_header<H: wire::Plain>(
        stream: &mut UnixStream,
        header: &mut H,
    ) -> anyhow::Result<Option<usize>> {
        let mut lengths = [0u8; 8];
        match stream.read_exact(&mut lengths) {
            Ok(()) => {}
            Err(err) if err.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
            Err(err) => return Err(err.into()),
        }
        let header_len =
            u32::from_ne_bytes([lengths[0], lengths[1], lengths[2], lengths[3]]) as usize;
        let payload_len =
            u32::from_ne_bytes([lengths[4], lengths[5], lengths[6], lengths[7]]) as usize;
        ensure!(
            header_len == std::mem::size_of::<H>(),
            "frame header of {header_len} bytes, expected {}",
            std::mem::size_of::<H>()
        );
        stream.read_exact(wire::bytes_of_mut(header))?;
        Ok(Some(payload_len))
    }
}

mod wire {
    //! Byte views of the plain `#[repr(C)]` headers and of f32 slices, for the socket frames.

    /// A `#[repr(C)]` type without padding whose every bit pattern is a valid value.
    ///
    /// # Safety
    /// Implement only for such types.
    pub(super) unsafe trait Plain: Copy {}

    // SAFETY: each is `#[repr(C)]` of integers, f32 and integer newtypes, with explicit
    // `reserved` fields instead of padding (see `protocol::payload` and `protocol::graph`).
    unsafe impl Plain for protocol::TrajectoryHeader {}
    unsafe impl Plain for protocol::WeightsHeader {}
    unsafe impl Plain for protocol::graph::GraphRequestHeader {}
    unsafe impl Plain for protocol::graph::GraphResponseHeader {}

    pub(super) fn bytes_of<H: Plain>(value: &H) -> &[u8] {
        // SAFETY: `H` has no padding, so all its bytes are initialised.
        unsafe {
            std::slice::from_raw_parts((value as *const H).cast::<u8>(), std::mem::size_of::<H>())
        }
    }

    pub(super) fn bytes_of_mut<H: Plain>(value: &mut H) -> &mut [u8] {
        // SAFETY: no padding, and every bit pattern written through the view is a valid `H`.
        unsafe {
            std::slice::from_raw_parts_mut((value as *mut H).cast::<u8>(), std::mem::size_of::<H>())
        }
    }

    pub(super) fn f32_bytes(values: &[f32]) -> &[u8] {
        // SAFETY: f32 has no padding; the view covers exactly the slice's memory.
        unsafe {
            std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), std::mem::size_of_val(values))
        }
    }

    pub(super) fn f32_bytes_mut(values: &mut [f32]) -> &mut [u8] {
        // SAFETY: every bit pattern is a valid f32; the view covers exactly the slice's memory.
        unsafe {
            std::slice::from_raw_parts_mut(
                values.as_mut_ptr().cast::<u8>(),
                std::mem::size_of_val(values),
            )
        }
    }
}
