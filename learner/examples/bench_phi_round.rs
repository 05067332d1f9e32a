//! φ round speed: Adam steps per second of one round at the default `[encoder]` sizes
//! (obs 29 as the ant, hidden [100, 100], batch 100, stable term on) on synthetic episodes.
//! Run: `cargo run --release -p learner --example bench_phi_round`

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
