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
    episode_with(l, ep, far, success, 0);
}

/// [`episode`] with `extra` flags on both chunks (the actor flags every chunk of an FR episode
/// `FRONTIER`).
fn episode_with(l: &mut Learner, ep: u64, far: bool, success: bool, extra: u32) {
    let mut all = steps(0..10, ep, 2, 9);
    all[3].success = success;
    let far_bit = if far { TrajectoryFlags::FAR_GOAL } else { 0 };
    ingest(
        l,
        0,
        ep,
        0,
        &all[..5],
        TrajectoryFlags::EPISODE_START | far_bit | extra,
    )
    .unwrap();
    let end = TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED | extra;
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

/// Seven episodes, FR ones (flagged `FRONTIER`) at 1, 2 and 5: ordinary far+success, FR
/// far+success twice, ordinary far without success, ordinary far+success, FR far+success,
/// ordinary success without a far goal. Returns the schedule after the fourth and the last.
fn fr_mix(l: &mut Learner) -> (RunSchedule, RunSchedule) {
    let fr = TrajectoryFlags::FRONTIER;
    episode(l, 0, true, true);
    episode_with(l, 1, true, true, fr);
    episode_with(l, 2, true, true, fr);
    episode(l, 3, true, false);
    let fourth = l.run_schedule();
    episode(l, 4, true, true);
    episode_with(l, 5, true, true, fr);
    episode(l, 6, false, true);
    (fourth, l.run_schedule())
}

/// The window's contents: (`schedule/window_episodes`, `schedule/window_far_goal_successes`).
fn window(l: &Learner) -> (f64, f64) {
    (
        metric(l, "schedule/window_episodes"),
        metric(l, "schedule/window_far_goal_successes"),
    )
}

#[test]
fn fr_episodes_fill_the_count_window_by_default_as_in_the_code() {
    let mut l = Learner::new(&config(), DIMS, 7).unwrap();
    let (fourth, last) = fr_mix(&mut l);
    // Window 1 = episodes 0-3: 3 far-goal successes (two of them FR), x = 1.5.
    assert_eq!(fourth.train_episodes, 4);
    close(fourth.count_prob, 0.119_202_922); // 1/(1+e^2)
                                             // Episodes 4-6 open window 2: 2 far-goal successes so far.
    assert_eq!(last.train_episodes, 7);
    close(last.count_prob, 0.119_202_922);
    assert_eq!(window(&l), (3.0, 2.0));
}

#[test]
fn with_fr_out_of_the_count_window_a_window_holds_only_ordinary_episodes() {
    let mut c = config();
    c.asi.fr_in_count_window = false;
    let mut l = Learner::new(&c, DIMS, 7).unwrap();
    let (fourth, last) = fr_mix(&mut l);
    // After episode 3 the window holds episodes 0 and 3 only: still open, count_prob at 1.
    assert_eq!((fourth.train_episodes, fourth.count_prob), (4, 1.0));
    // Episodes 0, 3, 4 and 6 close it: 2 far-goal successes (0 and 4), x = 1; the FR
    // episodes' successes and the non-far success at 6 do not count.
    assert_eq!(
        last.train_episodes, 7,
        "FR episodes still count as training episodes"
    );
    close(last.count_prob, 0.268_941_421); // 1/(1+e)
    assert_eq!(window(&l), (0.0, 0.0));
    // FR probability follows every training episode either way.
    close(last.fr_prob, 0.3);
}
