//! A hand-fused CPU forward of φ's MLP for mapping stored states (the rebuild's hot spot).
//!
//! Math: the same network as `nets::Mlp` — `h₀ = x`, `hᵢ₊₁ = relu(hᵢ Wᵢᵀ + bᵢ)` for the hidden
//! layers, a linear last layer — computed element by element as candle's CPU path does it:
//! `yⱼ = (Σₖ xₖ Wⱼₖ) + bⱼ`, the sum accumulated from 0 in `k` order with fused multiply-adds,
//! then the bias, then `max(y, 0)` on hidden layers.
//!
//! Invariant: a row's output depends on that row and the weights only — not on the block,
//! tile, thread or instruction set that computed it — so every way of splitting the rows gives
//! the same bits (`f32::mul_add` is correctly rounded on every path, with or without FMA
//! hardware).
//!
//! Layout and schedule: each weight is stored transposed and zero-padded to whole lane groups
//! of [`LANES`] outputs (`[in][padded_out]`), so one `k` step reads contiguous outputs. Rows go
//! through all layers in blocks of [`BLOCK_ROWS`] (the activations, `BLOCK_ROWS × padded`
//! floats, stay in L2), each layer in tiles of `R` rows × `NV` lane groups whose accumulators
//! live in registers: 4 × 7 groups (28 zmm) with AVX-512, 2 × 3 groups (12 ymm pairs) with
//! AVX2+FMA. The instruction set is detected once at construction; all variants run the same
//! generic code, compiled with different target features.
//!
//! Why not candle here: the per-batch tensor allocations, the separate bias and ReLU passes
//! over `[rows, 100]` arrays and the `Vec<Vec<f32>>` read-back cost more than the matrix
//! products at these sizes (profiled: about 60 % of the re-map outside gemm's kernels).

use nets::Mlp;
use protocol::LatentPoint;

use crate::error::GraphServiceError;

/// Outputs per lane group: one AVX-512 register of `f32`.
pub const LANES: usize = 16;
/// Rows per block: every layer runs over a block before the next block starts.
pub const BLOCK_ROWS: usize = 256;

/// One lane group of outputs.
type Lane = [f32; LANES];

/// Instruction-set variant of the kernel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// AVX-512F (x86-64), 4 × 7 register tiles.
    Avx512,
    /// AVX2 with FMA (x86-64), 2 × 3 register tiles.
    Avx2Fma,
    /// Any CPU: the same code without target features, 4 × 7 tiles.
    Portable,
}

impl Isa {
    /// The best variant this CPU supports.
    pub fn detect() -> Self {
        Self::supported()
            .into_iter()
            .next()
            .unwrap_or(Isa::Portable)
    }

    /// Every variant this CPU supports, best first (always ends with `Portable`).
    pub fn supported() -> Vec<Isa> {
        let mut isas = Vec::new();
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("fma")
            {
                isas.push(Isa::Avx512);
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                isas.push(Isa::Avx2Fma);
            }
        }
        isas.push(Isa::Portable);
        isas
    }
}

/// One dense layer, transposed and padded.
#[derive(Debug, Clone)]
struct DenseLayer {
    in_dim: usize,
    out_dim: usize,
    /// Lane groups per output row: `ceil(out_dim / LANES)`.
    out_lanes: usize,
    /// `Wᵀ`, `[in_dim][out_lanes]` lane groups, zero beyond `out_dim`.
    weight_t: Vec<Lane>,
    /// `b`, `out_lanes` lane groups, zero beyond `out_dim`.
    bias: Vec<Lane>,
    relu: bool,
}

/// Per-thread working memory of [`FusedMlp::map_into`]: one input block and two activation
/// blocks, reused across blocks and calls.
#[derive(Debug, Default, Clone)]
pub struct Scratch {
    input: Vec<f32>,
    even: Vec<f32>,
    odd: Vec<f32>,
}

/// φ's MLP copied out of candle for fused inference (see the module doc).
#[derive(Debug, Clone)]
pub struct FusedMlp {
    layers: Vec<DenseLayer>,
    isa: Isa,
}

impl FusedMlp {
    /// A copy of `mlp`'s weights (ReLU after every layer but the last), run with the best
    /// instruction set of this CPU.
    pub fn from_mlp(mlp: &Mlp) -> Result<Self, GraphServiceError> {
        let last = mlp.layers().len().saturating_sub(1);
        let layers = mlp
            .layers()
            .iter()
            .enumerate()
            .map(|(i, layer)| {
                let weight = layer.weight().to_vec2::<f32>()?;
                let bias = layer.bias().to_vec1::<f32>()?;
                Ok(DenseLayer::new(&weight, &bias, i < last))
            })
            .collect::<Result<Vec<_>, GraphServiceError>>()?;
        if layers.first().is_none_or(|l| l.in_dim == 0) {
            return Err(GraphServiceError::Internal(
                "φ has no layers or no inputs".to_owned(),
            ));
        }
        Ok(Self {
            layers,
            isa: Isa::detect(),
        })
    }

    /// The same network run with `isa`; `Err` if this CPU lacks it.
    pub fn with_isa(mut self, isa: Isa) -> Result<Self, GraphServiceError> {
        if !Isa::supported().contains(&isa) {
            return Err(GraphServiceError::Internal(format!(
                "this CPU does not support the {isa:?} kernel"
            )));
        }
        self.isa = isa;
        Ok(self)
    }

    /// The instruction set in use.
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// Input features.
    pub fn in_dim(&self) -> usize {
        self.layers[0].in_dim
    }

    /// Multiply-adds per row (Σ in × out over the layers), for FLOP rates (2 FLOP each).
    pub fn macs_per_row(&self) -> usize {
        self.layers.iter().map(|l| l.in_dim * l.out_dim).sum()
    }

    /// Appends the first two outputs of every row of `obs` (`n × in_dim`, row-major) to `out`.
    pub fn map_into(
        &self,
        obs: &[f32],
        out: &mut Vec<LatentPoint>,
        scratch: &mut Scratch,
    ) -> Result<(), GraphServiceError> {
        let in_dim = self.in_dim();
        if !obs.len().is_multiple_of(in_dim) {
            return Err(GraphServiceError::ObsLength {
                len: obs.len(),
                obs_dim: in_dim,
            });
        }
        out.reserve(obs.len() / in_dim);
        for block in obs.chunks(BLOCK_ROWS * in_dim) {
            self.block(block, out, scratch);
        }
        Ok(())
    }

    /// One block of at most [`BLOCK_ROWS`] rows through every layer.
    fn block(&self, block: &[f32], out: &mut Vec<LatentPoint>, scratch: &mut Scratch) {
        let in_dim = self.in_dim();
        let rows = block.len() / in_dim;
        // Whole tiles of 4 rows (the largest R); padding rows are zeros and are not returned.
        let padded_rows = rows.div_ceil(4) * 4;
        let widest = self.layers.iter().map(|l| l.out_lanes).max().unwrap_or(0) * LANES;
        scratch.input.clear();
        scratch.input.extend_from_slice(block);
        scratch.input.resize(padded_rows * in_dim, 0.0);
        scratch.even.resize(padded_rows * widest, 0.0);
        scratch.odd.resize(padded_rows * widest, 0.0);
        let Scratch { input, even, odd } = scratch;
        let mut stride = in_dim;
        for (i, layer) in self.layers.iter().enumerate() {
            let out_stride = layer.out_lanes * LANES;
            let (src, dst): (&[f32], &mut [f32]) = match i {
                0 => (input, even),
                _ if i % 2 == 1 => (even, odd),
                _ => (odd, even),
            };
            self.layer(
                layer,
                (src, stride),
                &mut dst[..padded_rows * out_stride],
                padded_rows,
            );
            stride = out_stride;
        }
        let last = if self.layers.len() % 2 == 1 {
            even
        } else {
            odd
        };
        out.extend(
            last.chunks_exact(stride)
                .take(rows)
                .map(|row| [row[0], row.get(1).copied().unwrap_or(f32::NAN)]),
        );
    }

    /// `y = act(x Wᵀ + b)` for `rows` rows (a multiple of 4), with this network's ISA.
    fn layer(&self, layer: &DenseLayer, x: (&[f32], usize), y: &mut [f32], rows: usize) {
        match self.isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx512` is only set when the CPU reports AVX-512F and FMA
            // (`Isa::detect` / `with_isa`).
            Isa::Avx512 => unsafe { x86::layer_avx512(layer, x, y, rows) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Avx2Fma` is only set when the CPU reports AVX2 and FMA.
            Isa::Avx2Fma => unsafe { x86::layer_avx2(layer, x, y, rows) },
            _ => layer_tiles::<4, 7>(layer, x, y, rows),
        }
    }
}

impl DenseLayer {
    /// From candle's `W: [out][in]` and `b: [out]`.
    fn new(weight: &[Vec<f32>], bias: &[f32], relu: bool) -> Self {
        let out_dim = weight.len();
        let in_dim = weight.first().map_or(0, Vec::len);
        let out_lanes = out_dim.div_ceil(LANES);
        let mut weight_t = vec![[0.0; LANES]; in_dim * out_lanes];
        for (j, row) in weight.iter().enumerate() {
            for (k, &w) in row.iter().enumerate() {
                weight_t[k * out_lanes + j / LANES][j % LANES] = w;
            }
        }
        let mut padded_bias = vec![[0.0; LANES]; out_lanes];
        for (j, &b) in bias.iter().enumerate().take(out_dim) {
            padded_bias[j / LANES][j % LANES] = b;
        }
        Self {
            in_dim,
            out_dim,
            out_lanes,
            weight_t,
            bias: padded_bias,
            relu,
        }
    }
}

/// Tiles of `R` rows × at most `NV` lane groups over the whole layer.
#[inline(always)]
fn layer_tiles<const R: usize, const NV: usize>(
    layer: &DenseLayer,
    (x, x_stride): (&[f32], usize),
    y: &mut [f32],
    rows: usize,
) {
    let y_stride = layer.out_lanes * LANES;
    for r0 in (0..rows).step_by(R) {
        let x_rows = &x[r0 * x_stride..(r0 + R) * x_stride];
        let y_rows = &mut y[r0 * y_stride..(r0 + R) * y_stride];
        let mut v0 = 0;
        while v0 < layer.out_lanes {
            let nv = (layer.out_lanes - v0).min(NV);
            match nv {
                1 => tile::<R, 1>(layer, x_rows, x_stride, y_rows, v0),
                2 => tile::<R, 2>(layer, x_rows, x_stride, y_rows, v0),
                3 => tile::<R, 3>(layer, x_rows, x_stride, y_rows, v0),
                4 => tile::<R, 4>(layer, x_rows, x_stride, y_rows, v0),
                5 => tile::<R, 5>(layer, x_rows, x_stride, y_rows, v0),
                6 => tile::<R, 6>(layer, x_rows, x_stride, y_rows, v0),
                _ => tile::<R, 7>(layer, x_rows, x_stride, y_rows, v0),
            }
            v0 += nv;
        }
    }
}

/// Lane groups `v0 .. v0 + NV` of `R` rows: accumulate over `k`, add the bias, apply ReLU
/// (`max(value, 0)` written as `value > 0 ? value : 0`, the form of `vmaxps(value, 0)`).
#[inline(always)]
fn tile<const R: usize, const NV: usize>(
    layer: &DenseLayer,
    x_rows: &[f32],
    x_stride: usize,
    y_rows: &mut [f32],
    v0: usize,
) {
    let k_dim = layer.in_dim;
    let xs: [&[f32]; R] = std::array::from_fn(|r| &x_rows[r * x_stride..r * x_stride + k_dim]);
    let mut acc = [[[0.0f32; LANES]; NV]; R];
    for (k, w_row) in layer
        .weight_t
        .chunks_exact(layer.out_lanes)
        .take(k_dim)
        .enumerate()
    {
        let w = &w_row[v0..v0 + NV];
        for r in 0..R {
            let xk = xs[r][k];
            for v in 0..NV {
                for l in 0..LANES {
                    acc[r][v][l] = xk.mul_add(w[v][l], acc[r][v][l]);
                }
            }
        }
    }
    let y_stride = layer.out_lanes * LANES;
    let bias = &layer.bias[v0..v0 + NV];
    for (r, acc_r) in acc.iter().enumerate() {
        let y = &mut y_rows[r * y_stride + v0 * LANES..r * y_stride + (v0 + NV) * LANES];
        for v in 0..NV {
            for l in 0..LANES {
                let value = acc_r[v][l] + bias[v][l];
                y[v * LANES + l] = if !layer.relu || value > 0.0 {
                    value
                } else {
                    0.0
                };
            }
        }
    }
}

/// The x86-64 kernels: the schedule of [`tile`] with explicit vector registers.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::{
        __m256, __m512, _mm256_add_ps, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_max_ps,
        _mm256_set1_ps, _mm256_setzero_ps, _mm256_storeu_ps, _mm512_add_ps, _mm512_fmadd_ps,
        _mm512_loadu_ps, _mm512_max_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps,
    };

    use super::{DenseLayer, LANES};

    /// Half a lane group: one AVX2 register.
    const HALF: usize = LANES / 2;

    /// `y = act(x Wᵀ + b)` with AVX-512F, tiles of 4 rows × 7 lane groups.
    #[target_feature(enable = "avx512f,avx2,fma")]
    pub(super) fn layer_avx512(
        layer: &DenseLayer,
        (x, x_stride): (&[f32], usize),
        y: &mut [f32],
        rows: usize,
    ) {
        const R: usize = 4;
        let y_stride = layer.out_lanes * LANES;
        for r0 in (0..rows).step_by(R) {
            let x_rows = &x[r0 * x_stride..(r0 + R) * x_stride];
            let y_rows = &mut y[r0 * y_stride..(r0 + R) * y_stride];
            let mut v0 = 0;
            while v0 < layer.out_lanes {
                let nv = (layer.out_lanes - v0).min(7);
                match nv {
                    1 => tile512::<R, 1>(layer, x_rows, x_stride, y_rows, v0),
                    2 => tile512::<R, 2>(layer, x_rows, x_stride, y_rows, v0),
                    3 => tile512::<R, 3>(layer, x_rows, x_stride, y_rows, v0),
                    4 => tile512::<R, 4>(layer, x_rows, x_stride, y_rows, v0),
                    5 => tile512::<R, 5>(layer, x_rows, x_stride, y_rows, v0),
                    6 => tile512::<R, 6>(layer, x_rows, x_stride, y_rows, v0),
                    _ => tile512::<R, 7>(layer, x_rows, x_stride, y_rows, v0),
                }
                v0 += nv;
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx512f,avx2,fma")]
    fn tile512<const R: usize, const NV: usize>(
        layer: &DenseLayer,
        x_rows: &[f32],
        x_stride: usize,
        y_rows: &mut [f32],
        v0: usize,
    ) {
        let k_dim = layer.in_dim;
        let xs: [&[f32]; R] = std::array::from_fn(|r| &x_rows[r * x_stride..r * x_stride + k_dim]);
        let mut acc: [[__m512; NV]; R] = [[_mm512_setzero_ps(); NV]; R];
        for (k, w_row) in layer
            .weight_t
            .chunks_exact(layer.out_lanes)
            .take(k_dim)
            .enumerate()
        {
            let w = &w_row[v0..v0 + NV];
            let xk: [__m512; R] = std::array::from_fn(|r| _mm512_set1_ps(xs[r][k]));
            for v in 0..NV {
                // SAFETY: `w[v]` is an array of LANES = 16 floats.
                let wv = unsafe { _mm512_loadu_ps(w[v].as_ptr()) };
                for r in 0..R {
                    acc[r][v] = _mm512_fmadd_ps(xk[r], wv, acc[r][v]);
                }
            }
        }
        let y_stride = layer.out_lanes * LANES;
        let zero = _mm512_setzero_ps();
        for (r, acc_r) in acc.iter().enumerate() {
            for (v, &sum) in acc_r.iter().enumerate() {
                // SAFETY: `bias[v0 + v]` is an array of 16 floats.
                let bias = unsafe { _mm512_loadu_ps(layer.bias[v0 + v].as_ptr()) };
                let mut value = _mm512_add_ps(sum, bias);
                if layer.relu {
                    value = _mm512_max_ps(value, zero);
                }
                let at = r * y_stride + (v0 + v) * LANES;
                let out = &mut y_rows[at..at + LANES];
                // SAFETY: `out` holds exactly 16 floats.
                unsafe { _mm512_storeu_ps(out.as_mut_ptr(), value) };
            }
        }
    }

    /// `y = act(x Wᵀ + b)` with AVX2+FMA, tiles of 2 rows × 3 lane groups (12 registers).
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn layer_avx2(
        layer: &DenseLayer,
        (x, x_stride): (&[f32], usize),
        y: &mut [f32],
        rows: usize,
    ) {
        const R: usize = 2;
        let y_stride = layer.out_lanes * LANES;
        for r0 in (0..rows).step_by(R) {
            let x_rows = &x[r0 * x_stride..(r0 + R) * x_stride];
            let y_rows = &mut y[r0 * y_stride..(r0 + R) * y_stride];
            let mut v0 = 0;
            while v0 < layer.out_lanes {
                let nv = (layer.out_lanes - v0).min(3);
                match nv {
                    1 => tile256::<R, 1>(layer, x_rows, x_stride, y_rows, v0),
                    2 => tile256::<R, 2>(layer, x_rows, x_stride, y_rows, v0),
                    _ => tile256::<R, 3>(layer, x_rows, x_stride, y_rows, v0),
                }
                v0 += nv;
            }
        }
    }

    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn tile256<const R: usize, const NV: usize>(
        layer: &DenseLayer,
        x_rows: &[f32],
        x_stride: usize,
        y_rows: &mut [f32],
        v0: usize,
    ) {
        let k_dim = layer.in_dim;
        let xs: [&[f32]; R] = std::array::from_fn(|r| &x_rows[r * x_stride..r * x_stride + k_dim]);
        let mut acc: [[[__m256; 2]; NV]; R] = [[[_mm256_setzero_ps(); 2]; NV]; R];
        for (k, w_row) in layer
            .weight_t
            .chunks_exact(layer.out_lanes)
            .take(k_dim)
            .enumerate()
        {
            let w = &w_row[v0..v0 + NV];
            let xk: [__m256; R] = std::array::from_fn(|r| _mm256_set1_ps(xs[r][k]));
            for v in 0..NV {
                for h in 0..2 {
                    // SAFETY: `w[v][h * 8..]` holds 8 floats.
                    let wv = unsafe { _mm256_loadu_ps(w[v][h * HALF..].as_ptr()) };
                    for r in 0..R {
                        acc[r][v][h] = _mm256_fmadd_ps(xk[r], wv, acc[r][v][h]);
                    }
                }
            }
        }
        let y_stride = layer.out_lanes * LANES;
        let zero = _mm256_setzero_ps();
        for (r, acc_r) in acc.iter().enumerate() {
            for (v, halves) in acc_r.iter().enumerate() {
                for (h, &sum) in halves.iter().enumerate() {
                    let b = &layer.bias[v0 + v][h * HALF..(h + 1) * HALF];
                    // SAFETY: `b` holds 8 floats.
                    let bias = unsafe { _mm256_loadu_ps(b.as_ptr()) };
                    let mut value = _mm256_add_ps(sum, bias);
                    if layer.relu {
                        value = _mm256_max_ps(value, zero);
                    }
                    let at = r * y_stride + (v0 + v) * LANES + h * HALF;
                    let out = &mut y_rows[at..at + HALF];
                    // SAFETY: `out` holds exactly 8 floats.
                    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), value) };
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor};
    use candle_nn::VarMap;
    use nets::LinearInit;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    use super::*;

    /// A seeded candle MLP `in → hidden… → 2`.
    fn candle_mlp(in_dim: usize, hidden: &[usize], seed: u64) -> Mlp {
        let params = VarMap::new();
        let vb = nets::seeded_var_builder(&params, seed, &Device::Cpu);
        Mlp::new(&vb, in_dim, hidden, 2, LinearInit::TorchDefault).unwrap()
    }

    fn random_obs(rows: usize, dim: usize, seed: u64) -> Vec<f32> {
        let mut rng = Pcg64::seed_from_u64(seed);
        (0..rows * dim)
            .map(|_| rng.random_range(-3.0..3.0))
            .collect()
    }

    fn fused(mlp: &FusedMlp, obs: &[f32]) -> Vec<LatentPoint> {
        let mut out = Vec::new();
        mlp.map_into(obs, &mut out, &mut Scratch::default())
            .unwrap();
        out
    }

    fn bits(points: &[LatentPoint]) -> Vec<[u32; 2]> {
        points
            .iter()
            .map(|p| [p[0].to_bits(), p[1].to_bits()])
            .collect()
    }

    #[test]
    fn the_fused_forward_matches_candle_on_random_inputs() {
        // Odd sizes: partial lane groups, a partial last tile and a partial last block.
        for (in_dim, hidden, rows) in [
            (29, vec![100, 100], 1_000),
            (7, vec![33], 5),
            (3, vec![17, 40, 9], 259),
        ] {
            let mlp = candle_mlp(in_dim, &hidden, 11);
            let obs = random_obs(rows, in_dim, 12);
            let input = Tensor::from_slice(&obs, (rows, in_dim), &Device::Cpu).unwrap();
            let expected = mlp.forward(&input).unwrap().to_vec2::<f32>().unwrap();
            let ours = fused(&FusedMlp::from_mlp(&mlp).unwrap(), &obs);
            assert_eq!(ours.len(), rows);
            for (row, (got, want)) in ours.iter().zip(&expected).enumerate() {
                for c in 0..2 {
                    let scale = want[c].abs().max(1.0);
                    assert!(
                        (got[c] - want[c]).abs() <= 1e-5 * scale,
                        "{in_dim}/{hidden:?} row {row} col {c}: fused {} candle {}",
                        got[c],
                        want[c]
                    );
                }
            }
        }
    }

    #[test]
    fn every_instruction_set_gives_the_same_bits() {
        let mlp = FusedMlp::from_mlp(&candle_mlp(29, &[100, 100], 3)).unwrap();
        let obs = random_obs(777, 29, 4);
        let reference = bits(&fused(&mlp.clone().with_isa(Isa::Portable).unwrap(), &obs));
        for isa in Isa::supported() {
            let ours = bits(&fused(&mlp.clone().with_isa(isa).unwrap(), &obs));
            assert_eq!(ours, reference, "{isa:?}");
        }
    }

    #[test]
    fn a_row_maps_to_the_same_bits_alone_or_in_a_block() {
        let mlp = FusedMlp::from_mlp(&candle_mlp(29, &[100, 100], 5)).unwrap();
        let obs = random_obs(300, 29, 6);
        let together = bits(&fused(&mlp, &obs));
        let alone: Vec<[u32; 2]> = obs
            .chunks(29)
            .flat_map(|row| bits(&fused(&mlp, row)))
            .collect();
        assert_eq!(together, alone);
    }

    #[test]
    fn a_ragged_observation_buffer_is_an_error() {
        let mlp = FusedMlp::from_mlp(&candle_mlp(4, &[8], 1)).unwrap();
        let err = mlp
            .map_into(&[0.0; 9], &mut Vec::new(), &mut Scratch::default())
            .unwrap_err();
        assert!(err.to_string().contains("9 floats"), "{err}");
    }
}
