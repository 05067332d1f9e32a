//! The evaluator: deterministic episodes on the test goal, weights checks, report consistency.

use actor::eval::{test_task_name, Evaluator};
use actor::Actor;
use protocol::{ActorId, Config, PhiVersion, PolicyVersion, WeightsHeader};

fn config(task: &str, episode_length: u32) -> Config {
    Config::load(
        None,
        &[
            format!("env.task={task}"),
            format!("env.episode_length={episode_length}"),
        ],
    )
    .expect("valid config")
}

/// Weights of a freshly seeded actor, as a learner would publish them.
fn weights(config: &Config, seed: u64) -> (WeightsHeader, Vec<u8>) {
    let actor = Actor::new(config, ActorId(0), seed).unwrap();
    let bytes = actor.weights_bytes().unwrap();
    let header = WeightsHeader::new(
        PolicyVersion(3),
        PhiVersion(2),
        actor.layout_hash(),
        bytes.len(),
    );
    (header, bytes)
}

#[test]
fn evaluation_is_reproducible_and_its_report_is_consistent() {
    let config = config("pointmaze-u", 60);
    let (header, bytes) = weights(&config, 11);
    let mut a = Evaluator::new(&config, 5).unwrap();
    let mut b = Evaluator::new(&config, 5).unwrap();
    a.load_weights(&header, &bytes).unwrap();
    b.load_weights(&header, &bytes).unwrap();
    let ra = a.run(4, 3).unwrap();
    let rb = b.run(4, 3).unwrap();
    assert_eq!(
        ra, rb,
        "same weights, seed and index must give the same evaluation"
    );
    assert_eq!(
        (ra.policy_version, ra.phi_version),
        (PolicyVersion(3), PhiVersion(2))
    );
    assert_eq!(ra.trajectories.len(), 3);
    // The test variant has one fixed goal.
    assert!(ra.goals.iter().all(|g| *g == ra.goals[0]));
    // Report fields recomputed from the trajectories.
    let lengths: f64 = ra
        .trajectories
        .iter()
        .map(|p| (p.len() - 1) as f64)
        .sum::<f64>()
        / 3.0;
    assert!((ra.mean_length - lengths).abs() < 1e-9);
    let dist: f64 = ra
        .trajectories
        .iter()
        .zip(&ra.goals)
        .map(|(p, g)| {
            let l = p.last().unwrap();
            f64::from((l[0] - g[0]).hypot(l[1] - g[1]))
        })
        .sum::<f64>()
        / 3.0;
    assert!((ra.mean_final_distance - dist).abs() < 1e-6);
    // The distance along the maze, from the final positions by hand: cells of the code's
    // lookup, BFS between them (the maze tests check both), × the cell size.
    let maze = a.maze().expect("a maze task");
    let along: Vec<f64> = ra
        .trajectories
        .iter()
        .zip(&ra.goals)
        .filter_map(|(p, g)| {
            let (from, to) = (maze.cell_of(*p.last().unwrap())?, maze.cell_of(*g)?);
            maze.path_distance(from, to)
                .map(|cells| f64::from(cells) * f64::from(maze.cell_size_m()))
        })
        .collect();
    assert!(!along.is_empty());
    let mean_along = along.iter().sum::<f64>() / along.len() as f64;
    assert_eq!(ra.mean_final_path_distance, Some(mean_along));
    // Episodes that did not succeed ran to the time limit.
    for path in &ra.trajectories {
        assert!(path.len() - 1 <= 60);
    }
    if ra.success_rate == 0.0 {
        assert!(ra.trajectories.iter().all(|p| p.len() - 1 == 60));
    }
    // Another evaluation index gives other start states.
    let rc = a.run(5, 3).unwrap();
    assert_ne!(ra.trajectories[0][0], rc.trajectories[0][0]);
}

#[test]
fn a_start_at_the_goal_region_succeeds_and_ends_the_episode_early() {
    // With episode length 1 nothing can succeed unless the start is in the goal region; use the
    // success accounting instead: an episode that reports success must stop before the limit.
    let config = config("pointmaze-u", 400);
    let (header, bytes) = weights(&config, 1);
    let mut eval = Evaluator::new(&config, 9).unwrap();
    eval.load_weights(&header, &bytes).unwrap();
    let report = eval.run(0, 2).unwrap();
    for path in &report.trajectories {
        let last = path.last().unwrap();
        let g = report.goals[0];
        let reached = (last[0] - g[0]).hypot(last[1] - g[1]) <= 1.5;
        assert_eq!(reached, path.len() - 1 < 400, "success ⇔ early end");
    }
}

#[test]
fn wrong_weights_are_refused_and_change_nothing() {
    let config = config("pointmaze-u", 30);
    let (header, bytes) = weights(&config, 2);
    let mut eval = Evaluator::new(&config, 3).unwrap();
    let before = eval.run(0, 1).unwrap();
    let mut bad = header;
    bad.layout_hash ^= 1;
    assert!(eval.load_weights(&bad, &bytes).is_err());
    assert!(eval
        .load_weights(&header, &bytes[..bytes.len() - 1])
        .is_err());
    assert_eq!(eval.run(0, 1).unwrap(), before);
}

#[test]
fn unknown_test_variant_is_an_error() {
    assert_eq!(test_task_name("antmaze-w"), "antmaze-w-test");
    let mut config = config("pointmaze-u", 30);
    config.env.task = "no-such-task".to_owned();
    assert!(Evaluator::new(&config, 0).is_err());
}
