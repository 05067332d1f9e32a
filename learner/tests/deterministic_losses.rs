//! Deterministic low-level losses against the numpy reference
//! `tests/reference/deterministic_losses.py` (float64; f32 here, hence the tolerances).
//! Regenerate with `python3 learner/tests/reference/deterministic_losses.py`.

use candle_core::{Device, Tensor, Var};
use learner::deterministic::losses::{
    deterministic_actor_loss, distance_critic_loss, distance_target, not_done,
};
use nets::q_from_distance;

fn col(values: &[f32]) -> Tensor {
    Tensor::from_slice(values, (values.len(), 1), &Device::Cpu).unwrap()
}

fn flat(t: &Tensor) -> Vec<f64> {
    let v: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
    v.into_iter().map(f64::from).collect()
}

fn close(what: &str, got: &[f64], want: &[f64]) {
    assert_eq!(got.len(), want.len(), "{what}");
    for (g, w) in got.iter().zip(want) {
        assert!(
            (g - w).abs() <= 1e-4 * (1.0 + w.abs()),
            "{what}: {g} vs reference {w}"
        );
    }
}

/// Reference: not_done [1, 0, 1, 0], target [-9.96617457, -0.05, -40.3043994, -0.02]
fn target() -> Tensor {
    let ag_next = Tensor::from_slice(
        &[1.0f32, 0.0, 0.05, 0.05, 3.0, 4.0, 0.0, 0.09],
        (4, 2),
        &Device::Cpu,
    )
    .unwrap();
    let subgoal = Tensor::zeros((4, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
    let mask = not_done(&ag_next, &subgoal, 0.1).unwrap();
    assert_eq!(flat(&mask), vec![1.0, 0.0, 1.0, 0.0]);
    let next_q = q_from_distance(&col(&[10.0, 2.0, 50.0, 0.0]), 0.99).unwrap();
    close(
        "next_q",
        &flat(&next_q),
        &[-9.5617925, -1.99, -39.49939329, 0.0],
    );
    distance_target(&col(&[-0.5, -0.05, -1.2, -0.02]), &mask, &next_q, 0.99).unwrap()
}

#[test]
fn the_target_bootstraps_until_the_subgoal_is_reached_and_is_clipped_at_zero() {
    close(
        "target",
        &flat(&target()),
        &[-9.96617457, -0.05, -40.3043994, -0.02],
    );
    let y = distance_target(&col(&[0.5]), &col(&[1.0]), &col(&[0.1]), 0.99).unwrap();
    assert_eq!(flat(&y), vec![0.0], "positive targets are clipped to 0");
}

#[test]
fn the_critic_loss_and_its_distance_gradient_match_the_reference() {
    // Reference: q [-7.72553056, -1, -36.38145139, 0.50378153], critic_loss 5.3967133481,
    // grad_d [-1.03897476, 0.47261704, -1.25414249, -0.26453501]
    let d = Var::from_tensor(&col(&[8.0, 1.0, 45.0, -0.5])).unwrap();
    let q = q_from_distance(d.as_tensor(), 0.99).unwrap();
    close(
        "q",
        &flat(&q),
        &[-7.72553056, -1.0, -36.38145139, 0.50378153],
    );
    let (loss, stats) = distance_critic_loss(&q, &target()).unwrap();
    close("critic_loss", &[stats.loss], &[5.396_713_348]);
    close("loss tensor", &flat(&loss), &[5.396_713_348]);
    let grads = loss.backward().unwrap();
    let grad = flat(grads.get(&d).unwrap());
    close(
        "grad_d",
        &grad,
        &[-1.03897476, 0.47261704, -1.25414249, -0.26453501],
    );
}

#[test]
fn the_actor_loss_is_minus_the_mean_q_and_shapes_are_checked() {
    // Reference: actor_loss 10.825
    let loss = deterministic_actor_loss(&col(&[-3.0, -0.5, -40.0, 0.2])).unwrap();
    close("actor_loss", &flat(&loss), &[10.825]);
    let err = distance_critic_loss(&col(&[1.0, 2.0]), &col(&[1.0])).unwrap_err();
    assert!(err.to_string().contains("target"), "{err}");
}
