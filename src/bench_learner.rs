//! `asi bench learner`: SAC updates per second of both levels and the time of one φ round, in
//! candle (this process, one thread) and in PyTorch on the CPU with one thread
//! (`scripts/bench_learner_torch.py`, run in the same invocation), with their ratio and the
//! FLOP rate achieved against the core's peak (issue 5, "Speed").
//!
//! What is timed (the Python script does exactly the same):
//! - One SAC update ([`learner::sac::SacLevel::update`]) at the paper's shapes (SPEC §5, §6.2):
//!   batch 128, 2 × 256 hidden, α fixed 0.2, Adam lr 3e-4. Low level: policy input
//!   `[obs 29, φ 2, subgoal 2]` = 33, 8 actions (scale 16), critic input 41. High level: policy
//!   input `[obs 29, goal 2]` = 31, 2 actions (scale 10), critic input 33.
//! - One φ step (SPEC §6.3, digest §4): encoder 29 → 100 → 100 → 2 on anchors, positives,
//!   negatives and regularisation states (batch 100 each, one forward of 400 rows), the code's
//!   triplet loss plus 0.001 × the stable loss against a frozen copy, one Adam step (lr 1e-4).
//!   The learner has no φ trainer yet, so the loss is written here ([`phi_loss`]). A round is
//!   50,000 steps; `--phi-steps` are timed and the round time is extrapolated from their median
//!   rate (pass `--phi-steps 50000` to time a whole round).
//!
//! Batches (and the policy noise) are drawn once, 8 of them cycled, so replay sampling is not
//! timed. A figure is the median over `--blocks` timed blocks after `--warmup` untimed calls.
//!
//! FLOPs ([`update_flops`], [`phi_step_flops`]) count the matrix products an update needs, at
//! 2 FLOPs per multiply–add: every forward product; the weight gradient of every layer that is
//! stepped; the input gradient of every layer whose input needs one (not the first layer of a
//! network fed with data, but the critic's first layer in the actor step, which carries
//! ∂L/∂ã). Not counted: biases, elementwise work, Adam, and the critic's weight gradients in the
//! actor step (not needed, though both candle and PyTorch compute them there).
//!
//! Peak ([`CorePeak`]): nominal frequency (from the CPU model name, else `cpu MHz`) × FLOPs per
//! cycle of one core's FMA units: with AVX-512 two 512-bit FMA ports (16 f32 lanes × 2 FLOPs ×
//! 2 = 64 FLOPs/cycle; Xeon Gold/Platinum class, an assumption: some parts have one port), with
//! AVX2 + FMA two 256-bit ports (32 FLOPs/cycle). The AVX2 figure is printed too because candle
//! 0.11's CPU matmul (the `gemm` crate, built without its `x86-v4` feature) uses the AVX2/FMA
//! kernels only.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, ensure, Context};
use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarMap};
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams};
use nets::weights::vars_under;
use nets::{seeded_var_builder, Encoder, GaussianPolicy, LinearInit, TwinCritic};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Batches (and noise) drawn up front and cycled through.
const N_BATCHES: usize = 8;
/// Adam steps in one φ round (SPEC §6.3).
pub const PHI_ROUND_STEPS: u64 = 50_000;
/// Encoder layer widths (SPEC §5): obs 29 → 100 → 100 → 2.
const PHI_DIMS: [usize; 4] = [29, 100, 100, 2];
/// Coefficient of the stable loss in the first rounds (SPEC §6.3).
const PHI_STABLE_COEFF: f64 = 0.001;
/// φ learning rate (SPEC §6.3).
const PHI_LR: f64 = 1e-4;
/// Triplet margin on the per-dimension mean of the squared distance (digest §4).
const PHI_MARGIN: f64 = 1.0;

/// Options of `asi bench learner`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchLearnerArgs {
    /// SAC minibatch size (SPEC §6.2: 128).
    #[arg(long, default_value_t = 128)]
    pub batch: usize,
    /// φ minibatch size (SPEC §6.3: 100).
    #[arg(long, default_value_t = 100)]
    pub phi_batch: usize,
    /// Timed blocks per measurement; the figure is their median.
    #[arg(long, default_value_t = 5)]
    pub blocks: usize,
    /// SAC updates per timed block.
    #[arg(long, default_value_t = 50)]
    pub updates_per_block: usize,
    /// Untimed calls before the first block.
    #[arg(long, default_value_t = 20)]
    pub warmup: usize,
    /// φ steps timed in all (spread over the blocks); the round time is extrapolated to 50,000.
    #[arg(long, default_value_t = 2_000)]
    pub phi_steps: usize,
    /// Skip the PyTorch side.
    #[arg(long)]
    pub no_torch: bool,
    /// Python of the torch venv (made by `scripts/bench_learner_torch_setup.sh`).
    #[arg(long, default_value = ".venv-bench-torch/bin/python")]
    pub python: PathBuf,
    /// The PyTorch bench script.
    #[arg(long, default_value = "scripts/bench_learner_torch.py")]
    pub torch_script: PathBuf,
}

impl Default for BenchLearnerArgs {
    fn default() -> Self {
        Self {
            batch: 128,
            phi_batch: 100,
            blocks: 5,
            updates_per_block: 50,
            warmup: 20,
            phi_steps: 2_000,
            no_torch: false,
            python: PathBuf::from(".venv-bench-torch/bin/python"),
            torch_script: PathBuf::from("scripts/bench_learner_torch.py"),
        }
    }
}

/// The shapes of one SAC level. Policy input `[head, tail]`, critic input `[head, action, tail]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LevelShape {
    /// Level name in the report.
    pub name: &'static str,
    /// Features before the action in the critic input.
    pub head: usize,
    /// Features after the action (the low level's subgoal); 0 for none.
    pub tail: usize,
    /// Action size.
    pub action: usize,
    /// Hidden widths of policy trunk and each Q network.
    pub hidden: [usize; 2],
}

impl LevelShape {
    /// Low level (SPEC §5): head `[obs 29, φ 2]`, tail subgoal 2, 8 torques.
    pub const LOW: Self = Self {
        name: "low",
        head: 31,
        tail: 2,
        action: 8,
        hidden: [256, 256],
    };
    /// High level (SPEC §5): head `[obs 29, goal 2]`, no tail, a 2-D delta.
    pub const HIGH: Self = Self {
        name: "high",
        head: 31,
        tail: 0,
        action: 2,
        hidden: [256, 256],
    };

    fn policy_in(&self) -> usize {
        self.head + self.tail
    }

    fn critic_in(&self) -> usize {
        self.head + self.action + self.tail
    }

    /// Action bound used by the bench (SPEC §5: low 16 N·m, high 10 φ units).
    fn scale(&self) -> f64 {
        if self.tail > 0 {
            16.0
        } else {
            10.0
        }
    }
}

/// Multiply–adds per row of the dense layers `(in, out)`.
fn macs(layers: &[(usize, usize)]) -> u64 {
    layers.iter().map(|&(i, o)| (i * o) as u64).sum()
}

/// Multiply–adds per row of the input gradients: every layer but the first, unless
/// `first_needs_grad`.
fn input_grad_macs(layers: &[(usize, usize)], first_needs_grad: bool) -> u64 {
    let skip = usize::from(!first_needs_grad);
    macs(&layers[skip.min(layers.len())..])
}

/// Matmul FLOPs of one SAC update of `shape` at `batch` (convention in the module doc).
pub fn update_flops(shape: &LevelShape, batch: usize) -> u64 {
    let [h0, h1] = shape.hidden;
    // Policy: trunk, then the mean and log-std heads (both read the trunk's output; their input
    // gradients are summed there, so the two heads count as one h1 → 2·action layer).
    let policy = [(shape.policy_in(), h0), (h0, h1), (h1, 2 * shape.action)];
    let q_net = [(shape.critic_in(), h0), (h0, h1), (h1, 1)];
    let (p_fwd, q_fwd) = (macs(&policy), macs(&q_net));
    let target = p_fwd + 2 * q_fwd;
    let critic_step = 2 * (q_fwd + q_fwd + input_grad_macs(&q_net, false));
    let actor_step = p_fwd
        + p_fwd
        + input_grad_macs(&policy, false)
        + 2 * (q_fwd + input_grad_macs(&q_net, true));
    2 * batch as u64 * (target + critic_step + actor_step)
}

/// Matmul FLOPs of one φ step: forward and backward of the encoder on `4 · batch` rows
/// (anchors, positives, negatives, regularisation states) and the frozen copy's forward on
/// `batch` rows.
pub fn phi_step_flops(batch: usize) -> u64 {
    let layers: Vec<(usize, usize)> = PHI_DIMS.windows(2).map(|w| (w[0], w[1])).collect();
    let fwd = macs(&layers);
    let online = 4 * batch as u64 * (fwd + fwd + input_grad_macs(&layers, false));
    let frozen = batch as u64 * fwd;
    2 * (online + frozen)
}

/// One core's peak f32 FLOP rate, estimated from `/proc/cpuinfo`.
#[derive(Debug, Clone, PartialEq)]
pub struct CorePeak {
    /// `model name`.
    pub model: String,
    /// Nominal clock, GHz.
    pub ghz: f64,
    /// Whether the core has AVX-512F.
    pub avx512: bool,
    /// Whether it has AVX2 and FMA.
    pub avx2_fma: bool,
}

impl CorePeak {
    /// Parses the first processor block of a `/proc/cpuinfo` text.
    pub fn parse(cpuinfo: &str) -> anyhow::Result<Self> {
        let field = |key: &str| {
            cpuinfo.lines().find_map(|line| {
                let (k, v) = line.split_once(':')?;
                (k.trim() == key).then(|| v.trim().to_owned())
            })
        };
        let model = field("model name").unwrap_or_else(|| "unknown CPU".to_owned());
        let flags = field("flags").unwrap_or_default();
        let has = |f: &str| flags.split_whitespace().any(|x| x == f);
        let ghz = match nominal_ghz(&model) {
            Some(ghz) => ghz,
            None => {
                let mhz = field("cpu MHz").context("/proc/cpuinfo has no clock figure")?;
                mhz.parse::<f64>()
                    .with_context(|| format!("cpu MHz `{mhz}`"))?
                    / 1000.0
            }
        };
        Ok(Self {
            model,
            ghz,
            avx512: has("avx512f"),
            avx2_fma: has("avx2") && has("fma"),
        })
    }

    /// f32 FLOPs per cycle of the widest FMA units (two ports assumed).
    pub fn flops_per_cycle(&self) -> f64 {
        if self.avx512 {
            64.0
        } else {
            self.avx2_flops_per_cycle()
        }
    }

    /// f32 FLOPs per cycle with AVX2 + FMA (two 256-bit ports), or SSE (4 lanes, mul + add).
    pub fn avx2_flops_per_cycle(&self) -> f64 {
        if self.avx2_fma {
            32.0
        } else {
            8.0
        }
    }

    /// Peak GFLOP/s of one core.
    pub fn peak_gflops(&self) -> f64 {
        self.ghz * self.flops_per_cycle()
    }

    /// Peak GFLOP/s of one core with AVX2 + FMA only.
    pub fn avx2_peak_gflops(&self) -> f64 {
        self.ghz * self.avx2_flops_per_cycle()
    }
}

/// The `@ 2.50GHz` part of an Intel model name.
fn nominal_ghz(model: &str) -> Option<f64> {
    let at = model.rsplit_once('@')?.1.trim();
    at.strip_suffix("GHz")?.trim().parse().ok()
}

/// Median of `values` (the mean of the two middle ones for an even count).
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Calls per second of `step` in each of `blocks` blocks of `per_block` calls, after `warmup`.
fn time_blocks(
    warmup: usize,
    blocks: usize,
    per_block: usize,
    mut step: impl FnMut() -> anyhow::Result<()>,
) -> anyhow::Result<Vec<f64>> {
    for _ in 0..warmup {
        step()?;
    }
    let mut rates = Vec::with_capacity(blocks);
    for _ in 0..blocks {
        let start = Instant::now();
        for _ in 0..per_block {
            step()?;
        }
        rates.push(per_block as f64 / start.elapsed().as_secs_f64());
    }
    Ok(rates)
}

/// `[rows, cols]` uniform in `[lo, hi)`.
fn uniform(rng: &mut StdRng, rows: usize, cols: usize, lo: f32, hi: f32) -> anyhow::Result<Tensor> {
    let data: Vec<f32> = (0..rows * cols).map(|_| rng.random_range(lo..hi)).collect();
    Ok(Tensor::from_vec(data, (rows, cols), &Device::Cpu)?)
}

/// `[rows, cols]` standard normal (Box–Muller).
fn normal(rng: &mut StdRng, rows: usize, cols: usize) -> anyhow::Result<Tensor> {
    let data: Vec<f32> = (0..rows * cols)
        .map(|_| {
            let u1: f64 = 1.0 - rng.random::<f64>();
            let u2: f64 = rng.random();
            ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
        })
        .collect();
    Ok(Tensor::from_vec(data, (rows, cols), &Device::Cpu)?)
}

/// A random minibatch of `shape` with its two noise tensors.
fn random_batch(
    rng: &mut StdRng,
    shape: &LevelShape,
    batch: usize,
) -> anyhow::Result<(SacBatch, Tensor, Tensor)> {
    let scale = shape.scale() as f32;
    let terminal: Vec<f32> = (0..batch)
        .map(|_| if rng.random::<f64>() < 0.05 { 1.0 } else { 0.0 })
        .collect();
    let sac_batch = SacBatch {
        head: normal(rng, batch, shape.head)?,
        next_head: normal(rng, batch, shape.head)?,
        tail: match shape.tail {
            0 => None,
            t => Some(normal(rng, batch, t)?),
        },
        action: uniform(rng, batch, shape.action, -scale, scale)?,
        reward: uniform(rng, batch, 1, -1.0, 0.0)?,
        terminal: Tensor::from_vec(terminal, (batch, 1), &Device::Cpu)?,
    };
    let next_eps = normal(rng, batch, shape.action)?;
    let eps = normal(rng, batch, shape.action)?;
    Ok((sac_batch, next_eps, eps))
}

/// A SAC level of `shape` (α fixed 0.2, lr 3e-4, γ 0.99, τ 0.005: SPEC §6.2).
fn build_level(shape: &LevelShape) -> anyhow::Result<SacLevel> {
    let device = Device::Cpu;
    let (vm, tvm) = (VarMap::new(), VarMap::new());
    let vb = seeded_var_builder(&vm, 0, &device);
    let init = LinearInit::XavierUniform;
    let policy = GaussianPolicy::new(
        &vb.pp("policy"),
        shape.policy_in(),
        &shape.hidden,
        shape.action,
        shape.scale(),
        init,
    )?;
    let critic = TwinCritic::new(&vb.pp("critic"), shape.critic_in(), &shape.hidden, init)?;
    let tvb = seeded_var_builder(&tvm, 1, &device);
    let target = TwinCritic::new(&tvb.pp("critic"), shape.critic_in(), &shape.hidden, init)?;
    let nets = SacNets {
        policy,
        policy_vars: vars_under(&vm, "policy"),
        critic,
        critic_vars: vars_under(&vm, "critic"),
        target,
        target_vars: vars_under(&tvm, "critic"),
    };
    let params = SacParams {
        gamma: 0.99,
        tau: 0.005,
        lr: 3e-4,
        alpha: 0.2,
        auto_alpha: false,
        target_entropy: -(shape.action as f64),
    };
    Ok(SacLevel::new(shape.name, nets, params)?)
}

/// Updates per second of `shape`, one rate per block.
fn bench_level(args: &BenchLearnerArgs, shape: &LevelShape) -> anyhow::Result<Vec<f64>> {
    let mut level = build_level(shape)?;
    let mut rng = StdRng::seed_from_u64(0);
    let batches = (0..N_BATCHES)
        .map(|_| random_batch(&mut rng, shape, args.batch))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut i = 0;
    time_blocks(args.warmup, args.blocks, args.updates_per_block, || {
        let (batch, next_eps, eps) = &batches[i % N_BATCHES];
        i += 1;
        level
            .update(batch, next_eps, eps)
            .with_context(|| format!("{} update", shape.name))?;
        Ok(())
    })
}

/// The φ loss of HESS's code (digest §4): with `z = φ([anchor; positive; negative; reg])` in
/// four blocks of `batch` rows and `z_old = φ_old(reg)`,
/// `mean(mean_d (za − zp)² + relu(1 − mean_d (za − zn)²)) + coeff · mean (zr − z_old)²`.
pub fn phi_loss(z: &Tensor, z_old: &Tensor, batch: usize, coeff: f64) -> anyhow::Result<Tensor> {
    ensure!(
        z.dims().len() == 2 && z.dims()[0] == 4 * batch,
        "phi_loss: z must be [4·{batch}, d], got {:?}",
        z.dims()
    );
    ensure!(
        z_old.dims() == [batch, z.dims()[1]],
        "phi_loss: z_old must be [{batch}, {}], got {:?}",
        z.dims()[1],
        z_old.dims()
    );
    let block = |k: usize| z.narrow(0, k * batch, batch);
    let (za, zp, zn, zr) = (block(0)?, block(1)?, block(2)?, block(3)?);
    let pos = za.sub(&zp)?.sqr()?.mean(1)?;
    let neg = za
        .sub(&zn)?
        .sqr()?
        .mean(1)?
        .affine(-1.0, PHI_MARGIN)?
        .relu()?;
    let triplet = pos.add(&neg)?.mean_all()?;
    let stable = zr.sub(&z_old.detach())?.sqr()?.mean_all()?;
    Ok(triplet.add(&stable.affine(coeff, 0.0)?)?)
}

/// φ steps per second, one rate per block.
fn bench_phi(args: &BenchLearnerArgs) -> anyhow::Result<Vec<f64>> {
    let device = Device::Cpu;
    let (vm, old_vm) = (VarMap::new(), VarMap::new());
    let (obs_dim, hidden, latent) = (PHI_DIMS[0], [PHI_DIMS[1], PHI_DIMS[2]], PHI_DIMS[3]);
    let phi = Encoder::new(
        &seeded_var_builder(&vm, 2, &device),
        obs_dim,
        &hidden,
        latent,
    )?;
    let phi_old = Encoder::new(
        &seeded_var_builder(&old_vm, 3, &device),
        obs_dim,
        &hidden,
        latent,
    )?;
    let params = ParamsAdamW {
        lr: PHI_LR,
        weight_decay: 0.0,
        ..ParamsAdamW::default()
    };
    let mut opt = AdamW::new(vm.all_vars(), params)?;
    let b = args.phi_batch;
    let mut rng = StdRng::seed_from_u64(1);
    let states = (0..N_BATCHES)
        .map(|_| normal(&mut rng, 4 * b, obs_dim))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut i = 0;
    let per_block = (args.phi_steps / args.blocks).max(1);
    time_blocks(args.warmup, args.blocks, per_block, || {
        let x = &states[i % N_BATCHES];
        i += 1;
        let z = phi.forward(x)?;
        let z_old = phi_old.forward(&x.narrow(0, 3 * b, b)?)?;
        let loss = phi_loss(&z, &z_old, b, PHI_STABLE_COEFF)?;
        opt.backward_step(&loss)?;
        Ok(())
    })
}

/// What the PyTorch script reported.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TorchReport {
    /// `torch.__version__`.
    pub torch: String,
    /// `torch.get_num_threads()`.
    pub threads: usize,
    /// Median low-level updates/s.
    pub low_updates_per_sec: f64,
    /// Median high-level updates/s.
    pub high_updates_per_sec: f64,
    /// Median φ steps/s.
    pub phi_steps_per_sec: f64,
}

/// Runs the PyTorch script with the same sizes; `Ok(None)` (with the reason printed) when the
/// venv is absent.
fn run_torch(args: &BenchLearnerArgs) -> anyhow::Result<Option<TorchReport>> {
    if args.no_torch {
        println!("torch: skipped (--no-torch)");
        return Ok(None);
    }
    if !args.python.exists() {
        println!(
            "torch: skipped: {} not found; create it with scripts/bench_learner_torch_setup.sh",
            args.python.display()
        );
        return Ok(None);
    }
    let output = Command::new(&args.python)
        .arg(&args.torch_script)
        .args(torch_flags(args))
        .output()
        .with_context(|| format!("running {}", args.python.display()))?;
    if !output.status.success() {
        bail!(
            "{} {} failed ({}): {}",
            args.python.display(),
            args.torch_script.display(),
            output.status,
            String::from_utf8_lossy(&output.stderr)
        );
    }
    parse_torch_output(&String::from_utf8_lossy(&output.stdout)).map(Some)
}

fn torch_flags(args: &BenchLearnerArgs) -> Vec<String> {
    [
        ("--batch", args.batch),
        ("--phi-batch", args.phi_batch),
        ("--blocks", args.blocks),
        ("--updates-per-block", args.updates_per_block),
        ("--warmup", args.warmup),
        ("--phi-steps", args.phi_steps),
        ("--threads", 1),
    ]
    .iter()
    .flat_map(|(flag, value)| [flag.to_string(), value.to_string()])
    .collect()
}

/// The JSON object on the last non-empty line of the script's stdout.
pub fn parse_torch_output(stdout: &str) -> anyhow::Result<TorchReport> {
    let line = stdout
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .context("the torch script printed nothing")?;
    serde_json::from_str(line).with_context(|| format!("parsing the torch script's line `{line}`"))
}

/// One measured rate with its FLOPs per call.
struct Figure {
    name: String,
    per_sec: f64,
    flops: u64,
}

impl Figure {
    fn gflops(&self) -> f64 {
        self.per_sec * self.flops as f64 / 1e9
    }
}

fn print_figure(fig: &Figure, peak: &CorePeak, torch: Option<f64>) {
    let gflops = fig.gflops();
    println!("{}_candle_per_sec: {:.1}", fig.name, fig.per_sec);
    println!("{}_flops_per_call: {}", fig.name, fig.flops);
    println!(
        "{}_candle_gflops: {:.2} ({:.1} % of the core's {:.0} GFLOP/s peak, {:.1} % of its AVX2 peak {:.0})",
        fig.name,
        gflops,
        100.0 * gflops / peak.peak_gflops(),
        peak.peak_gflops(),
        100.0 * gflops / peak.avx2_peak_gflops(),
        peak.avx2_peak_gflops()
    );
    if let Some(torch) = torch {
        let torch_gflops = torch * fig.flops as f64 / 1e9;
        println!("{}_torch_per_sec: {torch:.1}", fig.name);
        println!(
            "{}_torch_gflops: {torch_gflops:.2} ({:.1} % of peak)",
            fig.name,
            100.0 * torch_gflops / peak.peak_gflops()
        );
        println!(
            "{}_ratio_candle_over_torch: {:.3}",
            fig.name,
            fig.per_sec / torch
        );
    }
}

fn check_args(args: &BenchLearnerArgs) -> anyhow::Result<()> {
    let positive = [
        ("--batch", args.batch),
        ("--phi-batch", args.phi_batch),
        ("--blocks", args.blocks),
        ("--updates-per-block", args.updates_per_block),
        ("--phi-steps", args.phi_steps),
    ];
    let bad: Vec<&str> = positive
        .iter()
        .filter(|(_, v)| *v == 0)
        .map(|(n, _)| *n)
        .collect();
    ensure!(bad.is_empty(), "{} must be positive", bad.join(", "));
    Ok(())
}

/// Runs the whole bench and prints the report as `name: value` lines.
pub fn run(args: &BenchLearnerArgs) -> anyhow::Result<()> {
    check_args(args)?;
    let cpuinfo = std::fs::read_to_string(Path::new("/proc/cpuinfo")).unwrap_or_default();
    let peak = CorePeak::parse(&cpuinfo)?;
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".to_owned());
    println!("cpu: {} ({:.2} GHz nominal)", peak.model, peak.ghz);
    println!(
        "core_peak_gflops: {:.0} ({} FLOPs/cycle{}); avx2_peak_gflops: {:.0}",
        peak.peak_gflops(),
        peak.flops_per_cycle(),
        if peak.avx512 {
            ", AVX-512, two FMA ports assumed"
        } else {
            ""
        },
        peak.avx2_peak_gflops()
    );
    println!(
        "candle_threads (RAYON_NUM_THREADS): {threads}; dtype: {:?}",
        DType::F32
    );
    let low = bench_level(args, &LevelShape::LOW)?;
    let high = bench_level(args, &LevelShape::HIGH)?;
    let phi = bench_phi(args)?;
    let torch = run_torch(args)?;
    if let Some(t) = &torch {
        println!("torch: {} ({} thread)", t.torch, t.threads);
    }
    let figures = [
        (
            "low_update",
            median(&low),
            update_flops(&LevelShape::LOW, args.batch),
        ),
        (
            "high_update",
            median(&high),
            update_flops(&LevelShape::HIGH, args.batch),
        ),
        ("phi_step", median(&phi), phi_step_flops(args.phi_batch)),
    ];
    let torch_rates = torch.as_ref().map(|t| {
        [
            t.low_updates_per_sec,
            t.high_updates_per_sec,
            t.phi_steps_per_sec,
        ]
    });
    for (k, (name, per_sec, flops)) in figures.iter().enumerate() {
        let fig = Figure {
            name: (*name).to_owned(),
            per_sec: *per_sec,
            flops: *flops,
        };
        print_figure(&fig, &peak, torch_rates.map(|t| t[k]));
    }
    let round = |rate: f64| PHI_ROUND_STEPS as f64 / rate;
    if let Some(t) = torch_rates {
        println!("phi_round_torch_secs: {:.1}", round(t[2]));
    }
    println!("phi_round_candle_secs: {:.1}", round(figures[2].1));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_flops_match_a_hand_count_at_the_low_level_shape() {
        // Per row, multiply–adds. Policy 33→256→256→(8+8): 8448 + 65536 + 4096 = 78080.
        // One Q net 41→256→256→1: 10496 + 65536 + 256 = 76288.
        // Target: 78080 + 2·76288 = 230656.
        // Critic step: 2·(76288 fwd + 76288 dW + (65536 + 256) dX) = 436736.
        // Actor step: policy 78080 fwd + 78080 dW + (65536 + 4096) dX = 225792;
        //             critics 2·(76288 fwd + 76288 dX incl. the first layer) = 305152.
        // Sum 1198336 MACs per row; × 2 FLOPs × batch 128 = 306774016.
        assert_eq!(update_flops(&LevelShape::LOW, 128), 306_774_016);
    }

    #[test]
    fn update_flops_match_a_hand_count_on_a_tiny_network() {
        // head 1, no tail, action 1, hidden [2, 3], batch 1.
        // Policy (1,2),(2,3),(3,2): fwd 2+6+6 = 14, dX (no first) 12.
        // Q (2,2),(2,3),(3,1): fwd 4+6+3 = 13, dX without first 9, with first 13.
        // target 14 + 26 = 40; critic 2·(13+13+9) = 70; actor 14+14+12 + 2·(13+13) = 92.
        // (40 + 70 + 92) · 2 = 404.
        let tiny = LevelShape {
            name: "tiny",
            head: 1,
            tail: 0,
            action: 1,
            hidden: [2, 3],
        };
        assert_eq!(update_flops(&tiny, 1), 404);
        assert_eq!(update_flops(&tiny, 10), 4040);
    }

    #[test]
    fn phi_step_flops_match_a_hand_count() {
        // Encoder 29→100→100→2: 2900 + 10000 + 200 = 13100 MACs per row; dX skips the first
        // layer: 10200. Online: 400 rows · (13100 + 13100 + 10200) = 14560000; frozen copy:
        // 100 · 13100 = 1310000. × 2 = 31740000.
        assert_eq!(phi_step_flops(100), 31_740_000);
    }

    #[test]
    fn the_core_peak_comes_from_the_model_clock_and_the_vector_flags() {
        let text = "processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Processor @ 2.50GHz\n\
                    cpu MHz\t\t: 2499.998\nflags\t\t: fpu sse avx2 fma avx512f\n";
        let peak = CorePeak::parse(text).unwrap();
        assert_eq!(peak.ghz, 2.5);
        assert_eq!(peak.peak_gflops(), 160.0);
        assert_eq!(peak.avx2_peak_gflops(), 80.0);
        let amd = "model name\t: AMD EPYC 7B13\ncpu MHz\t\t: 3000.000\nflags\t\t: avx2 fma\n";
        let peak = CorePeak::parse(amd).unwrap();
        assert_eq!((peak.ghz, peak.peak_gflops()), (3.0, 96.0));
        assert!(CorePeak::parse("model name\t: mystery\n").is_err());
    }

    #[test]
    fn phi_loss_matches_a_hand_computed_value() {
        // batch 1, d 2: za (0,0), zp (1,1) → mean_d 1; zn (0.5,0.5) → mean_d 0.25 → relu(0.75);
        // zr (2,0), z_old (0,0) → mean 2. Loss = 1 + 0.75 + 0.1 · 2 = 1.95.
        let z = Tensor::from_slice(&[0f32, 0., 1., 1., 0.5, 0.5, 2., 0.], (4, 2), &Device::Cpu)
            .unwrap();
        let z_old = Tensor::zeros((1, 2), DType::F32, &Device::Cpu).unwrap();
        let loss = phi_loss(&z, &z_old, 1, 0.1)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!((loss - 1.95).abs() < 1e-6, "{loss}");
        assert!(phi_loss(&z, &z_old, 2, 0.1).is_err());
    }

    #[test]
    fn the_torch_line_is_parsed_and_a_bad_line_is_an_error() {
        let out = "warning\n{\"torch\": \"2.15.0\", \"threads\": 1, \"low_updates_per_sec\": 10.5, \
                   \"high_updates_per_sec\": 12.0, \"phi_steps_per_sec\": 70.0, \"low_block_rates\": []}\n";
        let report = parse_torch_output(out).unwrap();
        assert_eq!(report.low_updates_per_sec, 10.5);
        assert_eq!(report.threads, 1);
        assert!(parse_torch_output("").is_err());
        assert!(parse_torch_output("not json\n").is_err());
    }

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
