//! The streaming denoiser's layers, one time step at a time: dense layers (the Embedding),
//! causal dilated convolutions with their input rings (the Generator, DIGDL's CNN), channel
//! LayerNorm. Generic over the arithmetic: f32 on the node's path, f64 as the reference.
//!
//! Weights are laid out `[in][out]` (a conv's `[tap][in][out]`) and every output channel is its
//! own accumulation chain, `y[o] += w[i][o] · x[i]`: the compiler vectorises across the outputs
//! without reordering any sum, so a result does not depend on the vector width the CPU has
//! (SSE, AVX2 or NEON give the same bits). So the node's f32 path is stepped in AVX2 where
//! the CPU has it (chosen at run time: the build targets any x86-64), with the same bits as the
//! portable build, which the f64 reference stays in.

use std::fmt::Debug;
use std::ops::{Add, AddAssign, Mul, Sub};

use super::gelu::{gelu, gelu_f32};

/// The arithmetic a network is stepped in.
pub trait Real: Copy + Debug + Default + PartialEq + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + AddAssign {
    fn of(x: f64) -> Self;
    fn to_f64(self) -> f64;
    fn gelu(self) -> Self;
    fn tanh(self) -> Self;
    fn sqrt(self) -> Self;
    fn recip(self) -> Self;
    /// Stepped in the CPU's wider vectors where it has them (the node's f32 path); the f64
    /// reference stays in the portable build.
    const WIDE_VECTORS: bool;
}

impl Real for f64 {
    const WIDE_VECTORS: bool = false;
    fn of(x: f64) -> Self {
        x
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn gelu(self) -> Self {
        gelu(self)
    }
    fn tanh(self) -> Self {
        f64::tanh(self)
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    fn recip(self) -> Self {
        1.0 / self
    }
}

impl Real for f32 {
    const WIDE_VECTORS: bool = true;
    fn of(x: f64) -> Self {
        x as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn gelu(self) -> Self {
        gelu_f32(self)
    }
    fn tanh(self) -> Self {
        f32::tanh(self)
    }
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    fn recip(self) -> Self {
        1.0 / self
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Activation {
    Gelu,
    Tanh,
    Identity,
}

impl Activation {
    #[inline(always)]
    fn apply<T: Real>(self, y: &mut [T]) {
        match self {
            // Plain loops, not `for_each`: inlined into the caller's (wide) build.
            Activation::Gelu => {
                for v in y.iter_mut() {
                    *v = v.gelu();
                }
            }
            Activation::Tanh => {
                for v in y.iter_mut() {
                    *v = v.tanh();
                }
            }
            Activation::Identity => {}
        }
    }
}

/// Output channels accumulated together in registers.
const BLOCK: usize = 16;
/// The same where the CPU has wide vectors (the f32 path): eight 8-wide accumulators, enough
/// independent sums to keep the adders busy while each waits for its last one.
const WIDE_BLOCK: usize = 64;
/// Lanes of the partial sums of an output left over from the blocks.
const LANES: usize = 8;

/// The weights of `y[o] = bias[o] + Σ_s Σ_i x_s[i] · W_s[i][o]` (a dense layer: one term; a
/// conv: one term a tap), laid out for [`AffineWeights::apply`]: on the f32 path blocks of
/// `WIDE_BLOCK` outputs `[block][term][in][WIDE_BLOCK]` first, then blocks of `BLOCK`
/// outputs `[block][term][in][BLOCK]`, then the outputs left over `[o][term][in]`. A block's
/// outputs each sum in the same order whatever the block's size: the layout changes no bit.
#[derive(Debug, Clone)]
struct AffineWeights<T> {
    n_in: usize,
    n_out: usize,
    terms: usize,
    /// Outputs in the wide blocks.
    wide: usize,
    /// Outputs in the wide blocks and the blocks.
    blocked_out: usize,
    weights: Vec<T>,
}

impl<T: Real> AffineWeights<T> {
    /// `w(s, i, o)` = W_s[i][o].
    fn new(n_in: usize, n_out: usize, terms: usize, w: impl Fn(usize, usize, usize) -> f64) -> Self {
        Self::laid_out(n_in, n_out, terms, T::WIDE_VECTORS, w)
    }

    /// With or without the wide blocks.
    fn laid_out(n_in: usize, n_out: usize, terms: usize, wide_blocks: bool, w: impl Fn(usize, usize, usize) -> f64) -> Self {
        let wide = if wide_blocks { n_out / WIDE_BLOCK * WIDE_BLOCK } else { 0 };
        let blocked_out = wide + (n_out - wide) / BLOCK * BLOCK;
        let mut weights = Vec::with_capacity(n_out * terms * n_in);
        let mut blocks = |from: usize, to: usize, size: usize| {
            for b in (from..to).step_by(size) {
                for s in 0..terms {
                    for i in 0..n_in {
                        weights.extend((b..b + size).map(|o| T::of(w(s, i, o))));
                    }
                }
            }
        };
        blocks(0, wide, WIDE_BLOCK);
        blocks(wide, blocked_out, BLOCK);
        for o in blocked_out..n_out {
            for s in 0..terms {
                weights.extend((0..n_in).map(|i| T::of(w(s, i, o))));
            }
        }
        AffineWeights { n_in, n_out, terms, wide, blocked_out, weights }
    }

    /// W_s[i][o], back from the layout.
    fn get(&self, s: usize, i: usize, o: usize) -> T {
        let per_out = self.terms * self.n_in;
        // Blocks of `size` outputs from output `first`, whose weights start at `first · per_out`.
        let in_blocks =
            |first: usize, size: usize| first * per_out + ((o - first) / size * per_out + s * self.n_in + i) * size + (o - first) % size;
        self.weights[if o < self.wide {
            in_blocks(0, WIDE_BLOCK)
        } else if o < self.blocked_out {
            in_blocks(self.wide, BLOCK)
        } else {
            o * per_out + s * self.n_in + i
        }]
    }

    fn is_zero(&self) -> bool {
        self.weights.iter().all(|v| *v == T::default())
    }

    /// The same weights in another arithmetic, laid out for it.
    fn convert<U: Real>(&self) -> AffineWeights<U> {
        AffineWeights::new(self.n_in, self.n_out, self.terms, |s, i, o| self.get(s, i, o).to_f64())
    }

    /// `y = bias + Σ_s x(s) · W_s`. A block's outputs stay in registers over every term and
    /// input, each summed in the plain loop's order; an output left over sums its inputs in
    /// `LANES` partial sums, added in a fixed order at the end. Either way the order is fixed
    /// by the code, not by the vector width.
    #[inline(always)]
    fn apply<'a>(&self, y: &mut [T], bias: &[T], x: impl Fn(usize) -> &'a [T])
    where
        T: 'a,
    {
        let (n_in, terms, wide, blocked_out) = (self.n_in, self.terms, self.wide, self.blocked_out);
        let (wide_weights, rest) = self.weights.split_at(wide * terms * n_in);
        let (block_weights, tail) = rest.split_at((blocked_out - wide) * terms * n_in);
        apply_blocks::<T, WIDE_BLOCK>(&mut y[..wide], wide_weights, &bias[..wide], n_in, &x);
        apply_blocks::<T, BLOCK>(&mut y[wide..blocked_out], block_weights, &bias[wide..blocked_out], n_in, &x);
        for ((yo, wo), bo) in y[blocked_out..].iter_mut().zip(tail.chunks_exact(terms * n_in)).zip(&bias[blocked_out..]) {
            let mut partial = [T::default(); LANES];
            for (s, ws) in wo.chunks_exact(n_in).enumerate() {
                let xs = x(s);
                let (xc, wc) = (xs.chunks_exact(LANES), ws.chunks_exact(LANES));
                let (xr, wr) = (xc.remainder(), wc.remainder());
                for (xa, wa) in xc.zip(wc) {
                    for l in 0..LANES {
                        partial[l] += wa[l] * xa[l];
                    }
                }
                for (l, (xv, wv)) in xr.iter().zip(wr).enumerate() {
                    partial[l] += *wv * *xv;
                }
            }
            let quads = [partial[0] + partial[1], partial[2] + partial[3], partial[4] + partial[5], partial[6] + partial[7]];
            *yo = *bo + ((quads[0] + quads[1]) + (quads[2] + quads[3]));
        }
    }
}

/// Blocks of `N` outputs, `weights` `[block][term][in][N]`: the block's sums held in `N`
/// accumulators over every term and input, each in the plain loop's order.
#[inline(always)]
fn apply_blocks<'a, T: Real + 'a, const N: usize>(y: &mut [T], weights: &[T], bias: &[T], n_in: usize, x: &impl Fn(usize) -> &'a [T]) {
    if y.is_empty() {
        return;
    }
    let block_len = weights.len() / (y.len() / N);
    for ((yb, wb), bb) in y.chunks_exact_mut(N).zip(weights.chunks_exact(block_len)).zip(bias.chunks_exact(N)) {
        let mut acc = [T::default(); N];
        acc.copy_from_slice(bb);
        for (s, ws) in wb.chunks_exact(n_in * N).enumerate() {
            for (xi, wi) in x(s).iter().zip(ws.chunks_exact(N)) {
                let wi: &[T; N] = wi.try_into().expect("a block of N");
                for k in 0..N {
                    acc[k] += wi[k] * *xi;
                }
            }
        }
        yb.copy_from_slice(&acc);
    }
}

/// A dense layer.
#[derive(Debug, Clone)]
pub(crate) struct Dense<T> {
    pub n_in: usize,
    pub n_out: usize,
    weight: AffineWeights<T>,
    bias: Vec<T>,
    activation: Activation,
}

impl<T: Real> Dense<T> {
    /// From torch's `[out][in]` weight.
    pub fn new(n_in: usize, n_out: usize, weight_out_in: &[f64], bias: &[f64], activation: Activation) -> Self {
        let weight = AffineWeights::new(n_in, n_out, 1, |_, i, o| weight_out_in[o * n_in + i]);
        Dense { n_in, n_out, weight, bias: bias.iter().map(|b| T::of(*b)).collect(), activation }
    }

    #[inline(always)]
    fn forward(&self, x: &[T], out: &mut [T]) {
        let y = &mut out[..self.n_out];
        self.weight.apply(y, &self.bias, |_| &x[..self.n_in]);
        self.activation.apply(y);
    }

    fn convert<U: Real>(&self) -> Dense<U> {
        Dense {
            n_in: self.n_in,
            n_out: self.n_out,
            weight: self.weight.convert(),
            bias: self.bias.iter().map(|x| U::of(x.to_f64())).collect(),
            activation: self.activation,
        }
    }
}

/// One causal dilated conv with its input history.
#[derive(Debug, Clone)]
pub(crate) struct StreamConv<T> {
    pub n_in: usize,
    pub n_out: usize,
    pub kernel: usize,
    pub dilation: usize,
    /// One term a tap, tap 0 the oldest input.
    weight: AffineWeights<T>,
    bias: Vec<T>,
    /// Channel LayerNorm's γ and β after the conv (`Config::layer_norm`).
    layer_norm: Option<(Vec<T>, Vec<T>)>,
    activation: Activation,
    /// Ring of the last `rows` inputs, `[rows][n_in]`.
    pub history: Vec<T>,
    pub rows: usize,
    /// Row of the newest input.
    pub head: usize,
}

/// A conv layer's weights as torch holds them (f64 copies).
pub(crate) struct ConvWeights<'a> {
    /// `[out][in][tap]`.
    pub weight: &'a [f64],
    pub bias: &'a [f64],
    pub layer_norm: Option<(&'a [f64], &'a [f64])>,
    pub gelu: bool,
}

impl<T: Real> StreamConv<T> {
    pub fn new(n_out: usize, n_in: usize, kernel: usize, dilation: usize, w: ConvWeights<'_>) -> Self {
        let weight = AffineWeights::new(n_in, n_out, kernel, |tap, i, o| w.weight[(o * n_in + i) * kernel + tap]);
        let rows = (kernel - 1) * dilation + 1;
        let to_t = |v: &[f64]| v.iter().map(|x| T::of(*x)).collect::<Vec<T>>();
        StreamConv {
            n_in,
            n_out,
            kernel,
            dilation,
            weight,
            bias: to_t(w.bias),
            layer_norm: w.layer_norm.map(|(g, b)| (to_t(g), to_t(b))),
            activation: if w.gelu { Activation::Gelu } else { Activation::Identity },
            history: vec![T::default(); rows * n_in],
            rows,
            head: 0,
        }
    }

    /// The layer's output whatever its input, where its weights are all zero and nothing
    /// follows them (no LayerNorm, no activation): its bias. `None` otherwise.
    pub fn constant_output(&self) -> Option<Vec<f64>> {
        (self.weight.is_zero() && self.layer_norm.is_none() && matches!(self.activation, Activation::Identity))
            .then(|| self.bias.iter().map(|b| b.to_f64()).collect())
    }

    /// Advances the ring and returns the slot for the newest input.
    #[inline(always)]
    fn next_slot(&mut self) -> &mut [T] {
        self.head = (self.head + 1) % self.rows;
        let start = self.head * self.n_in;
        &mut self.history[start..start + self.n_in]
    }

    /// Copies the newest input into every row: the state after an infinite constant past.
    fn fill_with_newest(&mut self) {
        let (n, head) = (self.n_in, self.head);
        for row in 0..self.rows {
            if row != head {
                self.history.copy_within(head * n..(head + 1) * n, row * n);
            }
        }
    }

    #[inline(always)]
    fn forward(&self, out: &mut [T]) {
        let y = &mut out[..self.n_out];
        self.weight.apply(y, &self.bias, |tap| {
            let lag = (self.kernel - 1 - tap) * self.dilation;
            // head < rows and lag < rows: one wrap at most (no division in the inner loops).
            let row = self.head + self.rows - lag;
            let row = if row >= self.rows { row - self.rows } else { row };
            &self.history[row * self.n_in..(row + 1) * self.n_in]
        });
        if let Some((gamma, beta)) = &self.layer_norm {
            channel_layer_norm(y, gamma, beta);
        }
        self.activation.apply(y);
    }

    fn convert<U: Real>(&self) -> StreamConv<U> {
        let c = |v: &[T]| v.iter().map(|x| U::of(x.to_f64())).collect::<Vec<U>>();
        StreamConv {
            n_in: self.n_in,
            n_out: self.n_out,
            kernel: self.kernel,
            dilation: self.dilation,
            weight: self.weight.convert(),
            bias: c(&self.bias),
            layer_norm: self.layer_norm.as_ref().map(|(g, b)| (c(g), c(b))),
            activation: self.activation,
            history: c(&self.history),
            rows: self.rows,
            head: self.head,
        }
    }
}

/// `y ← γ (y − mean) / √(var + ε) + β` over the channels of one time step (biased variance,
/// as torch's `layer_norm`).
#[inline(always)]
fn channel_layer_norm<T: Real>(y: &mut [T], gamma: &[T], beta: &[T]) {
    let n = T::of(y.len() as f64).recip();
    let mean = y.iter().fold(T::default(), |s, v| s + *v) * n;
    let var = y.iter().fold(T::default(), |s, v| s + (*v - mean) * (*v - mean)) * n;
    let inv = (var + T::of(super::cnn::LAYER_NORM_EPS)).sqrt().recip();
    for ((v, g), b) in y.iter_mut().zip(gamma).zip(beta) {
        *v = (*v - mean) * inv * *g + *b;
    }
}

/// The networks of one model, stepped one normalised sample at a time: the Embedding's dense
/// layers (none for DIGDL), then the conv stack, ending in 3 channels.
#[derive(Debug, Clone)]
pub(crate) struct Networks<T> {
    pub embedding: Vec<Dense<T>>,
    /// The first conv's input ends with the normalised IMU (`Config::generator_sees_imu`).
    pub generator_sees_imu: bool,
    pub convs: Vec<StreamConv<T>>,
    /// Two halves of `max_width` each: the Embedding's ping-pong buffers.
    scratch: Vec<T>,
    max_width: usize,
    out: [T; 3],
}

impl<T: Real> Networks<T> {
    pub fn new(embedding: Vec<Dense<T>>, generator_sees_imu: bool, convs: Vec<StreamConv<T>>) -> Self {
        let max_width = embedding.iter().map(|d| d.n_out.max(d.n_in)).max().unwrap_or(0).max(6);
        Networks { embedding, generator_sees_imu, convs, scratch: vec![T::default(); 2 * max_width], max_width, out: [T::default(); 3] }
    }

    /// One normalised sample in, the networks' 3 outputs out. `first`: the sample starts a
    /// sequence (every ring is filled with it, as the batch forward's left padding).
    pub fn step(&mut self, imu: &[f64; 6], first: bool) -> [f64; 3] {
        #[cfg(target_arch = "x86_64")]
        if T::WIDE_VECTORS && std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe { self.step_avx2(imu, first) };
        }
        self.step_portable(imu, first)
    }

    /// [`Self::step`] compiled for AVX2: every layer is inlined here, so its loops use the
    /// 8-wide registers. No FMA: a product and its sum stay two roundings, as in the portable
    /// build, and the bits are the same (`tests::the_avx2_step_gives_the_portable_bits`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn step_avx2(&mut self, imu: &[f64; 6], first: bool) -> [f64; 3] {
        self.step_portable(imu, first)
    }

    #[inline(always)]
    fn step_portable(&mut self, imu: &[f64; 6], first: bool) -> [f64; 3] {
        let Self { embedding, generator_sees_imu, convs, scratch, max_width, out } = self;
        let (buf0, buf1) = scratch.split_at_mut(*max_width);
        let imu: [T; 6] = imu.map(T::of);
        buf0[..6].copy_from_slice(&imu);
        {
            let slot = convs[0].next_slot();
            let n = embedding.len();
            if n == 0 {
                slot.copy_from_slice(&buf0[..slot.len()]);
            }
            if *generator_sees_imu {
                let at = slot.len() - imu.len();
                slot[at..].copy_from_slice(&imu);
            }
            for (l, layer) in embedding.iter().enumerate() {
                let (src, dst): (&[T], &mut [T]) = if l % 2 == 0 { (buf0, buf1) } else { (buf1, buf0) };
                if l + 1 == n {
                    layer.forward(src, slot);
                } else {
                    layer.forward(src, dst);
                }
            }
        }
        if first {
            convs[0].fill_with_newest();
        }
        for l in 0..convs.len() {
            let (done, rest) = convs.split_at_mut(l + 1);
            let layer = &done[l];
            match rest.first_mut() {
                Some(next) => {
                    layer.forward(next.next_slot());
                    if first {
                        next.fill_with_newest();
                    }
                }
                None => layer.forward(out),
            }
        }
        out.map(T::to_f64)
    }

    /// The same networks and state in another arithmetic (the weights are f32 values: the
    /// conversion loses nothing of them).
    pub fn convert<U: Real>(&self) -> Networks<U> {
        Networks::new(
            self.embedding.iter().map(Dense::convert).collect(),
            self.generator_sees_imu,
            self.convs.iter().map(StreamConv::convert).collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A network of the bundled model's shape (Embedding 6→32→32→16, convs 22→16→32→64→128→3,
    /// kernel 7, dilations 1, 4, 16, 64, 1; one conv with a channel LayerNorm), its weights
    /// and inputs from a fixed pseudo-random stream.
    fn bundled_shape_networks() -> Networks<f32> {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut values = |n: usize, scale: f64| (0..n).map(|_| next() * scale).collect::<Vec<f64>>();
        let embedding = [(6, 32), (32, 32), (32, 16)]
            .iter()
            .map(|&(i, o)| Dense::new(i, o, &values(i * o, 0.6), &values(o, 0.1), Activation::Gelu))
            .collect();
        let convs = [(22, 16, 1), (16, 32, 4), (32, 64, 16), (64, 128, 64), (128, 3, 1)]
            .iter()
            .enumerate()
            .map(|(l, &(i, o, d))| {
                let (w, b, g, be) = (values(o * i * 7, 0.3), values(o, 0.1), values(o, 1.0), values(o, 0.1));
                let layer_norm = (l == 2).then_some((g.as_slice(), be.as_slice()));
                StreamConv::new(o, i, 7, d, ConvWeights { weight: &w, bias: &b, layer_norm, gelu: o != 3 })
            })
            .collect();
        Networks::new(embedding, true, convs)
    }

    /// The AVX2 build of a step (what the node runs on such a CPU) gives the portable build's
    /// bits: each output's sum keeps its order, and no product is fused with its sum.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_step_gives_the_portable_bits() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("no AVX2 on this CPU: nothing to compare");
            return;
        }
        let (mut wide, mut portable) = (bundled_shape_networks(), bundled_shape_networks());
        for k in 0..3000 {
            let imu: [f64; 6] = std::array::from_fn(|c| ((k * 7 + c * 13) % 29) as f64 * 0.2 - 2.8 + (k as f64 * 0.01).sin());
            // SAFETY: AVX2 was detected above.
            let a = unsafe { wide.step_avx2(&imu, k == 0) };
            let b = portable.step_portable(&imu, k == 0);
            assert!(a.iter().all(|v| v.is_finite() && v.abs() > 0.0), "sample {k}: {a:?}");
            assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "sample {k}: {a:?} vs {b:?}");
        }
    }

    /// Sizes that leave outputs over from the blocks and inputs over from the lanes: the
    /// layout gives every weight back, and `apply` equals the plain double sum.
    #[test]
    fn the_blocked_layout_holds_every_weight_and_sums_them_all() {
        for (n_in, n_out, terms) in [(7, 19, 3), (22, 16, 7), (6, 3, 1), (32, 40, 2), (1, 1, 1), (64, 128, 7), (5, 83, 2)] {
            let w = |s: usize, i: usize, o: usize| ((s * 131 + i * 17 + o * 7) % 23) as f64 / 23.0 - 0.5;
            let weights = AffineWeights::<f64>::new(n_in, n_out, terms, w);
            let xs: Vec<Vec<f64>> = (0..terms).map(|s| (0..n_in).map(|i| ((s * 5 + i * 3) % 11) as f64 * 0.1 - 0.4).collect()).collect();
            let bias: Vec<f64> = (0..n_out).map(|o| o as f64 * 0.01).collect();
            let mut y = vec![0.0; n_out];
            weights.apply(&mut y, &bias, |s| &xs[s]);
            for o in 0..n_out {
                let plain =
                    bias[o] + (0..terms).flat_map(|s| (0..n_in).map(move |i| (s, i))).map(|(s, i)| w(s, i, o) * xs[s][i]).sum::<f64>();
                assert!((y[o] - plain).abs() < 1e-12, "{n_in}×{n_out}×{terms}, output {o}: {} vs {plain}", y[o]);
                for s in 0..terms {
                    for i in 0..n_in {
                        assert_eq!(weights.get(s, i, o), w(s, i, o));
                    }
                }
            }
            // f32 the same sums to f32's precision; converted, the same weights.
            let mut y32 = vec![0.0f32; n_out];
            let (w32, b32) = (weights.convert::<f32>(), bias.iter().map(|b| *b as f32).collect::<Vec<_>>());
            for (s, i, o) in (0..terms).flat_map(|s| (0..n_in).flat_map(move |i| (0..n_out).map(move |o| (s, i, o)))) {
                assert_eq!(w32.get(s, i, o), w(s, i, o) as f32, "f32 layout ({s}, {i}, {o})");
            }
            let x32: Vec<Vec<f32>> = xs.iter().map(|x| x.iter().map(|v| *v as f32).collect()).collect();
            w32.apply(&mut y32, &b32, |s| &x32[s]);
            // Without the wide blocks, the same bits.
            let mut narrow = vec![0.0f32; n_out];
            AffineWeights::<f32>::laid_out(n_in, n_out, terms, false, w).apply(&mut narrow, &b32, |s| &x32[s]);
            assert_eq!(y32.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), narrow.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
            assert!(y32.iter().zip(&y).all(|(a, b)| (*a as f64 - b).abs() < 1e-5), "{y32:?} {y:?}");
        }
    }
}
