//! SAC losses against numbers from the numpy reference `tests/reference/sac_losses.py`
//! (float64; the Rust side is f32, hence the tolerances).

use candle_core::{Device, Tensor, Var};
use learner::sac::losses::{actor_loss, soft_target, temperature_loss, twin_critic_loss};
use learner::LearnerError;

fn col(values: &[f32]) -> Tensor {
    Tensor::from_slice(values, (values.len(), 1), &Device::Cpu).unwrap()
}

fn flat(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

fn close(a: f64, b: f64) {
    assert!(
        (a - b).abs() < 1e-4 * (1.0 + b.abs()),
        "{a} vs reference {b}"
    );
}

fn target() -> Tensor {
    let reward = col(&[-1.0, -0.5, 0.0, -2.0]);
    let terminal = col(&[0.0, 1.0, 0.0, 0.0]);
    let next_min_q = col(&[-10.0, -3.0, -1.5, -20.0]);
    let next_log_prob = col(&[-1.2, 0.3, 2.0, -0.7]);
    soft_target(&reward, &terminal, &next_min_q, &next_log_prob, 0.99, 0.2).unwrap()
}

#[test]
fn the_soft_target_bootstraps_only_where_not_terminal() {
    // Reference: target [-10.6624, -0.5, -1.881, -21.6614]
    let y = flat(&target());
    for (got, want) in y.iter().zip([-10.6624, -0.5, -1.881, -21.6614]) {
        close(f64::from(*got), want);
    }
}

#[test]
fn the_twin_critic_loss_sums_both_mean_squared_errors() {
    // Reference: critic_loss 3.11329236, q_means [-8.05, -7.825], target_mean -8.6762
    let q = Tensor::from_slice(
        &[-9.0f32, -9.5, -1.0, -0.8, -1.2, -2.0, -21.0, -19.0],
        (4, 2),
        &Device::Cpu,
    )
    .unwrap();
    let (loss, stats) = twin_critic_loss(&q, &target()).unwrap();
    close(f64::from(loss.to_scalar::<f32>().unwrap()), 3.113_292_36);
    close(stats.loss, 3.113_292_36);
    close(stats.q1_mean, -8.05);
    close(stats.q2_mean, -7.825);
    close(stats.target_mean, -8.6762);
}

#[test]
fn the_actor_loss_is_alpha_log_prob_minus_min_q() {
    // Reference: actor_loss 3.45, entropy 0.25
    let (loss, stats) = actor_loss(
        &col(&[-1.0, 0.5, 1.5, -2.0]),
        &col(&[-5.0, -4.0, -3.0, -2.0]),
        0.2,
    )
    .unwrap();
    close(f64::from(loss.to_scalar::<f32>().unwrap()), 3.45);
    close(stats.entropy, 0.25);
}

#[test]
fn the_temperature_loss_and_its_gradient_match_the_reference() {
    // Reference: temperature_loss 0.675 = d loss / d log_alpha (log_alpha = ln 0.3, H̄ = −2)
    let log_alpha = Var::from_slice(&[0.3f32.ln()], 1, &Device::Cpu).unwrap();
    let log_prob = col(&[-1.0, 0.5, 1.5, -2.0]);
    let loss = temperature_loss(log_alpha.as_tensor(), &log_prob, -2.0).unwrap();
    close(f64::from(loss.to_scalar::<f32>().unwrap()), 0.675);
    let grads = loss.backward().unwrap();
    let grad = flat(grads.get(&log_alpha).unwrap());
    close(f64::from(grad[0]), 0.675);
}

#[test]
fn losses_refuse_mismatched_shapes_and_name_the_tensor() {
    let q = Tensor::zeros((4, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = twin_critic_loss(&q, &target()).unwrap_err();
    assert!(
        matches!(
            err,
            LearnerError::Shape {
                what: "twin_critic_loss: q",
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("[4, 2]"), "{err}");
    let err = actor_loss(&col(&[1.0, 2.0]), &col(&[1.0]), 0.2).unwrap_err();
    assert!(err.to_string().contains("min_q"), "{err}");
}
