//! The network set built from a `NetsSpec`: shapes of every network, both low variants.

mod common;

use common::*;
use nets::{prefix, LowCritic, LowPolicy, NetsSpec, PolicySet};

#[test]
fn default_spec_builds_every_network_with_the_documented_shapes() {
    let spec = NetsSpec::default();
    let (_vm, vb) = seeded(1);
    let set = PolicySet::new(&spec, &vb).unwrap();
    let b = 7;
    assert_eq!(set.encoder.forward(&batch(b, 29)).unwrap().dims(), &[b, 2]);
    let (delta, log_prob) = set.high.sample(&batch(b, 31), &batch(b, 2)).unwrap();
    assert_eq!((delta.dims(), log_prob.dims()), (&[b, 2][..], &[b, 1][..]));
    assert!(flat(&delta).iter().all(|v| v.abs() <= 10.0));
    let LowPolicy::Gaussian(low) = &set.low else {
        panic!("SAC is the default low variant")
    };
    let (action, _) = low.sample(&batch(b, 33), &batch(b, 8)).unwrap();
    assert_eq!(action.dims(), &[b, 8]);
    assert_eq!(
        set.low.deterministic(&batch(b, 33)).unwrap().dims(),
        &[b, 8]
    );
    let high_q = spec.high_critic(&vb.pp(prefix::HIGH_CRITIC)).unwrap();
    assert_eq!(high_q.forward(&batch(b, 33)).unwrap().dims(), &[b, 2]);
    let LowCritic::Twin(low_q) = spec.low_critic(&vb.pp(prefix::LOW_CRITIC)).unwrap() else {
        panic!()
    };
    assert_eq!(low_q.min_q(&batch(b, 41)).unwrap().dims(), &[b, 1]);
}

#[test]
fn deterministic_low_variant_uses_the_reference_sizes() {
    let spec = NetsSpec::default().with_deterministic_low();
    let (vm, vb) = seeded(1);
    let set = PolicySet::new(&spec, &vb).unwrap();
    let LowPolicy::Deterministic(actor) = &set.low else {
        panic!("expected the deterministic actor")
    };
    let action = actor
        .forward(&batch(5, 33).affine(50.0, 0.0).unwrap())
        .unwrap();
    assert_eq!(action.dims(), &[5, 8]);
    assert!(flat(&action).iter().all(|v| v.abs() <= 16.0));
    let data = vm.data().lock().unwrap();
    assert_eq!(data["low_policy.l3.weight"].dims(), &[400, 400]);
    assert_eq!(data["low_policy.l4.weight"].dims(), &[8, 400]);
    drop(data);
    let LowCritic::Distance(critic) = spec.low_critic(&vb.pp(prefix::LOW_CRITIC)).unwrap() else {
        panic!()
    };
    assert_eq!(critic.q(&batch(5, 41), 0.99).unwrap().dims(), &[5, 1]);
    assert_eq!(
        vm.data().lock().unwrap()["low_critic.l5.weight"].dims(),
        &[1, 400]
    );
}

#[test]
fn an_invalid_spec_reports_every_problem_at_once() {
    let spec = NetsSpec {
        obs_dim: 0,
        high_hidden: vec![],
        low_action_scale: f64::NAN,
        ..NetsSpec::default()
    };
    let err = spec.validate().unwrap_err().to_string();
    for field in ["obs_dim", "high_hidden", "low_action_scale"] {
        assert!(err.contains(field), "{field} missing from: {err}");
    }
    let (_vm, vb) = seeded(0);
    assert!(PolicySet::new(&spec, &vb).is_err());
}

#[test]
fn wrong_observation_size_names_the_encoder_layer() {
    let (_vm, vb) = seeded(0);
    let set = PolicySet::new(&NetsSpec::default(), &vb).unwrap();
    let err = set.encoder.forward(&batch(3, 18)).unwrap_err().to_string();
    assert!(
        err.contains("encoder.l0") && err.contains("29") && err.contains("18"),
        "{err}"
    );
}

#[test]
fn spec_round_trips_through_serde_and_rejects_unknown_fields() {
    let spec = NetsSpec::default().with_deterministic_low();
    let json = serde_json::to_string(&spec).unwrap();
    assert!(json.contains("\"low_variant\":\"deterministic\""), "{json}");
    let back: NetsSpec = serde_json::from_str(&json).unwrap();
    assert_eq!(back, spec);
    assert!(serde_json::from_str::<NetsSpec>(r#"{"obs_dimm": 3}"#).is_err());
}
