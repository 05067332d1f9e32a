//! System test of `asi graph`: a real smoke training (`configs/smoke.toml`, real processes,
//! real iceoryx2), queried through the real `asi` binary with every subcommand while it runs;
//! then the run is stopped with SIGTERM and the tool must say that it is not running.
//!
//! The run is a [`common::Run`]: a unique run folder and run name, a watchdog that kills
//! the run if it hangs, and cleanup of the folder and processes on drop.

mod common;

use std::collections::HashMap;
use std::path::Path;
use std::process::{Command, Output};
use std::time::Duration;

use common::{one_run_at_a_time, png_size, signal, Run};

/// Starts a smoke training with two actors that runs until it is stopped, with one φ round
/// (smoke: at episode 4) and no more: the graph is rebuilt only when φ changes, so it holds
/// still while the test compares answers of separate queries.
fn start() -> Run {
    Run::start(
        "graph-tool",
        "configs/smoke.toml",
        &[
            "--actors",
            "2",
            "--set",
            "run.max_episodes=1000000",
            "--set",
            "encoder.interval_episodes=1000000",
        ],
    )
}

/// Runs `asi graph --run-dir DIR <args>`.
fn graph(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_asi"))
        .arg("graph")
        .arg("--run-dir")
        .arg(dir)
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("asi graph runs")
}

/// `asi graph <args>`, which must succeed, as its `key: value` lines.
fn ask(dir: &Path, args: &[&str]) -> HashMap<String, String> {
    let out = graph(dir, args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "asi graph {args:?}: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    parse_lines(&stdout)
}

/// Polls `asi graph stats` until the graph of the first trained φ (version ≥ 1: the run's only
/// φ round) has at least two nodes.
fn wait_for_graph(run: &mut Run) -> HashMap<String, String> {
    run.wait_for("a graph of the trained φ with two nodes", |dir| {
        let out = graph(dir, &["stats"]);
        if out.status.success() {
            let stats = parse_lines(&String::from_utf8_lossy(&out.stdout));
            if number(&stats, "phi_version") >= 1.0 && number(&stats, "nodes") >= 2.0 {
                return Some(stats);
            }
        }
        std::thread::sleep(Duration::from_millis(450));
        None
    })
}

/// `key: value` lines; every line must have that form.
fn parse_lines(text: &str) -> HashMap<String, String> {
    text.lines()
        .map(|line| {
            let (key, value) = line
                .split_once(": ")
                .unwrap_or_else(|| panic!("not a `key: value` line: {line:?}"));
            (key.to_owned(), value.to_owned())
        })
        .collect()
}

fn number(fields: &HashMap<String, String>, key: &str) -> f64 {
    let value = fields
        .get(key)
        .unwrap_or_else(|| panic!("`{key}` missing in {fields:?}"));
    value
        .parse()
        .unwrap_or_else(|e| panic!("`{key}: {value}` is not a number: {e}"))
}

fn point(fields: &HashMap<String, String>, key: &str) -> [f32; 2] {
    let value = fields
        .get(key)
        .unwrap_or_else(|| panic!("`{key}` missing in {fields:?}"));
    let (x, y) = value
        .split_once(',')
        .unwrap_or_else(|| panic!("`{key}: {value}` is not X,Y"));
    [x.parse().unwrap(), y.parse().unwrap()]
}

fn route(fields: &HashMap<String, String>) -> Vec<[f32; 2]> {
    let value = &fields["route"];
    serde_json::from_str(value)
        .unwrap_or_else(|e| panic!("route {value:?} is not a JSON list of points: {e}"))
}

#[test]
fn asi_graph_answers_every_question_about_a_running_smoke_training_and_refuses_a_stopped_one() {
    let _slot = one_run_at_a_time();
    let mut run = start();
    let stats = wait_for_graph(&mut run);
    let graph_version = number(&stats, "graph_version");
    assert!(graph_version >= 1.0, "{stats:?}");
    assert!(number(&stats, "stored_steps") > 0.0, "{stats:?}");

    let png = run.dir.join("graph.png");
    let dump = ask(&run.dir, &["dump", "--png", png.to_str().unwrap()]);
    assert!(number(&dump, "nodes") >= 2.0, "{dump:?}");
    assert!(number(&dump, "max_visits") >= 1.0, "{dump:?}");
    let (width, height) = png_size(&png);
    assert!(width > 0 && height > 0, "{width}×{height}");

    let from = point(&dump, "frontier_from");
    let from_arg = format!("{},{}", from[0], from[1]);
    let frontier = ask(&run.dir, &["frontier", "--from", &from_arg]);
    if frontier["frontier"] == "none" {
        assert!(frontier.contains_key("reason"), "{frontier:?}");
    } else {
        let target = point(&frontier, "frontier");
        let path = route(&frontier);
        assert_eq!(path.last(), Some(&target), "the route ends at the frontier");
        assert_eq!(
            path.len() as f64,
            number(&frontier, "distance") + 1.0,
            "unit edges: hops = distance"
        );
        let to_arg = format!("{},{}", target[0], target[1]);
        let direct = ask(&run.dir, &["route", "--from", &from_arg, "--to", &to_arg]);
        for reply in [&dump, &frontier, &direct] {
            assert_eq!(number(reply, "graph_version"), graph_version, "{reply:?}");
        }
        let direct_path = route(&direct);
        assert_eq!(direct_path.first(), path.first(), "same start node");
        assert_eq!(direct_path.last(), Some(&target));
        assert_eq!(direct_path.len(), path.len(), "both are shortest routes");
    }
    let unknown = ask(
        &run.dir,
        &["route", "--from", "-99999,-99999", "--to", &from_arg],
    );
    assert_eq!(unknown["route"], "none");
    assert!(unknown["reason"].starts_with("StartUnknown"), "{unknown:?}");

    let explore = ask(
        &run.dir,
        &["explore", "--from", &from_arg, "--episode", "1000"],
    );
    let (subgoal, candidate) = (point(&explore, "subgoal"), point(&explore, "candidate"));
    let pushed = (subgoal[0] - candidate[0]).hypot(subgoal[1] - candidate[1]);
    assert!(
        (pushed - 5.0).abs() < 1e-3 || pushed < 1e-6,
        "pushed by {pushed}"
    );

    let bad = graph(&run.dir, &["frontier", "--from", "1,nan"]);
    assert!(!bad.status.success(), "a non-finite point is refused");

    signal(run.child.id(), libc::SIGTERM);
    let status = run.wait();
    assert!(status.success(), "launcher exit after SIGTERM: {status}");
    let stopped = graph(&run.dir, &["stats"]);
    assert!(!stopped.status.success());
    let message = String::from_utf8_lossy(&stopped.stderr);
    assert!(message.contains("not running"), "{message}");
}
