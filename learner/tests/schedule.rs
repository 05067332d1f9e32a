//! The run-wide schedule: hand-computed `count_prob` windows and `fr_prob` steps, and its
//! publication with the weights.

mod common;

use common::*;
use learner::schedule::count_prob;
use learner::Learner;
use protocol::config::FrProbStep;
use protocol::{RunSchedule, TrajectoryFlags};

fn close(a: f32, b: f64) {
    assert!((f64::from(a) - b).abs() < 1e-6, "{a} vs {b}");
}

/// Count windows of 4 episodes, x = successes / 2; FR after episode 3 with p 0.2, 0.3 from 5.
fn config() -> protocol::Config {
    let mut c = common::config();
    c.exploration.count_prob_interval_episodes = 4;
    c.exploration.count_prob_success_unit = 2.0;
    c.asi.fr_start_episode = 3;
    c.asi.fr_prob_schedule = vec![
        FrProbStep {
            from_episode: 0,
            p: 0.2,
        },
        FrProbStep {
            from_episode: 5,
            p: 0.3,
        },
    ];
    c.validate().unwrap();
    c
}

/// One 10-step episode in two chunks; `far` sets FAR_GOAL on the first chunk only, `success`
/// reports success at step 3 only (the code counts any success during the episode).
fn episode(l: &mut Learner, ep: u64, far: bool, success: bool) {
    let mut all = steps(0..10, ep, 2, 9);
    all[3].success = success;
    let far_bit = if far { TrajectoryFlags::FAR_GOAL } else { 0 };
    ingest(
        l,
        0,
        ep,
        0,
        &all[..5],
        TrajectoryFlags::EPISODE_START | far_bit,
    )
    .unwrap();
    let end = TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
    ingest(l, 0, ep, 1, &all[5..], end).unwrap();
}

#[test]
fn count_prob_follows_the_logistic_rule_of_the_code() {
    // 1/(1+exp(2x−1)): x = 0 → 0.7310586, 0.5 → 0.5, 1 → 0.2689414, 2 → 0.0474259 (digest §5.1)
    for (successes, want) in [(0, 0.731_058_6), (5, 0.268_941_4), (10, 0.047_425_9)] {
        assert!((count_prob(successes, 5.0) - want).abs() < 1e-6);
    }
    assert!((count_prob(2, 4.0) - 0.5).abs() < 1e-12);
}

#[test]
fn the_schedule_counts_far_goal_successes_per_window_and_steps_fr_prob() {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    assert_eq!(l.run_schedule(), RunSchedule::START);
    // Window 1: far+success, far only, success only (not far), far+success → 2 successes, x = 1.
    episode(&mut l, 0, true, true);
    episode(&mut l, 1, true, false);
    episode(&mut l, 2, false, true);
    let s = l.run_schedule();
    assert_eq!(
        (s.train_episodes, s.count_prob, s.fr_prob),
        (3, 1.0, 0.0),
        "FR only after 3"
    );
    episode(&mut l, 3, true, true);
    let s = l.run_schedule();
    assert_eq!(s.train_episodes, 4);
    close(s.count_prob, 0.268_941_421); // 1/(1+e)
    close(s.fr_prob, 0.2);
    episode(&mut l, 4, false, false);
    close(l.run_schedule().fr_prob, 0.3);
    // Window 2: no success → x = 0.
    for ep in 5..8 {
        episode(&mut l, ep, true, false);
    }
    let s = l.run_schedule();
    assert_eq!(s.train_episodes, 8);
    close(s.count_prob, 0.731_058_579); // 1/(1+e^−1)
}

#[test]
fn fr_prob_is_zero_when_frontier_reaching_is_off() {
    let mut c = config();
    c.asi.frontier_reaching = false;
    let mut l = Learner::new(&c, DIMS, 7).unwrap();
    for ep in 0..6 {
        episode(&mut l, ep, false, false);
    }
    assert_eq!(l.run_schedule().fr_prob, 0.0);
}

#[test]
fn publications_carry_the_schedule_and_a_count_prob_change_is_published_without_updates() {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    let (first, _) = l.publish_due().unwrap().unwrap();
    assert_eq!(first.schedule, RunSchedule::START);
    for ep in 0..3 {
        episode(&mut l, ep, true, true);
    }
    assert!(
        l.publish_due().unwrap().is_none(),
        "no update, count_prob and fr_prob unchanged: train_episodes alone waits"
    );
    episode(&mut l, 3, true, true); // window closes: 4 successes, x = 2
    let (second, _) = l.publish_due().unwrap().expect("count_prob changed");
    assert_eq!(second.schedule, l.run_schedule());
    assert_eq!(second.schedule.train_episodes, 4);
    close(second.schedule.count_prob, 0.047_425_873);
    assert_eq!(l.progress().updates_low, 0);
}
