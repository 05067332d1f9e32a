//! The tanh-Gaussian policy against a reference computation, and the deterministic actor.

mod common;

use candle_core::Tensor;
use common::*;
use nets::{DeterministicActor, GaussianPolicy, LinearInit};

/// A policy in=3 → [4] → 2 heads, scale 10, with weights fixed to the values of the reference
/// snippet below.
fn fixed_policy() -> GaussianPolicy {
    let (mut vm, vb) = seeded(0);
    let policy = GaussianPolicy::new(&vb, 3, &[4], 2, 10.0, LinearInit::XavierUniform).unwrap();
    set(
        &mut vm,
        "trunk.l0.weight",
        t2(&[
            &[0.5, -0.3, 0.2],
            &[0.1, 0.4, -0.6],
            &[-0.7, 0.2, 0.3],
            &[0.3, 0.3, 0.3],
        ]),
    );
    set(&mut vm, "trunk.l0.bias", t1(&[0.1, -0.2, 0.05, 0.0]));
    set(
        &mut vm,
        "mean.weight",
        t2(&[&[0.6, -0.4, 0.3, 0.2], &[-0.5, 0.7, 0.1, -0.3]]),
    );
    set(&mut vm, "mean.bias", t1(&[0.05, -0.1]));
    set(
        &mut vm,
        "log_std.weight",
        t2(&[&[0.2, 0.1, -0.3, 0.4], &[-0.1, 0.3, 0.2, 0.1]]),
    );
    set(&mut vm, "log_std.bias", t1(&[-0.5, 3.0]));
    policy
}

fn fixed_inputs() -> (Tensor, Tensor) {
    let x = t2(&[&[1.0, -0.5, 0.25], &[-1.5, 2.0, 0.5]]);
    let eps = t2(&[&[0.3, -0.2], &[-1.1, 0.05]]);
    (x, eps)
}

// Reference (numpy, float64; the same formula as the reference SAC `GaussianPolicy.sample`
// in PyTorch: Normal(mean, std).log_prob(x_t) - log(10 * (1 - tanh(x_t)^2) + 1e-6), summed):
//
//   h = relu(x @ W0.T + b0); mean = h @ Wm.T + bm; log_std = clip(h @ Ws.T + bs, -20, 2)
//   std = exp(log_std); u = mean + std * eps; y = tanh(u); action = 10 * y
//   normal_lp = -((u - mean)**2) / (2 * std**2) - log_std - 0.5 * log(2 * pi)
//   log_prob = (normal_lp - log(10 * (1 - y**2) + 1e-6)).sum(1, keepdims=True)
//
// printed:
//   mean     [[ 0.575  -0.5675] [ 0.545  0.08 ]]
//   log_std  [[-0.25   2.    ] [-0.86   2.   ]]      (second column clamped from above 2)
//   action   [[ 6.688394636  -9.6709286223] [ 0.793545085   4.2144910642]]
//   log_prob [[-4.9275164713] [-7.9874285136]]
//   10*tanh(mean) [[ 5.190218339 -5.1352090124] [ 4.9676344321  0.7982976911]]

#[test]
fn tanh_gaussian_sample_matches_the_reference_numbers() {
    let policy = fixed_policy();
    let (x, eps) = fixed_inputs();
    let (mean, log_std) = policy.dist(&x).unwrap();
    assert_close(&flat(&mean), &[0.575, -0.5675, 0.545, 0.08], 1e-6);
    assert_close(&flat(&log_std), &[-0.25, 2.0, -0.86, 2.0], 1e-6);
    let (action, log_prob) = policy.sample(&x, &eps).unwrap();
    assert_eq!(action.dims(), &[2, 2]);
    assert_eq!(log_prob.dims(), &[2, 1]);
    assert_close(
        &flat(&action),
        &[6.688394636, -9.6709286223, 0.793545085, 4.2144910642],
        1e-5,
    );
    assert_close(&flat(&log_prob), &[-4.9275164713, -7.9874285136], 1e-5);
}

#[test]
fn deterministic_action_is_scaled_tanh_of_the_mean() {
    let policy = fixed_policy();
    let (x, _) = fixed_inputs();
    let action = policy.deterministic(&x).unwrap();
    assert_close(
        &flat(&action),
        &[5.190218339, -5.1352090124, 4.9676344321, 0.7982976911],
        1e-5,
    );
}

#[test]
fn sample_gradients_reach_every_policy_parameter() {
    let (vm, vb) = seeded(3);
    let policy = GaussianPolicy::new(&vb, 5, &[8, 8], 2, 10.0, LinearInit::XavierUniform).unwrap();
    let x = batch(4, 5);
    let eps = batch(4, 2);
    let (action, log_prob) = policy.sample(&x, &eps).unwrap();
    let loss = action
        .sum_all()
        .unwrap()
        .add(&log_prob.sum_all().unwrap())
        .unwrap();
    let grads = loss.backward().unwrap();
    for var in vm.all_vars() {
        assert!(
            grads.get(var.as_tensor()).is_some(),
            "no gradient for a parameter of shape {:?}",
            var.dims()
        );
    }
}

#[test]
fn noise_with_the_wrong_shape_is_an_error_naming_the_policy() {
    let (_vm, vb) = seeded(0);
    let policy = GaussianPolicy::new(
        &vb.pp("high_policy"),
        3,
        &[4],
        2,
        10.0,
        LinearInit::XavierUniform,
    )
    .unwrap();
    let err = policy
        .sample(&batch(2, 3), &batch(2, 3))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("high_policy") && err.contains("[2, 3]"),
        "{err}"
    );
}

#[test]
fn actions_stay_within_the_scale_even_for_huge_inputs() {
    let (_vm, vb) = seeded(1);
    let policy = GaussianPolicy::new(&vb, 3, &[16], 4, 16.0, LinearInit::XavierUniform).unwrap();
    let x = batch(64, 3).affine(1e4, 0.0).unwrap();
    let eps = batch(64, 4).affine(5.0, 0.0).unwrap();
    let (action, log_prob) = policy.sample(&x, &eps).unwrap();
    assert!(flat(&action).iter().all(|a| a.abs() <= 16.0));
    assert!(flat(&log_prob).iter().all(|l| l.is_finite()));
}

#[test]
fn deterministic_actor_is_scaled_tanh_of_its_mlp() {
    let (mut vm, vb) = seeded(0);
    let actor = DeterministicActor::new(&vb, 2, &[2], 1, 16.0, LinearInit::TorchDefault).unwrap();
    set(&mut vm, "l0.weight", t2(&[&[1.0, 0.0], &[0.0, 1.0]]));
    set(&mut vm, "l0.bias", t1(&[0.0, 0.0]));
    set(&mut vm, "l1.weight", t2(&[&[1.0, -1.0]]));
    set(&mut vm, "l1.bias", t1(&[0.5]));
    // relu([0.2, -0.3]) = [0.2, 0]; 0.2 + 0.5 = 0.7; relu([-1, 1]) = [0, 1]; -1 + 0.5 = -0.5
    let a = actor.forward(&t2(&[&[0.2, -0.3], &[-1.0, 1.0]])).unwrap();
    assert_close(
        &flat(&a),
        &[16.0 * 0.7f64.tanh(), 16.0 * (-0.5f64).tanh()],
        1e-6,
    );
}
