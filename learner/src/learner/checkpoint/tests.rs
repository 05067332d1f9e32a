//! The replay files of format 3: next observations kept only where they are not the next
//! row's observation, checked against a brute-force walk in insertion order.

use super::*;
use ckpt::Array;

/// Widths of the eight test columns, in [`restore_columns`]' order; `next_obs` (index 4)
/// follows `obs` (0) and `next_phi` (5) follows `phi` (1).
const WIDTHS: [usize; 8] = [2, 1, 1, 3, 2, 1, 1, 1];
const NAMES: [&str; 8] = [
    "obs",
    "phi",
    "action",
    "subgoal",
    "next_obs",
    "next_phi",
    "terminated",
    "truncated",
];

/// Columns of `capacity` rows filled with `rows` transitions of sequence numbers `0..rows`.
/// Transition `r`'s observation is `[r, r + 0.5]` and its φ `[-r]`; its next observation is
/// transition `r + 1`'s, except after the transitions in `ends` (an episode's last: `[-1, -r]`)
/// and at `r = 5`, whose next φ is `-0.0` where transition 6's φ is `0.0` (equal as floats,
/// not bit for bit). Transition 9's observation holds a NaN, which its predecessor's
/// next observation repeats bit for bit.
fn filled(capacity: usize, rows: u64, ends: &[u64]) -> (Ring, Vec<Column>) {
    let mut ring = Ring::new(capacity);
    let mut columns: Vec<Column> = WIDTHS.iter().map(|&w| Column::new(w, capacity)).collect();
    let obs = |r: u64| match r {
        9 => [f32::from_bits(0x7fc0_1234), 9.5],
        _ => [r as f32, r as f32 + 0.5],
    };
    let phi = |r: u64| match r {
        6 => [0.0],
        _ => [-(r as f32)],
    };
    for r in 0..rows {
        let slot = ring.claim();
        let (next_obs, next_phi) = if ends.contains(&r) {
            ([-1.0, -(r as f32)], [7.0])
        } else if r == 5 {
            (obs(6), [-0.0])
        } else {
            (obs(r + 1), phi(r + 1))
        };
        let values: [&[f32]; 8] = [
            &obs(r),
            &phi(r),
            &[r as f32 * 0.1],
            &[1.0, 2.0, r as f32],
            &next_obs,
            &next_phi,
            &[f32::from(u8::from(ends.contains(&r)))],
            &[0.0],
        ];
        for (col, v) in columns.iter_mut().zip(values) {
            col.write(slot, v);
        }
    }
    (ring, columns)
}

fn named(columns: &[Column]) -> Vec<(&'static str, &Column)> {
    NAMES.iter().copied().zip(columns.iter()).collect()
}

fn restore(bytes: &[u8], capacity: usize) -> Result<(Ring, Vec<Column>), String> {
    let mut ring = Ring::new(capacity);
    let mut columns: Vec<Column> = WIDTHS.iter().map(|&w| Column::new(w, capacity)).collect();
    let [a, b, c, d, e, f, g, h] = &mut columns[..] else {
        unreachable!("eight columns")
    };
    let parts = [
        (NAMES[0], a),
        (NAMES[1], b),
        (NAMES[2], c),
        (NAMES[3], d),
        (NAMES[4], e),
        (NAMES[5], f),
        (NAMES[6], g),
        (NAMES[7], h),
    ];
    restore_columns(bytes, &mut ring, parts, LOW_SUCCESSORS)?;
    Ok((ring, columns))
}

fn bits(col: &Column, len: usize) -> Vec<u32> {
    col.export_rows(len).iter().map(|x| x.to_bits()).collect()
}

/// Physical rows whose next observation and φ are the next transition's, found by walking the
/// transitions in insertion order (sequence numbers `total − len .. total`).
fn brute_force_follows(ring: &Ring, columns: &[Column]) -> Vec<bool> {
    let len = ring.len();
    let oldest = ring.total() - len as u64;
    let slot = |seq: u64| (seq % ring.capacity() as u64) as usize;
    let mut follows = vec![false; len];
    for seq in oldest..ring.total() - 1 {
        let (i, j) = (slot(seq), slot(seq + 1));
        let same = |d: usize, s: usize| {
            let (a, b) = (columns[d].row(i), columns[s].row(j));
            a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        follows[i] = same(4, 0) && same(5, 1);
    }
    follows
}

#[test]
fn next_observations_are_kept_only_where_they_do_not_follow_and_come_back_bit_for_bit() {
    // Not full (8 of 10 rows), then wrapped twice over (23 rows into 10: the newest is row 2).
    for (capacity, rows) in [(10, 8), (10, 23), (1, 3)] {
        let (ring, columns) = filled(capacity, rows, &[3, 14, 20]);
        let bytes = save_columns(&ring, &named(&columns), LOW_SUCCESSORS).unwrap();
        let expected = brute_force_follows(&ring, &columns);

        let (st, _) = parse_safetensors(&bytes).unwrap();
        let follows: Vec<bool> = array::<u8>(&st, FOLLOWS, Some(ring.len()))
            .unwrap()
            .into_iter()
            .map(|f| f == 1)
            .collect();
        assert_eq!(follows, expected, "capacity {capacity}, {rows} rows");
        let kept = expected.iter().filter(|&&f| !f).count();
        let shape = |name: &str| st.tensor(name).unwrap().shape().to_vec();
        assert_eq!(shape("next_obs"), [kept, 2]);
        assert_eq!(shape("next_phi"), [kept, 1]);
        assert_eq!(shape("obs"), [ring.len(), 2]);

        let (restored_ring, restored) = restore(&bytes, capacity).unwrap();
        assert_eq!(restored_ring, ring);
        for (name, (a, b)) in NAMES.iter().zip(columns.iter().zip(&restored)) {
            assert_eq!(bits(a, ring.len()), bits(b, ring.len()), "{name}");
        }
    }
    // The cases the walk must see: the rows after an episode's end, the sign of a zero, the
    // NaN, the newest row; everything else follows.
    let (ring, columns) = filled(10, 23, &[14, 20]);
    let follows = brute_force_follows(&ring, &columns);
    let not_following: Vec<usize> = (0..10).filter(|&i| !follows[i]).collect();
    // Rows hold sequence numbers 13..23: 14 → row 4, 20 → row 0, the newest (22) → row 2.
    assert_eq!(not_following, [0, 2, 4]);
    let (ring, columns) = filled(10, 10, &[]);
    let follows = brute_force_follows(&ring, &columns);
    // Transition 5's next φ is −0.0 against transition 6's 0.0; 8 → 9 repeats the NaN.
    assert_eq!((follows[5], follows[8], follows[9]), (false, true, false));
}

#[test]
fn whole_columns_of_formats_1_and_2_still_restore() {
    let (ring, columns) = filled(10, 23, &[3, 14, 20]);
    // Without successor pairs the columns are written whole and no flags: the older layout.
    let bytes = save_columns(&ring, &named(&columns), &[]).unwrap();
    let (st, _) = parse_safetensors(&bytes).unwrap();
    assert!(st.tensor(FOLLOWS).is_err());
    assert_eq!(st.tensor("next_obs").unwrap().shape(), [10, 2]);
    let (_, restored) = restore(&bytes, 10).unwrap();
    for (name, (a, b)) in NAMES.iter().zip(columns.iter().zip(&restored)) {
        assert_eq!(bits(a, 10), bits(b, 10), "{name}");
    }
}

/// `bytes` with the flags replaced by `follows` (everything else as written).
fn with_flags(bytes: &[u8], follows: &[u8]) -> Vec<u8> {
    let (st, metadata) = parse_safetensors(bytes).unwrap();
    let arrays: Vec<(String, Array)> = st
        .tensors()
        .into_iter()
        .map(|(name, view)| {
            let array = if name == FOLLOWS {
                Array::flat(follows)
            } else {
                let values: Vec<f32> = array(&st, &name, None).unwrap();
                Array::new(view.shape().to_vec(), &values).unwrap()
            };
            (name, array)
        })
        .collect();
    serialize(
        arrays.iter().map(|(n, a)| (n.clone(), a)).collect(),
        metadata,
    )
    .unwrap()
}

#[test]
fn flags_that_do_not_fit_the_ring_or_the_kept_rows_are_refused() {
    let (ring, columns) = filled(10, 23, &[3, 14, 20]);
    let bytes = save_columns(&ring, &named(&columns), LOW_SUCCESSORS).unwrap();
    let (st, _) = parse_safetensors(&bytes).unwrap();
    let flags: Vec<u8> = array(&st, FOLLOWS, None).unwrap();
    let newest = ring.next() - 1;
    let first_following = flags.iter().position(|&f| f == 1).unwrap();

    // The count of kept rows unchanged, so that only the newest row's flag is wrong.
    let mut newest_follows = flags.clone();
    newest_follows[newest] = 1;
    newest_follows[first_following] = 0;
    let mut one_more_kept = flags.clone();
    one_more_kept[first_following] = 0;
    let mut two = flags.clone();
    two[first_following] = 2;
    for (case, flags, expected) in [
        ("newest", &newest_follows, "newest row"),
        ("count", &one_more_kept, "tensor `next_obs` has"),
        ("value", &two, "not 0 or 1"),
    ] {
        let err = restore(&with_flags(&bytes, flags), 10).unwrap_err();
        assert!(err.contains(expected), "{case}: {err}");
    }
    let err = restore(&with_flags(&bytes, &flags[1..]), 10).unwrap_err();
    assert!(err.contains("tensor `follows` has"), "{err}");
}
