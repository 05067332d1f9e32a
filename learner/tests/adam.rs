//! [`learner::adam::Adam`] against `torch.optim.Adam`, and its state export/import.
//!
//! The numbers come from `learner/tests/reference/adam.py` (PyTorch 2, float32):
//! L = mean((x @ w + b − y)²), Adam(lr = 0.1), four steps.

use candle_core::{Device, Tensor, Var};
use candle_nn::Optimizer;
use learner::adam::{Adam, AdamParams, AdamStateError};

const X: [f32; 6] = [0.5, -1.0, 1.5, 0.25, -0.75, 2.0];
const Y: [f32; 9] = [1.0, 0.0, -1.0, 0.5, 2.0, 0.0, -1.0, 1.0, 3.0];
const W0: [f32; 6] = [0.1, -0.2, 0.3, 0.4, 0.0, -0.5];
const B0: [f32; 3] = [0.05, -0.05, 0.2];

/// w and b after each step (torch).
const TORCH_W: [[f32; 6]; 4] = [
    [0.2, -0.1, 0.2, 0.3, 0.1, -0.4],
    [
        0.299_246_28,
        -0.000_366_479_16,
        0.100_267_37,
        0.200_871_81,
        0.198_716_49,
        -0.300_310_13,
    ],
    [
        0.396_740_14,
        0.098_593_965,
        0.001_014_292_2,
        0.103_363_48,
        0.294_707_83,
        -0.201_18,
    ],
    [
        0.490_616,
        0.196_515_05,
        -0.097_516_38,
        0.008_255_415,
        0.385_913_76,
        -0.102_895_1,
    ],
];
const TORCH_B: [[f32; 3]; 4] = [
    [-0.05, 0.05, 0.3],
    [-0.109_989_93, 0.149_157_99, 0.398_984_9],
    [-0.109_139_91, 0.246_632_34, 0.495_886_68],
    [-0.079_044_975, 0.341_296_58, 0.589_227_6],
];
/// torch's exp_avg / exp_avg_sq after step 4.
const TORCH_M_W: [f32; 6] = [
    -0.126_988_81,
    -0.190_030_75,
    0.318_716_94,
    0.273_394_44,
    -0.113_334_47,
    -0.647_944_5,
];
const TORCH_V_W: [f32; 6] = [
    0.000_617_969_84,
    0.001_271_860_4,
    0.003_533_553,
    0.002_790_544,
    0.000_521_461_36,
    0.014_677_306,
];
const TORCH_M_B: [f32; 3] = [-0.004_586_776, -0.191_771_22, -0.089_037_46];
const TORCH_V_B: [f32; 3] = [7.844_626e-6, 0.001_385_923_4, 0.000_307_288_1];

struct Problem {
    x: Tensor,
    y: Tensor,
    w: Var,
    b: Var,
}

impl Problem {
    fn new() -> Problem {
        let cpu = Device::Cpu;
        Problem {
            x: Tensor::from_slice(&X, (3, 2), &cpu).unwrap(),
            y: Tensor::from_slice(&Y, (3, 3), &cpu).unwrap(),
            w: Var::from_slice(&W0, (2, 3), &cpu).unwrap(),
            b: Var::from_slice(&B0, 3, &cpu).unwrap(),
        }
    }

    fn optimizer(&self) -> Adam {
        Adam::new(
            vec![self.w.clone(), self.b.clone()],
            AdamParams::with_lr(0.1),
        )
        .unwrap()
    }

    fn loss(&self) -> Tensor {
        let pred = self
            .x
            .matmul(self.w.as_tensor())
            .unwrap()
            .broadcast_add(self.b.as_tensor())
            .unwrap();
        (pred - &self.y).unwrap().sqr().unwrap().mean_all().unwrap()
    }

    fn step(&self, opt: &mut Adam) {
        opt.backward_step(&self.loss()).unwrap();
    }

    /// ∂L/∂w and ∂L/∂b by hand, in f64: with r = x·w + b − y (3×3), ∂L/∂r = 2r/9,
    /// ∂L/∂w = xᵀ·∂L/∂r, ∂L/∂b = the column sums of ∂L/∂r.
    fn hand_gradient(&self) -> (Vec<f64>, Vec<f64>) {
        let (w, b) = (self.w(), self.b());
        let mut grad_w = vec![0.0; 6];
        let mut grad_b = vec![0.0; 3];
        for i in 0..3 {
            for j in 0..3 {
                let pred: f64 = (0..2)
                    .map(|k| f64::from(X[2 * i + k]) * f64::from(w[3 * k + j]))
                    .sum::<f64>()
                    + f64::from(b[j]);
                let d = 2.0 * (pred - f64::from(Y[3 * i + j])) / 9.0;
                grad_b[j] += d;
                for k in 0..2 {
                    grad_w[3 * k + j] += f64::from(X[2 * i + k]) * d;
                }
            }
        }
        (grad_w, grad_b)
    }

    fn w(&self) -> Vec<f32> {
        self.w.as_tensor().flatten_all().unwrap().to_vec1().unwrap()
    }

    fn b(&self) -> Vec<f32> {
        self.b.as_tensor().to_vec1().unwrap()
    }
}

fn assert_close(got: &[f32], want: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            (g - w).abs() <= tol * (1.0 + w.abs()),
            "{what}[{i}]: got {g}, torch {w}"
        );
    }
}

#[test]
fn four_steps_match_torch_adam() {
    let p = Problem::new();
    let mut opt = p.optimizer();
    for step in 0..4 {
        p.step(&mut opt);
        assert_close(
            &p.w(),
            &TORCH_W[step],
            2e-6,
            &format!("w after step {}", step + 1),
        );
        assert_close(
            &p.b(),
            &TORCH_B[step],
            2e-6,
            &format!("b after step {}", step + 1),
        );
    }
    let state = opt.export_state();
    assert_eq!(state.step, 4);
    assert_close(&state.m[0], &TORCH_M_W, 1e-5, "exp_avg of w");
    assert_close(&state.v[0], &TORCH_V_W, 1e-5, "exp_avg_sq of w");
    assert_close(&state.m[1], &TORCH_M_B, 1e-5, "exp_avg of b");
    assert_close(&state.v[1], &TORCH_V_B, 1e-5, "exp_avg_sq of b");
}

#[test]
fn an_imported_state_continues_exactly_like_the_uninterrupted_optimizer() {
    let straight = Problem::new();
    let mut opt = straight.optimizer();
    for _ in 0..4 {
        straight.step(&mut opt);
    }

    let first = Problem::new();
    let mut opt_first = first.optimizer();
    first.step(&mut opt_first);
    first.step(&mut opt_first);
    let state = opt_first.export_state();
    // A fresh optimiser on fresh variables holding the same values, as after a restore.
    let resumed = Problem::new();
    resumed.w.set(first.w.as_tensor()).unwrap();
    resumed.b.set(first.b.as_tensor()).unwrap();
    let mut opt_resumed = resumed.optimizer();
    opt_resumed.import_state(state).unwrap();
    resumed.step(&mut opt_resumed);
    resumed.step(&mut opt_resumed);

    assert_eq!(resumed.w(), straight.w());
    assert_eq!(resumed.b(), straight.b());
    assert_eq!(opt_resumed.export_state(), opt.export_state());
}

#[test]
fn a_state_of_the_wrong_shape_is_refused_and_changes_nothing() {
    let p = Problem::new();
    let mut opt = p.optimizer();
    p.step(&mut opt);
    let before = opt.export_state();

    let mut short = before.clone();
    short.m[1].pop();
    assert_eq!(
        opt.import_state(short),
        Err(AdamStateError::Length {
            index: 1,
            expected: 3,
            m: 2,
            v: 3
        })
    );
    let mut missing = before.clone();
    missing.v.pop();
    assert_eq!(
        opt.import_state(missing),
        Err(AdamStateError::VarCount {
            expected: 2,
            m: 2,
            v: 1
        })
    );
    assert_eq!(opt.export_state(), before);
}

#[test]
fn a_variable_that_is_not_f32_is_refused() {
    let v = Var::from_slice(&[1.0f64, 2.0], 2, &Device::Cpu).unwrap();
    let err = Adam::new(vec![v], AdamParams::default()).unwrap_err();
    assert!(err.to_string().contains("only f32"), "{err}");
}

#[test]
fn weight_decay_adds_lambda_theta_to_the_gradient_as_torch_adam() {
    // A zero loss gradient leaves only λ·θ: Adam's first step is lr · λθ / (|λθ| + ε), i.e.
    // lr · sign(θ) up to ε — torch.optim.Adam(weight_decay=λ) on a parameter with zero grad.
    let cpu = Device::Cpu;
    let w = Var::from_slice(&[2.0f32, -0.5], 2, &cpu).unwrap();
    let params = AdamParams {
        weight_decay: 0.1,
        ..AdamParams::with_lr(0.01)
    };
    let mut opt = Adam::new(vec![w.clone()], params).unwrap();
    let zeros = Tensor::zeros(2, candle_core::DType::F32, &cpu).unwrap();
    let loss = (w.as_tensor() * zeros).unwrap().sum_all().unwrap();
    opt.backward_step(&loss).unwrap();
    let got: Vec<f32> = w.as_tensor().to_vec1().unwrap();
    let want = [
        2.0 - 0.01 * 0.2 / (0.2 + 1e-8),
        -0.5 + 0.01 * 0.05 / (0.05 + 1e-8),
    ];
    assert_close(&got, &want, 1e-7, "one step with weight decay only");
    let state = opt.export_state();
    assert!(
        (state.m[0][0] - 0.1 * 0.1 * 2.0).abs() < 1e-7,
        "m = (1 − β₁)·λθ"
    );
}

fn l2(parts: &[&[f64]]) -> f64 {
    parts
        .iter()
        .flat_map(|p| p.iter())
        .map(|g| g * g)
        .sum::<f64>()
        .sqrt()
}

fn bits(values: &[f32]) -> Vec<u32> {
    values.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn backward_step_norm_takes_the_same_steps_as_backward_step_bit_for_bit() {
    let decayed = AdamParams {
        weight_decay: 0.1,
        ..AdamParams::with_lr(0.1)
    };
    for params in [AdamParams::with_lr(0.1), decayed] {
        let (plain, measured) = (Problem::new(), Problem::new());
        let vars = |p: &Problem| vec![p.w.clone(), p.b.clone()];
        let mut opt_plain = Adam::new(vars(&plain), params).unwrap();
        let mut opt_measured = Adam::new(vars(&measured), params).unwrap();
        for _ in 0..4 {
            opt_plain.backward_step(&plain.loss()).unwrap();
            let norm = opt_measured.backward_step_norm(&measured.loss()).unwrap();
            assert!(norm > 0.0, "{params:?}: a non-zero gradient");
        }
        assert_eq!(bits(&measured.w()), bits(&plain.w()), "{params:?}: w");
        assert_eq!(bits(&measured.b()), bits(&plain.b()), "{params:?}: b");
        assert_eq!(opt_measured.export_state(), opt_plain.export_state());
    }
}

#[test]
fn the_returned_norm_is_the_l2_norm_of_the_loss_gradient_over_the_optimizers_variables() {
    let p = Problem::new();
    let mut opt = p.optimizer();
    for step in 1..=3 {
        let (grad_w, grad_b) = p.hand_gradient();
        let want = l2(&[&grad_w, &grad_b]);
        let got = opt.backward_step_norm(&p.loss()).unwrap();
        assert!(
            (got - want).abs() <= 1e-6 * want,
            "step {step}: got {got}, by hand {want}"
        );
    }
    // An optimiser over w alone counts w's gradient only, though b has one too.
    let q = Problem::new();
    let mut w_only = Adam::new(vec![q.w.clone()], AdamParams::with_lr(0.1)).unwrap();
    let (grad_w, grad_b) = q.hand_gradient();
    let got = w_only.backward_step_norm(&q.loss()).unwrap();
    let want = l2(&[&grad_w]);
    assert!(
        (got - want).abs() <= 1e-6 * want,
        "w only: got {got}, by hand {want}"
    );
    assert!(
        l2(&[&grad_w, &grad_b]) > want * (1.0 + 1e-3),
        "b's gradient is not negligible"
    );
}

#[test]
fn the_returned_norm_leaves_out_the_weight_decay_term() {
    let cpu = Device::Cpu;
    let w = Var::from_slice(&[2.0f32, -0.5], 2, &cpu).unwrap();
    let params = AdamParams {
        weight_decay: 0.1,
        ..AdamParams::with_lr(0.01)
    };
    let mut opt = Adam::new(vec![w.clone()], params).unwrap();
    let zeros = Tensor::zeros(2, candle_core::DType::F32, &cpu).unwrap();
    let loss = (w.as_tensor() * zeros).unwrap().sum_all().unwrap();
    assert_eq!(opt.backward_step_norm(&loss).unwrap(), 0.0);
    assert_ne!(
        w.as_tensor().to_vec1::<f32>().unwrap(),
        vec![2.0, -0.5],
        "λ·θ still steps"
    );
}
