//! Replay-ratio accounting (SPEC §6.8): allowed updates follow floor(N·ρ), the budget
//! arithmetic, and the throttle never deadlocks.

mod common;

use common::*;
use learner::ratio::{floor_product, steps_for, ReplayRatio};

#[test]
fn after_n_ingested_steps_exactly_floor_n_ratio_low_updates_run() {
    let mut l = learner(); // ρ_low = 0.4, batch 4; high needs 4 transitions (c-length segments)
    let mut total_low = 0;
    let mut n = 0u64;
    for (ep, len) in [(0u64, 3usize), (1, 7), (2, 10), (3, 5)] {
        ingest_episode(&mut l, 0, ep, len, 0, 3); // no decisions: only low updates
        n += len as u64;
        l.train(usize::MAX).unwrap();
        let expected = if n < 4 {
            0
        } else {
            (n as f64 * 0.4).floor() as u64
        };
        total_low = l.progress().updates_low;
        assert_eq!(total_low, expected, "after {n} steps");
        assert_eq!(l.train(usize::MAX).unwrap(), 0, "nothing more is allowed");
    }
    assert_eq!((n, total_low), (25, 10));
    assert_eq!(l.progress().updates_high, 0);
}

#[test]
fn train_respects_max_updates_and_catches_up_later() {
    let mut l = learner();
    ingest_episode(&mut l, 0, 0, 20, 0, 10); // 8 low updates allowed
    assert_eq!(l.train(3).unwrap(), 3);
    assert_eq!(l.train(100).unwrap(), 5);
    assert_eq!(l.progress().updates_low, 8);
}

#[test]
fn high_updates_follow_new_transitions_once_min_transitions_are_stored() {
    let mut l = learner(); // min_transitions 4, one update per transition
    ingest_episode(&mut l, 0, 0, 6, 2, 6); // 3 segments: no high update yet
    l.train(usize::MAX).unwrap();
    assert_eq!(l.progress().updates_high, 0);
    ingest_episode(&mut l, 0, 1, 6, 2, 6); // 6 transitions: 6 − 4 + 1 = 3 updates
    l.train(usize::MAX).unwrap();
    assert_eq!(l.progress().updates_high, 3);
    let ratio = l.replay_ratio();
    assert_eq!(
        (
            ratio.high_allowed(3, 3),
            ratio.high_allowed(4, 4),
            ratio.high_allowed(10, 10)
        ),
        (0, 1, 7)
    );
}

#[test]
fn floor_product_and_steps_for_are_inverse() {
    assert_eq!(floor_product(5, 0.4), 2);
    assert_eq!(floor_product(15, 0.2), 3);
    assert_eq!(floor_product(3, 0.4), 1);
    for ratio in [0.2, 0.4, 1.0 / 3.0, 1.0, 2.5] {
        for k in 0..200 {
            let n = steps_for(k, ratio);
            assert!(floor_product(n, ratio) >= k, "k {k} ratio {ratio}");
            assert!(
                n == 0 || floor_product(n - 1, ratio) < k,
                "k {k} ratio {ratio}: {n} is not the least"
            );
        }
    }
}

#[test]
fn budget_is_the_steps_the_next_update_needs_plus_slack_and_covers_warm_up() {
    let ratio = ReplayRatio {
        low_per_env_step: 0.2,
        low_batch: 128,
        high_per_transition: 1.0,
        high_min_transitions: 128,
        slack_steps: 20,
    };
    // Before learning: the warm-up batch plus the slack.
    assert_eq!(ratio.env_step_budget(0), 128 + 20);
    // After 100 updates (500 steps consumed): the 101st needs 505 steps.
    assert_eq!(ratio.env_step_budget(100), 505 + 20);
    assert_eq!(
        l_budget_via_learner(),
        4 + 10,
        "test config: batch 4, slack 10, ρ 0.4 → next needs 3"
    );
}

fn l_budget_via_learner() -> u64 {
    learner().progress().env_step_budget
}

#[test]
fn a_throttled_run_never_deadlocks_even_with_the_smallest_slack() {
    for (rho, batch, slack) in [(0.2, 128, 1), (0.4, 32, 1), (3.0, 4, 1), (0.05, 1, 1)] {
        let ratio = ReplayRatio {
            low_per_env_step: rho,
            low_batch: batch,
            high_per_transition: 1.0,
            high_min_transitions: 1,
            slack_steps: slack,
        };
        let (mut ingested, mut updates) = (0u64, 0u64);
        for _ in 0..2000 {
            // Actors produce one step at a time while under budget; the learner then runs
            // everything allowed.
            let produced = ingested < ratio.env_step_budget(updates);
            if produced {
                ingested += 1;
            }
            let allowed = ratio.low_allowed(ingested, ingested);
            let ran = allowed > updates;
            updates = updates.max(allowed);
            assert!(
                produced || ran,
                "deadlock at ρ {rho}: ingested {ingested}, updates {updates}"
            );
        }
        assert!(updates > 0, "ρ {rho}: learning started");
    }
}
