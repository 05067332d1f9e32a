//! The φ store on its own: capacity and eviction order, freezing, candidates; the anchor split
//! against a brute-force sort.

use learner::phi::round::top_fraction;
use learner::phi::{PhiParams, PhiStore, RunKind};
use protocol::Config;

/// A run of `n` states of obs_dim 2: state t = [id, t].
fn run(id: f32, n: usize) -> Vec<f32> {
    (0..n).flat_map(|t| [id, t as f32]).collect()
}

#[test]
fn the_store_evicts_the_oldest_runs_beyond_its_state_capacity() {
    let mut s = PhiStore::new(2, 2, 10);
    s.push_run(run(0.0, 4), RunKind::Complete);
    s.push_run(run(1.0, 4), RunKind::Complete);
    assert_eq!((s.n_runs(), s.n_states()), (2, 8));
    s.push_run(run(2.0, 5), RunKind::Complete);
    assert_eq!((s.n_runs(), s.n_states()), (2, 9), "run 0 evicted");
    assert_eq!(s.state(0, 3), Some(&[1.0f32, 3.0][..]));
    assert_eq!(s.stats().evicted, 1);
    s.push_run(run(3.0, 11), RunKind::Complete);
    assert_eq!(
        s.stats().dropped_short,
        1,
        "a run above the capacity is refused, counted"
    );
    assert_eq!(s.n_runs(), 2);
}

#[test]
fn a_frozen_store_stages_new_runs_until_it_thaws() {
    let mut s = PhiStore::new(2, 1, 100);
    s.push_run(run(0.0, 3), RunKind::Complete);
    s.freeze();
    s.push_run(run(1.0, 3), RunKind::Complete);
    assert_eq!((s.n_runs(), s.n_staged()), (1, 1));
    assert_eq!(s.candidates().len(), 2, "t = 0, 1 with k = 1");
    s.thaw();
    assert_eq!((s.n_runs(), s.n_staged()), (2, 0));
    assert_eq!(s.candidates().len(), 4);
    assert_eq!(s.priority(1, 2), Some(1.0), "priorities start at 1");
}

#[test]
fn anchors_come_from_the_highest_priorities_as_a_sort_would_give() {
    let mut x: u64 = 12345;
    for n in [1usize, 2, 7, 50, 301] {
        let p: Vec<f32> = (0..n)
            .map(|_| {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (x >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        for ratio in [0.5, 0.3, 1.0, 0.01] {
            let got = top_fraction(&p, ratio);
            let cut = ((n as f64 * (1.0 - ratio)).floor() as usize).min(n - 1);
            let mut sorted: Vec<f32> = p.clone();
            sorted.sort_by(f32::total_cmp);
            let mut chosen: Vec<f32> = got.iter().map(|&i| p[i as usize]).collect();
            chosen.sort_by(f32::total_cmp);
            assert_eq!(chosen, sorted[cut..].to_vec(), "n {n} ratio {ratio}");
        }
    }
}

#[test]
fn the_stable_coefficient_starts_at_the_second_round_and_switches_after_the_episode() {
    let mut c = Config::default();
    c.encoder.stable_coeff = 0.001;
    c.encoder.stable_coeff_late = 0.1;
    let p = PhiParams::from_config(&c); // rounds at 100, 200, …; switch after 500
    assert_eq!(p.negative_offset, c.hierarchy.c as usize);
    assert_eq!((p.round_episode(0), p.round_episode(4)), (100, 500));
    assert_eq!(p.stable_coeff_for(0), 0.0);
    assert_eq!(p.stable_coeff_for(1), 0.001);
    assert_eq!(
        p.stable_coeff_for(4),
        0.001,
        "the round at 500: code's epoch > 500 is false"
    );
    assert_eq!(p.stable_coeff_for(5), 0.1);
}
