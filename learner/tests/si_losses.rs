//! The self-imitation losses against numpy (`tests/reference/si_losses.py`, numbers pasted
//! below), alone and behind a tanh-Gaussian policy with fixed weights; the low loss's gradient
//! must not reach the reference (target) branch.

// The expected values are numpy's float64 reprs, pasted as printed.
#![allow(clippy::excessive_precision)]

use candle_core::{DType, Device, Tensor, Var};
use candle_nn::{VarBuilder, VarMap};
use learner::si::step::low_action;
use learner::si::{high_si_loss, low_si_loss};
use learner::LearnerError;
use nets::{GaussianPolicy, LinearInit, LowPolicy};

fn close(what: &str, got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        let tol = 1e-6 * w.abs().max(1e-3);
        assert!((g - w).abs() <= tol, "{what}[{i}]: got {g}, want {w}");
    }
}

fn flat(t: &Tensor) -> Vec<f64> {
    t.flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect()
}

fn mat(values: &[f32], rows: usize, cols: usize) -> Tensor {
    Tensor::from_slice(values, (rows, cols), &Device::Cpu).unwrap()
}

const ROUTE_TARGET: [f32; 6] = [3.0, 4.0, -2.0, 1.0, 0.5, -0.5];
const PHI: [f32; 6] = [1.0, 2.0, 0.0, 0.5, 1.5, -1.0];

#[test]
fn the_high_loss_and_its_action_gradient_match_numpy() {
    let action =
        Var::from_slice(&[0.5f32, -1.0, 2.0, 0.25, -0.75, 1.5], (3, 2), &Device::Cpu).unwrap();
    let (loss, stats) = high_si_loss(
        action.as_tensor(),
        &mat(&ROUTE_TARGET, 3, 2),
        &mat(&PHI, 3, 2),
        0.01,
    )
    .unwrap();
    close("high loss", &[stats.loss], &[0.04729166666666667]);
    close("high mse", &[stats.mse], &[4.729166666666667]);
    let grads = loss.backward().unwrap();
    let grad = grads.get(action.as_tensor()).unwrap();
    close(
        "high grad",
        &flat(grad),
        &[
            -0.005,
            -0.01,
            0.01333333333333333,
            -0.00083333333333333,
            0.00083333333333333,
            0.00333333333333333,
        ],
    );
}

#[test]
fn the_low_loss_matches_numpy_and_its_gradient_never_reaches_the_references() {
    let aligned =
        Var::from_slice(&[1.0f32, -2.0, 0.5, 0.0, 3.0, -1.0], (2, 3), &Device::Cpu).unwrap();
    let reference = Var::from_slice(
        &[
            0.5f32, -1.0, 0.0, 1.5, -2.5, 1.0, 0.0, 0.0, 0.0, //
            1.0, 2.0, -1.0, -1.0, 4.0, 0.0, 0.5, 3.5, -2.0,
        ],
        (2, 3, 3),
        &Device::Cpu,
    )
    .unwrap();
    let (loss, stats) = low_si_loss(aligned.as_tensor(), reference.as_tensor(), 0.001).unwrap();
    close("low loss", &[stats.loss], &[0.0007777777777777778]);
    let grads = loss.backward().unwrap();
    close(
        "low grad",
        &flat(grads.get(aligned.as_tensor()).unwrap()),
        &[
            1.1111111111111112e-04,
            -2.7777777777777778e-04,
            5.5555555555555558e-05,
            -5.5555555555555558e-05,
            -5.5555555555555558e-05,
            0.0,
        ],
    );
    assert!(
        grads.get(reference.as_tensor()).is_none(),
        "the reference branch must be detached"
    );
}

#[test]
fn shapes_are_checked_with_the_dims_in_the_error() {
    let a = mat(&[0.0; 6], 3, 2);
    let err = high_si_loss(&a, &mat(&[0.0; 4], 2, 2), &a, 0.01).unwrap_err();
    assert!(
        matches!(
            err,
            LearnerError::Shape {
                what: "high_si_loss: route_target",
                ..
            }
        ),
        "{err}"
    );
    let refs = Tensor::zeros((3, 3, 3), DType::F32, &Device::Cpu).unwrap();
    let err = low_si_loss(&a, &refs, 0.001).unwrap_err();
    assert!(err.to_string().contains("[3, U ≥ 1, 2]"), "{err}");
}

/// The numpy script's policy: in 3 → hidden 4 → heads of 2, scale 2.
fn policy() -> (GaussianPolicy, VarMap) {
    let mut vm = VarMap::new();
    let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
    let policy = GaussianPolicy::new(&vb, 3, &[4], 2, 2.0, LinearInit::XavierUniform).unwrap();
    let set = |vm: &mut VarMap, name: &str, values: &[f32], shape: &[usize]| {
        let t = Tensor::from_slice(values, shape, &Device::Cpu).unwrap();
        vm.set_one(name, t).unwrap();
    };
    set(
        &mut vm,
        "trunk.l0.weight",
        &[
            0.2, -0.1, 0.4, -0.3, 0.5, 0.1, 0.6, 0.2, -0.2, 0.1, 0.1, 0.3,
        ],
        &[4, 3],
    );
    set(&mut vm, "trunk.l0.bias", &[0.05, -0.02, 0.1, 0.0], &[4]);
    set(
        &mut vm,
        "mean.weight",
        &[0.3, -0.2, 0.1, 0.4, -0.1, 0.5, 0.2, -0.3],
        &[2, 4],
    );
    set(&mut vm, "mean.bias", &[0.01, -0.03], &[2]);
    set(
        &mut vm,
        "log_std.weight",
        &[0.1, 0.1, -0.2, 0.05, 0.2, -0.1, 0.1, 0.0],
        &[2, 4],
    );
    set(&mut vm, "log_std.bias", &[-0.5, -1.0], &[2]);
    (policy, vm)
}

fn mean_bias(vm: &VarMap) -> Var {
    vm.data().lock().unwrap().get("mean.bias").unwrap().clone()
}

#[test]
fn the_high_loss_on_a_reparameterised_policy_sample_matches_numpy() {
    let (policy, vm) = policy();
    let x = mat(&[0.5, 1.0, -1.0, 1.0, -0.5, 2.0, -1.5, 0.3, 0.8], 3, 3);
    let eps = mat(&[0.3, -1.2, 0.0, 0.5, -0.7, 0.9], 3, 2);
    let (action, _) = policy.sample(&x, &eps).unwrap();
    close(
        "sampled action",
        &flat(&action),
        &[
            0.3998664600260801,
            -0.4375120710825697,
            1.102256057076294,
            -0.12218123567786182,
            -0.9555493108413333,
            1.0342898468633805,
        ],
    );
    let (loss, stats) =
        high_si_loss(&action, &mat(&ROUTE_TARGET, 3, 2), &mat(&PHI, 3, 2), 0.01).unwrap();
    close("policy high loss", &[stats.loss], &[0.031334060133911434]);
    let grads = loss.backward().unwrap();
    let grad = grads.get(mean_bias(&vm).as_tensor()).unwrap();
    close(
        "mean-bias grad",
        &flat(grad),
        &[0.00438735559783242, -0.01699550744109826],
    );
}

#[test]
fn the_low_loss_moves_the_policy_only_through_the_aligned_branch() {
    let (policy, vm) = policy();
    let policy = LowPolicy::Gaussian(policy);
    let base = mat(&[0.4, -0.8], 2, 1);
    let r_idx = mat(&[1.0, 2.0, -1.0, 0.5], 2, 2);
    let aligned = low_action(&policy, &base, &r_idx).unwrap();
    close(
        "aligned action",
        &flat(&aligned),
        &[
            0.8552719543854638,
            -0.05398688182524645,
            0.13379985071371095,
            -0.09792164258693253,
        ],
    );
    // References of row r are rows 3r … 3r + 2, as the SI step lays them out.
    let base_rep = mat(&[0.4, 0.4, 0.4, -0.8, -0.8, -0.8], 6, 1);
    let refs = mat(
        &[
            0.2, 0.4, 0.2, 0.4, 0.5, 1.0, -0.3, 0.1, -0.3, 0.1, -0.6, 0.3,
        ],
        6,
        2,
    );
    let reference = low_action(&policy, &base_rep, &refs)
        .unwrap()
        .reshape((2, 3, 2))
        .unwrap();
    let (loss, stats) = low_si_loss(&aligned, &reference, 0.001).unwrap();
    close("policy low loss", &[stats.loss], &[5.1120396487399944e-05]);
    let grads = loss.backward().unwrap();
    let grad = grads.get(mean_bias(&vm).as_tensor()).unwrap();
    // numpy: the gradient of the aligned branch alone. Through both branches it would differ.
    close(
        "mean-bias grad",
        &flat(grad),
        &[4.570665013656630e-04, -4.448430950549101e-05],
    );
}
