//! Fault injection (issue #7): during one smoke run of the real `asi train` (PointMaze U,
//! `configs/smoke.toml`, a step budget), SIGKILL each kind of process — actor, graph-service,
//! learner — twice, each at a random point of the run's progress, and check that the run still
//! finishes its budget with nothing lost beyond what a crash must lose, and leaves nothing
//! behind in iceoryx2.
//!
//! What may be lost, and the bound the test asserts:
//! - every actor incarnation keeps its published totals in `status/actor-<id>-<inc>.published`,
//!   counted just *before* each send (so they survive SIGKILL; a kill between count and send
//!   counts one chunk that never left): `produced` is their sum over all incarnations;
//! - a restarted learner continues from its newest checkpoint (env steps `R`); everything
//!   produced before its trajectory subscriber existed and not in that checkpoint may be lost,
//!   and that is at most `P − R`, where `P` is `produced` read after the restarted learner
//!   recorded its start (`status/learner.starts.jsonl`, written once the subscriber exists);
//! - after the last learner restart every published chunk reaches the learner, except that an
//!   actor killed afterwards may lose the chunk it counted but did not send.
//!
//! So `lost = produced − ingested ≤ (P_last − R_last) + chunk_steps × (actor kills after the
//! last learner restart)`; earlier losses (actor kills, the first learner restart) are inside
//! `P_last − R_last` because the checkpoint holds only what the learner had then.
//!
//! A second test drives the crash-loop guard: past `run.max_restarts` crashes of one kind the
//! launcher stops everything and exits non-zero, naming the process and its log.

mod common;

use std::cell::RefCell;
use std::collections::BTreeSet;
use std::path::Path;
use std::time::Instant;

use common::*;
use rand::seq::SliceRandom;
use rand::Rng;
use serde_json::Value;

/// Env-step budget of the run (`run.max_env_steps`).
const BUDGET: u64 = 15_000;
/// `transport.chunk_steps` of `configs/smoke.toml`.
const CHUNK_STEPS: u64 = 50;
const N_ACTORS: u32 = 2;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Target {
    Actor(u32),
    GraphService,
    Learner,
}

impl Target {
    fn process(self) -> String {
        match self {
            Target::Actor(id) => format!("actor-{id}"),
            Target::GraphService => "graph-service".to_owned(),
            Target::Learner => "learner".to_owned(),
        }
    }
}

/// One kill and what the test saw around it.
#[derive(Debug)]
struct Kill {
    target: Target,
    /// Learner env steps (metrics) when the kill was due.
    at_steps: u64,
    /// Seconds from SIGKILL to the new process (learner: to its recorded start).
    restart_secs: f64,
    learner: Option<LearnerRestart>,
}

#[derive(Debug)]
struct LearnerRestart {
    /// Env steps of the newest checkpoint on disk just before the kill.
    newest_checkpoint_steps: u64,
    /// Versions the killed learner had published (`learner_published.json`).
    published_policy: u64,
    published_phi: u64,
    /// The restarted learner's start record.
    start: Value,
    /// `produced` read right after that record appeared.
    produced_at_start: u64,
}

/// Sum of `published_steps` over every actor incarnation's running totals.
fn produced(dir: &Path) -> u64 {
    let entries = std::fs::read_dir(dir.join("status"))
        .map(|d| d.flatten().collect::<Vec<_>>())
        .unwrap_or_default();
    entries
        .iter()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".published"))
        .map(|e| as_u64(&read_json(&e.path()), "published_steps"))
        .sum()
}

/// Env steps of the newest checkpoint's manifest.
fn newest_checkpoint_steps(dir: &Path) -> Option<u64> {
    let mut names: Vec<String> = std::fs::read_dir(dir.join("checkpoints"))
        .ok()?
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("ckpt-"))
        .collect();
    names.sort();
    let manifest = std::fs::read_to_string(
        dir.join("checkpoints")
            .join(names.last()?)
            .join("manifest.json"),
    )
    .ok()?;
    serde_json::from_str::<Value>(&manifest)
        .ok()?
        .get("env_steps")?
        .as_u64()
}

fn learner_starts(dir: &Path) -> Vec<Value> {
    let text = std::fs::read_to_string(dir.join("status").join("learner.starts.jsonl"))
        .unwrap_or_default();
    text.lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// Two kills per kind in random order (random actors), each due at a random learner env-step
/// count in its own slice of 8–63 % of the budget (the rest leaves time for the last restart).
fn plan(rng: &mut impl Rng) -> Vec<(Target, u64)> {
    let mut targets: Vec<Target> = (0..2)
        .flat_map(|_| [Target::Actor(0), Target::GraphService, Target::Learner])
        .map(|t| {
            if t == Target::Actor(0) {
                Target::Actor(rng.random_range(0..N_ACTORS))
            } else {
                t
            }
        })
        .collect();
    targets.shuffle(rng);
    targets
        .into_iter()
        .enumerate()
        .map(|(i, t)| {
            let lo = BUDGET * (8 + 10 * i as u64) / 100;
            (t, rng.random_range(lo..lo + BUDGET * 5 / 100))
        })
        .collect()
}

fn kill_and_wait(
    run: &mut Run,
    target: Target,
    ids: &RefCell<BTreeSet<String>>,
    run_id: &str,
) -> Kill {
    let process = target.process();
    let old_pid = pid_of(&run.dir, &process).expect("pid file");
    let n_starts = learner_starts(&run.dir).len();
    let learner_before = (target == Target::Learner).then(|| {
        let published = read_json(&run.dir.join("learner_published.json"));
        (
            newest_checkpoint_steps(&run.dir).unwrap_or(0),
            as_u64(&published, "policy_version"),
            as_u64(&published, "phi_version"),
        )
    });
    collect_iceoryx2_ids(run_id, &mut ids.borrow_mut());
    let at_steps = learner_steps_now(&run.dir);
    signal(old_pid, libc::SIGKILL);
    let killed = Instant::now();
    let learner = match learner_before {
        Some((newest_checkpoint_steps, published_policy, published_phi)) => {
            let start = run.wait_for("the restarted learner's start record", |dir| {
                let starts = learner_starts(dir);
                (starts.len() > n_starts).then(|| starts[n_starts].clone())
            });
            let produced_at_start = produced(&run.dir);
            assert_ne!(as_u64(&start, "pid"), u64::from(old_pid));
            Some(LearnerRestart {
                newest_checkpoint_steps,
                published_policy,
                published_phi,
                start,
                produced_at_start,
            })
        }
        None => {
            run.wait_for(&format!("{process} restarted"), |dir| {
                pid_of(dir, &process).filter(|&pid| pid != old_pid)
            });
            None
        }
    };
    Kill {
        target,
        at_steps,
        restart_secs: killed.elapsed().as_secs_f64(),
        learner,
    }
}

#[test]
fn a_run_survives_sigkills_of_every_process_kind_and_loses_only_what_crashes_must_lose() {
    let _lock = one_run_at_a_time();
    let mut rng = rand::rng();
    let plan = plan(&mut rng);
    let budget = format!("run.max_env_steps={BUDGET}");
    let actors = N_ACTORS.to_string();
    let mut run = Run::start(
        "fault",
        "configs/smoke.toml",
        &[
            "--actors",
            &actors,
            "--set",
            &budget,
            "--set",
            "run.max_episodes=1000000",
            // A checkpoint every 3 s, so a killed learner always has one to come back to.
            "--set",
            "run.checkpoint_interval_mins=0.05",
            "--set",
            "run.max_restarts=10",
            // While the graph-service is down, requests fail after 2 s instead of 10.
            "--set",
            "transport.graph_request_timeout_ms=2000",
            // The evaluator runs but never evaluates: it only competes for the cores.
            "--set",
            "eval.interval_episodes=1000000",
        ],
    );
    let run_id = run
        .wait_for("the run id", |dir| {
            std::fs::read_to_string(dir.join("run_id")).ok()
        })
        .trim()
        .to_owned();
    let ids = RefCell::new(BTreeSet::new());
    let mut kills = Vec::new();
    for &(target, due_steps) in &plan {
        run.wait_for(
            &format!("{due_steps} env steps before killing {}", target.process()),
            |dir| {
                collect_iceoryx2_ids(&run_id, &mut ids.borrow_mut());
                let checkpointed = target != Target::Learner
                    || newest_checkpoint_steps(dir).is_some_and(|s| s > 0);
                (learner_steps_now(dir) >= due_steps && checkpointed).then_some(())
            },
        );
        kills.push(kill_and_wait(&mut run, target, &ids, &run_id));
    }
    let status = loop {
        collect_iceoryx2_ids(&run_id, &mut ids.borrow_mut());
        if let Some(status) = run.child.try_wait().unwrap() {
            break status;
        }
        run.check_watchdog("the end of the run");
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let wall_secs = run.elapsed_secs();
    let output = run.launcher_output();
    assert!(status.success(), "launcher exit {status}:\n{output}");
    assert!(output.contains("training budget reached"), "{output}");

    let learner = run.status("learner");
    let ingested = as_u64(&learner, "env_steps");
    assert!(ingested >= BUDGET, "budget reached: {learner}");
    assert_eq!(as_u64(&learner, "duplicate_chunks"), 0, "{learner}");
    assert_eq!(as_u64(&learner, "rejected_chunks"), 0, "{learner}");
    check_restart_counts(&run.dir, &kills);
    check_learner_continuity(&kills, &learner);
    check_metrics_follow_the_learner(&run.dir, &kills);
    check_losses(&run.dir, &kills, ingested);
    print_figures(&kills, wall_secs);
    let m = run.last_metrics();
    let total = |suffix: &str| {
        m.iter()
            .filter(|(k, _)| k.ends_with(suffix))
            .map(|(_, v)| v)
            .sum::<f64>()
    };
    let (explored, fallbacks) = (
        total("actor/explore_decisions"),
        total("actor/explore_fallbacks"),
    );
    println!(
        "graph-service clients (current actor incarnations): {} requests unanswered in time; \
         {fallbacks} of {} explore-subgoal requests fell back to the policy (no answer or not ready)",
        total("actor/graph_unreachable"),
        explored + fallbacks
    );

    assert_eq!(
        services_of(&run_id),
        Vec::<String>::new(),
        "iceoryx2 services of the run left"
    );
    assert_eq!(
        nodes_of(&run_id),
        Vec::<String>::new(),
        "iceoryx2 nodes of the run left"
    );
    let ids = ids.into_inner();
    assert!(
        ids.len() > 10,
        "iceoryx2 resources of the run were seen during the run: {ids:?}"
    );
    assert_eq!(
        iceoryx2_files_with(&ids),
        Vec::<String>::new(),
        "iceoryx2 files of the run left in {ICEORYX2_DIRS:?}"
    );
}

/// Every restart was one of ours: no process crashed on its own (e.g. an actor while the
/// graph-service or learner was away).
fn check_restarts_for(last: &Value, family: &str, expected: usize) {
    let key = format!("launcher/restarts_{family}");
    let got = last.get(&key).and_then(Value::as_f64).unwrap_or(0.0) as usize;
    assert_eq!(got, expected, "{key}");
}

fn check_restart_counts(dir: &Path, kills: &[Kill]) {
    let text = std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap();
    let last: Value = serde_json::from_str(text.lines().last().unwrap()).unwrap();
    let count = |f: fn(&Target) -> bool| kills.iter().filter(|k| f(&k.target)).count();
    check_restarts_for(&last, "actor", count(|t| matches!(t, Target::Actor(_))));
    check_restarts_for(
        &last,
        "graph_service",
        count(|t| *t == Target::GraphService),
    );
    check_restarts_for(&last, "learner", count(|t| *t == Target::Learner));
    check_restarts_for(&last, "evaluator", 0);
}

/// Each restarted learner started from the newest checkpoint (never from zero) and published
/// versions above its predecessor's; the final learner went on from there.
fn check_learner_continuity(kills: &[Kill], learner: &Value) {
    for restart in kills.iter().filter_map(|k| k.learner.as_ref()) {
        let restored = as_u64(&restart.start, "env_steps");
        assert!(
            restored > 0,
            "restored from a checkpoint, not from zero: {restart:?}"
        );
        assert!(
            restored >= restart.newest_checkpoint_steps,
            "restored from the newest checkpoint: {restart:?}"
        );
        assert!(
            as_u64(&restart.start, "policy_version") > restart.published_policy,
            "policy version went on: {restart:?}"
        );
        assert!(
            as_u64(&restart.start, "phi_version") >= restart.published_phi,
            "φ version went on: {restart:?}"
        );
        assert!(as_u64(learner, "env_steps") > restored);
    }
}

/// The learner env steps in `metrics.jsonl` and `metrics.csv` never go back although each
/// restarted learner went back to its checkpoint: the launcher moved the lines written past
/// it to side files (`metrics.jsonl.past-ckpt-N-…`), whose every line is past some restart's
/// restored steps.
fn check_metrics_follow_the_learner(dir: &Path, kills: &[Kill]) {
    let steps_key = "learner/ingest/env_steps";
    let jsonl_steps = |text: &str| -> Vec<f64> {
        text.lines()
            .filter_map(|l| {
                serde_json::from_str::<Value>(l)
                    .ok()?
                    .get(steps_key)?
                    .as_f64()
            })
            .collect()
    };
    let main = jsonl_steps(&std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap());
    assert!(main.len() > 10, "metrics.jsonl has lines: {}", main.len());
    if let Some(w) = main.windows(2).find(|w| w[1] < w[0]) {
        panic!(
            "metrics.jsonl goes back in env steps: {} then {}",
            w[0], w[1]
        );
    }
    let csv = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    let column = csv
        .lines()
        .next()
        .unwrap()
        .split(',')
        .position(|c| c == steps_key)
        .expect("metrics.csv has the env steps column");
    let csv_steps: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(column).unwrap().parse().unwrap())
        .collect();
    if let Some(w) = csv_steps.windows(2).find(|w| w[1] < w[0]) {
        panic!("metrics.csv goes back in env steps: {} then {}", w[0], w[1]);
    }
    let lowest_restore = kills
        .iter()
        .filter_map(|k| k.learner.as_ref())
        .map(|r| as_u64(&r.start, "env_steps"))
        .min()
        .unwrap() as f64;
    let mut moved = 0;
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with("metrics.jsonl.past-ckpt-") {
            let side = jsonl_steps(&std::fs::read_to_string(entry.path()).unwrap());
            assert!(
                side.iter().all(|&s| s > lowest_restore),
                "{name}: {side:?} not past {lowest_restore}"
            );
            moved += side.len();
        }
    }
    println!("metrics lines moved aside at learner restarts: {moved}");
}

fn check_losses(dir: &Path, kills: &[Kill], ingested: u64) {
    let produced = produced(dir);
    assert!(
        produced >= ingested,
        "the learner never holds more than was produced: {produced} < {ingested}"
    );
    let lost = produced - ingested;
    let last_learner = kills
        .iter()
        .rposition(|k| k.learner.is_some())
        .expect("a learner kill");
    let restart = kills[last_learner].learner.as_ref().unwrap();
    let not_checkpointed = restart.produced_at_start - as_u64(&restart.start, "env_steps");
    let later_actor_kills = kills[last_learner..]
        .iter()
        .filter(|k| matches!(k.target, Target::Actor(_)))
        .count() as u64;
    let bound = not_checkpointed + CHUNK_STEPS * later_actor_kills;
    println!(
        "transitions: produced {produced}, ingested {ingested}, lost {lost} ({:.1} %); bound {bound} = \
         {not_checkpointed} produced but not in the checkpoint at the last learner restart \
         + {CHUNK_STEPS} × {later_actor_kills} actor kills after it",
        100.0 * lost as f64 / produced as f64
    );
    for k in kills.iter().filter_map(|k| k.learner.as_ref()) {
        println!(
            "  learner restart: newest checkpoint {} steps, restored {} steps, produced then {} (not checkpointed {})",
            k.newest_checkpoint_steps,
            as_u64(&k.start, "env_steps"),
            k.produced_at_start,
            k.produced_at_start - as_u64(&k.start, "env_steps")
        );
    }
    assert!(lost <= bound, "lost {lost} > bound {bound}");
}

fn print_figures(kills: &[Kill], wall_secs: f64) {
    println!("run: {wall_secs:.1} s wall, budget {BUDGET} env steps");
    for k in kills {
        println!(
            "  SIGKILL {:<13} at {:>6} env steps; back in {:.2} s",
            k.target.process(),
            k.at_steps,
            k.restart_secs
        );
    }
    for (name, f) in [
        (
            "actor",
            (|t: &Target| matches!(t, Target::Actor(_))) as fn(&Target) -> bool,
        ),
        ("graph-service", |t| *t == Target::GraphService),
        ("learner", |t| *t == Target::Learner),
    ] {
        println!(
            "kills survived: {name} {}",
            kills.iter().filter(|k| f(&k.target)).count()
        );
    }
}

#[test]
fn a_crash_loop_stops_the_run_with_an_error_naming_the_process_and_its_log() {
    let _lock = one_run_at_a_time();
    let mut run = Run::start(
        "crash-loop",
        "configs/smoke.toml",
        &[
            "--actors",
            "2",
            "--set",
            "run.max_episodes=1000000",
            "--set",
            "run.max_restarts=1",
        ],
    );
    run.wait_for("the learner ingested data", |dir| {
        (learner_steps_now(dir) > 0).then_some(())
    });
    let run_id = run.run_id();
    let first = pid_of(&run.dir, "graph-service").unwrap();
    signal(first, libc::SIGKILL);
    let second = run.wait_for("graph-service restarted", |dir| {
        pid_of(dir, "graph-service").filter(|&pid| pid != first)
    });
    signal(second, libc::SIGKILL);
    let status = run.wait();
    let output = run.launcher_output();
    assert_eq!(
        status.code(),
        Some(1),
        "non-zero exit after the crash loop:\n{output}"
    );
    assert!(
        output.contains("crash loop: graph_service processes crashed 2 times")
            && output.contains("run.max_restarts = 1")
            && output.contains("logs/graph-service.log"),
        "the error names the process and its log:\n{output}"
    );
    for pid in pids(&run.dir) {
        // SAFETY: signal 0 only checks whether the pid exists.
        let alive = unsafe { libc::kill(pid as libc::pid_t, 0) } == 0;
        assert!(
            !alive,
            "process {pid} of the run still runs after the launcher gave up"
        );
    }
    let learner = run.status("learner");
    assert_eq!(
        learner["stop_reason"], "stop requested",
        "the learner was stopped cleanly: {learner}"
    );
    assert_eq!(services_of(&run_id), Vec::<String>::new());
    assert_eq!(nodes_of(&run_id), Vec::<String>::new());
}
