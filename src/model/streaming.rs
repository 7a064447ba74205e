//! Streaming inference (the per-sample form of §III-A's Embedding + Generator, or of DIGDL's
//! CNN): one IMU sample in, one corrected gyro sample out, in plain Rust (f64, no tch, no
//! allocation per step), from the eval-mode weights with BatchNorm folded.
//!
//! Each conv layer keeps a ring buffer of its last `(k − 1)·d + 1` input vectors (the
//! state, visible through [`StreamingDenoiser::layer_history`]), so a step costs
//! `Σ_l k_l · C_in,l · C_out,l` multiply-adds whatever the window N.
//!
//! Warm-up: the batch forward pads the sequence on the left with copies of its first sample.
//! A constant input gives every layer a constant output, so the first `step` fills every
//! layer's buffer with the activation of that first sample; from sample 0 on, the stream
//! reproduces the batch forward over the samples seen since the last [`StreamingDenoiser::reset`].

use nalgebra::{Matrix3, Vector3};
use tch::{Kind, Tensor};

use super::cnn::LAYER_NORM_EPS;
use super::net::{InferenceNet, Net};
use super::{ModelError, INPUT_CHANNELS};
use crate::core::ImuSample;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Activation {
    Gelu,
    Tanh,
    Identity,
}

impl Activation {
    fn apply(self, x: f64) -> f64 {
        match self {
            Activation::Gelu => gelu(x),
            Activation::Tanh => x.tanh(),
            Activation::Identity => x,
        }
    }
}

/// A dense layer, row-major `[out][in]` weights.
#[derive(Debug, Clone)]
struct Dense {
    n_in: usize,
    n_out: usize,
    weight: Vec<f64>,
    bias: Vec<f64>,
    activation: Activation,
}

impl Dense {
    fn forward(&self, x: &[f64], out: &mut [f64]) {
        for (o, y) in out[..self.n_out].iter_mut().enumerate() {
            let row = &self.weight[o * self.n_in..(o + 1) * self.n_in];
            *y = self.activation.apply(self.bias[o] + dot(row, &x[..self.n_in]));
        }
    }
}

/// One causal dilated conv with its input history.
#[derive(Debug, Clone)]
struct StreamConv {
    n_in: usize,
    n_out: usize,
    kernel: usize,
    dilation: usize,
    /// `[tap][out][in]`, tap 0 the oldest input.
    weight: Vec<f64>,
    bias: Vec<f64>,
    /// Channel LayerNorm's γ and β after the conv (`Config::layer_norm`).
    layer_norm: Option<(Vec<f64>, Vec<f64>)>,
    activation: Activation,
    /// Ring of the last `rows` inputs, `[rows][n_in]`.
    history: Vec<f64>,
    rows: usize,
    /// Row of the newest input.
    head: usize,
}

impl StreamConv {
    /// Advances the ring and returns the slot for the newest input.
    fn next_slot(&mut self) -> &mut [f64] {
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

    fn forward(&self, out: &mut [f64]) {
        let out = &mut out[..self.n_out];
        out.copy_from_slice(&self.bias);
        for tap in 0..self.kernel {
            let lag = (self.kernel - 1 - tap) * self.dilation;
            let row = (self.head + self.rows - lag) % self.rows;
            let x = &self.history[row * self.n_in..(row + 1) * self.n_in];
            let w = &self.weight[tap * self.n_out * self.n_in..(tap + 1) * self.n_out * self.n_in];
            for (o, y) in out.iter_mut().enumerate() {
                *y += dot(&w[o * self.n_in..(o + 1) * self.n_in], x);
            }
        }
        if let Some((gamma, beta)) = &self.layer_norm {
            channel_layer_norm(out, gamma, beta);
        }
        if self.activation != Activation::Identity {
            for y in out.iter_mut() {
                *y = self.activation.apply(*y);
            }
        }
    }
}

/// A read-only view of one conv layer's state.
#[derive(Debug, Clone, Copy)]
pub struct LayerHistory<'a> {
    /// `[rows][channels]`, a ring: row `newest_row` holds the newest input.
    pub samples: &'a [f64],
    /// Input channels of the layer.
    pub channels: usize,
    /// Ring row of the newest input.
    pub newest_row: usize,
    /// Kernel size and dilation.
    pub kernel: usize,
    pub dilation: usize,
}

/// The per-sample denoiser. Built from trained weights; `step` once per IMU sample.
#[derive(Debug, Clone)]
pub struct StreamingDenoiser {
    mean: [f64; 6],
    inv_std: [f64; 6],
    calib: Matrix3<f64>,
    scale: Vector3<f64>,
    embedding: Vec<Dense>,
    /// The first conv's input ends with the normalised IMU (`Config::generator_sees_imu`).
    generator_sees_imu: bool,
    convs: Vec<StreamConv>,
    receptive_field: usize,
    samples_seen: u64,
    /// Two halves of `max_width` each: the Embedding's ping-pong buffers.
    scratch: Vec<f64>,
    max_width: usize,
    out: [f64; 3],
    /// The share g of the model's correction applied: `ω + g (ω̂ − ω)` (1: the model as
    /// trained; see [`crate::model::export::ModelMetadata::imu_correction_gains`]).
    correction_gain: f64,
    /// The last layer is all zeros (an adaptation that kept the gyro calibration alone): the
    /// networks' output is exactly 0, so they are not run (`Ĉ_ω ω`, bit for bit the same).
    networks_off: bool,
}

/// `ω + g (ω̂ − ω)`: the share `g` of a model's correction `ω̂ − ω` (exactly `ω̂` for g = 1).
pub fn apply_correction_gain(raw: &Vector3<f64>, corrected: &Vector3<f64>, gain: f64) -> Vector3<f64> {
    if gain == 1.0 {
        *corrected
    } else {
        raw + (corrected - raw) * gain
    }
}

fn to_vec(t: &Tensor) -> Result<Vec<f64>, ModelError> {
    Ok(Vec::<f64>::try_from(&t.to_kind(Kind::Double).contiguous().flatten(0, -1))?)
}

fn usize_of(v: i64) -> usize {
    usize::try_from(v).expect("a non-negative size")
}

impl StreamingDenoiser {
    /// From a trained [`Net`] (eval mode, BatchNorm folded).
    pub fn from_net(net: &Net) -> Result<Self, ModelError> {
        Self::from_inference(&net.inference())
    }

    /// From the inference form of a model.
    pub fn from_inference(net: &InferenceNet) -> Result<Self, ModelError> {
        let arr6 = |t: &Tensor| -> Result<[f64; 6], ModelError> {
            let v = to_vec(t)?;
            v.try_into().map_err(|v: Vec<f64>| ModelError::InvalidConfig(format!("normalisation has {} entries, expected 6", v.len())))
        };
        let mean = arr6(&net.mean)?;
        let inv_std = arr6(&net.std)?.map(|s| 1.0 / s);
        let c = to_vec(&net.calib)?;
        let calib = Matrix3::from_row_slice(&c);
        let scale = Vector3::from_column_slice(&to_vec(&net.scale)?);
        let n_dense = net.embedding.len() / 2;
        let mut embedding = Vec::with_capacity(n_dense);
        for l in 0..n_dense {
            let (w, b) = (&net.embedding[2 * l], &net.embedding[2 * l + 1]);
            let (n_out, n_in) = (usize_of(w.size()[0]), usize_of(w.size()[1]));
            let activation = if l + 1 < n_dense { Activation::Gelu } else { Activation::Tanh };
            embedding.push(Dense { n_in, n_out, weight: to_vec(w)?, bias: to_vec(b)?, activation });
        }
        let mut convs = Vec::with_capacity(net.convs.len());
        for layer in &net.convs {
            let size = layer.weight.size();
            let (n_out, n_in, kernel) = (usize_of(size[0]), usize_of(size[1]), usize_of(size[2]));
            let dilation = usize_of(layer.dilation);
            let w = to_vec(&layer.weight)?; // [out][in][tap]
            let mut weight = vec![0.0; w.len()];
            for o in 0..n_out {
                for i in 0..n_in {
                    for tap in 0..kernel {
                        weight[(tap * n_out + o) * n_in + i] = w[(o * n_in + i) * kernel + tap];
                    }
                }
            }
            let rows = (kernel - 1) * dilation + 1;
            let activation = if layer.gelu { Activation::Gelu } else { Activation::Identity };
            let layer_norm = match &layer.layer_norm {
                Some([g, b]) => {
                    let (g, b) = (to_vec(g)?, to_vec(b)?);
                    if g.len() != n_out || b.len() != n_out {
                        return Err(ModelError::InvalidConfig(format!(
                            "layer norm of {} / {} channels after a {n_out}-channel conv",
                            g.len(),
                            b.len()
                        )));
                    }
                    Some((g, b))
                }
                None => None,
            };
            convs.push(StreamConv {
                n_in,
                n_out,
                kernel,
                dilation,
                weight,
                bias: to_vec(&layer.bias)?,
                layer_norm,
                activation,
                history: vec![0.0; rows * n_in],
                rows,
                head: 0,
            });
        }
        // Shapes must chain: 6 → embedding (→ [embedding, IMU]) → convs → 3.
        let mut width = usize_of(INPUT_CHANNELS);
        for d in &embedding {
            if d.n_in != width {
                return Err(ModelError::InvalidConfig(format!("embedding layer expects {} inputs, gets {width}", d.n_in)));
            }
            width = d.n_out;
        }
        let generator_sees_imu = net.generator_sees_imu && !embedding.is_empty();
        if generator_sees_imu {
            width += usize_of(INPUT_CHANNELS);
        }
        for c in &convs {
            if c.n_in != width {
                return Err(ModelError::InvalidConfig(format!("conv layer expects {} inputs, gets {width}", c.n_in)));
            }
            width = c.n_out;
        }
        if width != 3 || convs.is_empty() {
            return Err(ModelError::InvalidConfig(format!("the network ends with {width} channels, expected 3")));
        }
        let networks_off = convs.last().is_some_and(|c| c.weight.iter().chain(&c.bias).all(|v| *v == 0.0));
        let max_width = embedding.iter().map(|d| d.n_out.max(d.n_in)).max().unwrap_or(0).max(6);
        let receptive_field = 1 + convs.iter().map(|c| c.rows - 1).sum::<usize>();
        Ok(Self {
            mean,
            inv_std,
            calib,
            scale,
            embedding,
            generator_sees_imu,
            convs,
            receptive_field,
            samples_seen: 0,
            scratch: vec![0.0; 2 * max_width],
            max_width,
            out: [0.0; 3],
            correction_gain: 1.0,
            networks_off,
        })
    }

    /// Applies the share `gain` of the model's correction from now on (1: all of it).
    pub fn set_correction_gain(&mut self, gain: f64) {
        self.correction_gain = gain;
    }

    /// The share of the model's correction applied ([`StreamingDenoiser::set_correction_gain`]).
    pub fn correction_gain(&self) -> f64 {
        self.correction_gain
    }

    /// Window N, samples.
    pub fn receptive_field(&self) -> usize {
        self.receptive_field
    }

    /// Samples stepped since construction or the last [`StreamingDenoiser::reset`].
    pub fn samples_seen(&self) -> u64 {
        self.samples_seen
    }

    /// True once a full window of real samples has been seen (before that, the window is
    /// completed with copies of the first sample, exactly like the batch forward).
    pub fn is_warm(&self) -> bool {
        self.samples_seen >= self.receptive_field as u64
    }

    /// Forgets the past: the next sample is treated as the first of a sequence.
    pub fn reset(&mut self) {
        self.samples_seen = 0;
    }

    /// Number of conv layers.
    pub fn num_layers(&self) -> usize {
        self.convs.len()
    }

    /// The state of conv layer `layer` (None if out of range).
    pub fn layer_history(&self, layer: usize) -> Option<LayerHistory<'_>> {
        self.convs.get(layer).map(|c| LayerHistory {
            samples: &c.history,
            channels: c.n_in,
            newest_row: c.head,
            kernel: c.kernel,
            dilation: c.dilation,
        })
    }

    /// One sample: raw gyro (rad/s) and accel (m/s²) in, corrected gyro (rad/s) out. A
    /// non-finite input poisons the state for N samples: reject those first (see
    /// [`StreamingDenoiser::try_step`]).
    pub fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        if self.networks_off {
            self.samples_seen += 1;
            return apply_correction_gain(gyro, &(self.calib * gyro), self.correction_gain);
        }
        let first = self.samples_seen == 0;
        let Self { mean, inv_std, embedding, generator_sees_imu, convs, scratch, max_width, out, .. } = self;
        let (buf0, buf1) = scratch.split_at_mut(*max_width);
        let mut imu = [0.0; 6];
        for c in 0..3 {
            imu[c] = (gyro[c] - mean[c]) * inv_std[c];
            imu[c + 3] = (accel[c] - mean[c + 3]) * inv_std[c + 3];
        }
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
                let (src, dst): (&[f64], &mut [f64]) = if l % 2 == 0 { (buf0, buf1) } else { (buf1, buf0) };
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
        self.samples_seen += 1;
        let corrected = self.calib * gyro + self.scale.component_mul(&Vector3::from(self.out));
        apply_correction_gain(gyro, &corrected, self.correction_gain)
    }

    /// [`StreamingDenoiser::step`] on an [`ImuSample`].
    pub fn step_sample(&mut self, sample: &ImuSample) -> Vector3<f64> {
        self.step(&sample.gyro, &sample.accel)
    }

    /// Steps only a finite sample; a non-finite one is refused (`None`) and leaves the state
    /// untouched.
    pub fn try_step(&mut self, sample: &ImuSample) -> Option<Vector3<f64>> {
        sample.is_finite().then(|| self.step_sample(sample))
    }
}

/// `y ← γ (y − mean) / √(var + ε) + β` over the channels of one time step (biased variance,
/// as torch's `layer_norm`).
fn channel_layer_norm(y: &mut [f64], gamma: &[f64], beta: &[f64]) {
    let n = y.len() as f64;
    let mean = y.iter().sum::<f64>() / n;
    let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    let inv = 1.0 / (var + LAYER_NORM_EPS).sqrt();
    for ((v, g), b) in y.iter_mut().zip(gamma).zip(beta) {
        *v = (*v - mean) * inv * g + b;
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    // Four accumulators: lets the compiler vectorise without reassociating one chain.
    let mut acc = [0.0; 4];
    let chunks = a.len() / 4;
    for c in 0..chunks {
        for k in 0..4 {
            acc[k] += a[4 * c + k] * b[4 * c + k];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for k in 4 * chunks..a.len() {
        s += a[k] * b[k];
    }
    s
}

/// Exact GELU, `x Φ(x) = ½ x (1 + erf(x/√2))`, as torch's `gelu(approximate="none")`.
pub fn gelu(x: f64) -> f64 {
    let z = x * std::f64::consts::FRAC_1_SQRT_2;
    if z >= 0.0 {
        0.5 * x * (2.0 - erfc_pos(z))
    } else {
        0.5 * x * erfc_pos(-z)
    }
}

/// The error function, to about 1e-15 absolute.
pub fn erf(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 - erfc_pos(x)
    } else {
        erfc_pos(-x) - 1.0
    }
}

/// erfc(z) for z ≥ 0: a positive-term series for z < 2 (no cancellation inside the sum), the
/// continued fraction beyond (relative accuracy where erfc is tiny, which GELU needs for x ≪ 0).
const ERFC_SWITCH: f64 = 2.0;
const ERFC_CF_TERMS: usize = 100;

fn erfc_pos(z: f64) -> f64 {
    const FRAC_2_SQRT_PI: f64 = std::f64::consts::FRAC_2_SQRT_PI;
    if z.is_nan() {
        return f64::NAN;
    }
    if z < ERFC_SWITCH {
        // erf(z) = 2/√π e^{−z²} Σ_n 2ⁿ z^{2n+1} / (1·3·…·(2n+1)).
        let z2 = z * z;
        let mut term = z;
        let mut sum = z;
        let mut n = 0.0;
        while term > sum * 1e-17 {
            n += 1.0;
            term *= 2.0 * z2 / (2.0 * n + 1.0);
            sum += term;
        }
        1.0 - FRAC_2_SQRT_PI * (-z2).exp() * sum
    } else if z < 27.0 {
        // erfc(z) = e^{−z²}/√π · 1/(z + (1/2)/(z + 1/(z + (3/2)/(z + …)))).
        let mut f = z;
        for k in (1..=ERFC_CF_TERMS).rev() {
            f = z + 0.5 * k as f64 / f;
        }
        (-z * z).exp() / (f * std::f64::consts::PI.sqrt())
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Config, Mode};
    use rand::{Rng, SeedableRng};
    use tch::{nn::VarStore, Device};

    fn random_net(mode: Mode, seed: i64) -> (VarStore, Net) {
        random_net_with(&Config::for_mode(mode), seed)
    }

    fn random_net_with(cfg: &Config, seed: i64) -> (VarStore, Net) {
        tch::manual_seed(seed);
        let vs = VarStore::new(Device::Cpu);
        let net = Net::new(cfg, &vs.root()).unwrap();
        net.set_normalization(&[0.01, -0.02, 0.03, 9.0, 0.1, -0.3], &[0.3, 0.4, 0.2, 1.5, 1.2, 1.1]).unwrap();
        for _ in 0..3 {
            let _ = net.forward_t(&(Tensor::randn([2, 300, 6], (Kind::Float, Device::Cpu)) * 0.5 + 0.2), true);
        }
        // LayerNorm's γ and β away from (1, 0), so a mix-up shows.
        crate::model::cnn::perturb_layer_norms(&vs);
        (vs, net)
    }

    /// A 200 Hz-like motion: slow sinusoids, gravity on x, white noise, seeded.
    pub(crate) fn random_imu(n: usize, seed: u64) -> Vec<[f64; 6]> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|k| {
                let t = k as f64 * 0.005;
                let mut s = [
                    0.5 * (1.3 * t).sin(),
                    0.3 * (0.7 * t + 1.0).sin(),
                    0.8 * (0.4 * t).cos(),
                    9.81 + 0.5 * (2.0 * t).sin(),
                    0.4 * (1.1 * t).cos(),
                    -0.2 + 0.3 * (0.5 * t).sin(),
                ];
                for (c, v) in s.iter_mut().enumerate() {
                    *v += rng.gen_range(-1.0..1.0) * if c < 3 { 0.05 } else { 0.3 };
                }
                s
            })
            .collect()
    }

    fn batch(net_forward: impl Fn(&Tensor) -> Tensor, samples: &[[f64; 6]], kind: Kind) -> Vec<f64> {
        let flat: Vec<f64> = samples.iter().flatten().copied().collect();
        let u = Tensor::from_slice(&flat).reshape([1, samples.len() as i64, 6]).to_kind(kind);
        Vec::<f64>::try_from(&tch::no_grad(|| net_forward(&u)).to_kind(Kind::Double).flatten(0, -1)).unwrap()
    }

    fn stream(d: &mut StreamingDenoiser, samples: &[[f64; 6]]) -> Vec<f64> {
        samples.iter().flat_map(|s| d.step(&Vector3::new(s[0], s[1], s[2]), &Vector3::new(s[3], s[4], s[5])).data.0[0]).collect()
    }

    fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn gelu_matches_torch() {
        let xs: Vec<f64> = (-4000..=4000).map(|i| i as f64 * 0.005).chain([-40.0, -12.0, -8.5, 8.5, 40.0]).collect();
        let t = Tensor::from_slice(&xs).gelu("none");
        let reference = Vec::<f64>::try_from(&t).unwrap();
        let mine: Vec<f64> = xs.iter().map(|&x| gelu(x)).collect();
        for ((x, a), b) in xs.iter().zip(&mine).zip(&reference) {
            assert!((a - b).abs() <= 4e-16 * (1.0 + b.abs()) || (a - b).abs() <= 1e-13 * b.abs(), "gelu({x}): {a} vs torch {b}");
        }
        let zs: Vec<f64> = (0..=600).map(|i| i as f64 * 0.01).collect();
        let reference = Vec::<f64>::try_from(&Tensor::from_slice(&zs).erfc()).unwrap();
        let worst = zs.iter().zip(&reference).map(|(&z, r)| ((erfc_pos(z) - r) / r).abs()).fold(0.0, f64::max);
        println!("erfc: worst relative error {worst:.1e} on [0, 6]");
        assert!(worst < 1e-12);
    }

    #[test]
    fn streaming_equals_batch() {
        tch::set_num_threads(1);
        let samples = random_imu(3000, 7);
        let skip = Config { generator_sees_imu: true, ..Config::for_mode(Mode::FsdaF) };
        let layer_norm = Config { batch_norm: false, layer_norm: true, ..Config::for_mode(Mode::FsdaF) };
        for cfg in [Config::for_mode(Mode::Digdl), Config::for_mode(Mode::FsdaF), skip, layer_norm] {
            let mode = (cfg.mode, cfg.generator_sees_imu);
            let (_vs, net) = random_net_with(&cfg, 11);
            let mut d = StreamingDenoiser::from_net(&net).unwrap();
            assert_eq!(d.receptive_field() as i64, net.receptive_field());
            let start = std::time::Instant::now();
            let streamed = stream(&mut d, &samples);
            let per_step = start.elapsed().as_secs_f64() / samples.len() as f64;
            // Against the f64 batch forward (same math, different summation order) …
            let inference64 = net.inference().to_kind(Kind::Double);
            let exact = batch(|u| inference64.forward(u), &samples, Kind::Double);
            let d64 = max_abs_diff(&streamed, &exact);
            // … and against the f32 training model in eval mode.
            let f32_out = batch(|u| net.forward_t(u, false), &samples, Kind::Float);
            let d32 = max_abs_diff(&streamed, &f32_out);
            println!("{mode:?}: streaming vs batch f64 {d64:.2e} rad/s, vs batch f32 {d32:.2e} rad/s, {:.1} µs/step", per_step * 1e6);
            assert!(d64 < 1e-12, "{mode:?}: {d64:e}");
            assert!(d32 < 1e-5, "{mode:?}: {d32:e}");
            assert!(d.is_warm());
            // reset() starts a new sequence: same outputs again.
            d.reset();
            let again = stream(&mut d, &samples[..600]);
            assert_eq!(max_abs_diff(&again, &streamed[..1800]), 0.0);
        }
    }

    /// An adaptation that kept the gyro calibration alone zeroes the last layer: the step
    /// skips the networks and still equals the batch forward.
    #[test]
    fn a_zero_last_layer_skips_the_networks_and_equals_the_batch_forward() {
        tch::set_num_threads(1);
        let samples = random_imu(1000, 3);
        let (vs, net) = random_net(Mode::FsdaF, 5);
        let last =
            vs.variables().keys().filter_map(|n| n.strip_prefix("generator.conv")?.strip_suffix(".bias")?.parse::<usize>().ok()).max();
        let vars = vs.variables();
        tch::no_grad(|| {
            for part in ["weight", "bias"] {
                let _ = vars[&format!("generator.conv{}.{part}", last.unwrap())].shallow_clone().zero_();
            }
            vars["gyro_calib.delta"].shallow_clone().copy_(&(Tensor::randn([3, 3], (Kind::Float, Device::Cpu)) * 0.02));
        });
        let mut d = StreamingDenoiser::from_net(&net).unwrap();
        assert!(d.networks_off);
        let streamed = stream(&mut d, &samples);
        let inference64 = net.inference().to_kind(Kind::Double);
        let exact = batch(|u| inference64.forward(u), &samples, Kind::Double);
        assert!(max_abs_diff(&streamed, &exact) < 1e-12, "{:e}", max_abs_diff(&streamed, &exact));
        assert_eq!(d.samples_seen(), samples.len() as u64);
        // A trained last layer is run.
        assert!(!StreamingDenoiser::from_net(&random_net(Mode::FsdaF, 6).1).unwrap().networks_off);
    }

    #[test]
    fn streaming_equals_batch_on_euroc() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/euroc/MH_04_difficult/mav0/imu0/data.csv");
        let Ok(text) = std::fs::read_to_string(&path) else {
            eprintln!("SKIPPED streaming_equals_batch_on_euroc: {} not found", path.display());
            return;
        };
        let samples: Vec<[f64; 6]> = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .skip(6000)
            .take(3000)
            .map(|l| {
                let v: Vec<f64> = l.split(',').skip(1).map(|f| f.trim().parse().unwrap()).collect();
                [v[0], v[1], v[2], v[3], v[4], v[5]]
            })
            .collect();
        assert_eq!(samples.len(), 3000);
        let (_vs, net) = random_net(Mode::FsdaF, 12);
        // EuRoC-like normalisation (gravity mostly on x).
        net.set_normalization(&[0.0, 0.0, 0.0, 9.3, 0.0, -1.0], &[0.5, 0.5, 0.5, 1.5, 1.5, 1.5]).unwrap();
        let mut d = StreamingDenoiser::from_net(&net).unwrap();
        let streamed = stream(&mut d, &samples);
        let f32_out = batch(|u| net.forward_t(u, false), &samples, Kind::Float);
        let diff = max_abs_diff(&streamed, &f32_out);
        println!("EuRoC MH_04 slice: streaming vs batch f32 {diff:.2e} rad/s");
        assert!(diff < 1e-5, "{diff:e}");
    }

    #[test]
    fn try_step_refuses_non_finite_input() {
        let (_vs, net) = random_net(Mode::Digdl, 13);
        let mut d = StreamingDenoiser::from_net(&net).unwrap();
        let good = ImuSample { stamp_ns: 0, gyro: Vector3::new(0.1, 0.0, 0.0), accel: Vector3::new(9.8, 0.0, 0.0) };
        let bad = ImuSample { gyro: Vector3::new(f64::NAN, 0.0, 0.0), ..good };
        assert!(d.try_step(&good).is_some());
        assert!(d.try_step(&bad).is_none());
        assert_eq!(d.samples_seen(), 1);
        assert!(d.try_step(&good).unwrap().iter().all(|v| v.is_finite()));
        let h = d.layer_history(0).unwrap();
        assert_eq!(h.samples.len(), ((h.kernel - 1) * h.dilation + 1) * h.channels);
    }
}
