//! Updates per second of the low level, SAC against the reference code's deterministic level
//! (issue 5), at the paper's shapes: batch 128, head `[obs 29, φ 2]`, subgoal 2, 8 actions.
//! SAC 2 × 256 (policy, twin critics); deterministic actor 4 × 400 and critic 5 × 400 (digest
//! §3.2), and the deterministic level at SAC's 2 × 256 for an equal-size comparison.
//!
//! Run (one candle thread, as `asi bench learner`):
//! `RAYON_NUM_THREADS=1 cargo run --release -p learner --example low_update_rates`

use std::time::Instant;

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use learner::deterministic::{DeterministicLevel, DeterministicNets, DeterministicParams};
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams, SacShape};
use nets::weights::vars_under;
use nets::{seeded_var_builder, DeterministicActor, DistanceCritic, LinearInit};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64Mcg;

/// Any error of the example.
type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

const BATCH: usize = 128;
const HEAD: usize = 31;
const SUBGOAL: usize = 2;
const ACTION: usize = 8;
const SCALE: f64 = 16.0;
const WARMUP: usize = 20;
const TIMED: usize = 200;
/// Distinct random batches cycled through.
const N_BATCHES: usize = 8;

fn normal(rng: &mut Pcg64Mcg, rows: usize, cols: usize) -> Result<Tensor> {
    let v: Vec<f32> = (0..rows * cols)
        .map(|_| StandardNormal.sample(rng))
        .collect();
    Ok(Tensor::from_vec(v, (rows, cols), &Device::Cpu)?)
}

fn batch(rng: &mut Pcg64Mcg) -> Result<SacBatch> {
    let action: Vec<f32> = (0..BATCH * ACTION)
        .map(|_| rng.random_range(-SCALE as f32..SCALE as f32))
        .collect();
    let reward: Vec<f32> = (0..BATCH).map(|_| rng.random_range(-1.0..0.0)).collect();
    Ok(SacBatch {
        head: normal(rng, BATCH, HEAD)?,
        next_head: normal(rng, BATCH, HEAD)?,
        tail: Some(normal(rng, BATCH, SUBGOAL)?),
        action: Tensor::from_vec(action, (BATCH, ACTION), &Device::Cpu)?,
        reward: Tensor::from_vec(reward, (BATCH, 1), &Device::Cpu)?,
        terminal: Tensor::zeros((BATCH, 1), candle_core::DType::F32, &Device::Cpu)?,
    })
}

fn sac(hidden: &[usize]) -> Result<SacLevel> {
    let shape = SacShape {
        policy_in: HEAD + SUBGOAL,
        critic_in: HEAD + ACTION + SUBGOAL,
        hidden,
        action_dim: ACTION,
        action_scale: SCALE,
        init: LinearInit::XavierUniform,
    };
    let (nets, _, _) = SacNets::seeded(&shape, 0)?;
    let params = SacParams::spec_defaults(ACTION);
    Ok(SacLevel::new("low", nets, params)?)
}

fn deterministic(actor_hidden: &[usize], critic_hidden: &[usize]) -> Result<DeterministicLevel> {
    let (vm, tvm) = (VarMap::new(), VarMap::new());
    let init = LinearInit::TorchDefault;
    let (p_in, c_in) = (HEAD + SUBGOAL, HEAD + ACTION + SUBGOAL);
    let build = |vm: &VarMap, seed| -> Result<(DeterministicActor, DistanceCritic)> {
        let vb = seeded_var_builder(vm, seed, &Device::Cpu);
        Ok((
            DeterministicActor::new(&vb.pp("actor"), p_in, actor_hidden, ACTION, SCALE, init)?,
            DistanceCritic::new(&vb.pp("critic"), c_in, critic_hidden, init)?,
        ))
    };
    let (actor, critic) = build(&vm, 0)?;
    let (actor_target, critic_target) = build(&tvm, 1)?;
    let nets = DeterministicNets {
        actor,
        actor_vars: vars_under(&vm, "actor"),
        actor_target,
        actor_target_vars: vars_under(&tvm, "actor"),
        critic,
        critic_vars: vars_under(&vm, "critic"),
        critic_target,
        critic_target_vars: vars_under(&tvm, "critic"),
    };
    let params = DeterministicParams {
        gamma: 0.99,
        lr: 2e-4,
        lr_decay_episodes: 3000,
        lr_decay_factor: 0.5,
        critic_weight_decay: 1e-5,
        polyak: 0.99,
        target_update_period: 3,
        grad_clip: 1.0,
        reach_threshold: 0.1,
    };
    Ok(DeterministicLevel::new(nets, params)?)
}

/// Updates per second of `step` over [`TIMED`] updates after [`WARMUP`].
fn rate(mut step: impl FnMut(usize) -> Result<()>) -> Result<f64> {
    for i in 0..WARMUP {
        step(i)?;
    }
    let start = Instant::now();
    for i in 0..TIMED {
        step(i)?;
    }
    Ok(TIMED as f64 / start.elapsed().as_secs_f64())
}

fn main() -> Result<()> {
    let mut rng = Pcg64Mcg::seed_from_u64(0);
    let batches = (0..N_BATCHES)
        .map(|_| batch(&mut rng))
        .collect::<Result<Vec<_>>>()?;
    let noise = (0..N_BATCHES)
        .map(|_| {
            Ok((
                normal(&mut rng, BATCH, ACTION)?,
                normal(&mut rng, BATCH, ACTION)?,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".to_owned());
    println!("batch {BATCH}, head {HEAD}, subgoal {SUBGOAL}, action {ACTION}; RAYON_NUM_THREADS {threads}");
    let mut level = sac(&[256, 256])?;
    let r = rate(|i| {
        let (next_eps, eps) = &noise[i % N_BATCHES];
        level.update(&batches[i % N_BATCHES], next_eps, eps)?;
        Ok(())
    })?;
    println!("sac 2x256 low update: {r:.1} updates/s");
    for (name, actor, critic) in [
        (
            "deterministic 4x400 actor, 5x400 critic",
            vec![400; 4],
            vec![400; 5],
        ),
        ("deterministic 2x256", vec![256; 2], vec![256; 2]),
    ] {
        let mut level = deterministic(&actor, &critic)?;
        let r = rate(|i| {
            level.update(&batches[i % N_BATCHES], i as u64)?;
            Ok(())
        })?;
        println!("{name} low update: {r:.1} updates/s");
    }
    Ok(())
}
