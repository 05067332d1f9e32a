//! Command-line definitions: every flag documented, defaults stated.

use clap::{Args, Parser, Subcommand};

/// ASI: hierarchical reinforcement learning with subgoal graph learning, as a distributed
/// actor–learner system.
#[derive(Debug, Parser)]
#[command(name = "asi", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Measure throughput of a part of the system.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// List the registered task names.
    Tasks,
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Control steps per second of one environment on one thread, random actions.
    Env(BenchEnvArgs),
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
