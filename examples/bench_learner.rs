//! `asi bench learner` as a stand-alone example binary (the same module as the subcommand), so
//! the bench runs without the rest of the CLI:
//! `RAYON_NUM_THREADS=1 cargo run --release --example bench_learner -- [options]`
//! (options as `asi bench learner --help`). Run it from the repository root, where the torch venv
//! and script are found.

#[path = "../src/bench_learner.rs"]
#[allow(dead_code)]
mod bench_learner;

use clap::Parser;

/// Command line of the example: the bench's own options.
#[derive(Debug, Parser)]
struct Cli {
    #[command(flatten)]
    args: bench_learner::BenchLearnerArgs,
}

fn main() -> std::process::ExitCode {
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        std::env::set_var("RAYON_NUM_THREADS", "1");
    }
    match bench_learner::run(&Cli::parse().args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
