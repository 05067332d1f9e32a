//! `asi`: the one user-facing binary. Parses the command line, runs the subcommand, and maps
//! errors to an exit code with the whole error chain printed.

mod bench;
mod bench_graph;
mod channels;
mod cli;
mod eval_cmd;
mod graph_png;
mod graph_tool;
mod launcher;
mod maze_graph_png;
mod plot;
mod proc;
mod progress;
mod run;
mod serial;
mod tasks_cmd;
mod tensorboard;
mod weights_file;

use std::process::ExitCode;

use clap::Parser;

use cli::{Cli, Command};

fn main() -> ExitCode {
    let cli = Cli::parse();
    // One numeric thread per process unless the user says otherwise (SPEC §3): with two
    // cores, several processes each spawning a rayon pool would fight over them.
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        std::env::set_var("RAYON_NUM_THREADS", "1");
    }
    // iceoryx2 warns on every start that it runs on its built-in defaults; only errors matter.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    init_tracing();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli
        .command
        .unwrap_or_else(|| Command::Train(cli::TrainArgs::default()))
    {
        Command::Train(args) => {
            let launcher::Launch::Start(mut ctx) = launcher::prepare(&args)? else {
                return Ok(());
            };
            let mode = match args.serial {
                true => run::launches::Mode::Serial,
                false => run::launches::Mode::Processes,
            };
            let launch = run::launches::begin(&ctx, mode)?;
            ctx.launch = Some(launch);
            // A clone holds the folder's lock until the end line is written.
            let held = (*ctx).clone();
            let ending = match mode {
                run::launches::Mode::Serial => serial::run(*ctx),
                run::launches::Mode::Processes => launcher::run(*ctx),
            };
            // The history is a record: failing to write it does not change the exit status.
            if let Err(err) = run::launches::end(&held.run_dir, launch, &ending) {
                tracing::warn!("recording the end of launch {launch}: {err:#}");
            }
            ending.map(drop)
        }
        Command::Learner(args) => {
            proc::learner::run(&run::RunContext::open(&args.run_dir, &args.run_id)?)
        }
        Command::GraphService(args) => {
            proc::graph_service::run(&run::RunContext::open(&args.run_dir, &args.run_id)?)
        }
        Command::Evaluator(args) => {
            proc::evaluator::run(&run::RunContext::open(&args.run_dir, &args.run_id)?)
        }
        Command::Actor(args) => {
            let ctx = run::RunContext::open(&args.child.run_dir, &args.child.run_id)?;
            proc::actor::run(
                &ctx,
                &proc::actor::ActorArgs {
                    actor_id: args.actor_id,
                    incarnation: args.incarnation,
                    run_episodes: args.run_episodes,
                },
            )
        }
        Command::Bench(args) => bench::run(args),
        Command::Graph(args) => graph_tool::run(&args),
        Command::Plot(args) => plot::run(&args),
        Command::Eval(args) => eval_cmd::run(&args),
        Command::Tasks(args) => tasks_cmd::run(&args),
    }
}

/// Logs go to stderr, filtered by `RUST_LOG` (default `info`).
fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
}
