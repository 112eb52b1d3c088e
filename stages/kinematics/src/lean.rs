//! A lean f32 step for streaming inference at batch 1, over the weights of a candle [`Rnn`].
//!
//! Candle stays the training and weight-loading path; this is only the per-frame forward pass. At
//! batch 1 candle's step is dozens of small ops per net (transposes, matmuls through the gemm
//! crate, broadcasts, narrows, element-wise kernels), each allocating its output tensor. Here every
//! net's weights are copied once into plain f32 arrays, laid out so that one frame reads them front
//! to back, and every buffer the step writes is allocated up front.
//!
//! Where the time goes (PIP, 4.6 MB of weights per frame, H = 128, `imuflow bench kinematics` and
//! a scratch copy of these kernels, 2026-11-25, this 2-core AMD EPYC, 512 KB L2 per core, 32 MB L3): a
//! frame's weights do not fit in L2, so the matrix-vector products stream them from L3, and that
//! is the floor. A plain AVX2 read of the LSTM weights took 56 µs (76 GB/s); the products over the
//! row-major layout 74 µs, over the blocked layout of `Matrix` 62 µs. The gate nonlinearities
//! through libm (`expf`, `tanhf`: 5,400 calls a frame) took 39 µs, the vectorized polynomial below
//! 4.5 µs.
//!
//! Per LSTM layer the two PyTorch matrices `weight_ih [4H, in]` and `weight_hh [4H, H]` are fused
//! into one `[4H, in' + H']` matrix, row r = `[weight_ih[r] | 0 … | weight_hh[r] | 0 …]`, and the
//! layer keeps its input and its own hidden state next to each other in one buffer
//! `[x | 0 … | h | 0 …]`, so each gate pre-activation is one dot product plus the summed bias
//! (`bias_ih + bias_hh`, as candle adds them). `in'` and `H'` are rounded up to a multiple of 8:
//! zero weights against zero inputs change no sum, and every row is whole SIMD chunks. Gate order
//! and the order of the element-wise arithmetic are those of [`crate::net`] (i, f, g, o;
//! `c = f·c + i·g`, `h = o·tanh(c)`); the dot products sum in another order and e^x is a
//! polynomial (relative error 1e-7), so outputs agree with candle's to about 1e-7 per step
//! (tests below: ≤ 1e-5 over 300 frames; the committed nets' estimates, `infer`'s tests: 3e-7 PIP,
//! 1.1e-6 GlobalPose).

use candle_core::{Result as CandleResult, Tensor};

use crate::net::{LstmState, Rnn};

/// Rows per block of a [`Matrix`] (one accumulator register each).
const ROWS: usize = 4;
/// Columns per chunk: the f32 lanes of one 256-bit register.
const LANES: usize = 8;

/// Chunk k of a block's four rows: `[row0[8k..8k+8] | row1[…] | row2[…] | row3[…]]`, 128 bytes on
/// a 64-byte boundary (two cache lines; no load straddles one).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Chunk([f32; ROWS * LANES]);

/// A weight matrix in the order the kernels read it: rows in blocks of 4, each block column chunk
/// by column chunk, so a matrix-vector product reads the matrix as one sequential stream instead
/// of four rows 1 KB apart (measured 62 vs 74 µs a frame, module doc).
/// Rows are padded to a multiple of 4 and columns to a multiple of 8 with zeros.
#[derive(Clone, Debug)]
pub(crate) struct Matrix {
    rows: usize,
    /// Padded.
    cols: usize,
    chunks: Vec<Chunk>,
}

/// [`Matrix::touch`] asks whether to stop after this many chunks (256 KB).
const TOUCH_BATCH: usize = 2048;

impl Matrix {
    /// Reads one value of every cache line of the matrix, so the next product finds it in cache;
    /// stops early (returning false) when `stop()` says so between batches of 256 KB.
    fn touch(&self, stop: &mut dyn FnMut() -> bool) -> bool {
        for batch in self.chunks.chunks(TOUCH_BATCH) {
            // Each chunk is two cache lines: its rows 0 and 2 start them.
            let sum: f32 = batch.iter().map(|c| c.0[0] + c.0[2 * LANES]).sum();
            std::hint::black_box(sum);
            if stop() {
                return false;
            }
        }
        true
    }

    /// `rows × cols` with entry (r, c) = `at(r, c)` (0 in the padding).
    fn new(rows: usize, cols: usize, at: impl Fn(usize, usize) -> f32) -> Matrix {
        let (rows_p, cols_p) = (rows.next_multiple_of(ROWS), cols.next_multiple_of(LANES));
        let mut chunks = Vec::with_capacity(rows_p / ROWS * cols_p / LANES);
        for block in (0..rows_p).step_by(ROWS) {
            for col in (0..cols_p).step_by(LANES) {
                chunks.push(Chunk(std::array::from_fn(|k| {
                    let (r, c) = (block + k / LANES, col + k % LANES);
                    if r < rows && c < cols { at(r, c) } else { 0.0 }
                })));
            }
        }
        Matrix {
            rows,
            cols: cols_p,
            chunks,
        }
    }

    /// From a row-major `rows × cols` slice.
    pub(crate) fn from_row_major(rows: usize, cols: usize, w: &[f32]) -> Matrix {
        assert_eq!(w.len(), rows * cols);
        Matrix::new(rows, cols, |r, c| w[r * cols + c])
    }

    /// Rows of the product the kernels write (padded to a multiple of 4).
    pub(crate) fn padded_rows(&self) -> usize {
        self.rows.next_multiple_of(ROWS)
    }

    /// Length of the vector the kernels take (columns padded to a multiple of 8).
    pub(crate) fn padded_cols(&self) -> usize {
        self.cols
    }
}

/// Which kernels a [`LeanRnn`] uses. Private fields: a value that says AVX2 + FMA can only be made
/// after the CPU was checked for them, which is what makes calling those kernels sound.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kernel(KernelKind);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum KernelKind {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Kernel {
    /// The fastest kernel this CPU runs.
    pub fn detect() -> Kernel {
        Kernel::avx2_fma().unwrap_or(Kernel::portable())
    }

    /// Plain Rust for any CPU (the compiler vectorizes it for the baseline target, SSE2 on x86-64).
    pub fn portable() -> Kernel {
        Kernel(KernelKind::Portable)
    }

    /// 256-bit FMA kernels, if this CPU has AVX2 and FMA (checked at run time: the binary is built
    /// for plain x86-64).
    pub fn avx2_fma() -> Option<Kernel> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Some(Kernel(KernelKind::Avx2Fma));
        }
        None
    }

    pub fn name(self) -> &'static str {
        match self.0 {
            KernelKind::Portable => "portable",
            #[cfg(target_arch = "x86_64")]
            KernelKind::Avx2Fma => "avx2+fma",
        }
    }

    /// `out = m·x + bias`; `x`, `bias` and `out` padded (`m.padded_cols()`, `m.padded_rows()`).
    pub(crate) fn matvec(self, m: &Matrix, x: &[f32], bias: &[f32], out: &mut [f32]) {
        assert_eq!(
            x.len(),
            m.padded_cols(),
            "x is padded to the matrix's columns"
        );
        assert_eq!(bias.len(), m.padded_rows(), "one bias per (padded) row");
        assert_eq!(out.len(), m.padded_rows(), "one output per (padded) row");
        if m.cols == 0 {
            out.copy_from_slice(bias);
            return;
        }
        match self.0 {
            KernelKind::Portable => matvec_portable(m, x, bias, out),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `matvec_avx2` is only unsafe to call because it is compiled for AVX2 and FMA;
            // a `KernelKind::Avx2Fma` exists only after `Kernel::avx2_fma` found both on this CPU.
            // Its memory accesses go through references (checked above for length).
            KernelKind::Avx2Fma => unsafe { matvec_avx2(m, x, bias, out) },
        }
    }

    /// LSTM cell update: gate pre-activations `gates [4H]` → new `c [H]` and `h [H]`.
    pub(crate) fn cell(self, gates: &[f32], c: &mut [f32], h: &mut [f32]) {
        assert_eq!(gates.len(), 4 * c.len(), "four gates per unit");
        assert_eq!(h.len(), c.len(), "h and c of one size");
        match self.0 {
            KernelKind::Portable => cell_portable(gates, c, h),
            #[cfg(target_arch = "x86_64")]
            // SAFETY: as in `matvec`: only the target features make this call unsafe, and they
            // were detected.
            KernelKind::Avx2Fma => unsafe { cell_avx2(gates, c, h) },
        }
    }
}

/// Chunks per block row of `m`.
fn chunks_per_block(m: &Matrix) -> usize {
    m.cols / LANES
}

/// Four rows at a time with eight lanes of partial sums each (the compiler keeps them in SSE
/// registers on plain x86-64).
fn matvec_portable(m: &Matrix, x: &[f32], bias: &[f32], out: &mut [f32]) {
    let (xs, _) = x.as_chunks::<LANES>();
    let blocks = m.chunks.chunks_exact(chunks_per_block(m));
    for ((block, o), b) in blocks
        .zip(out.as_chunks_mut::<ROWS>().0)
        .zip(bias.as_chunks::<ROWS>().0)
    {
        let mut acc = [[0.0f32; LANES]; ROWS];
        for (chunk, xc) in block.iter().zip(xs) {
            for (r, a) in acc.iter_mut().enumerate() {
                for l in 0..LANES {
                    a[l] += chunk.0[r * LANES + l] * xc[l];
                }
            }
        }
        for r in 0..ROWS {
            let q: [f32; 4] = std::array::from_fn(|l| acc[r][l] + acc[r][l + 4]);
            o[r] = ((q[0] + q[2]) + (q[1] + q[3])) + b[r];
        }
    }
}

/// Four accumulators (one per row of the block) hide the FMA latency; each chunk of x is loaded
/// once for four rows. Intrinsics: the portable source compiled with AVX2 enabled stayed scalar
/// (`objdump` showed no ymm register in it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn matvec_avx2(m: &Matrix, x: &[f32], bias: &[f32], out: &mut [f32]) {
    use std::arch::x86_64::{_mm256_fmadd_ps, _mm256_setzero_ps};
    let (xs, _) = x.as_chunks::<LANES>();
    let blocks = m.chunks.chunks_exact(chunks_per_block(m));
    for ((block, o), b) in blocks
        .zip(out.as_chunks_mut::<ROWS>().0)
        .zip(bias.as_chunks::<ROWS>().0)
    {
        let mut acc = [_mm256_setzero_ps(); ROWS];
        for (chunk, xc) in block.iter().zip(xs) {
            let xv = load(xc);
            let (rows, _) = chunk.0.as_chunks::<LANES>();
            for (a, w) in acc.iter_mut().zip(rows) {
                *a = _mm256_fmadd_ps(load(w), xv, *a);
            }
        }
        for r in 0..ROWS {
            o[r] = horizontal_sum(acc[r]) + b[r];
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn load(lanes: &[f32; LANES]) -> std::arch::x86_64::__m256 {
    // SAFETY: an unaligned load of exactly the eight f32 the reference points to.
    unsafe { std::arch::x86_64::_mm256_loadu_ps(lanes.as_ptr()) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
fn horizontal_sum(v: std::arch::x86_64::__m256) -> f32 {
    use std::arch::x86_64::*;
    let q = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
    let d = _mm_add_ps(q, _mm_movehl_ps(q, q));
    _mm_cvtss_f32(_mm_add_ss(d, _mm_movehdup_ps(d)))
}

/// `a·b + c`, fused where the target has FMA (without it `mul_add` is a slow libm call).
#[inline(always)]
fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// e^x in f32 without a libm call, so that the cell update below vectorizes: Cody-Waite reduction
/// x = n·ln 2 + r (|r| ≤ ln 2 / 2) and Cephes' degree-7 polynomial for e^r (`expf.c`, relative
/// error about 1e-7), times 2^n built in the exponent bits. x is clamped to [−87, 88] so that 2^n
/// stays a normal number (e^±88 is far beyond anything a sigmoid or tanh below distinguishes);
/// NaN passes the clamp and comes out NaN.
#[inline(always)]
fn exp_poly<const FMA: bool>(x: f32) -> f32 {
    // Adding 1.5·2^23 rounds to an integer (to nearest) and leaves it in the low mantissa bits.
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0); // NaN stays NaN
    let t = madd::<FMA>(x, std::f32::consts::LOG2_E, ROUND);
    let n = t - ROUND;
    // ln 2 in two parts: 0.6933594 is 0.693359375 = 355/512, so n·it is exact for |n| ≤ 128.
    let r = madd::<FMA>(n, 2.121_944_4e-4, madd::<FMA>(n, -0.693_359_4, x));
    let mut p = 1.987_569_1e-4;
    for k in [
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        0.166_666_65,
        0.5,
    ] {
        p = madd::<FMA>(p, r, k);
    }
    let p = madd::<FMA>(p, r * r, r) + 1.0;
    // 2^n: n + 127 in the exponent field (n is in [−126, 127] after the clamp).
    let n_int = t.to_bits() as i32 - ROUND.to_bits() as i32;
    p * f32::from_bits(((n_int + 127) << 23) as u32)
}

/// candle_nn::ops::sigmoid's formula, 1 / (e^−v + 1).
#[inline(always)]
fn sigmoid<const FMA: bool>(v: f32) -> f32 {
    (exp_poly::<FMA>(-v) + 1.0).recip()
}

/// tanh v = 1 − 2 / (e^2v + 1): absolute error about 1e-7 (relative near 0 it is worse, but the
/// cell and hidden states are compared absolutely, and candle's f32 has the same 6e-8 spacing at 1).
#[inline(always)]
fn tanh<const FMA: bool>(v: f32) -> f32 {
    1.0 - 2.0 / (exp_poly::<FMA>(2.0 * v) + 1.0)
}

/// The LSTM cell from the gate pre-activations `[i | f | g | o]` (PyTorch's order): `c = f·c + i·g`,
/// `h = o·tanh(c)`, in that order of operations (candle's).
#[inline(always)]
fn cell_generic<const FMA: bool>(gates: &[f32], c: &mut [f32], h: &mut [f32]) {
    let hn = c.len();
    let (i, rest) = gates.split_at(hn);
    let (f, rest) = rest.split_at(hn);
    let (g, o) = rest.split_at(hn);
    let lanes = c.iter_mut().zip(h.iter_mut()).zip(i).zip(f).zip(g).zip(o);
    for (((((c, h), &i), &f), &g), &o) in lanes {
        let cn = sigmoid::<FMA>(f) * *c + sigmoid::<FMA>(i) * tanh::<FMA>(g);
        *c = cn;
        *h = sigmoid::<FMA>(o) * tanh::<FMA>(cn);
    }
}

fn cell_portable(gates: &[f32], c: &mut [f32], h: &mut [f32]) {
    cell_generic::<false>(gates, c, h);
}

/// The same source compiled for AVX2 + FMA: eight units per iteration.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn cell_avx2(gates: &[f32], c: &mut [f32], h: &mut [f32]) {
    cell_generic::<true>(gates, c, h);
}

fn to_vec(t: &Tensor) -> CandleResult<Vec<f32>> {
    t.flatten_all()?.to_vec1()
}

/// `v` padded with zeros to `len`.
fn padded(mut v: Vec<f32>, len: usize) -> Vec<f32> {
    v.resize(len, 0.0);
    v
}

/// A dense layer `y = W·x + b`.
#[derive(Clone, Debug)]
struct Dense {
    w: Matrix,
    /// Padded to `w.padded_rows()`.
    b: Vec<f32>,
}

impl Dense {
    fn new(l: &crate::net::Linear) -> CandleResult<Dense> {
        let (rows, cols) = l.weight.dims2()?;
        let w = Matrix::from_row_major(rows, cols, &to_vec(&l.weight)?);
        let b = padded(to_vec(&l.bias)?, w.padded_rows());
        Ok(Dense { w, b })
    }
}

/// One LSTM layer with its state.
#[derive(Clone, Debug)]
struct Layer {
    /// Input width (without padding).
    input: usize,
    /// Where `h` starts in `xh` (`input` rounded up to a multiple of 8).
    h_at: usize,
    /// Fused gate weights `[4H, h_at + H']`.
    w: Matrix,
    /// `bias_ih + bias_hh`, `[4H]`.
    bias: Vec<f32>,
    /// `[x | 0 … | h | 0 …]`: this frame's input and the previous frame's hidden state.
    xh: Vec<f32>,
    /// Cell state `[H]`.
    c: Vec<f32>,
    /// Gate pre-activations `[4H]` (scratch).
    gates: Vec<f32>,
}

impl Layer {
    fn new(l: &crate::net::LstmLayer, input: usize, hn: usize) -> CandleResult<Layer> {
        let h_at = input.next_multiple_of(LANES);
        let (w_ih, w_hh) = (to_vec(&l.w_ih)?, to_vec(&l.w_hh)?);
        let w = Matrix::new(4 * hn, h_at + hn, |r, c| {
            if c < input {
                w_ih[r * input + c]
            } else if c >= h_at {
                w_hh[r * hn + c - h_at]
            } else {
                0.0
            }
        });
        Ok(Layer {
            input,
            h_at,
            bias: to_vec(&(&l.b_ih + &l.b_hh)?)?,
            xh: vec![0.0; w.padded_cols()],
            c: vec![0.0; hn],
            gates: vec![0.0; 4 * hn],
            w,
        })
    }

    fn hidden(&self) -> usize {
        self.c.len()
    }

    /// `h` with its zero padding.
    fn h_padded(&self) -> &[f32] {
        &self.xh[self.h_at..]
    }

    fn h(&self) -> &[f32] {
        &self.xh[self.h_at..self.h_at + self.hidden()]
    }

    /// One frame: the input must already be in `xh[..input]`; replaces h and c.
    fn advance(&mut self, kernel: Kernel) {
        let hn = self.hidden();
        kernel.matvec(&self.w, &self.xh, &self.bias, &mut self.gates);
        kernel.cell(
            &self.gates,
            &mut self.c,
            &mut self.xh[self.h_at..self.h_at + hn],
        );
    }
}

/// One network's streaming forward pass with its own state and buffers: no allocation per step.
#[derive(Clone, Debug)]
pub struct LeanRnn {
    input: usize,
    output: usize,
    kernel: Kernel,
    linear1: Option<Dense>,
    /// linear1's input, padded (scratch).
    x1: Vec<f32>,
    layers: Vec<Layer>,
    linear2: Dense,
    /// linear2's output, padded.
    out: Vec<f32>,
}

impl LeanRnn {
    /// Copy `rnn`'s weights out of candle (once; the kernel is [`Kernel::detect`]'s). The state
    /// starts at zero.
    pub fn new(rnn: &Rnn) -> CandleResult<LeanRnn> {
        let spec = &rnn.spec;
        let hn = spec.hidden;
        let linear1 = rnn.linear1.as_ref().map(Dense::new).transpose()?;
        let layers = rnn
            .layers
            .iter()
            .enumerate()
            .map(|(k, l)| {
                let input = if k == 0 && linear1.is_none() {
                    spec.input
                } else {
                    hn
                };
                Layer::new(l, input, hn)
            })
            .collect::<CandleResult<Vec<_>>>()?;
        if layers.is_empty() {
            candle_core::bail!("{}: an LSTM without layers", spec.name);
        }
        let linear2 = Dense::new(&rnn.linear2)?;
        Ok(LeanRnn {
            input: spec.input,
            output: spec.output,
            kernel: Kernel::detect(),
            x1: vec![0.0; linear1.as_ref().map_or(0, |l| l.w.padded_cols())],
            linear1,
            layers,
            out: vec![0.0; linear2.w.padded_rows()],
            linear2,
        })
    }

    /// Use `kernel` from now on (tests compare the kernels; the default is the fastest).
    pub fn set_kernel(&mut self, kernel: Kernel) {
        self.kernel = kernel;
    }

    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Set h and c from a candle state of batch 1 (e.g. [`Rnn::initial_state`]'s).
    pub fn set_state(&mut self, state: &LstmState) -> CandleResult<()> {
        if state.h.len() != self.layers.len() || state.c.len() != self.layers.len() {
            candle_core::bail!(
                "a state of {} layers for a net of {}",
                state.h.len(),
                self.layers.len()
            );
        }
        for ((layer, h), c) in self.layers.iter_mut().zip(&state.h).zip(&state.c) {
            let (h, c) = (to_vec(h)?, to_vec(c)?);
            let hn = layer.hidden();
            if h.len() != hn || c.len() != hn {
                candle_core::bail!(
                    "state of {} values for a layer of hidden size {hn}",
                    h.len()
                );
            }
            let at = layer.h_at;
            layer.xh[at..at + hn].copy_from_slice(&h);
            layer.c.copy_from_slice(&c);
        }
        Ok(())
    }

    /// Brings the weights into cache ahead of the next [`LeanRnn::step`] (a live stage idles
    /// 16 ms between frames, long enough for other processes to evict them: the step then
    /// streams them from memory). Stops early, returning false, when `stop()` says so.
    pub fn warm(&self, stop: &mut dyn FnMut() -> bool) -> bool {
        let matrices = self
            .linear1
            .iter()
            .map(|d| &d.w)
            .chain(self.layers.iter().map(|l| &l.w))
            .chain(std::iter::once(&self.linear2.w));
        for m in matrices {
            if !m.touch(stop) {
                return false;
            }
        }
        true
    }

    /// One frame: `x [input]` → `[output]`, advancing the state.
    pub fn step(&mut self, x: &[f32]) -> &[f32] {
        assert_eq!(x.len(), self.input, "input width");
        let kernel = self.kernel;
        let first = &mut self.layers[0];
        match &self.linear1 {
            Some(l1) => {
                self.x1[..x.len()].copy_from_slice(x);
                let y = &mut first.xh[..l1.w.padded_rows()];
                kernel.matvec(&l1.w, &self.x1, &l1.b, y);
                for v in y.iter_mut() {
                    *v = v.max(0.0);
                }
            }
            None => first.xh[..x.len()].copy_from_slice(x),
        }
        for k in 0..self.layers.len() {
            let (done, next) = self.layers.split_at_mut(k + 1);
            let layer = &mut done[k];
            layer.advance(kernel);
            if let Some(next) = next.first_mut() {
                next.xh[..next.input].copy_from_slice(layer.h());
            }
        }
        let last = &self.layers[self.layers.len() - 1];
        let l2 = &self.linear2;
        kernel.matvec(&l2.w, last.h_padded(), &l2.b, &mut self.out);
        &self.out[..self.output]
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use candle_core::Device;

    use super::*;
    use crate::net::{RnnSpec, init_parameters};

    fn spec(input_linear: bool, layers: usize, hidden: usize, init: Option<usize>) -> RnnSpec {
        RnnSpec {
            name: "net".into(),
            input: 13,
            output: 6,
            hidden,
            layers,
            input_linear,
            init_input: init,
        }
    }

    fn random_tensors(spec: &RnnSpec) -> HashMap<String, Tensor> {
        init_parameters(
            spec,
            &Device::Cpu,
            &mut <rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(7),
        )
        .unwrap()
        .into_iter()
        .map(|(n, v)| (n, v.as_tensor().clone()))
        .collect()
    }

    /// Largest |lean − candle| over `frames` frames of random input, both started from the same
    /// (learned, if the net has one) state.
    fn max_difference(net: &Rnn, lean: &mut LeanRnn, frames: usize) -> f32 {
        let init = net
            .spec
            .init_input
            .map(|n| Tensor::randn(0f32, 1.0, (1, n), &Device::Cpu).unwrap());
        let mut state = net.initial_state(1, init.as_ref()).unwrap();
        lean.set_state(&state).unwrap();
        let xs = Tensor::randn(0f32, 1.0, (frames, net.spec.input), &Device::Cpu).unwrap();
        let mut worst = 0.0f32;
        for t in 0..frames {
            let x = xs.narrow(0, t, 1).unwrap();
            let want = to_vec(&net.step(&x, &mut state).unwrap()).unwrap();
            let got = lean.step(&to_vec(&x).unwrap());
            assert_eq!(got.len(), want.len());
            for (a, b) in got.iter().zip(&want) {
                worst = worst.max((a - b).abs());
            }
        }
        worst
    }

    fn kernels() -> Vec<Kernel> {
        let mut k = vec![Kernel::portable()];
        match Kernel::avx2_fma() {
            Some(simd) => k.push(simd),
            None => eprintln!("this CPU lacks AVX2/FMA: only the portable kernel is tested"),
        }
        k
    }

    /// Warming reads every matrix unless told to stop, and stops at the next 256 KB batch when
    /// told (a frame came): it never holds the stage up for a whole net.
    #[test]
    fn warming_touches_every_matrix_and_stops_when_the_frame_comes() {
        // 512 hidden, 3 layers: each gate matrix is 2048 × 1024 floats (8 MB: 32 batches).
        let s = spec(true, 3, 512, None);
        let net = Rnn::from_tensors(&s, &random_tensors(&s)).unwrap();
        let lean = LeanRnn::new(&net).unwrap();
        let mut asked = 0;
        assert!(lean.warm(&mut || {
            asked += 1;
            false
        }));
        let chunks: usize = std::iter::once(&lean.linear2.w)
            .chain(lean.linear1.iter().map(|d| &d.w))
            .chain(lean.layers.iter().map(|l| &l.w))
            .map(|m| m.chunks.len().div_ceil(TOUCH_BATCH))
            .sum();
        assert_eq!(asked, chunks, "asked once per batch of every matrix");
        let mut asked = 0;
        assert!(!lean.warm(&mut || {
            asked += 1;
            true
        }));
        assert_eq!(asked, 1, "stops at the first batch once the frame is there");
    }

    /// The kernels against a plain f64 sum, for every shape around the 4-row and 8-lane blocking
    /// (padded rows and columns, fewer columns than one chunk, no columns).
    #[test]
    fn matvec_kernels_match_a_plain_sum_at_every_blocking_edge() {
        let values = |n: usize, seed: f32| -> Vec<f32> {
            (0..n).map(|k| ((k as f32 + seed) * 0.7312).sin()).collect()
        };
        for kernel in kernels() {
            for rows in 1..=9 {
                for cols in [0, 1, 7, 8, 9, 15, 16, 17, 37, 64] {
                    let w = values(rows * cols, 0.3);
                    let m = Matrix::from_row_major(rows, cols, &w);
                    let x = padded(values(cols, 1.9), m.padded_cols());
                    let b = padded(values(rows, 4.2), m.padded_rows());
                    let mut out = vec![f32::NAN; m.padded_rows()];
                    kernel.matvec(&m, &x, &b, &mut out);
                    for (r, o) in out.iter().enumerate() {
                        let dot: f64 = match r < rows {
                            true => (0..cols)
                                .map(|k| w[r * cols + k] as f64 * x[k] as f64)
                                .sum(),
                            false => 0.0,
                        };
                        let want = dot + b[r] as f64;
                        assert!(
                            (*o as f64 - want).abs() < 1e-5,
                            "{} {rows}×{cols} row {r}: {o} vs {want}",
                            kernel.name(),
                        );
                    }
                }
            }
        }
    }

    /// The polynomial e^x, sigmoid and tanh against f64 over the range the gates see and beyond it
    /// (both builds of the arithmetic: with and without FMA), and NaN staying NaN.
    #[test]
    fn nonlinearities_match_f64() {
        let (mut exp_rel, mut sig_abs, mut tanh_abs) = (0.0f64, 0.0f64, 0.0f64);
        for k in -200_000..=200_000 {
            let v = k as f32 * 5e-4; // −100 … 100
            for (e, s, t) in [
                (exp_poly::<false>(v), sigmoid::<false>(v), tanh::<false>(v)),
                (exp_poly::<true>(v), sigmoid::<true>(v), tanh::<true>(v)),
            ] {
                let x = v as f64;
                if (-87.0..=88.0).contains(&x) {
                    exp_rel = exp_rel.max((e as f64 / x.exp() - 1.0).abs());
                }
                sig_abs = sig_abs.max((s as f64 - 1.0 / (1.0 + (-x).exp())).abs());
                tanh_abs = tanh_abs.max((t as f64 - x.tanh()).abs());
            }
        }
        assert!(exp_rel < 3e-7, "e^x relative error {exp_rel}");
        assert!(sig_abs < 1.2e-7, "sigmoid error {sig_abs}");
        assert!(tanh_abs < 2.4e-7, "tanh error {tanh_abs}");
        assert!(sigmoid::<false>(f32::NAN).is_nan() && tanh::<true>(f32::NAN).is_nan());
        // Far out the clamp shows only below f32's normal range: e^−87 ≈ 1.6e-38.
        assert_eq!(sigmoid::<false>(1e4), 1.0);
        assert!((0.0..1e-37).contains(&sigmoid::<false>(-1e4)));
        assert_eq!((tanh::<true>(1e4), tanh::<true>(-1e4)), (1.0, -1.0));
    }

    /// The cell update of every kernel against the gate equations in f64 (37 units: the AVX2 loop
    /// has a tail).
    #[test]
    fn cell_update_matches_the_gate_equations() {
        let hn = 37;
        let gates: Vec<f32> = (0..4 * hn)
            .map(|k| (k as f32 * 0.913).sin() * 4.0)
            .collect();
        let c0: Vec<f32> = (0..hn).map(|k| (k as f32 * 0.37).cos() * 2.0).collect();
        let sig = |v: f32| 1.0 / (1.0 + (-(v as f64)).exp());
        for kernel in kernels() {
            let (mut c, mut h) = (c0.clone(), vec![0.0f32; hn]);
            kernel.cell(&gates, &mut c, &mut h);
            for j in 0..hn {
                let g = |q: usize| gates[q * hn + j];
                let want_c = sig(g(1)) * c0[j] as f64 + sig(g(0)) * (g(2) as f64).tanh();
                let want_h = sig(g(3)) * want_c.tanh();
                assert!(
                    (c[j] as f64 - want_c).abs() < 1e-6,
                    "{} c[{j}]",
                    kernel.name()
                );
                assert!(
                    (h[j] as f64 - want_h).abs() < 1e-6,
                    "{} h[{j}]",
                    kernel.name()
                );
            }
        }
    }

    /// The lean step against candle's `Rnn::step` over 300 frames: with and without linear1, 1-3
    /// layers, hidden sizes that leave a SIMD tail (37, 13) and one that does not (16), zero and
    /// learned initial states, with every kernel this CPU has.
    #[test]
    fn lean_step_matches_candle_step() {
        let cases = [
            spec(true, 2, 37, None),
            spec(false, 1, 37, Some(5)),
            spec(false, 3, 16, None),
            spec(true, 3, 13, Some(4)),
            spec(true, 1, 8, None),
        ];
        for s in cases {
            let net = Rnn::from_tensors(&s, &random_tensors(&s)).unwrap();
            for kernel in kernels() {
                let mut lean = LeanRnn::new(&net).unwrap();
                lean.set_kernel(kernel);
                let d = max_difference(&net, &mut lean, 300);
                assert!(d <= 1e-5, "{s:?} with {}: differs by {d}", kernel.name());
            }
        }
    }

    /// The comparison above would catch the mistakes a fused layout invites: gates in the wrong
    /// order, one of the two biases dropped, the hidden state not fed back. Each is made in the
    /// weights the lean net is built from, while candle keeps the right ones.
    #[test]
    fn the_comparison_catches_wrong_gates_biases_and_recurrence() {
        let s = spec(true, 2, 37, None);
        let tensors = random_tensors(&s);
        let net = Rnn::from_tensors(&s, &tensors).unwrap();
        let hn = s.hidden;
        // Swap gate blocks a and b (rows a·H… and b·H…) of every gate tensor of layer `k`.
        let swap = |k: usize, a: usize, b: usize| {
            let mut t = tensors.clone();
            for kind in ["weight_ih", "weight_hh", "bias_ih", "bias_hh"] {
                let name = format!("net.rnn.{kind}_l{k}");
                let shape = t[&name].dims().to_vec();
                let cols = t[&name].elem_count() / shape[0];
                let mut v = to_vec(&t[&name]).unwrap();
                for i in 0..hn * cols {
                    v.swap(a * hn * cols + i, b * hn * cols + i);
                }
                t.insert(name, Tensor::from_vec(v, shape, &Device::Cpu).unwrap());
            }
            t
        };
        let zeroed = |name: &str| {
            let mut t = tensors.clone();
            t.insert(name.to_owned(), t[name].zeros_like().unwrap());
            t
        };
        let breakages = [
            ("i and f swapped", swap(0, 0, 1)),
            ("g and o swapped", swap(1, 2, 3)),
            ("bias_hh missing", zeroed("net.rnn.bias_hh_l1")),
            ("no recurrence", zeroed("net.rnn.weight_hh_l0")),
        ];
        let mut lean = LeanRnn::new(&net).unwrap();
        assert!(max_difference(&net, &mut lean, 300) <= 1e-5);
        for (what, broken) in breakages {
            let mut broken = LeanRnn::new(&Rnn::from_tensors(&s, &broken).unwrap()).unwrap();
            let d = max_difference(&net, &mut broken, 300);
            assert!(d > 1e-3, "{what}: only {d} from candle");
        }
    }
}
