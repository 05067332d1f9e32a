//! φ round speed: Adam steps per second of one round at the default `[encoder]` sizes
//! (obs 29 as the ant, hidden [100, 100], batch 100, stable term on) on synthetic episodes.
//! Run: `cargo run --release -p learner --example bench_phi_round` (`-- --parts`: median µs of
//! input building, forward with losses, backward and Adam for one step, 500 steps).

use std::time::Instant;

use learner::phi::{PhiParams, PhiStore, PhiTrainer, RunKind};
use nets::{seeded_var_builder, spec_from_config, PolicySet, TaskDims};
use protocol::Config;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut config = Config::default();
    config.encoder.steps_per_round = 2_000;
    config.encoder.first_round_episode = 1;
    config.encoder.interval_episodes = 1;
    let dims = TaskDims {
        obs_dim: 29,
        goal_dim: 2,
        action_dim: 8,
        action_scale: 16.0,
    };
    let spec = spec_from_config(&config, dims)?;
    let vm = candle_nn::VarMap::new();
    PolicySet::new(
        &spec,
        &seeded_var_builder(&vm, 1, &candle_core::Device::Cpu),
    )?;
    let params = PhiParams::from_config(&config);
    let mut store = PhiStore::new(29, params.negative_offset, 1_000_000);
    for ep in 0..100 {
        let obs: Vec<f32> = (0..501 * 29)
            .map(|i| ((i * 7 + ep * 13) % 97) as f32 * 0.01)
            .collect();
        store.push_run(obs, RunKind::Complete);
    }
    if std::env::args().any(|a| a == "--parts") {
        return parts(&vm, &spec, 500);
    }
    let mut trainer = PhiTrainer::new(params, &spec, &vm, 3)?;
    for round in 0..2 {
        trainer.start_if_due(round + 1, &mut store)?;
        let start = Instant::now();
        let mut steps = 0;
        while trainer.is_active() {
            steps += trainer.run_slice(&mut store, 50)?.steps;
        }
        let secs = start.elapsed().as_secs_f64();
        println!(
            "round {round} (stable term {}): {steps} steps in {secs:.2} s = {:.0} steps/s",
            round > 0,
            steps as f64 / secs
        );
    }
    Ok(())
}

/// Per-part timing of one φ step at batch 100 with the stable term: input building, forward
/// with losses, backward, Adam step (medians over `n` steps, microseconds).
fn parts(
    vm: &candle_nn::VarMap,
    spec: &nets::NetsSpec,
    n: usize,
) -> Result<(), Box<dyn std::error::Error>> {
    use candle_core::{DType, Device, Tensor};
    use candle_nn::Optimizer;
    let vb = candle_nn::VarBuilder::from_varmap(vm, DType::F32, &Device::Cpu);
    let enc = nets::Encoder::new(&vb.pp(nets::prefix::ENCODER), 29, &spec.encoder_hidden, 2)?;
    let old = nets::Encoder::new(&vb.pp(nets::prefix::ENCODER), 29, &spec.encoder_hidden, 2)?;
    let vars: Vec<candle_core::Var> = vm
        .data()
        .lock()
        .map_err(|_| "poisoned")?
        .iter()
        .filter(|(k, _)| k.starts_with("encoder."))
        .map(|(_, v)| v.clone())
        .collect();
    let mut opt = learner::phi::phi_optimizer(vars, 1e-3)?;
    let data: Vec<f32> = (0..400 * 29).map(|i| (i % 97) as f32 * 0.01).collect();
    let mut t = [Vec::new(), Vec::new(), Vec::new(), Vec::new()];
    for _ in 0..n {
        let s = Instant::now();
        let input = Tensor::from_slice(&data, (400, 29), &Device::Cpu)?;
        let a = s.elapsed();
        let obj = learner::phi::phi_objective(&enc, &input, 100, 1.0, Some((&old, 0.1)))?;
        let b = s.elapsed();
        let grads = obj.loss.backward()?;
        let c = s.elapsed();
        opt.step(&grads)?;
        let d = s.elapsed();
        t[0].push(a.as_secs_f64());
        t[1].push((b - a).as_secs_f64());
        t[2].push((c - b).as_secs_f64());
        t[3].push((d - c).as_secs_f64());
    }
    for (name, mut v) in ["input", "forward+losses", "backward", "adam"]
        .into_iter()
        .zip(t)
    {
        v.sort_by(f64::total_cmp);
        println!("{name}: median {:.0} µs", v[v.len() / 2] * 1e6);
    }
    Ok(())
}
