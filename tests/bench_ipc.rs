//! Smoke test of `asi bench ipc`: the real binary starts its worker processes, moves data over
//! iceoryx2 and a Unix domain socket, and prints figures that parse. No timing thresholds: only
//! that data flowed, that the lossless setups lost nothing, and that nothing was left behind.

use std::collections::BTreeMap;
use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Upper bound for the whole bench on a loaded 2-core machine; past it the bench is killed.
const WATCHDOG: Duration = Duration::from_secs(300);

/// Runs `asi` with `args` under the watchdog; returns (success, stdout, stderr).
fn run_asi(args: &[&str]) -> (bool, String, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_asi"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("asi starts");
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut text = String::new();
        stdout.read_to_string(&mut text).unwrap();
        text
    });
    let err = std::thread::spawn(move || {
        let mut text = String::new();
        stderr.read_to_string(&mut text).unwrap();
        text
    });
    let deadline = Instant::now() + WATCHDOG;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!(
                "watchdog: `asi {}` did not finish within {WATCHDOG:?}",
                args.join(" ")
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    (status.success(), out.join().unwrap(), err.join().unwrap())
}

/// The `name: value` lines of the output whose value is a number.
fn figures(stdout: &str) -> BTreeMap<String, f64> {
    stdout
        .lines()
        .filter_map(|line| line.split_once(": "))
        .filter_map(|(k, v)| Some((k.trim().to_owned(), v.trim().parse::<f64>().ok()?)))
        .collect()
}

fn get(figures: &BTreeMap<String, f64>, key: &str) -> f64 {
    *figures
        .get(key)
        .unwrap_or_else(|| panic!("`{key}` missing in {figures:?}"))
}

#[test]
fn bench_ipc_moves_data_over_both_transports_and_reports_it() {
    let (ok, stdout, stderr) =
        run_asi(&["bench", "ipc", "--seconds", "1", "--task", "pointmaze-u"]);
    assert!(ok, "bench failed:\n{stdout}\n{stderr}");
    assert!(
        stdout.starts_with("measurement"),
        "the table comes first:\n{stdout}"
    );
    let f = figures(&stdout);
    for setup in ["iceoryx2", "uds", "iceoryx2_discard"] {
        let key = format!("{setup}_pointmaze-u");
        assert!(
            get(&f, &format!("{key}_chunks_per_sec")) > 0.0,
            "{setup} delivered chunks:\n{stdout}"
        );
        assert!(get(&f, &format!("{key}_mb_per_sec")) > 0.0);
        assert!(get(&f, &format!("{key}_sent_chunks")) > 0.0);
        assert!(
            get(&f, &format!("{key}_lost_chunks")) <= 2.0 * get(&f, &format!("{key}_sent_chunks"))
        );
    }
    for setup in ["iceoryx2", "uds"] {
        assert_eq!(
            get(&f, &format!("{setup}_pointmaze-u_lost_chunks")),
            0.0,
            "{setup} is lossless:\n{stdout}"
        );
    }
    for transport in ["iceoryx2", "uds"] {
        for what in ["weights", "rpc"] {
            assert!(
                get(&f, &format!("{transport}_{what}_samples")) > 0.0,
                "{transport} {what} measured:\n{stdout}"
            );
            assert!(get(&f, &format!("{transport}_{what}_p50_us")) > 0.0);
            assert!(
                get(&f, &format!("{transport}_{what}_p99_us"))
                    >= get(&f, &format!("{transport}_{what}_p50_us"))
            );
        }
    }
    assert!(
        get(&f, "weights_bytes") > 100_000.0,
        "the full policy set of the default config"
    );
    assert_eq!(get(&f, "leftover_services"), 0.0);
    assert!(
        stderr.contains("[1/7]") && stderr.contains("[7/7]"),
        "progress on stderr:\n{stderr}"
    );
}

#[test]
fn bench_ipc_refuses_bad_arguments_with_a_clear_message() {
    let (ok, _, stderr) = run_asi(&["bench", "ipc", "--seconds", "0"]);
    assert!(!ok);
    assert!(stderr.contains("--seconds must be in"), "{stderr}");
    let (ok, _, stderr) = run_asi(&["bench", "ipc", "--seconds", "1", "--task", "no-such-task"]);
    assert!(!ok);
    assert!(stderr.contains("no-such-task"), "{stderr}");
    let (ok, _, stderr) = run_asi(&["bench", "system", "--actors", "1,0"]);
    assert!(!ok);
    assert!(stderr.contains("0 actors is outside"), "{stderr}");
}
