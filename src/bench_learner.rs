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
//!   triplet loss plus 0.001 × the stable loss against a frozen copy, one Adam step (lr 1e-4),
//!   through the learner's own [`learner::phi::phi_objective`] and [`learner::phi::phi_optimizer`]
//!   (which also read back the loss statistics the learner logs; the PyTorch side does not).
//!   Batch sampling from the φ store is not timed. A round is 50,000 steps; `--phi-steps` are
//!   timed and the round time is extrapolated from their median rate (pass `--phi-steps 50000`
//!   to time a whole round).
//!
//! Batches (and the policy noise) are drawn once, 8 of them cycled, so replay sampling is not
//! timed. After `--warmup` untimed calls on each side, the bench alternates: for each of
//! `--blocks` blocks and each workload, one candle block and one PyTorch block (the script runs
//! as a server, `--serve`, and times a block on request), candle first on even blocks and
//! PyTorch first on odd ones. A rate is the median over the blocks; the ratio is the median of
//! the per-block-pair ratios, so load that changes during the run (this is a shared 2-core
//! machine) moves both sides of a pair alike instead of one side of the whole comparison.
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
//! 2 = 64 FLOPs/cycle; Xeon Gold/Platinum class and AMD Zen 5, an assumption: some Intel parts
//! have one port), except AMD Zen 4 (family 25), which runs AVX-512 on two 256-bit FMA pipes;
//! with AVX2 + FMA two 256-bit ports (32 FLOPs/cycle). The AVX2 figure is printed too because candle
//! 0.11's CPU matmul (the `gemm` crate, built without its `x86-v4` feature) uses the AVX2/FMA
//! kernels only.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::Instant;

use anyhow::{bail, ensure, Context};
use candle_core::{DType, Device, Tensor};
use candle_nn::{Optimizer, VarMap};
use learner::phi::{phi_objective, phi_optimizer};
use learner::sac::{SacBatch, SacLevel, SacNets, SacParams, SacShape};
use nets::{seeded_var_builder, Encoder, LinearInit};
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
    /// Whether its FMA pipes are 512 bits wide (AVX-512F and not AMD family 25, Zen 4, whose
    /// AVX-512 instructions run as two 256-bit halves).
    pub fma512: bool,
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
        let zen4 = field("vendor_id").as_deref() == Some("AuthenticAMD")
            && field("cpu family").as_deref() == Some("25");
        Ok(Self {
            model,
            ghz,
            avx512: has("avx512f"),
            fma512: has("avx512f") && !zen4,
            avx2_fma: has("avx2") && has("fma"),
        })
    }

    /// f32 FLOPs per cycle of the widest FMA units (two ports assumed).
    pub fn flops_per_cycle(&self) -> f64 {
        if self.fma512 {
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

/// One timed workload: a call runs one update (or φ step).
type Step = Box<dyn FnMut() -> anyhow::Result<()>>;

/// Calls per second of `calls` calls of `step`.
fn time_calls(step: &mut Step, calls: usize) -> anyhow::Result<f64> {
    let start = Instant::now();
    for _ in 0..calls {
        step()?;
    }
    Ok(calls as f64 / start.elapsed().as_secs_f64())
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
    let sac_shape = SacShape {
        policy_in: shape.policy_in(),
        critic_in: shape.critic_in(),
        hidden: &shape.hidden,
        action_dim: shape.action,
        action_scale: shape.scale(),
        init: LinearInit::XavierUniform,
    };
    let (nets, _, _) = SacNets::seeded(&sac_shape, 0)?;
    let params = SacParams::spec_defaults(shape.action);
    Ok(SacLevel::new(shape.name, nets, params)?)
}

/// One SAC update of `shape` per call, cycling through pre-drawn batches.
fn level_step(args: &BenchLearnerArgs, shape: &LevelShape) -> anyhow::Result<Step> {
    let mut level = build_level(shape)?;
    let mut rng = StdRng::seed_from_u64(0);
    let batches = (0..N_BATCHES)
        .map(|_| random_batch(&mut rng, shape, args.batch))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let name = shape.name;
    let mut i = 0;
    Ok(Box::new(move || {
        let (batch, next_eps, eps) = &batches[i % N_BATCHES];
        i += 1;
        level
            .update(batch, next_eps, eps)
            .with_context(|| format!("{name} update"))?;
        Ok(())
    }))
}

/// One φ step per call, cycling through pre-drawn states.
fn phi_step(args: &BenchLearnerArgs) -> anyhow::Result<Step> {
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
    let mut opt = phi_optimizer(vm.all_vars(), PHI_LR)?;
    let b = args.phi_batch;
    let mut rng = StdRng::seed_from_u64(1);
    let states = (0..N_BATCHES)
        .map(|_| normal(&mut rng, 4 * b, obs_dim))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut i = 0;
    Ok(Box::new(move || {
        let x = &states[i % N_BATCHES];
        i += 1;
        let objective = phi_objective(&phi, x, b, PHI_MARGIN, Some((&phi_old, PHI_STABLE_COEFF)))?;
        opt.backward_step(&objective.loss)?;
        Ok(())
    }))
}

/// The PyTorch script's first line in `--serve` mode.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TorchHello {
    /// `torch.__version__`.
    pub torch: String,
    /// `torch.get_num_threads()`.
    pub threads: usize,
}

/// The script's answer to one timing request.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(untagged)]
pub enum TorchBlock {
    /// Calls per second of the requested workload.
    Timed {
        /// The workload (`low`, `high`, `phi`).
        what: String,
        /// Its rate.
        per_sec: f64,
    },
    /// The script refused the request.
    Refused {
        /// Why.
        error: String,
    },
}

/// Parses one line of the script's output as `T`, naming the line in the error.
pub fn parse_torch_line<T: serde::de::DeserializeOwned>(line: &str) -> anyhow::Result<T> {
    serde_json::from_str(line.trim())
        .with_context(|| format!("parsing the torch script's line `{}`", line.trim()))
}

/// `scripts/bench_learner_torch.py --serve`: the same workloads in PyTorch, timed on request.
struct TorchServer {
    child: Child,
    stdin: ChildStdin,
    stdout: BufReader<ChildStdout>,
    hello: TorchHello,
}

impl TorchServer {
    /// Starts the script (it warms its workloads up before answering); `Ok(None)` with the
    /// reason printed when the venv is absent or `--no-torch` was given.
    fn start(args: &BenchLearnerArgs) -> anyhow::Result<Option<Self>> {
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
        let mut child = Command::new(&args.python)
            .arg(&args.torch_script)
            .arg("--serve")
            .args(torch_flags(args))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {}", args.python.display()))?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            bail!("the torch script's pipes were not opened");
        };
        let mut server = Self {
            child,
            stdin,
            stdout: BufReader::new(stdout),
            hello: TorchHello {
                torch: String::new(),
                threads: 0,
            },
        };
        server.hello = parse_torch_line(&server.read_line()?)?;
        Ok(Some(server))
    }

    fn read_line(&mut self) -> anyhow::Result<String> {
        let mut line = String::new();
        let n = self
            .stdout
            .read_line(&mut line)
            .context("reading the torch script's output")?;
        if n == 0 {
            let status = self.child.wait().context("waiting for the torch script")?;
            bail!("the torch script ended ({status}) before answering; see its stderr above");
        }
        Ok(line)
    }

    /// Calls per second of `calls` calls of workload `what` in PyTorch.
    fn time(&mut self, what: &str, calls: usize) -> anyhow::Result<f64> {
        writeln!(self.stdin, "{what} {calls}").context("writing to the torch script")?;
        self.stdin.flush().context("writing to the torch script")?;
        match parse_torch_line::<TorchBlock>(&self.read_line()?)? {
            TorchBlock::Timed { what: got, per_sec } if got == what => Ok(per_sec),
            TorchBlock::Timed { what: got, .. } => {
                bail!("asked the torch script for `{what}`, it timed `{got}`")
            }
            TorchBlock::Refused { error } => bail!("the torch script refused: {error}"),
        }
    }
}

impl Drop for TorchServer {
    fn drop(&mut self) {
        // Best effort: the script exits on `quit`; if it cannot be told, it is killed.
        if writeln!(self.stdin, "quit")
            .and_then(|()| self.stdin.flush())
            .is_err()
        {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

fn torch_flags(args: &BenchLearnerArgs) -> Vec<String> {
    [
        ("--batch", args.batch),
        ("--phi-batch", args.phi_batch),
        ("--warmup", args.warmup),
        ("--threads", 1),
    ]
    .iter()
    .flat_map(|(flag, value)| [flag.to_string(), value.to_string()])
    .collect()
}

/// One workload's measurements: a rate per block on each side and the per-block ratios.
struct Figure {
    name: &'static str,
    /// The workload's name in the torch script's protocol.
    what: &'static str,
    flops: u64,
    calls_per_block: usize,
    candle: Vec<f64>,
    torch: Vec<f64>,
}

impl Figure {
    /// candle over PyTorch of each block pair (neighbouring blocks, so both saw the same load).
    fn ratios(&self) -> Vec<f64> {
        self.candle
            .iter()
            .zip(&self.torch)
            .map(|(c, t)| c / t)
            .collect()
    }
}

fn print_figure(fig: &Figure, peak: &CorePeak) {
    let gflops = |rate: f64| rate * fig.flops as f64 / 1e9;
    let candle = median(&fig.candle);
    println!("{}_candle_per_sec: {candle:.1}", fig.name);
    println!("{}_flops_per_call: {}", fig.name, fig.flops);
    println!(
        "{}_candle_gflops: {:.2} ({:.1} % of the core's {:.0} GFLOP/s peak, {:.1} % of its AVX2 peak {:.0})",
        fig.name,
        gflops(candle),
        100.0 * gflops(candle) / peak.peak_gflops(),
        peak.peak_gflops(),
        100.0 * gflops(candle) / peak.avx2_peak_gflops(),
        peak.avx2_peak_gflops()
    );
    if fig.torch.is_empty() {
        return;
    }
    let torch = median(&fig.torch);
    println!("{}_torch_per_sec: {torch:.1}", fig.name);
    println!(
        "{}_torch_gflops: {:.2} ({:.1} % of peak)",
        fig.name,
        gflops(torch),
        100.0 * gflops(torch) / peak.peak_gflops()
    );
    let ratios = fig.ratios();
    let (lo, hi) = ratios
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &r| {
            (lo.min(r), hi.max(r))
        });
    println!(
        "{}_ratio_candle_over_torch: {:.3} (median of {} block pairs, range {lo:.3}–{hi:.3})",
        fig.name,
        median(&ratios),
        ratios.len()
    );
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
        match (peak.avx512, peak.fma512) {
            (true, true) => ", AVX-512, two 512-bit FMA ports assumed",
            (true, false) => ", AVX-512 on two 256-bit FMA pipes (AMD Zen 4)",
            _ => "",
        },
        peak.avx2_peak_gflops()
    );
    println!(
        "candle_threads (RAYON_NUM_THREADS): {threads}; dtype: {:?}",
        DType::F32
    );
    let mut steps = [
        level_step(args, &LevelShape::LOW)?,
        level_step(args, &LevelShape::HIGH)?,
        phi_step(args)?,
    ];
    let phi_per_block = (args.phi_steps / args.blocks).max(1);
    let mut figures = [
        (
            "low_update",
            "low",
            update_flops(&LevelShape::LOW, args.batch),
            args.updates_per_block,
        ),
        (
            "high_update",
            "high",
            update_flops(&LevelShape::HIGH, args.batch),
            args.updates_per_block,
        ),
        (
            "phi_step",
            "phi",
            phi_step_flops(args.phi_batch),
            phi_per_block,
        ),
    ]
    .map(|(name, what, flops, calls_per_block)| Figure {
        name,
        what,
        flops,
        calls_per_block,
        candle: Vec::with_capacity(args.blocks),
        torch: Vec::with_capacity(args.blocks),
    });
    for step in &mut steps {
        time_calls(step, args.warmup)?;
    }
    let mut torch = TorchServer::start(args)?;
    if let Some(t) = &torch {
        println!("torch: {} ({} thread)", t.hello.torch, t.hello.threads);
    }
    // Blocks alternate between the two sides, candle first on even blocks and PyTorch first on
    // odd ones, so a load change during the run shifts both sides of a pair alike.
    for block in 0..args.blocks {
        for (fig, step) in figures.iter_mut().zip(&mut steps) {
            let mut side = |candle_side: bool| -> anyhow::Result<()> {
                match (candle_side, torch.as_mut()) {
                    (true, _) => fig.candle.push(time_calls(step, fig.calls_per_block)?),
                    (false, Some(t)) => fig.torch.push(t.time(fig.what, fig.calls_per_block)?),
                    (false, None) => {}
                }
                Ok(())
            };
            side(block % 2 == 0)?;
            side(block % 2 == 1)?;
        }
    }
    drop(torch);
    for fig in &figures {
        print_figure(fig, &peak);
    }
    let round = |rate: f64| PHI_ROUND_STEPS as f64 / rate;
    let phi = &figures[2];
    if !phi.torch.is_empty() {
        println!("phi_round_torch_secs: {:.1}", round(median(&phi.torch)));
    }
    println!("phi_round_candle_secs: {:.1}", round(median(&phi.candle)));
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
        // Zen 4 (family 25) has AVX-512 but 256-bit FMA pipes; Zen 5 (family 26) 512-bit ones.
        let zen = |family: u32| {
            format!(
                "vendor_id\t: AuthenticAMD\ncpu family\t: {family}\nmodel name\t: AMD EPYC\n\
                 cpu MHz\t\t: 2600.000\nflags\t\t: avx2 fma avx512f\n"
            )
        };
        let zen4 = CorePeak::parse(&zen(25)).unwrap();
        assert!(zen4.avx512 && !zen4.fma512);
        assert_eq!(zen4.peak_gflops(), 2.6 * 32.0);
        assert_eq!(CorePeak::parse(&zen(26)).unwrap().peak_gflops(), 2.6 * 64.0);
        assert!(CorePeak::parse("model name\t: mystery\n").is_err());
    }

    #[test]
    fn the_torch_lines_are_parsed_and_a_bad_line_is_an_error() {
        let hello: TorchHello =
            parse_torch_line("{\"torch\": \"2.15.0\", \"threads\": 1}\n").unwrap();
        assert_eq!(hello.threads, 1);
        assert_eq!(hello.torch, "2.15.0");
        let block: TorchBlock = parse_torch_line("{\"what\": \"low\", \"per_sec\": 10.5}").unwrap();
        assert_eq!(
            block,
            TorchBlock::Timed {
                what: "low".into(),
                per_sec: 10.5
            }
        );
        let refused: TorchBlock = parse_torch_line("{\"error\": \"bad request\"}").unwrap();
        assert!(matches!(refused, TorchBlock::Refused { .. }));
        assert!(parse_torch_line::<TorchHello>("").is_err());
        assert!(parse_torch_line::<TorchBlock>("not json").is_err());
        assert!(parse_torch_line::<TorchBlock>("{\"what\": \"low\"}").is_err());
    }

    #[test]
    fn ratios_pair_neighbouring_blocks() {
        let fig = Figure {
            name: "low_update",
            what: "low",
            flops: 1,
            calls_per_block: 1,
            candle: vec![10.0, 30.0, 20.0],
            torch: vec![5.0, 60.0, 20.0],
        };
        assert_eq!(fig.ratios(), vec![2.0, 0.5, 1.0]);
        assert_eq!(median(&fig.ratios()), 1.0);
    }

    #[test]
    fn median_of_odd_and_even_counts() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
    }
}
