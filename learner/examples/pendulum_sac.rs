//! Flat SAC sanity check (issue 5): the learner's SAC module ([`SacLevel`]) on the Rust port of
//! Gymnasium's `Pendulum-v1` ([`envs::pendulum::Pendulum`]). Success criterion: a mean return of
//! at least −200 over 10 deterministic evaluation episodes within 20,000 env steps, as
//! Stable-Baselines3's SAC reaches on that task.
//!
//! Hyper-parameters are Stable-Baselines3's SAC defaults with the RL Zoo's `Pendulum-v1` entry
//! (`hyperparams/sac.yml`: `n_timesteps 20000`, `learning_rate 1e-3`, everything else default):
//! γ 0.99, τ 0.005, Adam lr 1e-3, batch 256, 2 × 256 ReLU networks, automatic temperature
//! starting at α = 1 with target entropy −dim(A) = −1, `learning_starts` 100 (uniform random
//! actions before), one update per env step, a replay buffer larger than the run (no overwrite).
//! Only `terminated` stops bootstrapping; the 200-step truncation does not.
//!
//! Run (release):
//! `cargo run --release -p learner --example pendulum_sac -- [--seed N] [--steps N] [--csv PATH]`
//! Prints the learning curve (env steps, mean and std of the evaluation return, wall seconds)
//! and writes it as CSV to `--csv` (default `pendulum_sac_seed<N>.csv`; rewritten after every
//! evaluation). Exit status 0 when an evaluation reaches the criterion, 2 otherwise.
//! Set `RAYON_NUM_THREADS=1` on a shared machine: candle's matmul otherwise spreads over all
//! cores and slows down badly when they are busy.

use std::error::Error;
use std::fmt::Write as _;
use std::time::Instant;

use candle_core::{Device, Tensor};
use envs::pendulum::{Pendulum, PendulumParams, PENDULUM_ACTION_DIM, PENDULUM_OBS_DIM};
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams, SacShape};
use nets::LinearInit;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use rand_pcg::Pcg64Mcg;

type AnyResult<T> = Result<T, Box<dyn Error>>;

/// Evaluation return the run must reach (issue 5).
const TARGET_RETURN: f64 = -200.0;
/// Hidden widths of actor and critics (SB3 default `net_arch` for SAC).
const HIDDEN: [usize; 2] = [256, 256];
/// Minibatch size (SB3 default).
const BATCH: usize = 256;
/// Uniform-random env steps before learning starts (SB3 default `learning_starts`).
const LEARNING_STARTS: usize = 100;
/// Env steps between evaluations.
const EVAL_EVERY: usize = 2_000;
/// Deterministic episodes per evaluation.
const EVAL_EPISODES: u64 = 10;
/// Evaluation episodes use seeds from here on (fixed, apart from training seeds).
const EVAL_SEED_BASE: u64 = 1_000_000;

/// SB3 SAC defaults with the RL Zoo's Pendulum-v1 learning rate.
const PARAMS: SacParams = SacParams {
    gamma: 0.99,
    tau: 0.005,
    lr: 1e-3,
    alpha: 1.0,
    auto_alpha: true,
    target_entropy: -(PENDULUM_ACTION_DIM as f64),
    critic_action_scale: 1.0,
    target_clip: None,
};

/// Command line.
struct Args {
    seed: u64,
    n_env_steps: usize,
    csv: String,
}

fn parse_args() -> AnyResult<Args> {
    let mut seed = 0u64;
    let mut n_env_steps = 20_000usize;
    let mut csv = None;
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let value = args.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--seed" => seed = value.parse().map_err(|e| format!("--seed {value}: {e}"))?,
            "--steps" => {
                n_env_steps = value.parse().map_err(|e| format!("--steps {value}: {e}"))?
            }
            "--csv" => csv = Some(value),
            other => return Err(format!("unknown flag {other}; use --seed, --steps, --csv").into()),
        }
    }
    let csv = csv.unwrap_or_else(|| format!("pendulum_sac_seed{seed}.csv"));
    Ok(Args {
        seed,
        n_env_steps,
        csv,
    })
}

/// Transitions stored as flat rows (no overwrite: the buffer holds the whole run).
#[derive(Default)]
struct Replay {
    obs: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    terminated: Vec<f32>,
}

impl Replay {
    fn push(&mut self, obs: &[f32], action: f32, reward: f32, next_obs: &[f32], terminated: bool) {
        self.obs.extend_from_slice(obs);
        self.action.push(action);
        self.reward.push(reward);
        self.next_obs.extend_from_slice(next_obs);
        self.terminated.push(if terminated { 1.0 } else { 0.0 });
    }

    fn len(&self) -> usize {
        self.reward.len()
    }

    /// A uniform minibatch of `n` rows as a [`SacBatch`].
    fn sample(&self, rng: &mut Pcg64Mcg, n: usize) -> AnyResult<SacBatch> {
        let rows: Vec<usize> = (0..n).map(|_| rng.random_range(0..self.len())).collect();
        let gather = |src: &[f32], width: usize| -> AnyResult<Tensor> {
            let data: Vec<f32> = rows
                .iter()
                .flat_map(|&r| src[r * width..(r + 1) * width].iter().copied())
                .collect();
            Ok(Tensor::from_vec(data, (n, width), &Device::Cpu)?)
        };
        Ok(SacBatch {
            head: gather(&self.obs, PENDULUM_OBS_DIM)?,
            next_head: gather(&self.next_obs, PENDULUM_OBS_DIM)?,
            tail: None,
            action: gather(&self.action, PENDULUM_ACTION_DIM)?,
            reward: gather(&self.reward, 1)?,
            terminal: gather(&self.terminated, 1)?,
        })
    }
}

/// Policy, twin critic and target on two maps, seeded from `seed`.
fn build_level(seed: u64) -> AnyResult<SacLevel> {
    let shape = SacShape {
        policy_in: PENDULUM_OBS_DIM,
        critic_in: PENDULUM_OBS_DIM + PENDULUM_ACTION_DIM,
        hidden: &HIDDEN,
        action_dim: PENDULUM_ACTION_DIM,
        action_scale: PendulumParams::default().max_torque,
        init: LinearInit::XavierUniform,
    };
    let (nets, _, _) = SacNets::seeded(&shape, seed)?;
    Ok(SacLevel::new("pendulum", nets, PARAMS)?)
}

/// `[rows, cols]` of standard-normal noise.
fn noise(rng: &mut Pcg64Mcg, rows: usize, cols: usize) -> AnyResult<Tensor> {
    let data: Vec<f32> = (0..rows * cols)
        .map(|_| StandardNormal.sample(rng))
        .collect();
    Ok(Tensor::from_vec(data, (rows, cols), &Device::Cpu)?)
}

/// The policy's action for one observation: sampled (training) or `scale·tanh(μ)` (evaluation).
fn act(level: &SacLevel, obs: &[f32], rng: Option<&mut Pcg64Mcg>) -> AnyResult<f32> {
    let x = Tensor::from_slice(obs, (1, PENDULUM_OBS_DIM), &Device::Cpu)?;
    let action = match rng {
        Some(rng) => {
            level
                .policy()
                .sample(&x, &noise(rng, 1, PENDULUM_ACTION_DIM)?)?
                .0
        }
        None => level.policy().deterministic(&x)?,
    };
    Ok(action.flatten_all()?.to_vec1::<f32>()?[0])
}

/// Mean and standard deviation of the return of `EVAL_EPISODES` deterministic episodes.
fn evaluate(level: &SacLevel) -> AnyResult<(f64, f64)> {
    let mut env = Pendulum::new(PendulumParams::default())?;
    let mut returns = Vec::new();
    for episode in 0..EVAL_EPISODES {
        let mut obs = env.reset(EVAL_SEED_BASE + episode);
        let mut total = 0.0f64;
        loop {
            let step = env.step(&[act(level, &obs, None)?])?;
            total += f64::from(step.reward);
            obs = step.obs;
            if step.terminated || step.truncated {
                break;
            }
        }
        returns.push(total);
    }
    let n = returns.len() as f64;
    let mean = returns.iter().sum::<f64>() / n;
    let var = returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / n;
    Ok((mean, var.sqrt()))
}

/// One point of the learning curve.
struct CurvePoint {
    env_steps: usize,
    mean_return: f64,
    std_return: f64,
    wall_secs: f64,
}

/// Trains for `args.n_env_steps`, evaluating every `EVAL_EVERY` steps.
fn train(args: &Args) -> AnyResult<Vec<CurvePoint>> {
    let mut rng = Pcg64Mcg::seed_from_u64(args.seed);
    let mut level = build_level(args.seed)?;
    let mut env = Pendulum::new(PendulumParams::default())?;
    let max_torque = env.params().max_torque as f32;
    let mut replay = Replay::default();
    let mut episode = 0u64;
    let mut obs = env.reset(args.seed.wrapping_mul(1_000_003));
    let (start, mut curve) = (Instant::now(), Vec::new());
    for env_step in 1..=args.n_env_steps {
        let action = if replay.len() < LEARNING_STARTS {
            rng.random_range(-max_torque..max_torque)
        } else {
            act(&level, &obs, Some(&mut rng))?
        };
        let step = env.step(&[action])?;
        replay.push(&obs, action, step.reward, &step.obs, step.terminated);
        obs = step.obs;
        if step.terminated || step.truncated {
            episode += 1;
            obs = env.reset(args.seed.wrapping_mul(1_000_003).wrapping_add(episode));
        }
        if replay.len() >= LEARNING_STARTS {
            let batch = replay.sample(&mut rng, BATCH.min(replay.len()))?;
            let rows = batch.reward.dims()[0];
            let next_eps = noise(&mut rng, rows, PENDULUM_ACTION_DIM)?;
            let eps = noise(&mut rng, rows, PENDULUM_ACTION_DIM)?;
            level.update(&batch, &next_eps, &eps)?;
        }
        if env_step % EVAL_EVERY == 0 {
            let (mean_return, std_return) = evaluate(&level)?;
            let wall_secs = start.elapsed().as_secs_f64();
            let alpha = level.alpha()?;
            println!("{env_step:>8} {mean_return:>12.1} {std_return:>10.1} {wall_secs:>10.1} {alpha:>8.4}");
            curve.push(CurvePoint {
                env_steps: env_step,
                mean_return,
                std_return,
                wall_secs,
            });
            // Rewritten after every evaluation, so an interrupted run keeps its curve.
            write_csv(&args.csv, &curve)?;
        }
    }
    Ok(curve)
}

fn write_csv(path: &str, curve: &[CurvePoint]) -> AnyResult<()> {
    let mut text = String::from("env_steps,mean_return,std_return,wall_secs\n");
    for p in curve {
        writeln!(
            text,
            "{},{:.3},{:.3},{:.3}",
            p.env_steps, p.mean_return, p.std_return, p.wall_secs
        )?;
    }
    std::fs::write(path, text).map_err(|e| format!("writing {path}: {e}"))?;
    Ok(())
}

fn main() -> AnyResult<()> {
    let args = parse_args()?;
    println!(
        "pendulum_sac: seed {}, {} env steps, eval {} episodes every {}",
        args.seed, args.n_env_steps, EVAL_EPISODES, EVAL_EVERY
    );
    println!(
        "{:>8} {:>12} {:>10} {:>10} {:>8}",
        "env_step", "mean_return", "std", "wall_s", "alpha"
    );
    let curve = train(&args)?;
    let last = curve.last().map_or(f64::NEG_INFINITY, |p| p.mean_return);
    let best = curve
        .iter()
        .map(|p| p.mean_return)
        .fold(f64::NEG_INFINITY, f64::max);
    // "Reach within 20,000 env steps": any evaluation of the run counts.
    let passed = best >= TARGET_RETURN;
    println!(
        "best mean return {best:.1}, final {last:.1}, target ≥ {TARGET_RETURN}: {}; curve in {}",
        if passed { "PASS" } else { "FAIL" },
        args.csv
    );
    if !passed {
        std::process::exit(2);
    }
    Ok(())
}
