//! Checkpoint cost with 1 M steps in the low replay buffer: write time, size, restore time.
//!
//! The default config (AntMaze: c = 20, `replay.capacity_steps` = 8 M) with the ant's sizes
//! (obs 29, goal 2, action 8); 2,000 synthetic episodes of 500 steps are ingested through the
//! real chunk path, so the low buffer holds 1 M transitions, the high buffer 50 k and the φ
//! store 1.002 M states (only stored rows are written, so the capacity does not matter). No
//! update runs (the networks' size does not depend on it). Also times the file checksums over
//! the written files, CRC-64 (formats 2 and 3) and the word-wise FNV-1a of format 1.
//! Run: `cargo run --release -p learner --example bench_checkpoint [-- DIR]` (default: a folder
//! in the system temp dir, removed at the end; give DIR to measure another disk).
//!
//! With `-- --resave RUN_DIR` it measures a real run's newest learner checkpoint instead:
//! restores it (with the run's `config.resolved.toml` and the task's sizes), writes it again in
//! this build's format into a temp folder (removed at the end), and lists each file's size in
//! both, e.g. to see what a format change saves on a checkpoint of an older build.

use std::time::Instant;

use learner::{Learner, TaskDims};
use protocol::{
    ActorId, Config, DecisionKind, EpisodeId, PolicyVersion, StepLayout, StepRecord,
    TrajectoryFlags, TrajectoryHeader,
};

const EPISODES: u64 = 2_000;
const EPISODE_LENGTH: usize = 500;
const CHUNK: usize = 100;

/// Step `t` of episode `ep`; as in a real episode, its next observation (and φ) is step
/// `t + 1`'s observation.
fn record(t: usize, ep: u64, latent: usize, c: usize) -> StepRecord {
    let state = |t: usize| (t as f32 * 0.01).sin() + ep as f32 * 1e-3;
    let (x, next) = (state(t), state(t + 1));
    StepRecord {
        obs: vec![x; 29],
        next_obs: vec![next; 29],
        phi: vec![x; latent],
        next_phi: vec![next; latent],
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

type AnyError = Box<dyn std::error::Error>;

fn main() -> Result<(), AnyError> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [flag, run_dir] if flag == "--resave" => resave(std::path::Path::new(run_dir)),
        [flag, ..] if flag == "--resave" => Err("usage: bench_checkpoint --resave RUN_DIR".into()),
        _ => synthetic(args.first().map(std::path::PathBuf::from)),
    }
}

/// A folder in the system temp dir for one bench's checkpoint.
fn temp_dir() -> std::path::PathBuf {
    std::env::temp_dir().join(format!("asi-bench-checkpoint-{}", std::process::id()))
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1 << 20)
}

/// Restores the newest learner checkpoint of `run_dir` and writes it again in this build's
/// format: times and sizes, file by file beside the original's.
fn resave(run_dir: &std::path::Path) -> Result<(), AnyError> {
    let config_path = run_dir.join("config.resolved.toml");
    let text = std::fs::read_to_string(&config_path)
        .map_err(|e| format!("reading {}: {e}", config_path.display()))?;
    let config = Config::from_toml_str(&text, &config_path.display().to_string())?;
    let options = envs::EnvOptions {
        max_steps: config.env.episode_length,
    };
    let env = envs::make_with(&config.env.task, options)?;
    let spec = env.spec();
    let dims = learner::setup::task_dims(spec);
    let checkpoints = run_dir.join("checkpoints");
    let start = Instant::now();
    let (learner, original) = Learner::restore_latest(&config, dims, &checkpoints)?
        .ok_or_else(|| format!("no learner checkpoint in {}", checkpoints.display()))?;
    println!(
        "restore of {} (format {}): {:.2} s, {:.0} MiB ({} low transitions)",
        original.path.display(),
        original.manifest.format_version,
        start.elapsed().as_secs_f64(),
        mib(original.manifest.total_bytes()),
        learner.low_replay().ring().len()
    );
    let dir = temp_dir();
    let start = Instant::now();
    let again = learner.save_checkpoint(&config, &dir)?;
    println!(
        "written again (format {}): {:.2} s, {:.0} MiB",
        again.manifest.format_version,
        start.elapsed().as_secs_f64(),
        mib(again.manifest.total_bytes())
    );
    println!("  {:<24} {:>10} {:>10}", "file", "original", "again");
    for file in &again.manifest.files {
        let before = original
            .manifest
            .files
            .iter()
            .find(|f| f.name == file.name)
            .map_or(0, |f| f.bytes);
        println!(
            "  {:<24} {:>6.1} MiB {:>6.1} MiB",
            file.name,
            mib(before),
            mib(file.bytes)
        );
    }
    drop(learner);
    let start = Instant::now();
    let (restored, _) = Learner::restore_checkpoint(&config, dims, &again.path)?;
    println!(
        "restore of the new one: {:.2} s",
        start.elapsed().as_secs_f64()
    );
    // The new checkpoint holds the same state: restored and written once more, every file is
    // the same, byte for byte (the checksums in the manifests).
    let third = restored.save_checkpoint(&config, &dir)?;
    let same = third.manifest.files == again.manifest.files;
    println!("restored and written a third time, every file the same: {same}");
    std::fs::remove_dir_all(&dir)?;
    if !same {
        return Err("the rewritten checkpoint does not restore to the same state".into());
    }
    Ok(())
}

/// 2,000 synthetic episodes (see the module doc); the checkpoint goes to `out` or a temp dir.
fn synthetic(out: Option<std::path::PathBuf>) -> Result<(), AnyError> {
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

    let (dir, temporary) = match out {
        Some(dir) => (dir, false),
        None => (temp_dir(), true),
    };
    let start = Instant::now();
    let ckpt = learner.save_checkpoint(&config, &dir)?;
    let write_secs = start.elapsed().as_secs_f64();
    let size = mib(ckpt.manifest.total_bytes());
    println!(
        "write: {write_secs:.2} s, {size:.0} MiB ({:.0} MiB/s) in {}",
        size / write_secs,
        ckpt.path.display()
    );
    for file in &ckpt.manifest.files {
        println!("  {:<24} {:>8.1} MiB", file.name, mib(file.bytes));
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
        ("CRC-64 (formats 2, 3)", ckpt::Checksum::Crc64),
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
