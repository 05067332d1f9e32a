//! Ingest: records land in the low buffer, high transitions are built across chunk boundaries,
//! and lost, duplicate and malformed chunks are counted without corrupting the buffers.

mod common;

use common::*;
use learner::LearnerError;
use protocol::{TrajectoryFlags, PROTOCOL_VERSION};

const START: u32 = TrajectoryFlags::EPISODE_START;
const END: u32 = TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;

#[test]
fn ingest_fills_the_low_buffer_with_the_record_values() {
    let mut l = learner();
    let records = steps(0..3, 4, 100, 99);
    ingest(&mut l, 1, 4, 0, &records, START).unwrap();
    let low = l.low_replay();
    assert_eq!(low.ring().len(), 3);
    for (i, r) in records.iter().enumerate() {
        let t = low.get(i);
        assert_eq!(t.obs, &r.obs[..]);
        assert_eq!(t.next_obs, &r.next_obs[..]);
        assert_eq!(t.phi, &r.phi[..]);
        assert_eq!(t.next_phi, &r.next_phi[..]);
        assert_eq!(t.subgoal, &r.subgoal[..]);
        assert_eq!(t.action, &r.action[..]);
        assert!(!t.terminated && !t.truncated);
    }
    // next φ = [0.1 (t+1), 0], subgoal [1, 0]: distance 1 − 0.1 (t+1); reward −0.1 × that.
    let (reward, reached) = low.reward_of(1);
    assert!((reward - (-0.1 * 0.8)).abs() < 1e-6, "{reward}");
    assert!(!reached);
    let stats = l.ingest_stats();
    assert_eq!(
        (stats.chunks, stats.env_steps, stats.per_actor_steps[&1]),
        (1, 3, 3)
    );
}

#[test]
fn the_low_reward_marks_a_reached_subgoal_within_the_threshold() {
    let mut l = learner();
    let mut records = steps(0..1, 0, 100, 99);
    records[0].next_phi = vec![1.05, 0.0]; // 0.05 from the subgoal [1, 0] ≤ 0.1
    ingest(&mut l, 0, 0, 0, &records, START).unwrap();
    let (reward, reached) = l.low_replay().reward_of(0);
    assert!(reached);
    assert!((reward + 0.005).abs() < 1e-6, "{reward}");
}

/// Episode of 8 steps, decisions at t = 0, 3, 6, chunks [0, 1], [2, 3, 4], [5, 6, 7],
/// rewards −(t+1), success at t = 4, last step truncated.
fn three_segment_episode(l: &mut learner::Learner) {
    let mut all = steps(0..8, 9, 3, 7);
    all[4].success = true;
    ingest(l, 2, 9, 0, &all[0..2], START).unwrap();
    assert_eq!(
        l.high_replay().ring().len(),
        0,
        "no segment is complete yet"
    );
    ingest(l, 2, 9, 1, &all[2..5], 0).unwrap();
    assert_eq!(l.high_replay().ring().len(), 1);
    ingest(l, 2, 9, 2, &all[5..8], END).unwrap();
}

#[test]
fn high_transitions_sum_rewards_mask_success_and_cross_chunk_boundaries() {
    let mut l = learner();
    three_segment_episode(&mut l);
    let high = l.high_replay();
    assert_eq!(high.ring().len(), 3);
    let expected = [
        // (obs t, action t, R, next_obs t, mask, truncated)
        (0.0, 0.0, -6.0, 3.0, 1.0, false),
        (3.0, 3.0, -15.0, 6.0, 0.0, false),
        (6.0, 6.0, -15.0, 8.0, 1.0, true),
    ];
    for (i, (obs_t, act, reward, next_t, mask, truncated)) in expected.into_iter().enumerate() {
        let h = high.get(i);
        assert_eq!(h.obs, &[obs_t, 9.0, 0.5], "segment {i}");
        assert_eq!(h.goal, &[5.0, 6.0]);
        assert_eq!(h.action, &[act, -act]);
        assert_eq!(h.reward, reward, "segment {i}");
        assert_eq!(h.next_obs, &[next_t, 9.0, 0.5], "segment {i}");
        assert_eq!(h.mask, mask, "segment {i}");
        assert_eq!(
            (h.terminated, h.truncated),
            (false, truncated),
            "segment {i}"
        );
    }
    let stats = l.ingest_stats();
    assert_eq!(
        (
            stats.episodes_completed,
            stats.high_transitions,
            stats.env_steps
        ),
        (1, 3, 8)
    );
}

#[test]
fn a_terminating_step_closes_its_segment_as_terminated() {
    let mut l = learner();
    let mut all = steps(0..4, 1, 2, 99);
    all[3].terminated = true;
    ingest(
        &mut l,
        0,
        1,
        0,
        &all,
        START | TrajectoryFlags::EPISODE_END | TrajectoryFlags::TERMINATED,
    )
    .unwrap();
    let h = l.high_replay().get(1);
    assert_eq!((h.reward, h.terminated, h.truncated), (-7.0, true, false));
    assert_eq!(h.next_obs, &[4.0, 1.0, 0.5]);
    assert!(l.low_replay().get(3).terminated);
}

#[test]
fn an_episode_ending_without_a_flag_closes_its_segment_as_truncated() {
    let mut l = learner();
    let all = steps(0..3, 1, 2, 99); // physics failure after t = 2: no flag on any step
    let flags = START | TrajectoryFlags::EPISODE_END | TrajectoryFlags::PHYSICS_FAILURE;
    ingest(&mut l, 0, 1, 0, &all, flags).unwrap();
    let h = l.high_replay().get(1);
    assert_eq!((h.reward, h.terminated, h.truncated), (-3.0, false, true));
    assert_eq!(h.next_obs, &[3.0, 1.0, 0.5]);
}

#[test]
fn a_repeated_chunk_is_counted_as_duplicate_and_not_stored() {
    let mut l = learner();
    let all = steps(0..4, 3, 2, 99);
    ingest(&mut l, 0, 3, 0, &all[0..2], START).unwrap();
    let err = ingest(&mut l, 0, 3, 0, &all[0..2], START).unwrap_err();
    assert!(
        matches!(
            err,
            LearnerError::DuplicateChunk {
                chunk_index: 0,
                expected: 1,
                ..
            }
        ),
        "{err}"
    );
    assert_eq!(l.low_replay().ring().len(), 2);
    ingest(&mut l, 0, 3, 1, &all[2..4], END).unwrap();
    // A late repeat after the episode ended is still recognised.
    assert!(matches!(
        ingest(&mut l, 0, 3, 1, &all[2..4], END),
        Err(LearnerError::DuplicateChunk { .. })
    ));
    let stats = l.ingest_stats();
    assert_eq!(
        (
            stats.duplicate_chunks,
            stats.chunks,
            stats.env_steps,
            stats.rejected_chunks
        ),
        (2, 2, 4, 0)
    );
    assert_eq!(l.low_replay().ring().len(), 4);
}

#[test]
fn a_gap_counts_lost_chunks_and_drops_the_broken_segment() {
    let mut l = learner();
    let all = steps(0..8, 5, 3, 7);
    ingest(&mut l, 0, 5, 0, &all[0..2], START).unwrap();
    // Chunks 1 and 2 (steps 2..5) never arrive.
    ingest(&mut l, 0, 5, 3, &all[5..8], END).unwrap();
    let stats = l.ingest_stats();
    assert_eq!((stats.lost_chunks, stats.dropped_segments), (2, 1));
    assert_eq!(l.low_replay().ring().len(), 5);
    // Only the segment opened at t = 6 (after the gap) is complete and stored.
    assert_eq!(l.high_replay().ring().len(), 1);
    assert_eq!(l.high_replay().get(0).reward, -15.0);
}

#[test]
fn a_first_chunk_with_a_late_index_counts_the_earlier_chunks_lost() {
    let mut l = learner();
    ingest(&mut l, 0, 6, 2, &steps(0..2, 6, 100, 99), 0).unwrap();
    assert_eq!(l.ingest_stats().lost_chunks, 2);
}

fn assert_unchanged(l: &learner::Learner) {
    assert_eq!(l.low_replay().ring().len(), 0);
    assert_eq!(l.high_replay().ring().len(), 0);
    assert_eq!(l.ingest_stats().env_steps, 0);
}

#[test]
fn a_chunk_with_the_wrong_length_is_rejected_and_changes_nothing() {
    let mut l = learner();
    let records = steps(0..3, 0, 2, 99);
    let mut payload = layout().encode_chunk(&records).unwrap();
    payload.pop();
    let err = l
        .ingest(&header(0, 0, 0, &records, START), &payload)
        .unwrap_err();
    assert!(matches!(err, LearnerError::Rejected { .. }), "{err}");
    assert_unchanged(&l);
    assert_eq!(l.ingest_stats().rejected_chunks, 1);
    // The episode is still expected from chunk 0: the rejected chunk did not advance it.
    ingest(&mut l, 0, 0, 0, &records, START).unwrap();
    assert_eq!(l.ingest_stats().lost_chunks, 0);
}

#[test]
fn a_chunk_with_another_protocol_version_is_rejected_and_changes_nothing() {
    let mut l = learner();
    let records = steps(0..3, 0, 2, 99);
    let payload = layout().encode_chunk(&records).unwrap();
    let mut h = header(0, 0, 0, &records, START);
    h.protocol_version = PROTOCOL_VERSION + 1;
    let err = l.ingest(&h, &payload).unwrap_err().to_string();
    assert!(err.contains("version"), "{err}");
    assert_unchanged(&l);
    assert_eq!(l.ingest_stats().rejected_chunks, 1);
}

#[test]
fn a_chunk_of_another_layout_or_with_a_bad_record_is_rejected() {
    let mut l = learner();
    let records = steps(0..2, 0, 2, 99);
    let mut h = header(0, 0, 0, &records, START);
    h.obs_dim = 4;
    let payload = vec![0.0; 2 * protocol::StepLayout::new(4, 2, 2, 2).unwrap().record_len()];
    assert!(matches!(
        l.ingest(&h, &payload),
        Err(LearnerError::LayoutMismatch { .. })
    ));
    let mut payload = layout().encode_chunk(&records).unwrap();
    payload[0] = f32::NAN;
    assert!(matches!(
        l.ingest(&header(0, 0, 0, &records, START), &payload),
        Err(LearnerError::Rejected { .. })
    ));
    assert_unchanged(&l);
    assert_eq!(l.ingest_stats().rejected_chunks, 2);
}

#[test]
fn a_chunk_after_the_episode_end_is_rejected() {
    let mut l = learner();
    ingest(&mut l, 0, 0, 0, &steps(0..2, 0, 2, 1), START | END).unwrap();
    let err = ingest(&mut l, 0, 0, 1, &steps(2..3, 0, 2, 99), 0).unwrap_err();
    assert!(
        matches!(err, LearnerError::AfterEpisodeEnd { last: 0, .. }),
        "{err}"
    );
    assert_eq!(l.ingest_stats().rejected_chunks, 1);
}

#[test]
fn episodes_of_different_actors_with_the_same_id_are_kept_apart() {
    let mut l = learner();
    ingest(&mut l, 0, 1, 0, &steps(0..2, 1, 2, 99), START).unwrap();
    ingest(&mut l, 1, 1, 0, &steps(0..2, 1, 2, 99), START).unwrap();
    let stats = l.ingest_stats();
    assert_eq!((stats.duplicate_chunks, stats.env_steps), (0, 4));
    assert_eq!(
        stats.per_actor_steps.values().copied().collect::<Vec<_>>(),
        vec![2, 2]
    );
}

/// Ingests episode `ep` of actor 0 (10 steps, decisions every 2, two chunks) with `extra` flags
/// on every chunk.
fn episode_with_flags(l: &mut learner::Learner, ep: u64, extra: u32) {
    let all = steps(0..10, ep, 2, 9);
    ingest(l, 0, ep, 0, &all[0..5], START | extra).unwrap();
    ingest(l, 0, ep, 1, &all[5..10], END | extra).unwrap();
}

#[test]
fn fr_episodes_feed_both_replays_unless_switched_out() {
    // Default: an FR episode is stored like any other, 10 low transitions and 5 segments.
    let mut l = learner();
    episode_with_flags(&mut l, 1, TrajectoryFlags::FRONTIER);
    episode_with_flags(&mut l, 2, 0);
    assert_eq!(l.low_replay().ring().len(), 20);
    assert_eq!(l.high_replay().ring().len(), 10);
    for (low, high, want_low, want_high) in [
        (false, true, 10, 10),
        (true, false, 20, 5),
        (false, false, 10, 5),
    ] {
        let mut config = config();
        config.asi.fr_in_low_replay = low;
        config.asi.fr_in_high_replay = high;
        let mut l = learner::Learner::new(&config, DIMS, 7).unwrap();
        episode_with_flags(&mut l, 1, TrajectoryFlags::FRONTIER);
        episode_with_flags(&mut l, 2, 0);
        let switches = format!("fr_in_low_replay={low} fr_in_high_replay={high}");
        assert_eq!(l.low_replay().ring().len(), want_low, "{switches}");
        assert_eq!(l.high_replay().ring().len(), want_high, "{switches}");
        // What is kept is the ordinary episode's (obs[1] is the episode id), and the episode,
        // its env steps and the φ store count both episodes either way.
        if !low {
            assert!(
                (0..10).all(|i| l.low_replay().get(i).obs[1] == 2.0),
                "{switches}"
            );
        }
        if !high {
            assert!(
                (0..5).all(|i| l.high_replay().get(i).obs[1] == 2.0),
                "{switches}"
            );
        }
        let stats = l.ingest_stats();
        assert_eq!(
            (stats.episodes_completed, stats.env_steps),
            (2, 20),
            "{switches}"
        );
        assert_eq!(stats.high_transitions, want_high as u64, "{switches}");
        assert_eq!(
            stats.frontier_steps, 10,
            "the FR episode's steps, {switches}"
        );
    }
}
