//! The SI buffer: entries point at their episode's start, the oldest quarter goes when full,
//! sampling is uniform without replacement, refused input is counted.

use learner::si::routes::{usable_route, RouteKind};
use learner::si::SiBuffer;
use protocol::graph::{NoRouteReason, RouteAnswer};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

fn obs(v: f32) -> [f32; 3] {
    [v, v + 0.5, -v]
}

#[test]
fn entries_keep_their_episode_start_without_copying_it_per_step() {
    let mut b = SiBuffer::new(3, 2, 100);
    let e0 = b.begin_episode(&obs(0.0)).unwrap();
    let e1 = b.begin_episode(&obs(100.0)).unwrap();
    b.push(e0, &obs(1.0), &[5.0, 6.0]);
    b.push(e1, &obs(101.0), &[7.0, 8.0]);
    b.push(e0, &obs(2.0), &[5.0, 6.0]);
    assert_eq!(b.len(), 3);
    assert_eq!(b.n_starts(), 2);
    let third = b.get(2).unwrap();
    assert_eq!(third.s0, obs(0.0));
    assert_eq!(third.obs, obs(2.0));
    assert_eq!(third.goal, [5.0, 6.0]);
    assert_eq!(b.get(1).unwrap().s0, obs(100.0));
    assert!(b.get(3).is_none());
}

#[test]
fn a_full_buffer_drops_its_oldest_quarter_and_the_starts_nobody_needs() {
    let mut b = SiBuffer::new(3, 2, 8);
    let early = b.begin_episode(&obs(0.0)).unwrap();
    for t in 0..4 {
        assert!(b.push(early, &obs(t as f32), &[0.0, 0.0]));
    }
    let late = b.begin_episode(&obs(50.0)).unwrap();
    for t in 0..4 {
        assert!(b.push(late, &obs(50.0 + t as f32), &[1.0, 1.0]));
    }
    assert_eq!(b.len(), 8);
    // Full: the next push drops entries 0 and 1 (a quarter of 8) first.
    assert!(b.push(late, &obs(54.0), &[1.0, 1.0]));
    assert_eq!(b.len(), 7);
    assert_eq!(b.n_evicted(), 2);
    assert_eq!(b.get(0).unwrap().obs, obs(2.0));
    assert_eq!(b.n_starts(), 2, "the early episode still has entries");
    // One more eviction (at the second of three pushes) leaves only the late episode: its start
    // alone remains.
    for t in 55..58 {
        b.push(late, &obs(t as f32), &[1.0, 1.0]);
    }
    assert!(b.get(0).unwrap().s0 == obs(50.0));
    assert_eq!(b.n_starts(), 1);
    // The early episode's start is gone: a late step of it is counted, not stored.
    assert!(!b.push(early, &obs(9.0), &[0.0, 0.0]));
    assert_eq!(b.n_orphaned(), 1);
    assert!(b.len() <= 8);
}

#[test]
fn wrong_lengths_and_unknown_episodes_are_refused_and_counted() {
    let mut b = SiBuffer::new(3, 2, 8);
    assert!(b.begin_episode(&[1.0, 2.0]).is_none());
    let e = b.begin_episode(&obs(0.0)).unwrap();
    assert!(!b.push(e, &[1.0], &[0.0, 0.0]));
    assert!(!b.push(e, &obs(1.0), &[0.0]));
    assert!(!b.push(learner::si::EpisodeRef(7), &obs(1.0), &[0.0, 0.0]));
    assert_eq!(b.n_rejected(), 4);
    assert!(b.is_empty());
}

#[test]
fn sampling_draws_distinct_entries_uniformly() {
    let mut b = SiBuffer::new(3, 2, 100);
    let e = b.begin_episode(&obs(0.0)).unwrap();
    for t in 0..10 {
        b.push(e, &obs(t as f32), &[0.0, 0.0]);
    }
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut hits = [0u32; 10];
    for _ in 0..2000 {
        let mut rows = b.sample(&mut rng, 4);
        assert_eq!(rows.len(), 4);
        rows.sort_unstable();
        rows.dedup();
        assert_eq!(rows.len(), 4, "without replacement");
        for r in rows {
            hits[r] += 1;
        }
    }
    // Each entry is drawn with probability 0.4: 800 expected; ±5 σ (σ ≈ 22) is generous.
    for (i, h) in hits.iter().enumerate() {
        assert!((690..=910).contains(h), "entry {i} drawn {h} times");
    }
    assert_eq!(
        b.sample(&mut rng, 50).len(),
        10,
        "at most the buffer's length"
    );
}

#[test]
fn only_direct_and_frontier_routes_long_enough_are_usable() {
    let route = vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]];
    let direct = RouteAnswer::Direct(route.clone());
    let frontier = RouteAnswer::ViaFrontier(route.clone());
    assert_eq!(
        usable_route(&direct, 3).map(|(_, k)| k),
        Some(RouteKind::Direct)
    );
    assert_eq!(
        usable_route(&frontier, 2).map(|(_, k)| k),
        Some(RouteKind::ViaFrontier)
    );
    assert!(usable_route(&direct, 4).is_none(), "too short");
    let none = RouteAnswer::NoRoute {
        direct: NoRouteReason::Unreachable,
        fallback: None,
    };
    assert!(usable_route(&none, 1).is_none());
    let bad = RouteAnswer::Direct(vec![[0.0, 0.0], [f32::NAN, 1.0]]);
    assert!(
        usable_route(&bad, 2).is_none(),
        "non-finite points are refused"
    );
}

#[test]
fn a_buffer_rebuilt_from_its_parts_is_the_same_and_bad_parts_are_refused() {
    let mut b = SiBuffer::new(3, 2, 4);
    for ep in 0..3 {
        let e = b.begin_episode(&obs(10.0 * ep as f32)).unwrap();
        for t in 0..2 {
            b.push(
                e,
                &obs(10.0 * ep as f32 + t as f32 + 1.0),
                &[ep as f32, 0.0],
            );
        }
    }
    assert_eq!(
        b.n_evicted(),
        2,
        "the fifth and sixth pushes each evicted a quarter of 4"
    );
    let copy = SiBuffer::from_parts(3, 2, 4, b.parts()).unwrap();
    assert_eq!(copy.parts(), b.parts());
    for i in 0..b.len() {
        assert_eq!(copy.get(i), b.get(i));
    }
    // An entry whose episode start is not held, and wrong lengths, are refused.
    let mut parts = b.parts();
    let bad_episode = [0u64, 0, 0, 0];
    parts.episode = &bad_episode;
    let err = SiBuffer::from_parts(3, 2, 4, parts).unwrap_err();
    assert!(err.contains("no start"), "{err}");
    let err = SiBuffer::from_parts(4, 2, 4, b.parts()).unwrap_err();
    assert!(err.contains("obs"), "{err}");
    let err = SiBuffer::from_parts(3, 2, 2, b.parts()).unwrap_err();
    assert!(err.contains("capacity"), "{err}");
}
