//! Dense layers and MLPs: maths against candle_nn, shapes, input checks, initialisation.

mod common;

use candle_core::{DType, Tensor};
use candle_nn::{Module, VarBuilder, VarMap};
use common::*;
use nets::{Encoder, EnsembleMlp, Linear, LinearInit, Mlp, NetsError};

#[test]
fn linear_matches_candle_nn_linear_in_value_and_gradient() {
    let (vm, vb) = seeded(5);
    let ours = Linear::new(&vb, 7, 3, LinearInit::TorchDefault).unwrap();
    let reference = candle_nn::Linear::new(ours.weight().clone(), Some(ours.bias().clone()));
    let x = batch(4, 7);
    let y = ours.forward(&x).unwrap();
    let y_ref = reference.forward(&x).unwrap();
    assert!(max_abs_diff(&y, &y_ref) < 1e-6);
    let upstream = batch(4, 3);
    let grads = y
        .mul(&upstream)
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    let grads_ref = y_ref
        .mul(&upstream)
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    for var in vm.all_vars() {
        let (g, g_ref) = (
            grads.get(var.as_tensor()).unwrap(),
            grads_ref.get(var.as_tensor()).unwrap(),
        );
        assert!(
            max_abs_diff(g, g_ref) < 1e-5,
            "gradient of a {:?} parameter",
            var.dims()
        );
    }
}

#[test]
fn linear_parameters_are_named_weight_and_bias_under_the_prefix() {
    let (vm, vb) = seeded(0);
    Linear::new(&vb.pp("net").pp("l0"), 4, 3, LinearInit::XavierUniform).unwrap();
    let data = vm.data().lock().unwrap();
    assert_eq!(data["net.l0.weight"].dims(), &[3, 4]);
    assert_eq!(data["net.l0.bias"].dims(), &[3]);
}

#[test]
fn linear_rejects_wrong_rank_and_wrong_width_with_dims_in_the_message() {
    let (_vm, vb) = seeded(0);
    let layer = Linear::new(&vb.pp("enc").pp("l0"), 29, 100, LinearInit::TorchDefault).unwrap();
    let err = layer.forward(&batch(2, 31)).unwrap_err();
    assert!(
        matches!(
            err,
            NetsError::Dim {
                expected: 29,
                got: 31,
                ..
            }
        ),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("enc.l0") && msg.contains("29") && msg.contains("31"),
        "{msg}"
    );
    let rank3 = Tensor::zeros((2, 3, 29), DType::F32, &cpu()).unwrap();
    let msg = layer.forward(&rank3).unwrap_err().to_string();
    assert!(
        msg.contains("rank-2") && msg.contains("[2, 3, 29]") && msg.contains("[batch, 29]"),
        "{msg}"
    );
}

#[test]
fn mlp_layers_are_named_l0_l1_and_shapes_follow_the_widths() {
    let (vm, vb) = seeded(0);
    let mlp = Mlp::new(&vb, 5, &[16, 8], 3, LinearInit::TorchDefault).unwrap();
    assert_eq!(mlp.forward(&batch(10, 5)).unwrap().dims(), &[10, 3]);
    let mut names: Vec<String> = vm.data().lock().unwrap().keys().cloned().collect();
    names.sort();
    assert_eq!(
        names,
        [
            "l0.bias",
            "l0.weight",
            "l1.bias",
            "l1.weight",
            "l2.bias",
            "l2.weight"
        ]
    );
}

#[test]
fn mlp_output_layer_is_linear_and_a_trunk_ends_on_relu() {
    let (mut vm, vb) = seeded(0);
    let head = Mlp::new(&vb.pp("head"), 1, &[1], 1, LinearInit::TorchDefault).unwrap();
    let trunk = Mlp::trunk(&vb.pp("trunk"), 1, &[1], LinearInit::TorchDefault).unwrap();
    set(&mut vm, "head.l0.weight", t2(&[&[1.0]]));
    set(&mut vm, "head.l0.bias", t1(&[0.0]));
    set(&mut vm, "head.l1.weight", t2(&[&[-1.0]]));
    set(&mut vm, "head.l1.bias", t1(&[0.0]));
    set(&mut vm, "trunk.l0.weight", t2(&[&[-1.0]]));
    set(&mut vm, "trunk.l0.bias", t1(&[0.0]));
    let x = t2(&[&[2.0]]);
    assert_eq!(flat(&head.forward(&x).unwrap()), [-2.0]);
    assert_eq!(flat(&trunk.forward(&x).unwrap()), [0.0]);
}

#[test]
fn zero_widths_and_empty_trunks_are_spec_errors() {
    let (_vm, vb) = seeded(0);
    let err = Mlp::new(&vb.pp("bad"), 4, &[8, 0], 2, LinearInit::TorchDefault)
        .unwrap_err()
        .to_string();
    assert!(err.contains("bad") && err.contains("[4, 8, 0, 2]"), "{err}");
    assert!(Mlp::trunk(&vb.pp("t"), 4, &[], LinearInit::TorchDefault).is_err());
}

#[test]
fn ensemble_mlp_accepts_shared_or_per_member_inputs() {
    let (_vm, vb) = seeded(2);
    let ens = EnsembleMlp::new(&vb, 3, 4, &[8], 2, LinearInit::XavierUniform).unwrap();
    let x = batch(5, 4);
    let shared = ens.forward(&x).unwrap();
    assert_eq!(shared.dims(), &[3, 5, 2]);
    let stacked = Tensor::stack(&[&x, &x, &x], 0).unwrap();
    assert!(max_abs_diff(&shared, &ens.forward(&stacked).unwrap()) < 1e-5);
    let wrong_members = Tensor::stack(&[&x, &x], 0).unwrap();
    let err = ens.forward(&wrong_members).unwrap_err().to_string();
    assert!(
        err.contains("ensemble size") && err.contains('3') && err.contains('2'),
        "{err}"
    );
}

#[test]
fn encoder_maps_observations_to_the_latent_space_without_squashing() {
    let (_vm, vb) = seeded(4);
    let encoder = Encoder::new(&vb.pp("encoder"), 29, &[100, 100], 2).unwrap();
    let z = encoder
        .forward(&batch(16, 29).affine(100.0, 0.0).unwrap())
        .unwrap();
    assert_eq!(z.dims(), &[16, 2]);
    assert!(
        flat(&z).iter().any(|v| v.abs() > 1.0),
        "large inputs should give unsquashed outputs"
    );
}

/// Max |value| of a parameter in the map.
fn max_abs(vm: &VarMap, name: &str) -> f32 {
    flat(vm.data().lock().unwrap()[name].as_tensor())
        .iter()
        .fold(0.0, |m, v| m.max(v.abs()))
}

#[test]
fn xavier_init_draws_within_its_bound_and_zeroes_the_bias() {
    let (vm, vb) = seeded(9);
    Linear::new(&vb, 256, 128, LinearInit::XavierUniform).unwrap();
    let bound = (6.0f32 / 384.0).sqrt();
    let max_w = max_abs(&vm, "weight");
    assert!(
        max_w <= bound && max_w > 0.95 * bound,
        "max |w| {max_w}, bound {bound}"
    );
    assert_eq!(max_abs(&vm, "bias"), 0.0);
}

#[test]
fn torch_default_init_draws_weight_and_bias_within_one_over_sqrt_fan_in() {
    let (vm, vb) = seeded(10);
    Linear::new(&vb, 100, 400, LinearInit::TorchDefault).unwrap();
    let bound = 0.1f32;
    let max_w = max_abs(&vm, "weight");
    let max_b = max_abs(&vm, "bias");
    assert!(max_w <= bound && max_w > 0.95 * bound, "max |w| {max_w}");
    assert!(max_b <= bound && max_b > 0.8 * bound, "max |b| {max_b}");
}

#[test]
fn seeded_init_is_reproducible_and_depends_on_the_seed() {
    let values = |seed| {
        let (vm, vb) = seeded(seed);
        let mlp = Mlp::new(&vb, 6, &[10], 2, LinearInit::TorchDefault).unwrap();
        let _ = vm;
        flat(mlp.layers()[0].weight())
    };
    assert_eq!(values(42), values(42));
    assert_ne!(values(42), values(43));
}

#[test]
fn building_twice_on_one_map_shares_the_parameters() {
    let vm = VarMap::new();
    let vb = VarBuilder::from_varmap(&vm, DType::F32, &cpu());
    let a = Mlp::new(&vb, 3, &[4], 1, LinearInit::TorchDefault).unwrap();
    let b = Mlp::new(&vb, 3, &[4], 1, LinearInit::TorchDefault).unwrap();
    let x = batch(2, 3);
    assert_eq!(flat(&a.forward(&x).unwrap()), flat(&b.forward(&x).unwrap()));
    assert!(
        Mlp::new(&vb, 5, &[4], 1, LinearInit::TorchDefault).is_err(),
        "shape clash must fail"
    );
}

#[test]
fn ensemble_mlp_equals_separate_mlps_in_value_and_gradient() {
    let (ens_vm, ens_vb) = seeded(7);
    let ens = EnsembleMlp::new(&ens_vb, 2, 6, &[8, 8], 1, LinearInit::XavierUniform).unwrap();
    let (mut sep_vm, sep_vb) = seeded(8);
    let nets: Vec<Mlp> = (0..2)
        .map(|j| {
            Mlp::new(
                &sep_vb.pp(format!("m{j}")),
                6,
                &[8, 8],
                1,
                LinearInit::XavierUniform,
            )
            .unwrap()
        })
        .collect();
    let stacked = ens_vm.data().lock().unwrap().clone();
    for i in 0..3 {
        for param in ["weight", "bias"] {
            let both = stacked[&format!("l{i}.{param}")].as_tensor().clone();
            for j in 0..2 {
                set(
                    &mut sep_vm,
                    &format!("m{j}.l{i}.{param}"),
                    both.get(j).unwrap(),
                );
            }
        }
    }
    let x = batch(5, 6);
    let target = batch(5, 1);
    let y = ens.forward(&x).unwrap();
    let ens_grads = y
        .broadcast_sub(&target)
        .unwrap()
        .sqr()
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    let mut sep_loss = Tensor::zeros((), DType::F32, &cpu()).unwrap();
    for (j, net) in nets.iter().enumerate() {
        let yj = net.forward(&x).unwrap();
        assert!(
            max_abs_diff(&y.get(j).unwrap(), &yj) < 1e-5,
            "member {j} output"
        );
        sep_loss = sep_loss
            .add(&yj.sub(&target).unwrap().sqr().unwrap().sum_all().unwrap())
            .unwrap();
    }
    let sep_grads = sep_loss.backward().unwrap();
    for i in 0..3 {
        let g_ens = ens_grads
            .get(stacked[&format!("l{i}.weight")].as_tensor())
            .unwrap();
        for (j, net) in nets.iter().enumerate() {
            let g = sep_grads.get(net.layers()[i].weight()).unwrap();
            assert!(
                max_abs_diff(&g_ens.get(j).unwrap(), g) < 1e-4,
                "layer {i}, member {j}"
            );
        }
    }
}
