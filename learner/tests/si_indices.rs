//! SI route indices (digest §8) against values worked out by hand from the reference code:
//! `idx = min(k, L − 1)`, references `int(linspace(1, max(1, min(L − 1, idx) // 2), 3))`.

use learner::si::{reference_indices, target_index, MIN_HIGH_ROUTE_LEN, MIN_LOW_ROUTE_LEN};

#[test]
fn the_target_index_is_k_clamped_to_the_last_route_node() {
    // Rows: route length L = 1..=8; columns: k = 3, 4, 5.
    let want: [[usize; 3]; 8] = [
        [0, 0, 0],
        [1, 1, 1],
        [2, 2, 2],
        [3, 3, 3],
        [3, 4, 4],
        [3, 4, 5],
        [3, 4, 5],
        [3, 4, 5],
    ];
    for (row, len) in (1..=8).enumerate() {
        for (col, k) in [3, 4, 5].into_iter().enumerate() {
            assert_eq!(
                target_index(k, len),
                Some(want[row][col]),
                "L = {len}, k = {k}"
            );
        }
    }
    assert_eq!(target_index(3, 0), None, "an empty route has no index");
}

#[test]
fn reference_indices_follow_the_truncated_linspace() {
    // idx 3 → stop 1 → [1, 1, 1]; idx 4 or 5 → stop 2 → linspace(1, 2, 3) = [1, 1.5, 2] → [1, 1, 2].
    assert_eq!(reference_indices(3, 8, 3), vec![1, 1, 1]);
    assert_eq!(reference_indices(4, 8, 3), vec![1, 1, 2]);
    assert_eq!(reference_indices(5, 8, 3), vec![1, 1, 2]);
    // Short routes: L = 3 → idx ≤ 2 → stop 1.
    assert_eq!(reference_indices(2, 3, 3), vec![1, 1, 1]);
    // An index beyond the route is clamped first: min(L − 1, 5) = 3 → [1, 1, 1].
    assert_eq!(reference_indices(5, 4, 3), vec![1, 1, 1]);
    // Other |u|: idx 9 → stop 4: linspace(1, 4, 4) = [1, 2, 3, 4]; linspace(1, 4, 3) = [1, 2.5, 4].
    assert_eq!(reference_indices(9, 20, 4), vec![1, 2, 3, 4]);
    assert_eq!(reference_indices(9, 20, 3), vec![1, 2, 4]);
    // |u| = 1: numpy's linspace gives its start.
    assert_eq!(reference_indices(5, 8, 1), vec![1]);
}

#[test]
fn references_never_pass_the_target_on_routes_the_low_level_keeps() {
    for len in MIN_LOW_ROUTE_LEN..=12 {
        for k in 1..=8 {
            let idx = target_index(k, len).unwrap();
            for u in reference_indices(idx, len, 3) {
                assert!(
                    u >= 1 && u <= idx && u < len,
                    "L {len} k {k}: u {u} idx {idx}"
                );
            }
        }
    }
}

#[test]
fn the_minimum_route_lengths_are_the_codes() {
    // High level: L > 1; low level: L > 2.
    assert_eq!(MIN_HIGH_ROUTE_LEN, 2);
    assert_eq!(MIN_LOW_ROUTE_LEN, 3);
}
