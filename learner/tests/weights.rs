//! Publishing: the bytes load into a fresh actor-side PolicySet and reproduce the learner's
//! outputs; versions only go up; nothing is published when nothing changed.

mod common;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use common::*;
use nets::{load_safetensors_bytes, seeded_var_builder, PolicySet};
use protocol::{PhiVersion, PolicyVersion};

fn probe(rows: usize, cols: usize) -> Tensor {
    let values: Vec<f32> = (0..rows * cols).map(|i| (i as f32 * 0.37).sin()).collect();
    Tensor::from_slice(&values, (rows, cols), &Device::Cpu).unwrap()
}

/// Encoder, high and low deterministic outputs on fixed inputs.
fn outputs(set: &PolicySet) -> Vec<Vec<f32>> {
    let flat = |t: Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    vec![
        flat(set.encoder.forward(&probe(5, 3)).unwrap()),
        flat(set.high.deterministic(&probe(5, 5)).unwrap()),
        flat(set.low.deterministic(&probe(5, 7)).unwrap()),
    ]
}

/// A fresh actor-side set (other init seed) with `bytes` loaded after the header check.
fn actor_set_from(
    l: &learner::Learner,
    header: &protocol::WeightsHeader,
    bytes: &[u8],
) -> PolicySet {
    let vm = VarMap::new();
    let set = PolicySet::new(l.nets_spec(), &seeded_var_builder(&vm, 999, &Device::Cpu)).unwrap();
    header.check(nets::layout_hash(&vm), bytes.len()).unwrap();
    load_safetensors_bytes(&vm, bytes).unwrap();
    set
}

/// The learner's own current outputs (a PolicySet on its map shares its parameters).
fn learner_outputs(l: &learner::Learner) -> Vec<Vec<f32>> {
    let set = PolicySet::new(
        l.nets_spec(),
        &seeded_var_builder(l.policy_varmap(), 0, &Device::Cpu),
    )
    .unwrap();
    outputs(&set)
}

#[test]
fn published_weights_round_trip_into_a_fresh_policy_set() {
    let mut l = learner();
    let (header, bytes) = l
        .publish_due()
        .unwrap()
        .expect("the initial weights are published first");
    assert_eq!(
        (header.policy_version, header.phi_version),
        (PolicyVersion(0), PhiVersion(0))
    );
    assert_eq!(header.layout_hash, l.weights_layout_hash());
    let actor = actor_set_from(&l, &header, &bytes);
    assert_eq!(outputs(&actor), learner_outputs(&l));
}

#[test]
fn a_new_version_is_published_only_after_updates_and_the_interval_and_versions_go_up() {
    let mut l = learner(); // interval 10 env steps
    let (first, _) = l.publish_due().unwrap().unwrap();
    assert!(l.publish_due().unwrap().is_none(), "nothing changed");
    ingest_episode(&mut l, 0, 0, 10, 2, 5);
    assert!(l.publish_due().unwrap().is_none(), "no update has run yet");
    assert!(l.train(usize::MAX).unwrap() > 0);
    let (second, bytes) = l
        .publish_due()
        .unwrap()
        .expect("updates ran and 10 steps arrived");
    assert_eq!(
        second.policy_version,
        PolicyVersion(first.policy_version.0 + 1)
    );
    assert_eq!(l.progress().policy_version, second.policy_version);
    let actor = actor_set_from(&l, &second, &bytes);
    assert_eq!(outputs(&actor), learner_outputs(&l));
    ingest_episode(&mut l, 0, 1, 4, 2, 4);
    l.train(usize::MAX).unwrap();
    assert!(
        l.publish_due().unwrap().is_none(),
        "only 4 steps since the last publication"
    );
    ingest_episode(&mut l, 0, 2, 6, 2, 6);
    l.train(usize::MAX).unwrap();
    let (third, _) = l.publish_due().unwrap().unwrap();
    assert_eq!(third.policy_version, PolicyVersion(2));
}

#[test]
fn a_restarted_learner_continues_its_versions_above_what_was_published_before() {
    let mut l = learner();
    let (first, _) = l.publish_due().unwrap().unwrap();
    assert_eq!(first.phi_version, PhiVersion(0));
    // An earlier incarnation published policy 7 with φ 2 after the checkpoint we restored.
    l.continue_versions_after(PolicyVersion(7), PhiVersion(2));
    let (next, _) = l
        .publish_due()
        .unwrap()
        .expect("a new φ version is published at once");
    assert!(next.policy_version.0 > 7, "{next:?}");
    assert_eq!(next.phi_version, PhiVersion(3));
    // Versions above the given ones are kept; the φ version does not move for an equal one.
    l.continue_versions_after(PolicyVersion(1), PhiVersion(3));
    assert_eq!(l.progress().policy_version, next.policy_version);
    assert_eq!(l.progress().phi_version, PhiVersion(3));
    l.continue_versions_after(next.policy_version, PhiVersion(3));
    assert_eq!(
        l.progress().policy_version.0,
        next.policy_version.0 + 1,
        "an equal policy version is passed"
    );
}
