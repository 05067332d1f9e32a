//! The batched twin critic against two separate MLPs, and the γ-distance critic's Q.

mod common;

use candle_core::Tensor;
use common::*;
use nets::{q_from_distance, DistanceCritic, LinearInit, Mlp, TwinCritic};

/// A twin critic and two plain MLPs `q1`, `q2` (on another map) holding the same weights.
fn twin_and_separate(in_dim: usize, hidden: &[usize]) -> (TwinCritic, Mlp, Mlp) {
    let (twin_vm, twin_vb) = seeded(7);
    let twin = TwinCritic::new(&twin_vb, in_dim, hidden, LinearInit::XavierUniform).unwrap();
    let (mut sep_vm, sep_vb) = seeded(8);
    let q1 = Mlp::new(
        &sep_vb.pp("q1"),
        in_dim,
        hidden,
        1,
        LinearInit::XavierUniform,
    )
    .unwrap();
    let q2 = Mlp::new(
        &sep_vb.pp("q2"),
        in_dim,
        hidden,
        1,
        LinearInit::XavierUniform,
    )
    .unwrap();
    let twin_params = twin_vm.data().lock().unwrap().clone();
    assert_eq!(twin_params.len(), sep_vm.data().lock().unwrap().len());
    for (name, var) in twin_params {
        set(&mut sep_vm, &name, var.as_tensor().clone());
    }
    (twin, q1, q2)
}

#[test]
fn twin_critic_equals_two_separate_mlps_with_the_same_weights() {
    let (twin, q1, q2) = twin_and_separate(11, &[32, 16]);
    let x = batch(9, 11);
    let q = twin.forward(&x).unwrap();
    assert_eq!(q.dims(), &[9, 2]);
    let separate = Tensor::cat(&[q1.forward(&x).unwrap(), q2.forward(&x).unwrap()], 1).unwrap();
    assert!(
        max_abs_diff(&q, &separate) < 1e-6,
        "{:?} vs {:?}",
        vec2(&q),
        vec2(&separate)
    );
}

#[test]
fn twin_critic_members_are_initialised_independently() {
    let (twin, _, _) = twin_and_separate(4, &[8]);
    let (q1, q2) = twin.forward_pair(&batch(3, 4)).unwrap();
    assert_ne!(flat(&q1), flat(&q2));
}

#[test]
fn twin_critic_min_q_is_the_elementwise_minimum() {
    let (twin, q1, q2) = twin_and_separate(5, &[8]);
    let x = batch(6, 5);
    let min_q = twin.min_q(&x).unwrap();
    assert_eq!(min_q.dims(), &[6, 1]);
    let want = q1
        .forward(&x)
        .unwrap()
        .minimum(&q2.forward(&x).unwrap())
        .unwrap();
    assert!(max_abs_diff(&min_q, &want) < 1e-6);
}

#[test]
fn twin_critic_rejects_a_wrong_input_size_naming_the_layer() {
    let (_vm, vb) = seeded(0);
    let twin = TwinCritic::new(&vb.pp("high_critic"), 33, &[8], LinearInit::XavierUniform).unwrap();
    let err = twin.forward(&batch(4, 31)).unwrap_err().to_string();
    assert!(
        err.contains("high_critic.q1.l0") && err.contains("33") && err.contains("31"),
        "{err}"
    );
}

#[test]
fn distance_q_follows_the_gamma_formula() {
    // Q = -(1 - 0.99^d) / (1 - 0.99): d = 0 → 0, 1 → -1, 10 → -9.5617924991, 100 → -63.3967658726
    let d = t2(&[&[0.0], &[1.0], &[10.0], &[100.0]]);
    let q = q_from_distance(&d, 0.99).unwrap();
    assert_close(&flat(&q), &[0.0, -1.0, -9.5617924991, -63.3967658726], 1e-5);
}

#[test]
fn distance_critic_q_uses_its_network_output_as_d() {
    let (mut vm, vb) = seeded(0);
    let critic = DistanceCritic::new(&vb, 3, &[4, 4], LinearInit::TorchDefault).unwrap();
    set(&mut vm, "l2.weight", t2(&[&[0.0, 0.0, 0.0, 0.0]]));
    set(&mut vm, "l2.bias", t1(&[10.0]));
    let x = batch(2, 3);
    assert_close(&flat(&critic.distance(&x).unwrap()), &[10.0, 10.0], 1e-6);
    assert_close(
        &flat(&critic.q(&x, 0.99).unwrap()),
        &[-9.5617924991, -9.5617924991],
        1e-5,
    );
}

#[test]
fn distance_q_rejects_a_gamma_outside_the_unit_interval() {
    let d = t2(&[&[1.0]]);
    for gamma in [0.0, 1.0, 1.5, f64::NAN] {
        let err = q_from_distance(&d, gamma).unwrap_err().to_string();
        assert!(err.contains("gamma"), "{err}");
    }
}
