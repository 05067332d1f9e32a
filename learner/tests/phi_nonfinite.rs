//! φ rounds on states that make the loss non-finite (issue #7, hostile input): such a step is
//! skipped and counted, no Adam step touches φ; a round made only of such steps ends without
//! a new φ version; a round with some good steps trains on those; the learner goes on.
//!
//! The bad states are finite (the protocol refuses NaN and infinities) but ±3e38: the first
//! layer's pre-activations reach ~1e38 or overflow, so φ's squared distances overflow f32.

mod common;

use candle_core::{Device, Tensor, Var};
use candle_nn::VarMap;
use common::*;
use learner::phi::{PhiParams, PhiStore, PhiTrainer, RunKind};
use learner::Learner;
use nets::{seeded_var_builder, spec_from_config, PolicySet};
use protocol::PhiVersion;

/// A run of 11 states: huge ones, or a point moving on a line (`[0.1 t, 0.1 run, 0.5]`).
fn run_obs(run: usize, huge: bool) -> Vec<f32> {
    (0..=10)
        .flat_map(|t| {
            if huge {
                huge_state(t)
            } else {
                [0.1 * t as f32, 0.1 * run as f32, 0.5]
            }
        })
        .collect()
}

/// A trainer on a fresh policy set, and the set's encoder variables (name-sorted copies of
/// their values are what the tests compare).
fn trainer(steps_per_round: u64, batch_size: usize) -> (PhiTrainer, VarMap) {
    let mut c = phi_config();
    c.encoder.steps_per_round = steps_per_round;
    c.encoder.batch_size = batch_size;
    let spec = spec_from_config(&c, DIMS).unwrap();
    let vm = VarMap::new();
    PolicySet::new(&spec, &seeded_var_builder(&vm, 1, &Device::Cpu)).unwrap();
    let t = PhiTrainer::new(PhiParams::from_config(&c), &spec, &vm, 3).unwrap();
    (t, vm)
}

/// The encoder's parameter values, by name.
fn encoder_values(vm: &VarMap) -> Vec<(String, Vec<f32>)> {
    let data = vm.data().lock().unwrap();
    let mut out: Vec<(String, Vec<f32>)> = data
        .iter()
        .filter(|(n, _)| n.starts_with("encoder."))
        .map(|(n, v): (&String, &Var)| (n.clone(), v.flatten_all().unwrap().to_vec1().unwrap()))
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    assert!(!out.is_empty(), "the policy set has encoder parameters");
    out
}

/// Runs the active round to its end in slices of 50; returns the slices' outcomes summed:
/// (steps, skipped, whether a slice reported `round_finished`).
fn run_round(t: &mut PhiTrainer, store: &mut PhiStore) -> (u64, u64, bool) {
    let (mut steps, mut skipped, mut finished) = (0, 0, false);
    while t.is_active() {
        let o = t
            .run_slice(store, 50)
            .expect("a non-finite step is not an error");
        steps += o.steps;
        skipped += o.skipped_nonfinite;
        finished |= o.round_finished;
    }
    (steps, skipped, finished)
}

#[test]
fn a_round_of_only_non_finite_steps_skips_them_all_leaves_phi_bit_identical_and_is_counted() {
    let (mut t, vm) = trainer(120, 16);
    let mut store = PhiStore::new(3, t.params().negative_offset, 10_000);
    for run in 0..4 {
        store.push_run(run_obs(run, true), RunKind::Complete);
    }
    let before = encoder_values(&vm);
    assert!(t.start_if_due(4, &mut store).unwrap());
    let (steps, skipped, finished) = run_round(&mut t, &mut store);
    assert_eq!(
        (steps, skipped),
        (120, 120),
        "every step is used up and skipped"
    );
    assert!(!finished, "nothing to publish");
    assert!(
        !t.is_active() && !store.is_frozen(),
        "the round ended, ingest goes on"
    );
    assert!(encoder_values(&vm) == before, "φ changed by skipped steps");
    let s = t.stats();
    assert_eq!(s.skipped_nonfinite_steps, 120);
    assert_eq!(s.nonfinite_rounds, 1);
    assert_eq!(
        (s.rounds, s.steps),
        (0, 0),
        "no round completed, no Adam step"
    );
    for c in store.candidates() {
        assert_eq!(
            store.priority(c.run, c.t),
            Some(1.0),
            "priorities untouched"
        );
    }
    // The next round, on good data, trains as usual.
    let mut fresh = PhiStore::new(3, t.params().negative_offset, 10_000);
    for run in 4..8 {
        fresh.push_run(run_obs(run, false), RunKind::Complete);
    }
    assert!(t.start_if_due(8, &mut fresh).unwrap());
    let (_, skipped, finished) = run_round(&mut t, &mut fresh);
    assert_eq!(skipped, 0);
    assert!(finished);
    assert_eq!(t.stats().rounds, 1);
    assert!(encoder_values(&vm) != before);
}

#[test]
fn a_round_with_some_non_finite_steps_trains_on_the_others_only() {
    // Batch 1: a step's triplet (t, t + 1, t + 2) lies in one run, so a step is bad exactly
    // when its anchor comes from a huge run; the first round has no stable term.
    let (mut t, vm) = trainer(200, 1);
    let mut store = PhiStore::new(3, t.params().negative_offset, 10_000);
    for run in 0..6 {
        store.push_run(run_obs(run, run % 2 == 1), RunKind::Complete);
    }
    let before = encoder_values(&vm);
    assert!(t.start_if_due(4, &mut store).unwrap());
    let (steps, skipped, finished) = run_round(&mut t, &mut store);
    assert_eq!(steps, 200);
    assert!(
        skipped > 20 && skipped < 180,
        "about half skipped: {skipped}"
    );
    assert!(finished, "a round with good steps publishes");
    let s = t.stats();
    assert_eq!(s.skipped_nonfinite_steps, skipped);
    assert_eq!(s.steps, 200 - skipped, "one Adam step per good step");
    assert_eq!((s.rounds, s.nonfinite_rounds), (1, 0));
    assert!(s.triplet.loss.is_finite() && s.round_end_loss.is_finite());
    let after = encoder_values(&vm);
    assert!(after != before, "φ trained on the good steps");
    assert!(after.iter().all(|(_, v)| v.iter().all(|x| x.is_finite())));
    // Priorities: written for sampled good anchors, never for huge runs (their runs are the
    // odd ones: the store keeps push order).
    let (mut good_written, mut bad_written) = (0, 0);
    for c in store.candidates() {
        let p = store.priority(c.run, c.t).unwrap();
        if !c.run.is_multiple_of(2) {
            bad_written += usize::from(p != 1.0);
        } else {
            good_written += usize::from(p != 1.0);
        }
    }
    assert_eq!(bad_written, 0);
    assert!(good_written > 0);
}

#[test]
fn a_learner_fed_overflowing_states_ends_the_phi_round_without_a_new_version_and_goes_on() {
    let mut l = Learner::new(&phi_config(), DIMS, 7).unwrap();
    let probe = Tensor::from_vec(vec![0.3f32, -0.2, 0.5], (1, 3), &Device::Cpu).unwrap();
    let phi_before = encoder_of(&l)
        .forward(&probe)
        .unwrap()
        .to_vec2::<f32>()
        .unwrap();
    l.publish_due().unwrap().unwrap();
    for ep in 0..4 {
        ingest_episode_in_one_chunk(&mut l, ep, true);
    }
    let mut phi_steps = 0;
    loop {
        phi_steps += l
            .train(usize::MAX)
            .expect("non-finite φ steps are not an error");
        if !l.phi_round_active() {
            break;
        }
    }
    assert_eq!(phi_steps, 300);
    assert_eq!(metric(&l, "phi/skipped_nonfinite_steps"), 300.0);
    assert_eq!(metric(&l, "phi/nonfinite_rounds"), 1.0);
    assert_eq!(metric(&l, "phi/rounds"), 0.0);
    assert_eq!(l.progress().phi_version, PhiVersion(0));
    let phi_after = encoder_of(&l)
        .forward(&probe)
        .unwrap()
        .to_vec2::<f32>()
        .unwrap();
    assert_eq!(phi_after, phi_before, "φ unchanged");
    // The learner goes on: SAC updates run (or are skipped) and nothing errs.
    l.train(usize::MAX)
        .expect("the learner goes on after the round");
    assert!(l
        .publish_due()
        .unwrap()
        .is_none_or(|(h, _)| h.phi_version == PhiVersion(0)));
}
