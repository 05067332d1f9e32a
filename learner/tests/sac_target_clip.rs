//! `learner.high.clip_target`: the SAC critic target y, as the update builds it, is clamped to
//! `[low, high]` when a [`TargetClip`] is set and left as it is otherwise; the critic loss of an
//! update is taken against the clamped y.
//!
//! The level's critics are made constant so that every y can be worked out by hand: all weights
//! are 0 and all biases `Q_CONST`, so Q(s, a) = Q'(s', a') = `Q_CONST` for every input (the
//! target critic starts as a copy of the online one), and α = 0 removes the log π term. Then
//! `y = r + γ · (1 − d) · Q_CONST`.

use candle_core::{Device, Tensor};
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams, SacShape, TargetClip};
use nets::LinearInit;

/// The output of both critics (online and target) for every input.
const Q_CONST: f32 = -600.0;
/// The reference's bound for a 500-step task paying −1 per step.
const CLIP: TargetClip = TargetClip {
    low: -500.0,
    high: 0.0,
};

const PARAMS: SacParams = SacParams {
    gamma: 0.99,
    tau: 0.005,
    lr: 3e-4,
    alpha: 0.0,
    auto_alpha: false,
    target_entropy: -1.0,
    critic_action_scale: 1.0,
    target_clip: None,
};

/// Per sample: reward r, terminal d, and y = r + 0.99 · (1 − d) · (−600) by hand.
const CASES: [(f32, f32, f32); 6] = [
    (700.0, 0.0, 106.0),   // above 0: 700 − 594
    (3.0, 1.0, 3.0),       // above 0, no bootstrap
    (-20.0, 1.0, -20.0),   // inside
    (-20.0, 0.0, -614.0),  // below −500: −20 − 594
    (300.0, 0.0, -294.0),  // inside, bootstrapped: 300 − 594
    (-700.0, 1.0, -700.0), // below −500, no bootstrap
];
/// The same y clamped to [−500, 0].
const CLAMPED: [f32; 6] = [0.0, 0.0, -20.0, -500.0, -294.0, -500.0];

/// A 1-D state → 1-D action level (a high level: no tail) whose critics output `Q_CONST`.
fn level(target_clip: Option<TargetClip>) -> SacLevel {
    let shape = SacShape {
        policy_in: 1,
        critic_in: 2,
        hidden: &[8],
        action_dim: 1,
        action_scale: 1.0,
        init: LinearInit::XavierUniform,
    };
    let (nets, _, _) = SacNets::seeded(&shape, 1).unwrap();
    for var in &nets.critic_vars {
        let value = if var.dims().len() == 1 { Q_CONST } else { 0.0 };
        var.set(
            &var.as_tensor()
                .ones_like()
                .unwrap()
                .affine(f64::from(value), 0.0)
                .unwrap(),
        )
        .unwrap();
    }
    let params = SacParams {
        target_clip,
        ..PARAMS
    };
    SacLevel::new("high", nets, params).unwrap()
}

fn column(values: &[f32]) -> Tensor {
    Tensor::from_slice(values, (values.len(), 1), &Device::Cpu).unwrap()
}

/// The batch of [`CASES`] and the policy noise for a' and ã.
fn batch() -> (SacBatch, Tensor, Tensor) {
    let n = CASES.len();
    let states: Vec<f32> = (0..n).map(|i| i as f32 * 0.1 - 0.3).collect();
    let batch = SacBatch {
        head: column(&states),
        next_head: column(&states.iter().map(|s| -s).collect::<Vec<_>>()),
        tail: None,
        action: column(&vec![0.5; n]),
        reward: column(&CASES.map(|(r, _, _)| r)),
        terminal: column(&CASES.map(|(_, d, _)| d)),
    };
    let noise = column(&(0..n).map(|i| i as f32 * 0.4 - 1.0).collect::<Vec<_>>());
    (batch, noise.clone(), noise.affine(-1.0, 0.0).unwrap())
}

fn as_vec(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() < 1e-3, "sample {i}: y = {g}, expected {w}");
    }
}

#[test]
fn with_the_clip_on_each_target_is_clamped_to_minus_t_and_zero() {
    let (batch, next_eps, _) = batch();
    let y = level(Some(CLIP)).critic_target(&batch, &next_eps).unwrap();
    assert_close(&as_vec(&y), &CLAMPED);
}

#[test]
fn with_the_clip_off_the_targets_are_the_unclamped_soft_targets() {
    let (batch, next_eps, _) = batch();
    let y = level(None).critic_target(&batch, &next_eps).unwrap();
    assert_close(&as_vec(&y), &CASES.map(|(_, _, y)| y));
}

#[test]
fn an_update_with_the_clip_on_fits_the_critic_to_the_clamped_targets() {
    // L_Q = mean((Q₁ − y)²) + mean((Q₂ − y)²) with Q₁ = Q₂ = −600 and y = CLAMPED:
    // (600² + 600² + 580² + 100² + 306² + 100²) / 6 · 2 = 1,170,036 / 3 = 390,012.
    let clamped_loss = 390_012.0;
    // Against the raw y: (706² + 603² + 580² + 14² + 306² + 100²) / 3 = 1,302,277 / 3.
    let raw_loss = 1_302_277.0 / 3.0;
    let (batch, next_eps, eps) = batch();
    let on = level(Some(CLIP)).update(&batch, &next_eps, &eps).unwrap();
    assert!(
        (on.critic.loss - clamped_loss).abs() < 1.0,
        "clip on: L_Q = {}, expected {clamped_loss}",
        on.critic.loss
    );
    let clamped_mean = f64::from(CLAMPED.iter().sum::<f32>()) / 6.0;
    assert!((on.critic.target_mean - clamped_mean).abs() < 1e-3);
    let off = level(None).update(&batch, &next_eps, &eps).unwrap();
    assert!(
        (off.critic.loss - raw_loss).abs() < 1.0,
        "clip off: L_Q = {}, expected {raw_loss}",
        off.critic.loss
    );
}
