//! φ rounds end to end in the learner: a small real round learns the temporal structure of a
//! point moving on a line, is run in slices that hold the SAC updates and the throttle, and
//! publishes a new φ version with the actors' layout hash unchanged.

mod common;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use common::*;
use learner::phi::triplet_loss;
use learner::{Learner, PHI_STEPS_PER_CALL};
use nets::{load_safetensors_bytes, seeded_var_builder, Encoder, PolicySet};
use protocol::{PhiVersion, TrajectoryFlags};

/// A learner on [`phi_config`]: rounds of 300 steps, run in several slices.
fn learner() -> Learner {
    Learner::new(&phi_config(), DIMS, 7).unwrap()
}

/// Mean triplet loss (margin 1, k = 2) over every triplet of the synthetic episodes
/// `0..n_episodes`: obs_t = [t, ep, 0.5], t = 0..=10 (a point moving on a line).
fn line_loss(phi: &Encoder, n_episodes: u64) -> f64 {
    let rows = |offset: usize| {
        let mut v = Vec::new();
        for ep in 0..n_episodes {
            for t in 0..=8usize {
                v.extend([(t + offset) as f32, ep as f32, 0.5]);
            }
        }
        let n = v.len() / 3;
        phi.forward(&Tensor::from_vec(v, (n, 3), &Device::Cpu).unwrap())
            .unwrap()
    };
    let (_, _, stats) = triplet_loss(&rows(0), &rows(1), &rows(2), 1.0).unwrap();
    stats.loss
}

#[test]
fn a_round_lowers_the_triplet_loss_and_publishes_a_new_phi_with_the_same_layout() {
    let mut l = learner();
    let (first, _) = l.publish_due().unwrap().unwrap();
    for ep in 0..4 {
        ingest_episode(&mut l, ep as u32 % 2, ep, 10, 2, 5);
    }
    assert_eq!(l.phi_store().n_runs(), 4);
    assert_eq!(
        l.phi_store().n_states(),
        44,
        "11 states per 10-step episode"
    );
    let before = line_loss(&encoder_of(&l), 4);
    let mut phi_steps = 0;
    while l.progress().phi_version == PhiVersion(0) {
        let ran = l.train(usize::MAX).unwrap();
        assert!(ran > 0, "a due round always makes progress");
        phi_steps += ran;
    }
    assert_eq!(phi_steps, 300);
    let after = line_loss(&encoder_of(&l), 4);
    assert!(
        after < 0.5 * before,
        "triplet loss {before} → {after}: φ should spread s_t+2 beyond s_t+1"
    );
    assert_eq!(metric(&l, "phi/rounds"), 1.0);
    assert_eq!(metric(&l, "phi/version"), 1.0);
    assert_eq!(
        metric(&l, "phi/stable_loss"),
        0.0,
        "no stable term in the first round"
    );
    assert!(metric(&l, "phi/round_end_loss") < metric(&l, "phi/round_start_loss"));
    let (header, bytes) = l
        .publish_due()
        .unwrap()
        .expect("a new φ is published at once");
    assert_eq!(header.phi_version, PhiVersion(1));
    assert_eq!(header.policy_version.0, first.policy_version.0 + 1);
    assert_eq!(header.layout_hash, first.layout_hash);
    // An actor's fresh set has the same layout and, loaded, the learner's new φ.
    let vm = VarMap::new();
    let actor = PolicySet::new(l.nets_spec(), &seeded_var_builder(&vm, 99, &Device::Cpu)).unwrap();
    header.check(nets::layout_hash(&vm), bytes.len()).unwrap();
    load_safetensors_bytes(&vm, &bytes).unwrap();
    assert_eq!(line_loss(&actor.encoder, 4), after);
}

#[test]
fn while_a_round_runs_no_sac_update_runs_the_budget_holds_and_new_episodes_wait() {
    let mut l = learner();
    for ep in 0..4 {
        ingest_episode(&mut l, 0, ep, 10, 2, 5);
    }
    let before = l.progress();
    assert_eq!(l.train(usize::MAX).unwrap() as u64, PHI_STEPS_PER_CALL);
    assert!(l.phi_round_active());
    let during = l.progress();
    assert_eq!(
        (
            during.updates_low,
            during.updates_high,
            during.env_step_budget
        ),
        (
            before.updates_low,
            before.updates_high,
            before.env_step_budget
        ),
        "SAC updates wait for the round, so the throttle budget does not grow"
    );
    ingest_episode(&mut l, 1, 10, 10, 2, 5);
    assert_eq!(
        l.phi_store().n_runs(),
        4,
        "the store is frozen during a round"
    );
    assert_eq!(l.phi_store().n_staged(), 1);
    let mut rest = 0;
    while l.phi_round_active() {
        assert_eq!(l.progress().updates_low, before.updates_low);
        rest += l.train(usize::MAX).unwrap() as u64;
    }
    assert_eq!(rest, 300 - PHI_STEPS_PER_CALL, "the rest of the round");
    assert_eq!(
        l.phi_store().n_runs(),
        5,
        "staged episodes enter after the round"
    );
    assert!(l.train(usize::MAX).unwrap() > 0, "now SAC updates run");
    assert!(l.progress().updates_low > during.updates_low);
}

#[test]
fn sampled_anchors_get_their_triplet_loss_as_priority() {
    let mut l = learner();
    for ep in 0..4 {
        ingest_episode(&mut l, 0, ep, 10, 2, 5);
    }
    while l.train(usize::MAX).unwrap() > 0 && l.progress().phi_version == PhiVersion(0) {}
    let store = l.phi_store();
    let mut changed = 0;
    for c in store.candidates() {
        let p = store.priority(c.run, c.t).unwrap();
        assert!(p.is_finite() && p >= 0.0);
        changed += usize::from(p != 1.0);
    }
    // 300 steps × 16 anchors from the top half (18 of 36 candidates): all of them sampled.
    assert!(changed >= 18, "{changed} priorities written back");
    assert_eq!(
        store.priority(0, 10),
        Some(1.0),
        "the last state is never an anchor"
    );
}

#[test]
fn the_second_round_adds_the_stable_term_and_rounds_follow_the_episode_schedule() {
    let mut l = learner();
    let mut ep = 0;
    let mut run_until = |l: &mut Learner, episodes: u64| {
        while ep < episodes {
            ingest_episode(l, 0, ep, 10, 2, 5);
            ep += 1;
        }
        while l.train(usize::MAX).unwrap() > 0 {}
    };
    run_until(&mut l, 3);
    assert_eq!(metric(&l, "phi/rounds"), 0.0, "first round at 4 episodes");
    run_until(&mut l, 7);
    assert_eq!(metric(&l, "phi/rounds"), 1.0);
    assert_eq!(metric(&l, "phi/stable_loss"), 0.0);
    run_until(&mut l, 8);
    assert_eq!(metric(&l, "phi/rounds"), 2.0);
    assert!(
        metric(&l, "phi/stable_loss") > 0.0,
        "round 1 regularises towards φ_old"
    );
    assert_eq!(l.progress().phi_version, PhiVersion(2));
    assert_eq!(metric(&l, "phi/steps"), 600.0);
}

#[test]
fn the_same_seed_gives_the_same_phi() {
    let run = || {
        let mut l = learner();
        for ep in 0..4 {
            ingest_episode(&mut l, 0, ep, 10, 2, 5);
        }
        while l.train(usize::MAX).unwrap() > 0 {}
        line_loss(&encoder_of(&l), 4)
    };
    assert_eq!(run(), run());
}

#[test]
fn lost_chunks_split_an_episode_and_short_runs_are_dropped_and_counted() {
    let mut l = learner();
    let all = steps(0..10, 0, 2, 9);
    ingest(&mut l, 0, 0, 0, &all[..4], TrajectoryFlags::EPISODE_START).unwrap();
    // chunk 1 (steps 4..6) lost; chunk 2 holds steps 6..10
    let end = TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
    ingest(&mut l, 0, 0, 2, &all[6..], end).unwrap();
    let store = l.phi_store();
    assert_eq!(store.stats().fragments, 2);
    assert_eq!(store.n_runs(), 2, "s_0..s_4 and s_6..s_10, 5 states each");
    assert_eq!(store.state(0, 4), Some(&[4.0f32, 0.0, 0.5][..]));
    assert_eq!(store.state(1, 0), Some(&[6.0f32, 0.0, 0.5][..]));
    // no candidate crosses the gap: anchors t ≤ 2 in each run (k = 2)
    assert_eq!(store.candidates().len(), 6);
    // a physics-failure episode of 2 steps: 3 states ≥ k + 1 = 3, stored; 1 step: dropped.
    let phys = TrajectoryFlags::EPISODE_START
        | TrajectoryFlags::EPISODE_END
        | TrajectoryFlags::PHYSICS_FAILURE;
    ingest(&mut l, 0, 1, 0, &steps(0..2, 1, 2, 99), phys).unwrap();
    ingest(&mut l, 0, 2, 0, &steps(0..1, 2, 2, 99), phys).unwrap();
    let s = l.phi_store().stats();
    assert_eq!((s.physics_failures, s.dropped_short), (2, 1));
    assert_eq!(l.phi_store().n_runs(), 3);
    assert_eq!(metric(&l, "phi/store_fragments"), 2.0);
}

#[test]
fn overdue_rounds_coalesce_into_one() {
    let mut l = learner();
    for ep in 0..13 {
        ingest_episode(&mut l, 0, ep, 10, 2, 5); // points 4, 8, 12 all reached
    }
    while l.train(usize::MAX).unwrap() > 0 {}
    assert_eq!(metric(&l, "phi/rounds"), 1.0);
    assert_eq!(metric(&l, "phi/coalesced_rounds"), 2.0);
    assert_eq!(
        metric(&l, "phi/stable_loss"),
        0.0,
        "still the first round: no stable term"
    );
    assert!(
        l.progress().updates_low > 0,
        "SAC updates ran after the single round"
    );
    for ep in 13..16 {
        ingest_episode(&mut l, 0, ep, 10, 2, 5);
    }
    while l.train(usize::MAX).unwrap() > 0 {}
    assert_eq!(metric(&l, "phi/rounds"), 2.0, "the next point is 16");
    assert!(metric(&l, "phi/stable_loss") > 0.0);
}
