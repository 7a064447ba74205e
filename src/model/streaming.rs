//! Streaming inference (the per-sample form of §III-A's Embedding + Generator, or of DIGDL's
//! CNN): one IMU sample in, one corrected gyro sample out, in plain Rust (no tch, no
//! allocation per step), from the eval-mode weights with BatchNorm folded.
//!
//! The networks run in f32 ([`Precision::F32`], the default: the node's path) or in f64
//! ([`Precision::F64`], the reference). The input's normalisation and the gyro calibration
//! `Ĉ_ω ω` are f64 in both; the weights are f32 values in both (the model is trained in f32),
//! so the two differ by arithmetic alone (within the equality tests' 1e-5 rad/s of the
//! TorchScript forward; `imu-fsda bench` times both).
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

use super::kernels::{Activation, ConvWeights, Dense, Networks, StreamConv};
use super::net::{InferenceNet, Net};
use super::{ModelError, INPUT_CHANNELS};
use crate::core::ImuSample;

/// The arithmetic the networks are stepped in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Precision {
    /// f32: the node's, `replay`'s and `eval`'s path.
    #[default]
    F32,
    /// f64: the reference the f32 path is checked against.
    F64,
}

#[derive(Debug, Clone)]
enum SteppedNetworks {
    F32(Networks<f32>),
    F64(Networks<f64>),
}

impl SteppedNetworks {
    fn step(&mut self, imu: &[f64; 6], first: bool) -> [f64; 3] {
        match self {
            SteppedNetworks::F32(n) => n.step(imu, first),
            SteppedNetworks::F64(n) => n.step(imu, first),
        }
    }
}

/// A read-only view of one conv layer's state (as f64).
#[derive(Debug, Clone)]
pub struct LayerHistory {
    /// `[rows][channels]`, a ring: row `newest_row` holds the newest input.
    pub samples: Vec<f64>,
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
    networks: SteppedNetworks,
    receptive_field: usize,
    samples_seen: u64,
    /// The share g of the model's correction applied: `ω + g (ω̂ − ω)` (1: the model as
    /// trained; see [`crate::model::export::ModelMetadata::imu_correction_gains`]).
    correction_gain: f64,
    /// The last layer's weights are all zero (an adaptation that kept the gyro calibration,
    /// alone or with a bias offset in motion): the networks' output is exactly σ ⊙ its bias,
    /// so they are not run (`Ĉ_ω ω + σ ⊙ b`, bit for bit the same).
    constant_correction: Option<Vector3<f64>>,
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

/// The networks of `net` in f32, their shapes checked to chain 6 → embedding (→ [embedding,
/// IMU]) → convs → 3.
fn networks_of(net: &InferenceNet) -> Result<Networks<f32>, ModelError> {
    let n_dense = net.embedding.len() / 2;
    let mut embedding = Vec::with_capacity(n_dense);
    for l in 0..n_dense {
        let (w, b) = (&net.embedding[2 * l], &net.embedding[2 * l + 1]);
        let (n_out, n_in) = (usize_of(w.size()[0]), usize_of(w.size()[1]));
        let activation = if l + 1 < n_dense { Activation::Gelu } else { Activation::Tanh };
        embedding.push(Dense::new(n_in, n_out, &to_vec(w)?, &to_vec(b)?, activation));
    }
    let mut convs = Vec::with_capacity(net.convs.len());
    for layer in &net.convs {
        let size = layer.weight.size();
        let (n_out, n_in, kernel) = (usize_of(size[0]), usize_of(size[1]), usize_of(size[2]));
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
        let (weight, bias) = (to_vec(&layer.weight)?, to_vec(&layer.bias)?);
        let weights = ConvWeights {
            weight: &weight,
            bias: &bias,
            layer_norm: layer_norm.as_ref().map(|(g, b)| (g.as_slice(), b.as_slice())),
            gelu: layer.gelu,
        };
        convs.push(StreamConv::new(n_out, n_in, kernel, usize_of(layer.dilation), weights));
    }
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
    Ok(Networks::new(embedding, generator_sees_imu, convs))
}

impl StreamingDenoiser {
    /// From a trained [`Net`] (eval mode, BatchNorm folded), in f32.
    pub fn from_net(net: &Net) -> Result<Self, ModelError> {
        Self::from_inference(&net.inference())
    }

    /// From the inference form of a model, in f32.
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
        let networks = networks_of(net)?;
        let constant_correction = networks
            .convs
            .last()
            .and_then(StreamConv::constant_output)
            .filter(|b| b.len() == 3)
            .map(|b| scale.component_mul(&Vector3::from_column_slice(&b)));
        let receptive_field = 1 + networks.convs.iter().map(|c| c.rows - 1).sum::<usize>();
        Ok(Self {
            mean,
            inv_std,
            calib,
            scale,
            networks: SteppedNetworks::F32(networks),
            receptive_field,
            samples_seen: 0,
            correction_gain: 1.0,
            constant_correction,
        })
    }

    /// Steps the networks in `precision` from now on (their state carried over).
    pub fn set_precision(&mut self, precision: Precision) {
        match (&self.networks, precision) {
            (SteppedNetworks::F32(n), Precision::F64) => self.networks = SteppedNetworks::F64(n.convert()),
            (SteppedNetworks::F64(n), Precision::F32) => self.networks = SteppedNetworks::F32(n.convert()),
            _ => {}
        }
    }

    /// The arithmetic the networks are stepped in.
    pub fn precision(&self) -> Precision {
        match self.networks {
            SteppedNetworks::F32(_) => Precision::F32,
            SteppedNetworks::F64(_) => Precision::F64,
        }
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

    /// The networks' output is a constant (the gyro calibration, alone or with a bias offset
    /// in motion): they are not run.
    pub fn networks_off(&self) -> bool {
        self.constant_correction.is_some()
    }

    /// Number of conv layers.
    pub fn num_layers(&self) -> usize {
        match &self.networks {
            SteppedNetworks::F32(n) => n.convs.len(),
            SteppedNetworks::F64(n) => n.convs.len(),
        }
    }

    /// The state of conv layer `layer` (None if out of range).
    pub fn layer_history(&self, layer: usize) -> Option<LayerHistory> {
        fn view<T: super::kernels::Real>(c: &StreamConv<T>) -> LayerHistory {
            LayerHistory {
                samples: c.history.iter().map(|v| v.to_f64()).collect(),
                channels: c.n_in,
                newest_row: c.head,
                kernel: c.kernel,
                dilation: c.dilation,
            }
        }
        match &self.networks {
            SteppedNetworks::F32(n) => n.convs.get(layer).map(view),
            SteppedNetworks::F64(n) => n.convs.get(layer).map(view),
        }
    }

    /// One sample: raw gyro (rad/s) and accel (m/s²) in, corrected gyro (rad/s) out. A
    /// non-finite input poisons the state for N samples: reject those first (see
    /// [`StreamingDenoiser::try_step`]).
    pub fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        if let Some(constant) = &self.constant_correction {
            self.samples_seen += 1;
            return apply_correction_gain(gyro, &(self.calib * gyro + constant), self.correction_gain);
        }
        let first = self.samples_seen == 0;
        let mut imu = [0.0; 6];
        for c in 0..3 {
            imu[c] = (gyro[c] - self.mean[c]) * self.inv_std[c];
            imu[c + 3] = (accel[c] - self.mean[c + 3]) * self.inv_std[c + 3];
        }
        let out = self.networks.step(&imu, first);
        self.samples_seen += 1;
        let corrected = self.calib * gyro + self.scale.component_mul(&Vector3::from(out));
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
    fn streaming_equals_batch() {
        tch::set_num_threads(1);
        let samples = random_imu(3000, 7);
        let skip = Config { generator_sees_imu: true, ..Config::for_mode(Mode::FsdaF) };
        let layer_norm = Config { batch_norm: false, layer_norm: true, ..Config::for_mode(Mode::FsdaF) };
        for cfg in [Config::for_mode(Mode::Digdl), Config::for_mode(Mode::FsdaF), skip, layer_norm] {
            let mode = (cfg.mode, cfg.generator_sees_imu);
            let (_vs, net) = random_net_with(&cfg, 11);
            let mut d = StreamingDenoiser::from_net(&net).unwrap();
            assert_eq!(d.precision(), Precision::F32);
            assert_eq!(d.receptive_field() as i64, net.receptive_field());
            let mut reference = d.clone();
            reference.set_precision(Precision::F64);
            let start = std::time::Instant::now();
            let streamed = stream(&mut d, &samples);
            let per_step = start.elapsed().as_secs_f64() / samples.len() as f64;
            let streamed64 = stream(&mut reference, &samples);
            // The f64 reference against the f64 batch forward (same math, different summation
            // order) …
            let inference64 = net.inference().to_kind(Kind::Double);
            let exact = batch(|u| inference64.forward(u), &samples, Kind::Double);
            let d64 = max_abs_diff(&streamed64, &exact);
            // … and the f32 path against the f32 training model in eval mode and the reference.
            let f32_out = batch(|u| net.forward_t(u, false), &samples, Kind::Float);
            let d32 = max_abs_diff(&streamed, &f32_out);
            let d_ref = max_abs_diff(&streamed, &streamed64);
            println!(
                "{mode:?}: f64 streaming vs batch f64 {d64:.2e} rad/s; f32 streaming vs batch f32 {d32:.2e}, vs f64 streaming {d_ref:.2e} rad/s, {:.1} µs/step",
                per_step * 1e6
            );
            assert!(d64 < 1e-12, "{mode:?}: {d64:e}");
            assert!(d32 < 1e-5, "{mode:?}: {d32:e}");
            assert!(d_ref < 1e-5, "{mode:?}: {d_ref:e}");
            assert!(d.is_warm());
            // reset() starts a new sequence: same outputs again.
            d.reset();
            let again = stream(&mut d, &samples[..600]);
            assert_eq!(max_abs_diff(&again, &streamed[..1800]), 0.0);
        }
    }

    /// An adaptation that kept the gyro calibration zeroes the last layer's weights, and its
    /// bias too (alone) or holds the bias offset in motion there: the step skips the networks
    /// and still equals the batch forward.
    #[test]
    fn a_zero_last_layer_skips_the_networks_and_equals_the_batch_forward() {
        tch::set_num_threads(1);
        let samples = random_imu(1000, 3);
        for offset in [[0.0f32; 3], [0.3, -0.1, 0.05]] {
            let (vs, net) = random_net(Mode::FsdaF, 5);
            let last = vs
                .variables()
                .keys()
                .filter_map(|n| n.strip_prefix("generator.conv")?.strip_suffix(".bias")?.parse::<usize>().ok())
                .max()
                .unwrap();
            let vars = vs.variables();
            tch::no_grad(|| {
                let _ = vars[&format!("generator.conv{last}.weight")].shallow_clone().zero_();
                vars[&format!("generator.conv{last}.bias")].shallow_clone().copy_(&Tensor::from_slice(&offset));
                vars["gyro_calib.delta"].shallow_clone().copy_(&(Tensor::randn([3, 3], (Kind::Float, Device::Cpu)) * 0.02));
            });
            let mut d = StreamingDenoiser::from_net(&net).unwrap();
            assert!(d.networks_off());
            assert_eq!(net.correction_networks_off(), offset == [0.0; 3], "the metadata's flag is for an exact 0 only");
            let streamed = stream(&mut d, &samples);
            let inference64 = net.inference().to_kind(Kind::Double);
            let exact = batch(|u| inference64.forward(u), &samples, Kind::Double);
            assert!(max_abs_diff(&streamed, &exact) < 1e-12, "{offset:?}: {:e}", max_abs_diff(&streamed, &exact));
            assert_eq!(d.samples_seen(), samples.len() as u64);
        }
        // A trained last layer is run.
        assert!(!StreamingDenoiser::from_net(&random_net(Mode::FsdaF, 6).1).unwrap().networks_off());
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
