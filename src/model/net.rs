//! The whole model (paper §II eq. (4) `ω̂_n = Ĉ_ω ω_n + ω'_n` and §III-A "Framework"; DIGDL's
//! GyroNet for [`Mode::Digdl`]): raw IMU in, corrected gyro out, with the input normalisation
//! and the output assembly inside the model so the exported file is self-contained.
//!
//! Weight paths under the root:
//! - `input_norm/mean`, `input_norm/std` — `[6]` buffers (not trained): `norm(u) = (u − mean) / std`;
//! - `gyro_calib/delta` — `[3, 3]`, trained: `Ĉ_ω = I + delta` (identity at `delta = 0`; decaying
//!   `delta` pulls Ĉ_ω toward I, not toward 0). With `Config::imu_calibrations` it is a buffer
//!   holding the selected IMU's `Ĉ_ω − I` ([`Net::select_imu`]; zero: an unknown IMU) and
//! - `gyro_calib/per_imu` — `[K, 3, 3]`, trained: `Ĉ_ω − I` of each named IMU;
//! - `output_scale/sigma` — `[3]` buffer, rad/s: σ;
//! - [`Mode::Digdl`]: `digdl/conv{l}`, `digdl/bn{l}`;
//! - FSDA modes: `embedding/fc{l}`, `restructor/conv{l}`, `restructor/bn{l}`, `generator/conv{l}`,
//!   `generator/bn{l}`.
//!
//! [`Net`] is the trainable model (batch statistics, dropout, Restructor, fast weights);
//! [`InferenceNet`] its eval-mode form with BatchNorm folded into the convs, which is what
//! gets traced to TorchScript and what the streaming denoiser is built from.

use tch::nn::{self, ModuleT};
use tch::{Kind, Tensor};

use super::cnn::{folded_forward, folded_receptive_field, FoldedConv};
use super::digdl::DigdlCnn;
use super::embedding::{mlp_forward, Embedding};
use super::generator::Generator;
use super::restructor::Restructor;
use super::{Config, Mode, ModelError, INPUT_CHANNELS, OUTPUT_CHANNELS};

#[derive(Debug)]
enum Body {
    Digdl(DigdlCnn),
    Fsda { embedding: Embedding, restructor: Restructor, generator: Generator },
}

/// The trainable model.
#[derive(Debug)]
pub struct Net {
    cfg: Config,
    input_mean: Tensor,
    input_std: Tensor,
    gyro_calib_delta: Tensor,
    /// `[K, 3, 3]`: `Ĉ_ω − I` per named IMU (`Config::imu_calibrations`).
    gyro_calib_per_imu: Option<Tensor>,
    output_scale: Tensor,
    body: Body,
}

/// What a training forward returns.
#[derive(Debug)]
pub struct NetOutput {
    /// Corrected gyro `ω̂`, `[B, T, 3]`, rad/s.
    pub gyro: Tensor,
    /// The Restructor's reconstruction of `norm(u)`, `[B, T, 6]` (FSDA modes, when asked).
    pub reconstruction: Option<Tensor>,
    /// `norm(u)`, `[B, T, 6]`: the reconstruction target.
    pub input_normalised: Tensor,
    /// The embedding, `[B, T, E]` (FSDA modes), e.g. for a t-SNE.
    pub embedding: Option<Tensor>,
}

/// Options of [`Net::forward_with`].
#[derive(Debug, Clone, Copy, Default)]
pub struct ForwardOptions<'a> {
    /// Training mode: batch statistics in BatchNorm, dropout, Restructor input noise.
    pub train: bool,
    /// Run the Restructor (FSDA modes; ignored for DIGDL).
    pub reconstruct: bool,
    /// Functional parameters for the Embedding (MAML fast weights), ordered as
    /// [`Net::embedding_parameters`]; `None` uses the module's own.
    pub embedding_params: Option<&'a [Tensor]>,
    /// Ĉ_ω per batch element: `[B]` int64 rows of [`Net::gyro_calibration_rows`] (see
    /// [`Net::calibration_row`]); `None` uses [`Net::gyro_calibration`] for all.
    pub calibration_rows: Option<&'a Tensor>,
    /// The embedding `[B, T, E]`, computed elsewhere, in place of the Embedding's output (the
    /// batched MAML step: each task's windows through that task's fast weights). FSDA modes.
    pub embedding: Option<&'a Tensor>,
}

/// Trainable scalars per module, as built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ParameterCounts {
    pub embedding: i64,
    pub restructor: i64,
    pub generator: i64,
    pub digdl: i64,
    /// `gyro_calib/delta` (9), or `gyro_calib/per_imu` (9 per IMU).
    pub gyro_calib: i64,
    /// Everything trained.
    pub total: i64,
    /// What the exported model uses (all but the Restructor), before BatchNorm folding.
    pub inference: i64,
}

impl Net {
    /// Builds the model's variables under `root` (usually `vs.root()`), normalisation at
    /// identity (mean 0, std 1) until [`Net::set_normalization`].
    pub fn new(cfg: &Config, root: &nn::Path) -> Result<Self, ModelError> {
        cfg.validate()?;
        let norm = root / "input_norm";
        let input_mean = norm.zeros_no_train("mean", &[INPUT_CHANNELS]);
        let input_std = norm.ones_no_train("std", &[INPUT_CHANNELS]);
        let calib_init = if cfg.gyro_calib_init_std > 0.0 {
            nn::Init::Randn { mean: 0.0, stdev: cfg.gyro_calib_init_std }
        } else {
            nn::Init::Const(0.0)
        };
        let calib = root / "gyro_calib";
        let (gyro_calib_delta, gyro_calib_per_imu) = match cfg.imu_calibrations.len() as i64 {
            0 => (calib.var("delta", &[3, 3], calib_init), None),
            k => (calib.zeros_no_train("delta", &[3, 3]), Some(calib.var("per_imu", &[k, 3, 3], calib_init))),
        };
        let output_scale = (root / "output_scale").zeros_no_train("sigma", &[OUTPUT_CHANNELS]);
        tch::no_grad(|| output_scale.shallow_clone().copy_(&Tensor::from_slice(&cfg.output_scale_rad_s())));
        let body = match cfg.mode {
            Mode::Digdl => Body::Digdl(DigdlCnn::new(cfg, &(root / "digdl"))),
            Mode::Fsda | Mode::FsdaF => Body::Fsda {
                embedding: Embedding::new(&cfg.embedding, INPUT_CHANNELS, &(root / "embedding")),
                restructor: Restructor::new(cfg, &(root / "restructor")),
                generator: Generator::new(cfg, &(root / "generator")),
            },
        };
        Ok(Self { cfg: cfg.clone(), input_mean, input_std, gyro_calib_delta, gyro_calib_per_imu, output_scale, body })
    }

    /// The hyper-parameters it was built from.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Window N: receptive field of the correction, samples.
    pub fn receptive_field(&self) -> i64 {
        match &self.body {
            Body::Digdl(cnn) => cnn.receptive_field(),
            Body::Fsda { generator, .. } => generator.receptive_field(),
        }
    }

    /// Sets the input normalisation (per channel: gyro x, y, z in rad/s, accel x, y, z in
    /// m/s²), usually the training set's mean and std.
    pub fn set_normalization(&self, mean: &[f64; 6], std: &[f64; 6]) -> Result<(), ModelError> {
        if mean.iter().any(|m| !m.is_finite()) || std.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(ModelError::InvalidConfig(format!("normalisation must be finite with std > 0: mean {mean:?}, std {std:?}")));
        }
        tch::no_grad(|| {
            self.input_mean.shallow_clone().copy_(&Tensor::from_slice(mean));
            self.input_std.shallow_clone().copy_(&Tensor::from_slice(std));
        });
        Ok(())
    }

    /// The input normalisation `(mean, std)`.
    pub fn normalization(&self) -> ([f64; 6], [f64; 6]) {
        let get = |t: &Tensor| {
            let v = Vec::<f64>::try_from(&t.to_kind(Kind::Double)).expect("a [6] buffer");
            [v[0], v[1], v[2], v[3], v[4], v[5]]
        };
        (get(&self.input_mean), get(&self.input_std))
    }

    /// `Ĉ_ω = I + delta`, `[3, 3]`.
    pub fn gyro_calibration(&self) -> Tensor {
        Tensor::eye(3, (self.gyro_calib_delta.kind(), self.gyro_calib_delta.device())) + &self.gyro_calib_delta
    }

    /// The row of [`Net::gyro_calibration_rows`] for recordings of IMU `imu`: 0 (the shared
    /// Ĉ_ω) without per-IMU calibrations; else its index, or K (Ĉ_ω = I) for an unknown IMU.
    pub fn calibration_row(&self, imu: &str) -> i64 {
        let names = &self.cfg.imu_calibrations;
        if names.is_empty() {
            return 0;
        }
        names.iter().position(|n| n == imu).unwrap_or(names.len()) as i64
    }

    /// Every Ĉ_ω the model can use, `[K + 1, 3, 3]`: the K per-IMU matrices then I (an
    /// unknown IMU); without per-IMU calibrations `[Ĉ_ω, I]`.
    pub fn gyro_calibration_rows(&self) -> Tensor {
        let eye = Tensor::eye(3, (self.gyro_calib_delta.kind(), self.gyro_calib_delta.device())).unsqueeze(0);
        match &self.gyro_calib_per_imu {
            Some(per_imu) => Tensor::cat(&[per_imu + &eye, eye], 0),
            None => Tensor::cat(&[self.gyro_calibration().unsqueeze(0), eye], 0),
        }
    }

    /// `Ĉ_ω ω` for `omega: [B, T, 3]`, with Ĉ_ω per batch element when `rows` (`[B]`) is given.
    pub(crate) fn calibrate(&self, omega: &Tensor, rows: Option<&Tensor>) -> Tensor {
        match rows {
            Some(rows) => omega.matmul(&self.gyro_calibration_rows().index_select(0, rows).transpose(1, 2)),
            None => omega.matmul(&self.gyro_calibration().tr()),
        }
    }

    /// Makes IMU `imu`'s Ĉ_ω the one [`Net::gyro_calibration`], the inference net and the
    /// streaming denoiser use (a model with `Config::imu_calibrations` only).
    pub fn select_imu(&self, imu: &str) -> Result<(), ModelError> {
        let names = &self.cfg.imu_calibrations;
        let Some(per_imu) = &self.gyro_calib_per_imu else {
            return Err(ModelError::UnknownImu { name: imu.into(), detail: "this model has one Ĉ_ω shared by every IMU".into() });
        };
        let Some(k) = names.iter().position(|n| n == imu) else {
            return Err(ModelError::UnknownImu { name: imu.into(), detail: format!("the model knows {names:?}") });
        };
        tch::no_grad(|| self.gyro_calib_delta.shallow_clone().copy_(&per_imu.get(k as i64)));
        Ok(())
    }

    /// Ĉ_ω of each named IMU (`Config::imu_calibrations`), row-major.
    pub fn imu_calibration_matrices(&self) -> std::collections::BTreeMap<String, [[f64; 3]; 3]> {
        let rows = tch::no_grad(|| self.gyro_calibration_rows());
        self.cfg.imu_calibrations.iter().enumerate().map(|(k, name)| (name.clone(), matrix3(&rows.get(k as i64)))).collect()
    }

    /// σ, `[3]` rad/s: the scale of the correction CNN's output.
    pub fn output_scale(&self) -> &Tensor {
        &self.output_scale
    }

    /// The Generator's last layer is all zeros (an adaptation that kept the gyro calibration
    /// alone): the networks' correction is exactly 0, the model is `Ĉ_ω ω`.
    pub fn correction_networks_off(&self) -> bool {
        let zero = |t: &Tensor| t.abs().max().double_value(&[]) == 0.0;
        match &self.body {
            Body::Fsda { generator, .. } => generator.folded().last().is_some_and(|l| zero(&l.weight) && zero(&l.bias)),
            Body::Digdl(_) => false,
        }
    }

    /// The Generator's last layer has zero weights and a bias (the adaptation's gyro
    /// calibration with a bias offset in motion): the networks' correction is the constant
    /// σ ⊙ b, rad/s, returned; `None` where it varies or is 0.
    pub fn correction_constant(&self) -> Option<[f64; 3]> {
        let Body::Fsda { generator, .. } = &self.body else { return None };
        let layers = generator.folded();
        let last = layers.last()?;
        let zero = |t: &Tensor| t.abs().max().double_value(&[]) == 0.0;
        if !zero(&last.weight) || zero(&last.bias) || last.layer_norm.is_some() || last.gelu {
            return None;
        }
        let c = Vec::<f64>::try_from(&(tch::no_grad(|| &last.bias * &self.output_scale)).to_kind(Kind::Double)).ok()?;
        (c.len() == 3).then(|| [c[0], c[1], c[2]])
    }

    /// The Embedding (FSDA modes).
    pub fn embedding(&self) -> Option<&Embedding> {
        match &self.body {
            Body::Fsda { embedding, .. } => Some(embedding),
            Body::Digdl(_) => None,
        }
    }

    /// The Embedding's parameters θ_e (shallow clones, gradients shared), in the order
    /// [`ForwardOptions::embedding_params`] expects; empty for DIGDL. For MAML:
    /// `fast = θ_e − α ∇_{θ_e} L_support`, then `forward_with(.., embedding_params: Some(&fast))`.
    pub fn embedding_parameters(&self) -> Vec<Tensor> {
        self.embedding().map(Embedding::parameters).unwrap_or_default()
    }

    /// Names of [`Net::embedding_parameters`] as VarStore paths (`embedding.fc0.weight`, …).
    pub fn embedding_parameter_names(&self) -> Vec<String> {
        self.embedding().map(|e| e.parameter_names().iter().map(|n| format!("embedding.{n}")).collect()).unwrap_or_default()
    }

    /// Trainable scalars per module.
    pub fn parameter_counts(&self) -> ParameterCounts {
        let gyro_calib = self.gyro_calib_per_imu.as_ref().unwrap_or(&self.gyro_calib_delta).numel() as i64;
        let (embedding, restructor, generator, digdl) = match &self.body {
            Body::Digdl(cnn) => (0, 0, 0, cnn.parameter_count()),
            Body::Fsda { embedding, restructor, generator } => {
                (embedding.parameter_count(), restructor.parameter_count(), generator.parameter_count(), 0)
            }
        };
        let total = embedding + restructor + generator + digdl + gyro_calib;
        ParameterCounts { embedding, restructor, generator, digdl, gyro_calib, total, inference: total - restructor }
    }

    /// Checks that `u` is `[B, T, 6]` (B, T ≥ 1) of the weights' kind.
    pub fn check_input(&self, u: &Tensor) -> Result<(), ModelError> {
        check_input(u, self.input_mean.kind())
    }

    /// `norm(u)`, `[B, T, 6]`.
    pub fn normalize(&self, u: &Tensor) -> Tensor {
        (u - &self.input_mean) / &self.input_std
    }

    /// The full forward. `u: [B, T, 6]` raw IMU (rad/s, m/s²).
    pub fn forward_with(&self, u: &Tensor, opts: &ForwardOptions<'_>) -> NetOutput {
        let u_norm = self.normalize(u);
        let (correction, embedding, reconstruction) = match &self.body {
            Body::Digdl(cnn) => (cnn.forward_t(&u_norm, opts.train), None, None),
            Body::Fsda { embedding, restructor, generator } => {
                let e = match (opts.embedding, opts.embedding_params) {
                    (Some(e), _) => e.shallow_clone(),
                    (None, Some(params)) => embedding.forward_with(&u_norm, params),
                    (None, None) => embedding.forward(&u_norm),
                };
                let reconstruction = opts.reconstruct.then(|| restructor.forward_t(&e, opts.train));
                let generator_input = generator_input(&e, &u_norm, self.cfg.generator_sees_imu);
                (generator.forward_t(&generator_input, opts.train), Some(e), reconstruction)
            }
        };
        let omega = u.narrow(2, 0, 3);
        let gyro = self.calibrate(&omega, opts.calibration_rows) + correction * &self.output_scale;
        NetOutput { gyro, reconstruction, input_normalised: u_norm, embedding }
    }

    /// Corrected gyro `[B, T, 3]` from raw IMU `[B, T, 6]` (panics on a bad shape, like tch).
    pub fn forward_t(&self, u: &Tensor, train: bool) -> Tensor {
        self.forward_with(u, &ForwardOptions { train, ..Default::default() }).gyro
    }

    /// Eval-mode forward with the input checked first.
    pub fn try_forward(&self, u: &Tensor) -> Result<Tensor, ModelError> {
        self.check_input(u)?;
        Ok(self.forward_t(u, false))
    }

    /// The eval-mode model with BatchNorm folded into the convs, as detached copies.
    pub fn inference(&self) -> InferenceNet {
        self.inference_with(tch::no_grad(|| self.gyro_calibration().detach()))
    }

    /// [`Net::inference`] with row `row` of [`Net::gyro_calibration_rows`] as Ĉ_ω.
    pub fn inference_for_row(&self, row: i64) -> InferenceNet {
        self.inference_with(tch::no_grad(|| self.gyro_calibration_rows().get(row).detach()))
    }

    fn inference_with(&self, calib: Tensor) -> InferenceNet {
        let (embedding, convs) = match &self.body {
            Body::Digdl(cnn) => (Vec::new(), cnn.folded()),
            Body::Fsda { embedding, generator, .. } => (embedding.detached(), generator.folded()),
        };
        let detach = |t: &Tensor| tch::no_grad(|| t.detach().copy());
        InferenceNet {
            mode: self.cfg.mode,
            mean: detach(&self.input_mean),
            std: detach(&self.input_std),
            calib,
            scale: detach(&self.output_scale),
            left_pad: folded_receptive_field(&convs) - 1,
            embedding,
            generator_sees_imu: self.cfg.generator_sees_imu,
            convs,
        }
    }
}

/// A `[3, 3]` tensor as a row-major array (NaN if it cannot be read).
pub(crate) fn matrix3(t: &Tensor) -> [[f64; 3]; 3] {
    let v = Vec::<f64>::try_from(tch::no_grad(|| t.to_kind(Kind::Double).reshape([9]))).unwrap_or_else(|_| vec![f64::NAN; 9]);
    [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]]
}

/// What the Generator convolves: the embedding, or `[embedding, normalised IMU]`.
pub(crate) fn generator_input(embedding: &Tensor, u_norm: &Tensor, sees_imu: bool) -> Tensor {
    if sees_imu {
        Tensor::cat(&[embedding, u_norm], 2)
    } else {
        embedding.shallow_clone()
    }
}

impl ModuleT for Net {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        Net::forward_t(self, xs, train)
    }
}

fn check_input(u: &Tensor, kind: Kind) -> Result<(), ModelError> {
    let size = u.size();
    if size.len() != 3 || size[2] != INPUT_CHANNELS || size[0] < 1 || size[1] < 1 || u.kind() != kind {
        return Err(ModelError::InputShape {
            expected: format!("[B, T, 6] of {kind:?}, B, T ≥ 1"),
            got: size,
            kind: format!("{:?}", u.kind()),
        });
    }
    Ok(())
}

/// The eval-mode model: no dropout, no Restructor, BatchNorm folded, all tensors detached
/// (so it can be traced without freezing the training VarStore).
#[derive(Debug)]
pub struct InferenceNet {
    /// The mode of the model it came from.
    pub mode: Mode,
    /// `[6]`.
    pub mean: Tensor,
    /// `[6]`.
    pub std: Tensor,
    /// Ĉ_ω, `[3, 3]`.
    pub calib: Tensor,
    /// σ, `[3]`, rad/s.
    pub scale: Tensor,
    /// Embedding parameters `[w0, b0, …]` (empty for DIGDL).
    pub embedding: Vec<Tensor>,
    /// The Generator's input is `[embedding, normalised IMU]` (`Config::generator_sees_imu`).
    pub generator_sees_imu: bool,
    /// The Generator's (or DIGDL's) convs, BatchNorm folded.
    pub convs: Vec<FoldedConv>,
    left_pad: i64,
}

impl InferenceNet {
    /// Receptive field N, samples.
    pub fn receptive_field(&self) -> i64 {
        self.left_pad + 1
    }

    /// Kind of the weights (inputs must match).
    pub fn kind(&self) -> Kind {
        self.mean.kind()
    }

    /// `[B, T, 6]` raw IMU → `[B, T, 3]` corrected gyro, rad/s.
    pub fn forward(&self, u: &Tensor) -> Tensor {
        let x = (u - &self.mean) / &self.std;
        let h = if self.embedding.is_empty() { x } else { generator_input(&mlp_forward(&x, &self.embedding), &x, self.generator_sees_imu) };
        let correction = folded_forward(&self.convs, self.left_pad, &h.transpose(1, 2)).transpose(1, 2);
        u.narrow(2, 0, 3).matmul(&self.calib.tr()) + correction * &self.scale
    }

    /// Eval forward with the input checked first.
    pub fn try_forward(&self, u: &Tensor) -> Result<Tensor, ModelError> {
        check_input(u, self.kind())?;
        Ok(tch::no_grad(|| self.forward(u)))
    }

    /// A copy with every tensor cast to `kind` (e.g. `Kind::Double` for reference outputs).
    pub fn to_kind(&self, kind: Kind) -> Self {
        let c = |t: &Tensor| t.to_kind(kind);
        Self {
            mode: self.mode,
            mean: c(&self.mean),
            std: c(&self.std),
            calib: c(&self.calib),
            scale: c(&self.scale),
            embedding: self.embedding.iter().map(c).collect(),
            generator_sees_imu: self.generator_sees_imu,
            convs: self
                .convs
                .iter()
                .map(|l| FoldedConv {
                    weight: c(&l.weight),
                    bias: c(&l.bias),
                    dilation: l.dilation,
                    layer_norm: l.layer_norm.as_ref().map(|[g, b]| [c(g), c(b)]),
                    gelu: l.gelu,
                })
                .collect(),
            left_pad: self.left_pad,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use tch::{nn::VarStore, Device};

    /// A net with non-trivial BatchNorm statistics and normalisation, seeded.
    pub(crate) fn random_net(mode: Mode, seed: i64, kind: Kind) -> (VarStore, Net) {
        random_net_with(&Config::for_mode(mode), seed, kind)
    }

    fn random_net_with(cfg: &Config, seed: i64, kind: Kind) -> (VarStore, Net) {
        tch::manual_seed(seed);
        let mut vs = VarStore::new(Device::Cpu);
        let net = Net::new(cfg, &vs.root()).unwrap();
        if kind == Kind::Double {
            vs.double();
        }
        net.set_normalization(&[0.01, -0.02, 0.03, 9.0, 0.1, -0.3], &[0.3, 0.4, 0.2, 1.5, 1.2, 1.1]).unwrap();
        // A few training-mode forwards move the running statistics away from (0, 1).
        for _ in 0..3 {
            let u = Tensor::randn([2, 300, 6], (kind, Device::Cpu)) * 0.5 + 0.2;
            let _ = net.forward_t(&u, true);
        }
        (vs, net)
    }

    #[test]
    fn receptive_fields() {
        assert_eq!(Config::for_mode(Mode::Digdl).receptive_field(), 511);
        assert_eq!(Config::for_mode(Mode::Fsda).receptive_field(), 517);
        assert_eq!(Config::for_mode(Mode::FsdaF).receptive_field(), 517);
    }

    #[test]
    fn shapes_and_causality() {
        for mode in [Mode::Digdl, Mode::FsdaF] {
            let (_vs, net) = random_net(mode, 1, Kind::Double);
            let u = Tensor::randn([2, 700, 6], (Kind::Double, Device::Cpu));
            let out =
                net.forward_with(&u, &ForwardOptions { train: false, reconstruct: true, embedding_params: None, ..Default::default() });
            assert_eq!(out.gyro.size(), [2, 700, 3]);
            if mode.has_embedding() {
                assert_eq!(out.reconstruction.as_ref().unwrap().size(), [2, 700, 6]);
            }
            // Changing the future does not change the past.
            let u2 = u.copy();
            let _ = u2.narrow(1, 400, 300).fill_(3.0);
            let y2 = net.forward_t(&u2, false);
            let diff = (out.gyro.narrow(1, 0, 400) - y2.narrow(1, 0, 400)).abs().max().double_value(&[]);
            assert_eq!(diff, 0.0, "{mode:?}: output depends on the future");
            // And the receptive field is exactly N: a change at 0 reaches n = N − 1, not n = N.
            let n = net.receptive_field();
            let u3 = u.copy();
            let _ = u3.narrow(1, 0, 1).fill_(3.0);
            let y3 = net.forward_t(&u3, false);
            let at = |t: i64| (out.gyro.narrow(1, t, 1) - y3.narrow(1, t, 1)).abs().max().double_value(&[]);
            assert!(at(n - 1) > 0.0, "{mode:?}: n = N − 1 must see sample 0");
            assert_eq!(at(n), 0.0, "{mode:?}: n = N must not see sample 0");
        }
    }

    #[test]
    fn folding_matches_eval_forward() {
        for mode in [Mode::Digdl, Mode::Fsda] {
            let (_vs, net) = random_net(mode, 2, Kind::Double);
            let u = Tensor::randn([1, 900, 6], (Kind::Double, Device::Cpu));
            let a = net.forward_t(&u, false);
            let b = net.inference().forward(&u);
            let diff = (a - b).abs().max().double_value(&[]);
            assert!(diff < 1e-12, "{mode:?}: folded vs eval {diff:e}");
        }
    }

    /// `batch_norm: false` with `restructor_batch_norm: true`: BatchNorm in the training-only
    /// Restructor alone, so the deployed network holds no batch statistics and its eval-mode
    /// output is the same whatever batches the training forwards saw.
    #[test]
    fn batch_norm_in_the_restructor_alone() {
        let cfg = Config { batch_norm: false, restructor_batch_norm: Some(true), ..Config::for_mode(Mode::FsdaF) };
        let (vs, net) = random_net_with(&cfg, 3, Kind::Double);
        let names: Vec<String> = vs.variables().into_keys().collect();
        assert!(names.iter().any(|n| n.starts_with("restructor.bn")), "{names:?}");
        assert!(!names.iter().any(|n| n.starts_with("generator.bn")), "{names:?}");
        let u = Tensor::randn([1, 900, 6], (Kind::Double, Device::Cpu));
        let before = net.forward_t(&u, false);
        let diff = (&before - net.inference().forward(&u)).abs().max().double_value(&[]);
        assert!(diff < 1e-12, "folded vs eval {diff:e}");
        let _ = net.forward_t(&(Tensor::randn([2, 300, 6], (Kind::Double, Device::Cpu)) * 3.0), true);
        assert_eq!((net.forward_t(&u, false) - before).abs().max().double_value(&[]), 0.0);
        // Metadata written before the key existed reads as "as batch_norm".
        let mut old = serde_json::to_value(Config::for_mode(Mode::FsdaF)).unwrap();
        old.as_object_mut().unwrap().remove("restructor_batch_norm");
        assert_eq!(serde_json::from_value::<Config>(old).unwrap().restructor_batch_norm, None);
        assert_eq!(serde_json::from_str::<Config>(&serde_json::to_string(&cfg).unwrap()).unwrap(), cfg);
    }

    /// `layer_norm: true`: a channel LayerNorm after every hidden conv of the three CNNs in
    /// place of BatchNorm. The inference form keeps it (equal to the eval forward), the
    /// output holds no batch statistics, stays causal, and the config reads back; LayerNorm
    /// with BatchNorm is refused, and so is `restructor_batch_norm` in DIGDL.
    #[test]
    fn channel_layer_norm_in_place_of_batch_norm() {
        for mode in [Mode::Digdl, Mode::FsdaF] {
            let cfg = Config { batch_norm: false, layer_norm: true, ..Config::for_mode(mode) };
            let (vs, net) = random_net_with(&cfg, 4, Kind::Double);
            let names: Vec<String> = vs.variables().into_keys().collect();
            assert!(!names.iter().any(|n| n.contains(".bn")), "{names:?}");
            let prefixes: &[&str] = if mode == Mode::Digdl { &["digdl"] } else { &["generator", "restructor"] };
            for p in prefixes {
                let cnn = if *p == "digdl" { &cfg.digdl } else { &cfg.generator };
                let hidden = cnn.kernel_sizes.len() - 1;
                assert_eq!(names.iter().filter(|n| n.starts_with(&format!("{p}.ln"))).count(), 2 * hidden, "{p}: {names:?}");
            }
            let plain = Net::new(&Config { batch_norm: false, ..Config::for_mode(mode) }, &VarStore::new(Device::Cpu).root()).unwrap();
            let width: i64 =
                if mode == Mode::Digdl { cfg.digdl.hidden_channels.iter().sum() } else { cfg.generator.hidden_channels.iter().sum() };
            let (a, b) = (net.parameter_counts(), plain.parameter_counts());
            assert_eq!(a.generator + a.digdl - b.generator - b.digdl, 2 * width, "{mode:?}: γ and β per hidden channel");
            assert_eq!(a.total, vs.trainable_variables().iter().map(|t| t.numel() as i64).sum::<i64>());
            // Non-trivial γ and β, so a mix-up of the two or a missing norm shows.
            crate::model::cnn::perturb_layer_norms(&vs);
            let u = Tensor::randn([2, 900, 6], (Kind::Double, Device::Cpu));
            let before = net.forward_t(&u, false);
            let diff = (&before - net.inference().forward(&u)).abs().max().double_value(&[]);
            assert!(diff < 1e-12, "{mode:?}: inference vs eval {diff:e}");
            let _ = net.forward_t(&(Tensor::randn([2, 300, 6], (Kind::Double, Device::Cpu)) * 3.0), true);
            assert_eq!((net.forward_t(&u, false) - &before).abs().max().double_value(&[]), 0.0, "{mode:?}: batch statistics");
            // One batch element does not see the other, and the future is not seen.
            let alone = net.forward_t(&u.narrow(0, 1, 1).narrow(1, 0, 500), false);
            let diff = (alone - before.narrow(0, 1, 1).narrow(1, 0, 500)).abs().max().double_value(&[]);
            assert!(diff < 1e-12, "{mode:?}: {diff:e}");
            assert_eq!(serde_json::from_str::<Config>(&serde_json::to_string(&cfg).unwrap()).unwrap(), cfg);
        }
        let both = Config { layer_norm: true, ..Config::for_mode(Mode::FsdaF) };
        assert!(matches!(both.validate(), Err(ModelError::InvalidConfig(m)) if m.contains("layer_norm")));
        let digdl = Config { restructor_batch_norm: Some(true), ..Config::for_mode(Mode::Digdl) };
        assert!(matches!(digdl.validate(), Err(ModelError::InvalidConfig(m)) if m.contains("restructor_batch_norm")));
        // Metadata written before the key existed reads as no LayerNorm.
        let mut old = serde_json::to_value(Config::for_mode(Mode::FsdaF)).unwrap();
        old.as_object_mut().unwrap().remove("layer_norm");
        assert!(!serde_json::from_value::<Config>(old).unwrap().layer_norm);
    }

    /// The skip connection around the Embedding: the Generator gets 6 more input channels,
    /// folding is exact, and with the embedding held constant the IMU still reaches the
    /// output through the skip alone, causally and over exactly N samples.
    #[test]
    fn generator_sees_imu_skip_connection() {
        let cfg = Config { generator_sees_imu: true, ..Config::for_mode(Mode::FsdaF) };
        let (vs, net) = random_net_with(&cfg, 5, Kind::Double);
        let plain = Net::new(&Config::for_mode(Mode::FsdaF), &VarStore::new(Device::Cpu).root()).unwrap();
        assert_eq!(net.parameter_counts().generator - plain.parameter_counts().generator, 6 * 16 * 7);
        assert_eq!(net.receptive_field(), 517);
        let u = Tensor::randn([1, 1200, 6], (Kind::Double, Device::Cpu));
        let a = net.forward_t(&u, false);
        let diff = (&a - net.inference().forward(&u)).abs().max().double_value(&[]);
        assert!(diff < 1e-12, "folded vs eval {diff:e}");
        // With the Embedding's output layer at zero the embedding is constant (tanh 0):
        // a change of the input can only reach the output through the skip.
        tch::no_grad(|| {
            for (name, t) in vs.variables() {
                if name.starts_with("embedding.fc2") {
                    let _ = t.shallow_clone().zero_();
                }
            }
        });
        let u2 = u.copy();
        let _ = u2.narrow(1, 500, 1).fill_(2.0);
        let change = net.forward_t(&u, false) - net.forward_t(&u2, false);
        assert_eq!(change.narrow(1, 0, 500).abs().max().double_value(&[]), 0.0, "the output depends on the future");
        let d = change.narrow(1, 501, 10).abs().max().double_value(&[]);
        assert!(d > 0.0, "the skip connection carries the IMU to the Generator");
        assert_eq!(change.narrow(1, 500 + 517, 1200 - 500 - 517).abs().max().double_value(&[]), 0.0, "seen beyond N samples");
        let digdl = Config { generator_sees_imu: true, ..Config::for_mode(Mode::Digdl) };
        assert!(matches!(digdl.validate(), Err(ModelError::InvalidConfig(_))));
    }

    /// Per-IMU Ĉ_ω: each batch element gets its IMU's matrix, an unknown IMU the identity,
    /// and selecting an IMU makes the inference net use its matrix.
    #[test]
    fn per_imu_gyro_calibrations() {
        let cfg = Config { imu_calibrations: vec!["euroc".into(), "tumvi".into()], ..Config::for_mode(Mode::FsdaF) };
        let (vs, net) = random_net_with(&cfg, 6, Kind::Double);
        assert_eq!(net.parameter_counts().gyro_calib, 18);
        let trainable: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
        assert_eq!(net.parameter_counts().total, trainable, "the selected Ĉ_ω is a buffer");
        let per_imu = vs.variables()["gyro_calib.per_imu"].shallow_clone();
        tch::no_grad(|| {
            per_imu.get(0).copy_(&Tensor::from_slice(&[0.1, 0.0, 0.0, 0.0, -0.05, 0.02, 0.0, 0.0, 0.2]).reshape([3, 3]));
            per_imu.get(1).copy_(&(Tensor::eye(3, (Kind::Double, Device::Cpu)) * -0.01));
        });
        assert_eq!([net.calibration_row("euroc"), net.calibration_row("tumvi"), net.calibration_row("robot")], [0, 1, 2]);
        let u = Tensor::randn([3, 600, 6], (Kind::Double, Device::Cpu));
        let rows = Tensor::from_slice(&[0i64, 1, 2]);
        let opts = ForwardOptions { calibration_rows: Some(&rows), ..Default::default() };
        let batched = net.forward_with(&u, &opts).gyro;
        let plain = net.forward_t(&u, false);
        let omega = u.narrow(2, 0, 3);
        for (b, name) in ["euroc", "tumvi"].iter().enumerate() {
            let b = b as i64;
            let c = net.gyro_calibration_rows().get(b);
            let expect = plain.get(b) + omega.get(b).matmul(&(&c - Tensor::eye(3, (Kind::Double, Device::Cpu))).tr());
            assert!((batched.get(b) - &expect).abs().max().double_value(&[]) < 1e-12, "{name}");
            net.select_imu(name).unwrap();
            let inf = net.inference().forward(&u.narrow(0, b, 1));
            assert!((inf.squeeze_dim(0) - &expect).abs().max().double_value(&[]) < 1e-12, "{name}: selected");
            assert!((net.inference_for_row(b).forward(&u.narrow(0, b, 1)).squeeze_dim(0) - &expect).abs().max().double_value(&[]) < 1e-12);
        }
        // Unselected (row K): Ĉ_ω = I, the same as the freshly built model's output.
        assert!((batched.get(2) - plain.get(2)).abs().max().double_value(&[]) < 1e-12);
        let m = net.imu_calibration_matrices();
        assert!((m["euroc"][0][0] - 1.1).abs() < 1e-12 && (m["tumvi"][2][2] - 0.99).abs() < 1e-12, "{m:?}");
        assert!(matches!(net.select_imu("robot"), Err(ModelError::UnknownImu { .. })));
        let (_vs, shared) = random_net(Mode::FsdaF, 7, Kind::Double);
        assert!(matches!(shared.select_imu("euroc"), Err(ModelError::UnknownImu { .. })));
        assert_eq!(shared.calibration_row("euroc"), 0);
        let dup = Config { imu_calibrations: vec!["a".into(), "a".into()], ..Config::for_mode(Mode::FsdaF) };
        assert!(matches!(dup.validate(), Err(ModelError::InvalidConfig(_))));
    }

    #[test]
    fn calibration_starts_at_identity_and_input_is_checked() {
        let (_vs, net) = random_net(Mode::Fsda, 3, Kind::Float);
        let c = net.gyro_calibration();
        assert_eq!((c - Tensor::eye(3, (Kind::Float, Device::Cpu))).abs().max().double_value(&[]), 0.0);
        let bad = Tensor::zeros([1, 10, 5], (Kind::Float, Device::Cpu));
        assert!(matches!(net.try_forward(&bad), Err(ModelError::InputShape { .. })));
        let bad_kind = Tensor::zeros([1, 10, 6], (Kind::Double, Device::Cpu));
        assert!(matches!(net.try_forward(&bad_kind), Err(ModelError::InputShape { .. })));
    }

    #[test]
    fn parameter_counts_match_the_var_store() {
        for mode in [Mode::Digdl, Mode::Fsda] {
            tch::manual_seed(0);
            let vs = VarStore::new(Device::Cpu);
            let net = Net::new(&Config::for_mode(mode), &vs.root()).unwrap();
            let counts = net.parameter_counts();
            let trainable: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
            assert_eq!(counts.total, trainable);
            println!("{mode:?}: {counts:?}, receptive field {}", net.receptive_field());
        }
    }

    /// Second-order MAML through the fast-weight path: inner step with `create_graph`, outer
    /// gradient reaches θ_e and the Generator, all finite.
    #[test]
    fn maml_fast_weights_second_order() {
        let (vs, net) = random_net(Mode::FsdaF, 4, Kind::Double);
        let u = Tensor::randn([1, 64, 6], (Kind::Double, Device::Cpu));
        let theta = net.embedding_parameters();
        assert_eq!(theta.len(), net.embedding_parameter_names().len());
        let names = vs.variables();
        for n in net.embedding_parameter_names() {
            assert!(names.contains_key(&n), "{n} not in the VarStore");
        }
        let support =
            net.forward_with(&u, &ForwardOptions { train: false, reconstruct: true, embedding_params: None, ..Default::default() });
        let loss = (support.reconstruction.unwrap() - &support.input_normalised).square().mean(None) + support.gyro.square().mean(None);
        let grads = Tensor::run_backward(&[&loss], &theta, true, true);
        let fast: Vec<Tensor> = theta.iter().zip(&grads).map(|(p, g)| p - g * 0.01).collect();
        let query =
            net.forward_with(&u, &ForwardOptions { train: false, reconstruct: false, embedding_params: Some(&fast), ..Default::default() });
        let outer = query.gyro.square().mean(None);
        outer.backward();
        for (name, t) in vs.variables() {
            if t.requires_grad() && (name.starts_with("embedding") || name.starts_with("generator.conv")) {
                let g = t.grad();
                assert!(g.defined(), "{name}: no gradient");
                assert!(bool::try_from(g.isfinite().all()).unwrap(), "{name}: non-finite gradient");
            }
        }
    }
}
