//! System test of `asi graph`: a real smoke training (`configs/smoke.toml`, real processes,
//! real iceoryx2), queried through the real `asi` binary with every subcommand while it runs;
//! then the run is stopped with SIGTERM and the tool must say that it is not running.
//!
//! Same patterns as `tests/system.rs`: a unique run folder and run name, a watchdog that kills
//! the run if it hangs, and cleanup of the folder and processes on drop.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

/// Upper bound for the run to build a graph and stop on a loaded 2-core machine.
const WATCHDOG: Duration = Duration::from_secs(600);

struct Run {
    dir: PathBuf,
    child: Child,
}

impl Run {
    fn start(test: &str) -> Run {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos();
        let dir = std::env::temp_dir().join(format!(
            "asi-graph-tool-{test}-{}-{nanos}",
            std::process::id()
        ));
        let name = format!("g{}", nanos % 1_000_000_000);
        let dir_arg = dir.to_string_lossy().into_owned();
        let name_arg = format!("run.name={name}");
        let args = [
            "train",
            "--config",
            "configs/smoke.toml",
            "--actors",
            "2",
            "--run-dir",
            &dir_arg,
            "--set",
            &name_arg,
            "--set",
            "run.max_episodes=1000000",
            // One φ round (smoke: at episode 4) and no more: the graph is rebuilt only when φ
            // changes, so it holds still while the test compares answers of separate queries.
            "--set",
            "encoder.interval_episodes=1000000",
        ];
        let child = Command::new(env!("CARGO_BIN_EXE_asi"))
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("asi starts");
        Run { dir, child }
    }

    fn kill_all(&mut self) {
        for name in ["actor-0", "actor-1", "learner", "graph-service"] {
            if let Some(pid) = pid_of(&self.dir, name) {
                // SAFETY: plain syscall on a pid of this run.
                unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
            }
        }
        let _ = self.child.kill();
    }

    fn stop(&mut self) -> ExitStatus {
        // SAFETY: plain syscall on the launcher this test started.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let deadline = Instant::now() + WATCHDOG;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            if Instant::now() > deadline {
                self.kill_all();
                panic!(
                    "watchdog: run in {} did not stop within {WATCHDOG:?}",
                    self.dir.display()
                );
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Runs `asi graph --run-dir DIR <args>`.
    fn graph(&self, args: &[&str]) -> Output {
        Command::new(env!("CARGO_BIN_EXE_asi"))
            .arg("graph")
            .arg("--run-dir")
            .arg(&self.dir)
            .args(args)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("asi graph runs")
    }

    /// `asi graph <args>`, which must succeed, as its `key: value` lines.
    fn ask(&self, args: &[&str]) -> HashMap<String, String> {
        let out = self.graph(args);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "asi graph {args:?}: {}\n{stdout}",
            String::from_utf8_lossy(&out.stderr)
        );
        parse_lines(&stdout)
    }

    /// Polls `asi graph stats` until the graph of the first trained φ (version ≥ 1: the run's
    /// only φ round) has at least two nodes.
    fn wait_for_graph(&mut self) -> HashMap<String, String> {
        let deadline = Instant::now() + WATCHDOG;
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!("launcher exited ({status}) before the graph had nodes");
            }
            if Instant::now() > deadline {
                self.kill_all();
                panic!("watchdog: the graph never had two nodes");
            }
            let out = self.graph(&["stats"]);
            if out.status.success() {
                let stats = parse_lines(&String::from_utf8_lossy(&out.stdout));
                if number(&stats, "phi_version") >= 1.0 && number(&stats, "nodes") >= 2.0 {
                    return stats;
                }
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if self.child.try_wait().ok().flatten().is_none() {
            self.kill_all();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn pid_of(dir: &Path, process: &str) -> Option<u32> {
    std::fs::read_to_string(dir.join("status").join(format!("{process}.pid")))
        .ok()?
        .trim()
        .parse()
        .ok()
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
    let _slot = common::one_run_at_a_time();
    let mut run = Run::start("all");
    let stats = run.wait_for_graph();
    let graph_version = number(&stats, "graph_version");
    assert!(graph_version >= 1.0, "{stats:?}");
    assert!(number(&stats, "stored_steps") > 0.0, "{stats:?}");

    let png = run.dir.join("graph.png");
    let dump = run.ask(&["dump", "--png", png.to_str().unwrap()]);
    assert!(number(&dump, "nodes") >= 2.0, "{dump:?}");
    assert!(number(&dump, "max_visits") >= 1.0, "{dump:?}");
    let (width, height) = decoded_size(&png);
    assert!(width > 0 && height > 0, "{width}×{height}");

    let from = point(&dump, "frontier_from");
    let from_arg = format!("{},{}", from[0], from[1]);
    let frontier = run.ask(&["frontier", "--from", &from_arg]);
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
        let direct = run.ask(&["route", "--from", &from_arg, "--to", &to_arg]);
        for reply in [&dump, &frontier, &direct] {
            assert_eq!(number(reply, "graph_version"), graph_version, "{reply:?}");
        }
        let direct_path = route(&direct);
        assert_eq!(direct_path.first(), path.first(), "same start node");
        assert_eq!(direct_path.last(), Some(&target));
        assert_eq!(direct_path.len(), path.len(), "both are shortest routes");
    }
    let unknown = run.ask(&["route", "--from", "-99999,-99999", "--to", &from_arg]);
    assert_eq!(unknown["route"], "none");
    assert!(unknown["reason"].starts_with("StartUnknown"), "{unknown:?}");

    let explore = run.ask(&["explore", "--from", &from_arg, "--episode", "1000"]);
    let (subgoal, candidate) = (point(&explore, "subgoal"), point(&explore, "candidate"));
    let pushed = (subgoal[0] - candidate[0]).hypot(subgoal[1] - candidate[1]);
    assert!(
        (pushed - 5.0).abs() < 1e-3 || pushed < 1e-6,
        "pushed by {pushed}"
    );

    let bad = run.graph(&["frontier", "--from", "1,nan"]);
    assert!(!bad.status.success(), "a non-finite point is refused");

    let status = run.stop();
    assert!(status.success(), "launcher exit after SIGTERM: {status}");
    let stopped = run.graph(&["stats"]);
    assert!(!stopped.status.success());
    let message = String::from_utf8_lossy(&stopped.stderr);
    assert!(message.contains("not running"), "{message}");
}

/// Width and height of the PNG at `path`, decoding every pixel.
fn decoded_size(path: &Path) -> (u32, u32) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .expect("a PNG header");
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).expect("PNG pixels decode");
    assert!(pixels.iter().any(|&b| b != 255), "the picture is not blank");
    (info.width, info.height)
}
