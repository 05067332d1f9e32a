//! Quick bench (no criterion): forward + backward of a 2 × 256 MLP at batch 128, with
//! `nets::Linear` (bias as a `1 · bᵀ` matmul) against `candle_nn::Linear` (bias by
//! `broadcast_add`), both holding the same weights; plus `TwinCritic` (two MLPs) against the
//! stacked `EnsembleMlp` (one batched network). Prints the median time per iteration over
//! alternating rounds, and the ratios.
//!
//! Run single-threaded, in release:
//! `RAYON_NUM_THREADS=1 cargo run --release -p nets --example bench_forward`

use std::time::Instant;

use candle_core::{DType, Device, Tensor};
use candle_nn::{Module, VarBuilder, VarMap};
use nets::{EnsembleMlp, LinearInit, Mlp, TwinCritic};

const BATCH: usize = 128;
const IN_DIM: usize = 33;
const HIDDEN: [usize; 2] = [256, 256];
const OUT_DIM: usize = 8;
const WARMUP: usize = 50;
const ITERS: usize = 300;
const ROUNDS: usize = 9;

/// The same MLP as `nets::Mlp`, built from `candle_nn::Linear` layers.
struct CandleMlp {
    layers: Vec<candle_nn::Linear>,
}

impl CandleMlp {
    /// Wraps the weights of `mlp` (shared tensors, so the two compute the same function).
    fn from_nets(mlp: &Mlp) -> Self {
        let layers = mlp
            .layers()
            .iter()
            .map(|l| candle_nn::Linear::new(l.weight().clone(), Some(l.bias().clone())))
            .collect();
        Self { layers }
    }

    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let last = self.layers.len() - 1;
        let mut h = x.clone();
        for (i, layer) in self.layers.iter().enumerate() {
            h = layer.forward(&h)?;
            if i < last {
                h = h.relu()?;
            }
        }
        Ok(h)
    }
}

/// A boxed error, so the example needs no extra dependency.
type BenchResult<T> = Result<T, Box<dyn std::error::Error>>;

/// Mean microseconds per call of `step` over `ITERS` calls.
fn round_us(step: &mut impl FnMut() -> BenchResult<()>) -> BenchResult<f64> {
    let start = Instant::now();
    for _ in 0..ITERS {
        step()?;
    }
    Ok(start.elapsed().as_secs_f64() * 1e6 / ITERS as f64)
}

/// Median µs per call of `a` and of `b` over `ROUNDS` rounds. The rounds alternate between the
/// two, so a change in machine load (teammates compiling) affects both alike.
fn compare_us(
    mut a: impl FnMut() -> BenchResult<()>,
    mut b: impl FnMut() -> BenchResult<()>,
) -> BenchResult<(f64, f64)> {
    for _ in 0..WARMUP {
        a()?;
        b()?;
    }
    let (mut ta, mut tb) = (Vec::with_capacity(ROUNDS), Vec::with_capacity(ROUNDS));
    for _ in 0..ROUNDS {
        ta.push(round_us(&mut a)?);
        tb.push(round_us(&mut b)?);
    }
    Ok((median(ta), median(tb)))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Forward, squared-output loss, backward.
fn train_step(y: candle_core::Result<Tensor>) -> BenchResult<()> {
    let grads = y?.sqr()?.mean_all()?.backward()?;
    std::hint::black_box(grads);
    Ok(())
}

fn main() -> BenchResult<()> {
    let dev = Device::Cpu;
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into());
    println!("batch {BATCH}, MLP {IN_DIM} → {HIDDEN:?} → {OUT_DIM}, RAYON_NUM_THREADS={threads}");
    let x = Tensor::rand(-1f32, 1.0, (BATCH, IN_DIM), &dev)?;

    let vm = VarMap::new();
    let vb = nets::seeded_var_builder(&vm, 0, &dev);
    let ours = Mlp::new(
        &vb.pp("mlp"),
        IN_DIM,
        &HIDDEN,
        OUT_DIM,
        LinearInit::TorchDefault,
    )?;
    let theirs = CandleMlp::from_nets(&ours);
    let diff = ours
        .forward(&x)?
        .sub(&theirs.forward(&x)?)?
        .abs()?
        .max_all()?
        .to_scalar::<f32>()?;
    println!("max |nets − candle_nn| output difference: {diff:e}");

    let to_candle = |e: nets::NetsError| candle_core::Error::Msg(e.to_string());
    let (t_nets, t_candle) = compare_us(
        || train_step(ours.forward(&x).map_err(to_candle)),
        || train_step(theirs.forward(&x)),
    )?;
    println!("fwd+bwd nets::Linear      : {t_nets:8.1} µs/iter");
    println!("fwd+bwd candle_nn::Linear : {t_candle:8.1} µs/iter");
    println!("ratio candle_nn / nets    : {:.3}", t_candle / t_nets);

    bench_twin(&x, &dev)
}

/// `TwinCritic` (two plain MLPs) against the stacked `EnsembleMlp` form (one batched network,
/// `weight [2, out, in]`), both `IN_DIM → HIDDEN → 1` per member.
fn bench_twin(x: &Tensor, dev: &Device) -> BenchResult<()> {
    let vm = VarMap::new();
    let vb = VarBuilder::from_varmap(&vm, DType::F32, dev);
    let twin = TwinCritic::new(&vb.pp("twin"), IN_DIM, &HIDDEN, LinearInit::XavierUniform)?;
    let stacked = EnsembleMlp::new(
        &vb.pp("stacked"),
        2,
        IN_DIM,
        &HIDDEN,
        1,
        LinearInit::XavierUniform,
    )?;
    let to_candle = |e: nets::NetsError| candle_core::Error::Msg(e.to_string());
    let (t_twin, t_stacked) = compare_us(
        || train_step(twin.forward(x).map_err(to_candle)),
        || train_step(stacked.forward(x).map_err(to_candle)),
    )?;
    println!("fwd+bwd TwinCritic (two MLPs)      : {t_twin:8.1} µs/iter");
    println!("fwd+bwd stacked EnsembleMlp (k = 2): {t_stacked:8.1} µs/iter");
    println!(
        "ratio stacked / two MLPs           : {:.3}",
        t_stacked / t_twin
    );
    Ok(())
}
