//! Command-line definitions: every flag documented, defaults stated.

use clap::{Args, Parser, Subcommand};

/// ASI: hierarchical reinforcement learning with subgoal graph learning, as a distributed
/// actor–learner system.
#[derive(Debug, Parser)]
#[command(name = "asi", version, about)]
pub struct Cli {
    /// Without a subcommand, `asi` runs `asi train` on the default config.
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Train an agent: launches graph-service, learner and actors and supervises them.
    Train(TrainArgs),
    /// (spawned by `asi train`) The learner process.
    #[command(hide = true)]
    Learner(ChildArgs),
    /// (spawned by `asi train`) An actor process.
    #[command(hide = true)]
    Actor(ActorArgs),
    /// (spawned by `asi train`) The graph-service process.
    #[command(hide = true, name = "graph-service")]
    GraphService(ChildArgs),
    /// (spawned by `asi train`) The evaluation process.
    #[command(hide = true)]
    Evaluator(ChildArgs),
    /// Measure throughput of a part of the system.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// List the registered task names, or describe one (`asi tasks antmaze-u [--json]`): maze
    /// map, start, goals, episode length, observation and action sizes.
    Tasks(crate::tasks_cmd::TasksArgs),
    /// Learning curves of several runs on one PNG: runs grouped into arms by name without the
    /// seed tag, mean over seeds with a 95 % confidence band, x axis env steps.
    Plot(PlotArgs),
    /// Query the live graph-service of a running training run.
    Graph(GraphArgs),
    /// Evaluate the newest weights saved in a run folder on the test goal (deterministic, no
    /// exploration); `--png` draws the episodes on the maze.
    Eval(crate::eval_cmd::EvalArgs),
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Control steps per second of one environment on one thread, random actions.
    Env(BenchEnvArgs),
    /// Transport speed between real processes: trajectory chunks, weights broadcast and
    /// request–response over iceoryx2, each beside the same bytes over a Unix domain socket.
    Ipc(BenchIpcArgs),
    /// (spawned by `asi bench ipc`) One sending or receiving process of an IPC measurement.
    #[command(hide = true, name = "ipc-worker")]
    IpcWorker(BenchIpcWorkerArgs),
    /// End-to-end speed of real `asi train` runs for several actor counts: env steps/s,
    /// learner updates/s, policy lag and CPU cores used.
    System(BenchSystemArgs),
    /// SAC updates/s of both levels at the paper's shapes, the time of one φ round and the FLOP
    /// rate, each beside the same update in PyTorch (scripts/bench_learner_torch.py) as a ratio.
    Learner(crate::bench::learner::BenchLearnerArgs),
    /// Graph-service speed on synthetic trajectories: rebuild for 1 M and 10 M stored steps
    /// (φ re-mapping and graph construction apart), route latency at 5,000 nodes, and scipy's
    /// shortest paths on the same graph side by side.
    Graph(crate::bench_graph::BenchGraphArgs),
}

#[derive(Debug, Args)]
pub struct BenchIpcArgs {
    /// Seconds each measurement runs (each is done once per transport).
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Env steps per trajectory chunk (`transport.chunk_steps`; default as in the default config).
    #[arg(long, default_value_t = 100)]
    pub chunk_steps: u32,
    /// Task whose step-record layout the chunks use (repeatable; see `asi tasks`). Default:
    /// pointmaze-u and antmaze-u.
    #[arg(long = "task", value_name = "T")]
    pub tasks: Vec<String>,
}

/// What `asi bench ipc` hands one of its worker processes.
#[derive(Debug, Args)]
pub struct BenchIpcWorkerArgs {
    /// The worker's job as JSON (written by `asi bench ipc`, not meant to be typed).
    #[arg(long)]
    pub spec: String,
}

#[derive(Debug, Args)]
pub struct BenchSystemArgs {
    /// Actor counts to measure, comma-separated, each a separate run (e.g. `1,2,4`).
    #[arg(long, default_value = "1,2,4", value_parser = crate::bench::system::parse_actor_counts)]
    pub actors: crate::bench::system::ActorCounts,
    /// Seconds of steady state measured per actor count (after the warm-up).
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Seconds waited once the run is past start-up (the learner has data and the throttle
    /// lets actors send again), before measuring.
    #[arg(long, default_value_t = 5.0)]
    pub warmup_secs: f64,
    /// TOML config of the runs (copied into each run folder); default: the embedded
    /// `configs/smoke.toml` (PointMaze-U, tiny networks). Its budget is lifted so runs last.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
}

#[derive(Debug, Args)]
pub struct BenchEnvArgs {
    /// Task name (see `asi tasks`).
    #[arg(long, default_value = "antmaze-u")]
    pub task: String,
    /// Control steps per repeat.
    #[arg(long, default_value_t = 10_000)]
    pub steps: usize,
    /// Repeats; the final line reports their median.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Seed of the random actions and resets.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

#[derive(Debug, Default, Args)]
pub struct TrainArgs {
    /// TOML config file; without it, the embedded defaults (AntMaze-U, the paper's setting).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Override one config value, e.g. `--set learner.high.lr=1e-4` (repeatable; applied after
    /// the file, in order).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Number of actor processes (overrides `run.n_actors`; default: cores − 2, at least 1;
    /// with `--serial`, 1 unless the config file or a `--set` gives `run.n_actors`, so a serial
    /// run does not depend on the machine's core count).
    #[arg(long)]
    pub actors: Option<usize>,
    /// Run folder (default `<run.root_dir>/<run.name>`, i.e. `runs/antmaze-u`).
    #[arg(long)]
    pub run_dir: Option<std::path::PathBuf>,
    /// Master seed (overrides `run.seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Run every component in this one process, in a fixed order, with no transport:
    /// deterministic for a seed (for debugging and tests).
    #[arg(long)]
    pub serial: bool,
    /// Start over even if the run folder holds a checkpoint. Without it, `asi train` on an
    /// existing run folder resumes from its newest checkpoint (`checkpoints/`). The old
    /// folder is moved aside to `<run-dir>.old-<unix seconds>`, never deleted.
    #[arg(long)]
    pub restart: bool,
}

/// Arguments every child process gets from the launcher.
#[derive(Debug, Args)]
pub struct ChildArgs {
    /// The run folder holding `config.resolved.toml`.
    #[arg(long)]
    pub run_dir: std::path::PathBuf,
    /// The run id; must match the run folder's (refuses processes of another run).
    #[arg(long)]
    pub run_id: String,
}

#[derive(Debug, Args)]
pub struct ActorArgs {
    #[command(flatten)]
    pub child: ChildArgs,
    /// This actor's index (0-based).
    #[arg(long)]
    pub actor_id: u32,
    /// Earlier starts of this actor in the run folder, over all launches (set by the launcher;
    /// fixes the actor's episode ids, env seeds and generator).
    #[arg(long, default_value_t = 0)]
    pub incarnation: u32,
    /// Training episodes the run had completed when the launcher started this actor (set by
    /// the launcher): the actor takes its share of what is left of the random warm-up.
    #[arg(long, default_value_t = 0)]
    pub run_episodes: u64,
}

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories (each with a metrics.jsonl, or a metrics.jsonl.gz where the folder was
    /// packed by scripts/run_archive.py). Seeds of one setting are recognised by a
    /// trailing `_seed-N`, `-seedN` or `_sN` in the directory name and averaged; past the
    /// shortest seed's end the curve goes on dashed with the seeds that got further.
    #[arg(required = true, num_args = 1..)]
    pub run_dirs: Vec<std::path::PathBuf>,
    /// Output PNG file.
    #[arg(long, default_value = "plot.png")]
    pub out: std::path::PathBuf,
    /// Metric key to plot, one panel each (repeatable). Default: test success rate
    /// (`evaluator0/eval/success_rate`) and coverage (`learner/charts/coverage`).
    #[arg(long)]
    pub metric: Vec<String>,
    /// Metric key of the x axis.
    #[arg(long, default_value = crate::plot::DEFAULT_X)]
    pub x: String,
}

#[derive(Debug, Args)]
pub struct GraphArgs {
    /// Run folder of a running `asi train`.
    #[arg(long)]
    pub run_dir: std::path::PathBuf,
    /// Seconds to wait for the graph-service's answer (it answers between trajectory chunks
    /// and graph rebuilds).
    #[arg(long, default_value_t = 10.0)]
    pub timeout_secs: f64,
    #[command(subcommand)]
    pub command: GraphCommand,
}

/// Questions `asi graph` can ask. Points are `X,Y` in φ-space (e.g. `--from=-3.5,4`).
#[derive(Debug, Clone, Subcommand)]
pub enum GraphCommand {
    /// Graph size and trajectory store counts.
    Stats,
    /// A random frontier node seen from the cell of a point, and the route to it.
    Frontier {
        /// Start point X,Y.
        #[arg(long, allow_hyphen_values = true, value_parser = crate::graph_tool::parse_point)]
        from: [f32; 2],
    },
    /// The shortest route between the cells of two points.
    Route {
        /// Start point X,Y.
        #[arg(long, allow_hyphen_values = true, value_parser = crate::graph_tool::parse_point)]
        from: [f32; 2],
        /// End point X,Y.
        #[arg(long, allow_hyphen_values = true, value_parser = crate::graph_tool::parse_point)]
        to: [f32; 2],
    },
    /// HESS's count-based exploration subgoal near a point.
    Explore {
        /// φ(s_t) X,Y.
        #[arg(long, allow_hyphen_values = true, value_parser = crate::graph_tool::parse_point)]
        from: [f32; 2],
        /// Training episode index (the potential term and the push apply after
        /// `exploration.potential_start_episode`).
        #[arg(long, default_value_t = 0)]
        episode: u64,
    },
    /// Draw the graph (nodes coloured by visit count, edges, a frontier and its route) to a PNG.
    Dump {
        /// Output PNG file.
        #[arg(long)]
        png: std::path::PathBuf,
        /// Start of the drawn frontier route X,Y (default: node 0, the oldest cell).
        #[arg(long, allow_hyphen_values = true, value_parser = crate::graph_tool::parse_point)]
        from: Option<[f32; 2]>,
    },
}
