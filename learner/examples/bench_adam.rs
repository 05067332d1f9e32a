//! Optimiser step speed: [`learner::adam::Adam`] against candle's `AdamW` (weight decay 0) on
//! the parameters of one low-level SAC critic pair at the default sizes (input 29 + 8 + 16 + 2,
//! hidden [256, 256], twin heads), the same gradients every step.
//! Run: `cargo run --release -p learner --example bench_adam` (prints µs per step, median of
//! 7 blocks of 500 steps each).

use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use learner::adam::{Adam, AdamParams};

/// Layer shapes `(in, out)` of one critic head; two heads make the twin critic.
const LAYERS: [(usize, usize); 3] = [(55, 256), (256, 256), (256, 1)];
const BLOCKS: usize = 7;
const STEPS_PER_BLOCK: usize = 500;

fn vars() -> candle_core::Result<Vec<Var>> {
    let mut out = Vec::new();
    for head in 0..2 {
        for (k, &(i, o)) in LAYERS.iter().enumerate() {
            let seed = (head * 10 + k) as f32;
            let w: Vec<f32> = (0..i * o)
                .map(|j| ((j as f32 + seed) * 0.37).sin() * 0.1)
                .collect();
            out.push(Var::from_vec(w, (i, o), &Device::Cpu)?);
            out.push(Var::zeros(o, candle_core::DType::F32, &Device::Cpu)?);
        }
    }
    Ok(out)
}

/// A loss touching every variable: Σ sin(θ)·0.01 over all parameters.
fn loss(vars: &[Var]) -> candle_core::Result<Tensor> {
    let mut total = Tensor::zeros((), candle_core::DType::F32, &Device::Cpu)?;
    for v in vars {
        total = (total + (v.as_tensor().sin()?.sum_all()? * 0.01)?)?;
    }
    Ok(total)
}

fn time<O: Optimizer>(name: &str, mut opt: O, vars: &[Var]) -> candle_core::Result<()> {
    let grads = loss(vars)?.backward()?;
    let mut per_step = Vec::new();
    for _ in 0..BLOCKS {
        let start = Instant::now();
        for _ in 0..STEPS_PER_BLOCK {
            opt.step(&grads)?;
        }
        per_step.push(start.elapsed().as_secs_f64() * 1e6 / STEPS_PER_BLOCK as f64);
    }
    per_step.sort_by(f64::total_cmp);
    println!(
        "{name}: {:.1} µs per step (median of {BLOCKS} blocks)",
        per_step[BLOCKS / 2]
    );
    Ok(())
}

fn main() -> candle_core::Result<()> {
    let n: usize = vars()?.iter().map(|v| v.elem_count()).sum();
    println!("{n} parameters in {} variables", 4 * LAYERS.len());
    let v = vars()?;
    time(
        "learner::adam::Adam",
        Adam::new(v.clone(), AdamParams::with_lr(3e-4))?,
        &v,
    )?;
    let v = vars()?;
    let params = ParamsAdamW {
        lr: 3e-4,
        weight_decay: 0.0,
        ..ParamsAdamW::default()
    };
    time("candle_nn::AdamW", AdamW::new(v.clone(), params)?, &v)?;
    Ok(())
}
