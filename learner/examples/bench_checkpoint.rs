//! Checkpoint cost with 1 M steps in the low replay buffer: write time, size, restore time.
//!
//! The default config (AntMaze: c = 20, `replay.capacity_steps` = 8 M) with the ant's sizes
//! (obs 29, goal 2, action 8); 2,000 synthetic episodes of 500 steps are ingested through the
//! real chunk path, so the low buffer holds 1 M transitions, the high buffer 50 k and the φ
//! store 1.002 M states (only stored rows are written, so the capacity does not matter). No
//! update runs (the networks' size does not depend on it). Also times the file checksums over
//! the written files, CRC-64 (format 2) and the word-wise FNV-1a of format 1.
//! Run: `cargo run --release -p learner --example bench_checkpoint [-- DIR]` (default: a folder
//! in the system temp dir, removed at the end; give DIR to measure another disk).

use std::time::Instant;

use learner::{Learner, TaskDims};
use protocol::{
    ActorId, Config, DecisionKind, EpisodeId, PolicyVersion, StepLayout, StepRecord,
    TrajectoryFlags, TrajectoryHeader,
};

const EPISODES: u64 = 2_000;
const EPISODE_LENGTH: usize = 500;
const CHUNK: usize = 100;

fn record(t: usize, ep: u64, latent: usize, c: usize) -> StepRecord {
    let x = (t as f32 * 0.01).sin() + ep as f32 * 1e-3;
    StepRecord {
        obs: vec![x; 29],
        next_obs: vec![x + 0.01; 29],
        phi: vec![x; latent],
        next_phi: vec![x + 0.01; latent],
        subgoal: vec![0.5; latent],
        high_action: vec![0.5; latent],
        action: vec![0.1; 8],
        goal: vec![4.0, 8.0],
        achieved_goal: vec![x, x],
        reward: -1.0,
        decision: if t.is_multiple_of(c) {
            DecisionKind::Policy
        } else {
            DecisionKind::None
        },
        success: false,
        terminated: false,
        truncated: t + 1 == EPISODE_LENGTH,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut config = Config::default();
    config.env.episode_length = Some(EPISODE_LENGTH as u32);
    config.validate()?;
    let dims = TaskDims {
        obs_dim: 29,
        goal_dim: 2,
        action_dim: 8,
        action_scale: 30.0,
    };
    let mut learner = Learner::new(&config, dims, 1)?;
    let latent = learner.nets_spec().latent_dim;
    let c = config.hierarchy.c as usize;
    let layout = StepLayout::new(29, 8, 2, latent)?;
    let start = Instant::now();
    for ep in 0..EPISODES {
        let records: Vec<StepRecord> = (0..EPISODE_LENGTH)
            .map(|t| record(t, ep, latent, c))
            .collect();
        for (i, part) in records.chunks(CHUNK).enumerate() {
            let mut header = TrajectoryHeader::for_layout(&layout)?;
            header.actor_id = ActorId(0);
            header.episode_id = EpisodeId(ep);
            header.chunk_index = i as u32;
            header.n_steps = part.len() as u32;
            header.first_env_step = (i * CHUNK) as u64;
            header.policy_version = PolicyVersion(0);
            let mut flags = 0;
            if i == 0 {
                flags |= TrajectoryFlags::EPISODE_START;
            }
            if (i + 1) * CHUNK >= EPISODE_LENGTH {
                flags |= TrajectoryFlags::EPISODE_END | TrajectoryFlags::TRUNCATED;
            }
            header.flags = TrajectoryFlags(flags);
            learner.ingest(&header, &layout.encode_chunk(part)?)?;
        }
    }
    println!(
        "filled in {:.1} s: low replay {} transitions, high {}, φ store {} states",
        start.elapsed().as_secs_f64(),
        learner.low_replay().ring().len(),
        learner.high_replay().ring().len(),
        learner.phi_store().n_states()
    );

    let (dir, temporary) = match std::env::args().nth(1) {
        Some(dir) => (std::path::PathBuf::from(dir), false),
        None => (
            std::env::temp_dir().join(format!("asi-bench-checkpoint-{}", std::process::id())),
            true,
        ),
    };
    let start = Instant::now();
    let ckpt = learner.save_checkpoint(&config, &dir)?;
    let write_secs = start.elapsed().as_secs_f64();
    let mib = ckpt.manifest.total_bytes() as f64 / f64::from(1 << 20);
    println!(
        "write: {write_secs:.2} s, {mib:.0} MiB ({:.0} MiB/s) in {}",
        mib / write_secs,
        ckpt.path.display()
    );
    for file in &ckpt.manifest.files {
        println!(
            "  {:<24} {:>8.1} MiB",
            file.name,
            file.bytes as f64 / f64::from(1 << 20)
        );
    }
    drop(learner);
    let start = Instant::now();
    let (restored, _) = Learner::restore_checkpoint(&config, dims, &ckpt.path)?;
    println!(
        "restore: {:.2} s ({} low transitions)",
        start.elapsed().as_secs_f64(),
        restored.low_replay().ring().len()
    );
    // The share of the file checksums in both (each computes them once over every file), and
    // what the format-1 checksum cost over the same bytes.
    let files: Vec<Vec<u8>> = ckpt
        .manifest
        .files
        .iter()
        .map(|f| std::fs::read(ckpt.path.join(&f.name)))
        .collect::<Result<_, _>>()?;
    for (name, sum) in [
        ("CRC-64 (format 2)", ckpt::Checksum::Crc64),
        ("FNV-1a words (format 1)", ckpt::Checksum::Fnv1aWords),
    ] {
        let start = Instant::now();
        for bytes in &files {
            std::hint::black_box(sum.of(bytes));
        }
        println!(
            "  checksums, {name}: {:.2} s",
            start.elapsed().as_secs_f64()
        );
    }
    if temporary {
        std::fs::remove_dir_all(&dir)?;
    }
    Ok(())
}
