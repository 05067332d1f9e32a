//! Safetensors bytes, strict loading, layout hash and subsets, on real network sets.

mod common;

use candle_nn::VarMap;
use common::*;
use nets::weights::{layout_hash_of, vars_under};
use nets::{
    layout_hash, load_safetensors_bytes, prefix, subset, to_safetensors_bytes, NetsError, NetsSpec,
    PolicySet,
};

fn policy_set(spec: &NetsSpec, seed: u64) -> VarMap {
    let (vm, vb) = seeded(seed);
    PolicySet::new(spec, &vb).unwrap();
    vm
}

#[test]
fn safetensors_round_trip_preserves_every_tensor_bit_exactly() {
    let spec = NetsSpec::default();
    let source = policy_set(&spec, 1);
    let receiver = policy_set(&spec, 2);
    assert_ne!(var_bits(&source), var_bits(&receiver));
    let bytes = to_safetensors_bytes(&source).unwrap();
    load_safetensors_bytes(&receiver, &bytes).unwrap();
    assert_eq!(var_bits(&source), var_bits(&receiver));
    assert_eq!(layout_hash(&source), layout_hash(&receiver));
    assert_eq!(
        to_safetensors_bytes(&receiver).unwrap(),
        bytes,
        "serialisation is deterministic"
    );
}

#[test]
fn loading_a_wrong_shape_fails_naming_the_tensor_and_changes_nothing() {
    let receiver = policy_set(&NetsSpec::default(), 2);
    let before = var_bits(&receiver);
    let other = policy_set(
        &NetsSpec {
            obs_dim: 30,
            ..NetsSpec::default()
        },
        1,
    );
    let err =
        load_safetensors_bytes(&receiver, &to_safetensors_bytes(&other).unwrap()).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, NetsError::ShapeMismatch { .. }), "{err:?}");
    assert!(
        msg.contains("encoder.l0.weight") && msg.contains("[100, 29]") && msg.contains("[100, 30]"),
        "{msg}"
    );
    assert_eq!(
        var_bits(&receiver),
        before,
        "a rejected payload must not change any value"
    );
}

#[test]
fn loading_with_a_missing_name_fails_naming_it() {
    let receiver = policy_set(&NetsSpec::default(), 2);
    let source = policy_set(&NetsSpec::default(), 1);
    let partial = subset(&source, &[prefix::ENCODER, prefix::HIGH_POLICY]).unwrap();
    let err =
        load_safetensors_bytes(&receiver, &to_safetensors_bytes(&partial).unwrap()).unwrap_err();
    assert!(matches!(err, NetsError::MissingTensor { .. }), "{err:?}");
    assert!(err.to_string().contains("low_policy.log_std.bias"), "{err}");
}

#[test]
fn loading_a_payload_with_an_extra_tensor_fails_naming_it() {
    let source = policy_set(&NetsSpec::default(), 1);
    let receiver = subset(&policy_set(&NetsSpec::default(), 2), &[prefix::ENCODER]).unwrap();
    let err =
        load_safetensors_bytes(&receiver, &to_safetensors_bytes(&source).unwrap()).unwrap_err();
    assert!(matches!(err, NetsError::UnexpectedTensor { .. }), "{err:?}");
    assert!(
        err.to_string().contains("high_policy.log_std.bias"),
        "{err}"
    );
}

#[test]
fn garbage_bytes_are_a_safetensors_error() {
    let receiver = policy_set(&NetsSpec::default(), 2);
    let err = load_safetensors_bytes(&receiver, b"not a safetensors buffer").unwrap_err();
    assert!(matches!(err, NetsError::Safetensors(_)), "{err:?}");
}

#[test]
fn layout_hash_changes_when_a_shape_changes_but_not_with_values() {
    let base = layout_hash(&policy_set(&NetsSpec::default(), 1));
    assert_eq!(base, layout_hash(&policy_set(&NetsSpec::default(), 2)));
    let wider = NetsSpec {
        high_hidden: vec![256, 257],
        ..NetsSpec::default()
    };
    assert_ne!(base, layout_hash(&policy_set(&wider, 1)));
    let deterministic = NetsSpec::default().with_deterministic_low();
    assert_ne!(base, layout_hash(&policy_set(&deterministic, 1)));
}

#[test]
fn layout_hash_follows_the_documented_contract() {
    // Python: h = 0xcbf29ce484222325
    //         for c in b"net.l0.bias:3\nnet.l0.weight:3x2\nscalar:\n": h = ((h ^ c) * 0x100000001b3) % 2**64
    // → 0x61e44d8456f349ec (each sorted line followed by a newline, protocol::layout_hash)
    let entries: [(&str, &[usize]); 3] = [
        ("scalar", &[]),
        ("net.l0.weight", &[3, 2]),
        ("net.l0.bias", &[3]),
    ];
    assert_eq!(layout_hash_of(entries), 0x61e4_4d84_56f3_49ec);
}

#[test]
fn actor_side_subset_holds_exactly_the_policy_set_and_shares_storage() {
    let (full, vb) = seeded(1);
    PolicySet::new(&NetsSpec::default(), &vb).unwrap();
    let spec = NetsSpec::default();
    spec.high_critic(&vb.pp(prefix::HIGH_CRITIC)).unwrap();
    spec.low_critic(&vb.pp(prefix::LOW_CRITIC)).unwrap();
    let actor_side = subset(&full, &prefix::ACTOR_SIDE).unwrap();
    let names: Vec<String> = var_bits(&actor_side).into_iter().map(|(n, _)| n).collect();
    assert!(names.iter().all(|n| !n.contains("critic")), "{names:?}");
    assert_eq!(layout_hash(&actor_side), layout_hash(&policy_set(&spec, 3)));
    // Shared storage: loading into the subset updates the full map.
    let fresh = policy_set(&spec, 4);
    load_safetensors_bytes(&actor_side, &to_safetensors_bytes(&fresh).unwrap()).unwrap();
    let encoder_vars = vars_under(&full, prefix::ENCODER);
    let fresh_encoder = vars_under(&fresh, prefix::ENCODER);
    assert_eq!(encoder_vars.len(), 6);
    for (a, b) in encoder_vars.iter().zip(&fresh_encoder) {
        assert_eq!(flat(a.as_tensor()), flat(b.as_tensor()));
    }
}

#[test]
fn subset_with_an_unknown_prefix_is_an_error() {
    let vm = policy_set(&NetsSpec::default(), 1);
    let Err(err) = subset(&vm, &["encoder", "hihg_policy"]) else {
        panic!("typo must fail")
    };
    let err = err.to_string();
    assert!(err.contains("hihg_policy"), "{err}");
    // `encoder` must not match a hypothetical `encoder2.*`: prefixes end at a dot.
    assert!(nets::weights::is_under("encoder.l0.weight", "encoder"));
    assert!(!nets::weights::is_under("encoder2.l0.weight", "encoder"));
}
