//! Replay buffers: lazy block allocation, ring overwrite, and sampling into reusable staging.

use learner::replay::{sample_into, Column, LowReplay, LowRewardSpec, LowTransition, BLOCK_ROWS};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

const REWARD: LowRewardSpec = LowRewardSpec {
    scale: 0.1,
    threshold: 0.1,
};

fn push(buffer: &mut LowReplay, t: f32) {
    let obs = [t, t, t];
    let next_obs = [t + 1.0; 3];
    buffer.push(&LowTransition {
        obs: &obs,
        phi: &[t, 0.0],
        action: &[t, -t],
        subgoal: &[0.0, 0.0],
        next_obs: &next_obs,
        next_phi: &[t + 1.0, 0.0],
        terminated: t == 2.0,
        truncated: false,
    });
}

#[test]
fn nothing_is_allocated_before_the_first_row_and_blocks_grow_with_the_data() {
    let mut column = Column::new(29, 8_000_000);
    assert_eq!(column.allocated(), 0);
    column.write(0, &[1.0; 29]);
    assert_eq!(
        column.allocated(),
        BLOCK_ROWS * 29,
        "one block, not the whole capacity"
    );
    column.write(BLOCK_ROWS, &[2.0; 29]);
    assert_eq!(column.allocated(), 2 * BLOCK_ROWS * 29);
    assert_eq!(column.row(0), &[1.0; 29]);
    assert_eq!(column.row(BLOCK_ROWS), &[2.0; 29]);
}

#[test]
fn a_full_buffer_overwrites_its_oldest_row_first() {
    let mut buffer = LowReplay::new(3, 3, 2, 2, REWARD);
    for t in 0..5 {
        push(&mut buffer, t as f32);
    }
    assert_eq!((buffer.ring().len(), buffer.ring().total()), (3, 5));
    // Rows: slot 0 ← t3, slot 1 ← t4, slot 2 ← t2.
    let firsts: Vec<f32> = (0..3).map(|i| buffer.get(i).obs[0]).collect();
    assert_eq!(firsts, vec![3.0, 4.0, 2.0]);
    assert!(buffer.get(2).terminated);
}

#[test]
fn sampling_fills_the_staging_in_network_input_order() {
    let mut buffer = LowReplay::new(4, 3, 2, 2, REWARD);
    push(&mut buffer, 2.0);
    let mut stage = buffer.stage(3);
    let mut rng = Pcg64Mcg::seed_from_u64(0);
    sample_into(&mut rng, 1, &mut stage, |s, k, i| buffer.fill(s, k, i));
    // head = [obs, φ], tail = subgoal, next head = [next_obs, next φ].
    assert_eq!(&stage.head[..5], &[2.0, 2.0, 2.0, 2.0, 0.0]);
    assert_eq!(&stage.next_head[..5], &[3.0, 3.0, 3.0, 3.0, 0.0]);
    assert_eq!(&stage.tail[..2], &[0.0, 0.0]);
    assert_eq!(&stage.action[..2], &[2.0, -2.0]);
    assert!((stage.reward[0] + 0.3).abs() < 1e-6);
    assert_eq!(stage.terminal, vec![1.0; 3], "terminated at t = 2");
}
