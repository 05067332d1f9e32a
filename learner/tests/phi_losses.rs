//! φ losses, their gradients and one Adam step against the numpy reference
//! `tests/reference/phi_losses.py` (float64; the Rust side is f32, hence the tolerances).
//! Regenerate the numbers with `python3 learner/tests/reference/phi_losses.py`.

use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarBuilder, VarMap};
use learner::phi::{phi_objective, phi_optimizer, stable_loss, triplet_loss};
use learner::LearnerError;
use nets::Encoder;

fn t(rows: &[[f32; 3]]) -> Tensor {
    let flat: Vec<f32> = rows.iter().flatten().copied().collect();
    Tensor::from_slice(&flat, (rows.len(), 3), &Device::Cpu).unwrap()
}

fn flat(t: &Tensor) -> Vec<f64> {
    let v: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
    v.into_iter().map(f64::from).collect()
}

fn close(what: &str, got: &[f64], want: &[f64], tol: f64) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= tol * (1.0 + w.abs()),
            "{what}[{i}]: {g} vs reference {w}"
        );
    }
}

const ANCHOR: [[f32; 3]; 3] = [[0.0, 1.0, 0.6], [1.0, 0.0, -0.5], [2.0, 1.0, 0.0]];
const POSITIVE: [[f32; 3]; 3] = [[0.2, 1.1, 0.5], [1.1, 0.2, -0.4], [2.2, 1.0, 0.1]];
const NEGATIVE: [[f32; 3]; 3] = [[2.0, 1.5, 0.5], [8.0, -6.0, -2.0], [2.1, 1.1, 0.0]];
const REG: [[f32; 3]; 3] = [[0.5, 0.5, 0.5], [-1.0, 2.0, 0.0], [1.5, -0.5, 1.0]];

/// The reference network's parameters (`W0, b0, W1, b1`), shifted by `d` as in the script's
/// φ_old (`W0 + 0.05·d, b0 − 0.02·d, W1 − 0.03·d, b1 + 0.01·d`).
fn params(d: f32) -> [(&'static str, Vec<f32>, Vec<usize>); 4] {
    let w0 = [
        0.5, -0.3, 0.2, -0.4, 0.6, 0.1, 0.3, 0.2, -0.5, 0.1, -0.2, 0.4,
    ];
    let b0 = [0.1, -0.1, 0.05, 0.03];
    let w1 = [0.7, -0.5, 0.3, 0.2, -0.2, 0.4, 0.6, -0.3];
    let b1 = [0.05, -0.05];
    [
        ("l0.weight", w0.map(|x| x + 0.05 * d).to_vec(), vec![4, 3]),
        ("l0.bias", b0.map(|x| x - 0.02 * d).to_vec(), vec![4]),
        ("l1.weight", w1.map(|x| x - 0.03 * d).to_vec(), vec![2, 4]),
        ("l1.bias", b1.map(|x| x + 0.01 * d).to_vec(), vec![2]),
    ]
}

/// An encoder 3 → 4 → 2 on a fresh map holding `params(d)` under `encoder.`.
fn encoder(d: f32) -> (VarMap, Encoder) {
    let mut vm = VarMap::new();
    let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
    let enc = Encoder::new(&vb.pp("encoder"), 3, &[4], 2).unwrap();
    for (name, values, shape) in params(d) {
        let value = Tensor::from_vec(values, shape, &Device::Cpu).unwrap();
        vm.set_one(format!("encoder.{name}"), value).unwrap();
    }
    (vm, enc)
}

fn var(vm: &VarMap, name: &str) -> candle_core::Var {
    vm.data().lock().unwrap()[&format!("encoder.{name}")].clone()
}

#[test]
fn the_triplet_loss_matches_the_reference_per_sample_and_in_the_mean() {
    // Reference: per_sample [0.4984785, 1.345e-4, 1.0047635], triplet 0.5011255,
    // positive_sq 0.0024385, negative_sq 3.1896, hinge_active 2/3
    let (_vm, enc) = encoder(0.0);
    let phi = |x| enc.forward(&t(x)).unwrap();
    let (loss, per, stats) =
        triplet_loss(&phi(&ANCHOR), &phi(&POSITIVE), &phi(&NEGATIVE), 1.0).unwrap();
    close(
        "per_sample",
        &flat(&per),
        &[0.498_478_5, 1.345e-4, 1.004_763_5],
        1e-5,
    );
    close("loss", &flat(&loss), &[0.501_125_5], 1e-5);
    close("stats.loss", &[stats.loss], &[0.501_125_5], 1e-5);
    close("positive_sq", &[stats.positive_sq], &[0.002_438_5], 1e-5);
    close("negative_sq", &[stats.negative_sq], &[3.1896], 1e-5);
    close("hinge_active", &[stats.hinge_active], &[2.0 / 3.0], 1e-6);
}

#[test]
fn the_stable_loss_matches_the_reference_with_and_without_weights() {
    // Reference: stable 1.98292667e-4, stable_weighted 3.24419167e-4 (λ = [1, 0.5, 2], coeff 0.1)
    let (_vm, enc) = encoder(0.0);
    let (_old_vm, old) = encoder(1.0);
    let phi = enc.forward(&t(&REG)).unwrap();
    let phi_old = old.forward(&t(&REG)).unwrap();
    let (_, plain) = stable_loss(&phi, &phi_old, None, 0.1).unwrap();
    close("stable", &[plain], &[1.982_926_67e-4], 1e-4);
    let lam = Tensor::from_slice(&[1.0f32, 0.5, 2.0], (3, 1), &Device::Cpu).unwrap();
    let (loss, weighted) = stable_loss(&phi, &phi_old, Some(&lam), 0.1).unwrap();
    close("stable_weighted", &[weighted], &[3.244_191_67e-4], 1e-4);
    close("tensor", &flat(&loss), &[3.244_191_67e-4], 1e-4);
}

#[test]
fn the_objective_gradients_and_one_adam_step_match_the_reference() {
    let (vm, enc) = encoder(0.0);
    let (_old_vm, old) = encoder(1.0);
    let input = Tensor::cat(&[t(&ANCHOR), t(&POSITIVE), t(&NEGATIVE), t(&REG)], 0).unwrap();
    let objective = phi_objective(&enc, &input, 3, 1.0, Some((&old, 0.1))).unwrap();
    close("triplet", &[objective.triplet.loss], &[0.501_125_5], 1e-5);
    close("stable", &[objective.stable], &[1.982_926_67e-4], 1e-4);
    let grads = objective.loss.backward().unwrap();
    let reference_grads: [(&str, Vec<f64>); 4] = [
        (
            "l0.weight",
            vec![
                -0.4581808333,
                -0.3455575,
                -0.1138475,
                0.3221985,
                0.0792621667,
                -0.0160691667,
                -0.2179965,
                -0.1497795,
                -0.0482075,
                -0.1239868333,
                -0.0306521667,
                0.0064285,
            ],
        ),
        (
            "l0.bias",
            vec![-0.232175, -0.0004093333, -0.096916, -0.001079],
        ),
        (
            "l1.weight",
            vec![
                -2.4775366667e-01,
                1.7235416667e-01,
                -2.3281100000e-01,
                -1.9001800000e-02,
                -1.0087000000e-02,
                8.2225000000e-03,
                -1.0422666667e-02,
                -2.3713333333e-04,
            ],
        ),
        ("l1.bias", vec![6.6666666667e-05, 2.9666666667e-03]),
    ];
    for (name, want) in &reference_grads {
        let got = flat(grads.get(&var(&vm, name)).unwrap());
        close(&format!("grad {name}"), &got, want, 2e-5);
    }
    let vars: Vec<_> = reference_grads.iter().map(|(n, _)| var(&vm, n)).collect();
    let mut opt = phi_optimizer(vars, 0.01).unwrap();
    opt.step(&grads).unwrap();
    let after: [(&str, Vec<f64>); 4] = [
        (
            "l0.weight",
            vec![
                0.5099999998,
                -0.2900000003,
                0.2099999991,
                -0.4099999997,
                0.5900000013,
                0.1099999938,
                0.3099999995,
                0.2099999993,
                -0.4900000021,
                0.1099999992,
                -0.1900000033,
                0.3900000156,
            ],
        ),
        (
            "l0.bias",
            vec![0.1099999996, -0.0900002443, 0.059999999, 0.0399999073],
        ),
        (
            "l1.weight",
            vec![
                0.7099999996,
                -0.5099999994,
                0.3099999996,
                0.2099999947,
                -0.1900000099,
                0.3900000122,
                0.6099999904,
                -0.2900004217,
            ],
        ),
        ("l1.bias", vec![0.0400014998, -0.0599999663]),
    ];
    for (name, want) in &after {
        let got = flat(var(&vm, name).as_tensor());
        close(&format!("after adam {name}"), &got, want, 1e-6);
    }
}

#[test]
fn phi_losses_refuse_mismatched_shapes_and_name_the_tensor() {
    let a = Tensor::zeros((4, 2), DType::F32, &Device::Cpu).unwrap();
    let wrong = Tensor::zeros((3, 2), DType::F32, &Device::Cpu).unwrap();
    let err = triplet_loss(&a, &wrong, &a, 1.0).unwrap_err();
    assert!(
        matches!(
            err,
            LearnerError::Shape {
                what: "triplet_loss: positive",
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("[4, 2]"), "{err}");
    let lam = Tensor::zeros((4, 2), DType::F32, &Device::Cpu).unwrap();
    let err = stable_loss(&a, &a, Some(&lam), 0.1).unwrap_err();
    assert!(err.to_string().contains("weight"), "{err}");
    let (_vm, enc) = encoder(0.0);
    let err = phi_objective(&enc, &t(&ANCHOR), 3, 1.0, None).unwrap_err();
    assert!(err.to_string().contains("phi_objective"), "{err}");
}
