//! The denoising networks (paper §III "Few-shot domain adaptation", and DIGDL, Brossard et
//! al. RA-L 2020, as the baseline), in tch, with a pure-Rust streaming form for the node.
//!
//! Every mode maps a window of raw IMU samples `u_n = [ω_n; a_n]` (rad/s, m/s²) to a
//! corrected angular velocity `ω̂_n = Ĉ_ω ω_n + ω'_n` (rad/s), causally: `ω̂_n` depends on
//! `u_{n−N+1} … u_n` only, `N` the receptive field ([`Config::receptive_field`]).
//!
//! | mode | correction `ω'_n` | extra training-only branch |
//! |---|---|---|
//! | [`Mode::Digdl`] | `σ ⊙ CNN(norm(u))` (DIGDL's GyroNet) | — |
//! | [`Mode::Fsda`], [`Mode::FsdaF`] | `σ ⊙ Generator(Embedding(norm(u)))` | Restructor reconstructs `norm(u)` |
//!
//! FSDA and FSDA-F share the network; they differ in training only (FSDA-F adapts the
//! Embedding with MAML, see `src/train/`).
//!
//! Files, bottom to top: [`cnn`] (the shared dilated causal CNN), [`embedding`],
//! [`restructor`], [`generator`], [`digdl`], [`net`] (the whole model, batch `forward`),
//! [`so3_tensor`], [`loss`], [`export`] (TorchScript / weights / metadata, and loading),
//! [`streaming`] (per-sample `step`, no tch).
//!
//! ```no_run
//! use imu_fsda::model::{export, Config, Mode, Net};
//! use tch::{nn::VarStore, Device, Kind, Tensor};
//!
//! let cfg = Config::for_mode(Mode::FsdaF);
//! let vs = VarStore::new(Device::Cpu);
//! let net = Net::new(&cfg, &vs.root()).unwrap();
//! let u = Tensor::zeros([1, 2000, 6], (Kind::Float, Device::Cpu)); // raw IMU, [B, T, 6]
//! let omega_hat = net.try_forward(&u).unwrap(); // [B, T, 3], rad/s
//! # let _ = omega_hat;
//! let files = export::export_model(std::path::Path::new("models"), "demo", &vs, &net, &export::ExportInfo::default()).unwrap();
//! let (mut denoiser, _meta) = export::load_streaming(&files.metadata, None).unwrap();
//! let w = denoiser.step(&nalgebra::Vector3::zeros(), &nalgebra::Vector3::new(9.81, 0.0, 0.0));
//! # let _ = w;
//! ```

pub mod cnn;
pub mod digdl;
pub mod embedding;
pub mod export;
pub mod gelu;
pub mod generator;
pub mod kernels;
pub mod loss;
pub mod net;
pub mod predict;
pub mod restructor;
pub mod so3_tensor;
pub mod streaming;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

pub use export::{ExportInfo, ExportPaths, LoadedNet, ModelMetadata, TorchScriptModel};
pub use loss::{LossConfig, LossTerms};
pub use net::{ForwardOptions, InferenceNet, Net, NetOutput, ParameterCounts};
pub use streaming::{Precision, StreamingDenoiser};

/// Number of input channels: gyro x, y, z (rad/s), then accel x, y, z (m/s²).
pub const INPUT_CHANNELS: i64 = 6;
/// Number of output channels: corrected gyro x, y, z (rad/s).
pub const OUTPUT_CHANNELS: i64 = 3;

/// Which model (and, for the trainer, which training strategy).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// DIGDL (Brossard et al. 2020): one dilated CNN on the normalised IMU.
    Digdl,
    /// The paper's framework (Embedding + Restructor + Generator), trained without MAML.
    Fsda,
    /// The same network, trained with the few-shot (MAML) strategy on the Embedding.
    #[default]
    FsdaF,
}

impl Mode {
    /// True for the two modes with Embedding, Restructor and Generator.
    pub fn has_embedding(self) -> bool {
        !matches!(self, Mode::Digdl)
    }
}

/// Shape of one dilated causal CNN: `kernel_sizes.len()` conv layers; every layer but the
/// last is followed by (BatchNorm,) GELU and Dropout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CnnConfig {
    /// Output channels of the hidden layers; one entry fewer than `kernel_sizes`.
    pub hidden_channels: Vec<i64>,
    /// Kernel size of each layer (samples).
    pub kernel_sizes: Vec<i64>,
    /// Dilation of each layer (samples).
    pub dilations: Vec<i64>,
}

impl CnnConfig {
    /// DIGDL's CNN: 16, 32, 64, 128 channels, kernels 7,7,7,7 and a 1×1 output layer,
    /// dilations 1, 4, 16, 64 (receptive field 511).
    pub fn digdl() -> Self {
        Self { hidden_channels: vec![16, 32, 64, 128], kernel_sizes: vec![7, 7, 7, 7, 1], dilations: vec![1, 4, 16, 64, 1] }
    }

    /// The paper's Generator / Restructor: five layers, all kernel 7, dilations 1, 4, 16, 64, 1
    /// (receptive field 517); DIGDL's widths for the hidden layers.
    pub fn fsda() -> Self {
        Self { hidden_channels: vec![16, 32, 64, 128], kernel_sizes: vec![7; 5], dilations: vec![1, 4, 16, 64, 1] }
    }

    /// Receptive field in samples: `1 + Σ_l (k_l − 1) d_l`.
    pub fn receptive_field(&self) -> i64 {
        1 + self.kernel_sizes.iter().zip(&self.dilations).map(|(k, d)| (k - 1) * d).sum::<i64>()
    }

    fn validate(&self, what: &str) -> Result<(), ModelError> {
        let bad = |msg: String| Err(ModelError::InvalidConfig(format!("{what}: {msg}")));
        if self.kernel_sizes.is_empty() {
            return bad("no layers".into());
        }
        if self.dilations.len() != self.kernel_sizes.len() {
            return bad(format!("{} dilations for {} layers", self.dilations.len(), self.kernel_sizes.len()));
        }
        if self.hidden_channels.len() + 1 != self.kernel_sizes.len() {
            return bad(format!("{} hidden widths for {} layers (need one fewer)", self.hidden_channels.len(), self.kernel_sizes.len()));
        }
        if self.kernel_sizes.iter().chain(&self.dilations).chain(&self.hidden_channels).any(|&v| v < 1) {
            return bad("kernel sizes, dilations and widths must be ≥ 1".into());
        }
        // Far beyond any IMU model; larger values are typos that would ask libtorch for
        // gigabytes and abort instead of failing here.
        if let Some(v) = self.hidden_channels.iter().find(|&&v| v > MAX_WIDTH) {
            return bad(format!("a width of {v} channels (at most {MAX_WIDTH})"));
        }
        if self.kernel_sizes.iter().any(|&k| k > MAX_KERNEL) || self.receptive_field() > MAX_RECEPTIVE_FIELD {
            return bad(format!(
                "kernel sizes {:?} with dilations {:?}: at most {MAX_KERNEL} taps and a receptive field of {MAX_RECEPTIVE_FIELD} samples",
                self.kernel_sizes, self.dilations
            ));
        }
        Ok(())
    }
}

/// Bounds of a network's shape ([`CnnConfig`], the Embedding).
const MAX_WIDTH: i64 = 4096;
const MAX_KERNEL: i64 = 1024;
const MAX_RECEPTIVE_FIELD: i64 = 1 << 20;

impl Default for CnnConfig {
    fn default() -> Self {
        Self::fsda()
    }
}

/// The per-sample Embedding MLP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmbeddingConfig {
    /// Widths of the hidden layers (GELU after each).
    pub hidden: Vec<i64>,
    /// Size of the embedding (tanh output, so each component is in (−1, 1)).
    pub dim: i64,
}

impl Default for EmbeddingConfig {
    fn default() -> Self {
        Self { hidden: vec![32, 32], dim: 16 }
    }
}

/// What follows each hidden conv of a CNN before its GELU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HiddenNorm {
    /// Nothing.
    None,
    /// BatchNorm (running statistics at inference, folded into the conv).
    Batch,
    /// LayerNorm over the channels of each time step, with a learned per-channel γ and β.
    ChannelLayer,
}

/// The model's hyper-parameters: everything needed to rebuild the network from its weights.
/// Travels in the exported metadata.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// Which network.
    pub mode: Mode,
    /// IMU rate the model is trained for, Hz. The network sees sample indices, not time: a
    /// model is only valid at (about) this rate. EuRoC: 200 Hz.
    pub rate_hz: f64,
    /// σ: fixed per-axis scale of the learned correction, deg/s (DIGDL: 1, 2, 5 on EuRoC,
    /// 0.2 on TUM-VI). Stored in the weights as rad/s.
    pub output_scale_deg_s: [f64; 3],
    /// Std of the random initialisation of `Ĉ_ω − I` (0: Ĉ_ω starts at identity as in the
    /// paper; DIGDL starts from 0.05·N(0, 1)).
    pub gyro_calib_init_std: f64,
    /// BatchNorm after each hidden conv (DIGDL: yes). Folded into the convs for inference.
    pub batch_norm: bool,
    /// BatchNorm in the Restructor's hidden convs; absent: as `batch_norm`. The Restructor is
    /// training-only, so with `batch_norm: false` and this on, the deployed network has no
    /// batch statistics while `L^R` keeps its normalised CNN.
    pub restructor_batch_norm: Option<bool>,
    /// LayerNorm over each time step's channels after each hidden conv, in place of
    /// BatchNorm (refused with `batch_norm: true`). No batch statistics and causal, so the
    /// deployed output depends on the window alone; kept as is for inference (not folded).
    pub layer_norm: bool,
    /// Dropout probability after each hidden conv (training only; DIGDL: 0.1).
    pub dropout: f64,
    /// The CNN of [`Mode::Digdl`].
    #[serde(default = "CnnConfig::digdl")]
    pub digdl: CnnConfig,
    /// The Embedding of the FSDA modes.
    pub embedding: EmbeddingConfig,
    /// The Generator of the FSDA modes (its receptive field is the model's window N).
    pub generator: CnnConfig,
    /// The Restructor of the FSDA modes (training only).
    pub restructor: CnnConfig,
    /// Std of the Gaussian noise added to the embedding before the Restructor (training
    /// only; embedding units, the embedding lies in (−1, 1)).
    pub restructor_noise_std: f64,
    /// FSDA modes: the Generator also sees the normalised IMU window beside the embedding
    /// (a skip connection around the Embedding). Off in the paper. Why: the per-sample
    /// tanh Embedding squeezes 6 channels where a gyro bias is < 1 % of the motion's range,
    /// and with DIGDL's data and no MAML the paper's network is 1.8× worse than DIGDL's,
    /// which convolves the raw input (docs/training.md).
    pub generator_sees_imu: bool,
    /// One Ĉ_ω per IMU, by name (e.g. `euroc`, `tumvi`), instead of one shared by all the
    /// training data (the paper). Empty: shared. Why: the training split mixes a raw
    /// ADIS16448 (EuRoC, large scale and misalignment errors) with a factory-calibrated
    /// BMI160 (TUM-VI); one matrix for both costs one of them (docs/training.md). The
    /// Generator is shared; an IMU not in the list gets Ĉ_ω = I (and `imu-fsda adapt`).
    pub imu_calibrations: Vec<String>,
}

impl Config {
    /// The defaults of one mode (DIGDL's published settings for [`Mode::Digdl`]).
    pub fn for_mode(mode: Mode) -> Self {
        let fsda = Self {
            mode,
            rate_hz: 200.0,
            output_scale_deg_s: [1.0, 2.0, 5.0],
            gyro_calib_init_std: 0.0,
            batch_norm: true,
            restructor_batch_norm: None,
            layer_norm: false,
            dropout: 0.1,
            digdl: CnnConfig::digdl(),
            embedding: EmbeddingConfig::default(),
            generator: CnnConfig::fsda(),
            restructor: CnnConfig::fsda(),
            restructor_noise_std: 0.1,
            generator_sees_imu: false,
            imu_calibrations: Vec::new(),
        };
        match mode {
            Mode::Digdl => Self { gyro_calib_init_std: 0.05, ..fsda },
            Mode::Fsda | Mode::FsdaF => fsda,
        }
    }

    /// The normalisation after the Generator's (or DIGDL's) hidden convs.
    pub fn generator_norm(&self) -> HiddenNorm {
        self.norm_with_batch_norm(self.batch_norm)
    }

    /// The normalisation after the Restructor's hidden convs: BatchNorm if
    /// `restructor_batch_norm` (absent: `batch_norm`) says so, else as the Generator's.
    pub fn restructor_norm(&self) -> HiddenNorm {
        self.norm_with_batch_norm(self.restructor_batch_norm.unwrap_or(self.batch_norm))
    }

    fn norm_with_batch_norm(&self, batch_norm: bool) -> HiddenNorm {
        match (batch_norm, self.layer_norm) {
            (true, _) => HiddenNorm::Batch,
            (false, true) => HiddenNorm::ChannelLayer,
            (false, false) => HiddenNorm::None,
        }
    }

    /// Receptive field N in samples: the output at n depends on inputs n−N+1 … n.
    /// 511 for DIGDL's CNN, 517 for the paper's Generator.
    pub fn receptive_field(&self) -> i64 {
        match self.mode {
            Mode::Digdl => self.digdl.receptive_field(),
            Mode::Fsda | Mode::FsdaF => self.generator.receptive_field(),
        }
    }

    /// σ in rad/s.
    pub fn output_scale_rad_s(&self) -> [f64; 3] {
        self.output_scale_deg_s.map(f64::to_radians)
    }

    /// Checks the shapes and ranges; every constructor calls it.
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(ModelError::InvalidConfig(format!("rate_hz must be > 0, got {}", self.rate_hz)));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(ModelError::InvalidConfig(format!("dropout must be in [0, 1), got {}", self.dropout)));
        }
        if self.output_scale_deg_s.iter().any(|s| !s.is_finite() || *s <= 0.0) {
            return Err(ModelError::InvalidConfig("output_scale_deg_s must be > 0".into()));
        }
        if !(self.gyro_calib_init_std >= 0.0 && self.restructor_noise_std >= 0.0) {
            return Err(ModelError::InvalidConfig("standard deviations must be ≥ 0".into()));
        }
        let mut names = self.imu_calibrations.clone();
        names.sort();
        names.dedup();
        if names.len() != self.imu_calibrations.len() || names.iter().any(|n| n.trim().is_empty()) {
            return Err(ModelError::InvalidConfig(format!(
                "imu_calibrations must be distinct non-empty names, got {:?}",
                self.imu_calibrations
            )));
        }
        if self.batch_norm && self.layer_norm {
            return Err(ModelError::InvalidConfig("layer_norm replaces BatchNorm: set batch_norm: false with it".into()));
        }
        match self.mode {
            Mode::Digdl if self.restructor_batch_norm.is_some() => {
                Err(ModelError::InvalidConfig("restructor_batch_norm is for the FSDA modes (DIGDL has no Restructor)".into()))
            }
            Mode::Digdl if self.generator_sees_imu => {
                Err(ModelError::InvalidConfig("generator_sees_imu is for the FSDA modes (DIGDL's CNN already sees the IMU)".into()))
            }
            Mode::Digdl => self.digdl.validate("digdl"),
            Mode::Fsda | Mode::FsdaF => {
                if self.embedding.dim < 1 || self.embedding.hidden.iter().any(|&w| w < 1) {
                    return Err(ModelError::InvalidConfig("embedding widths must be ≥ 1".into()));
                }
                if self.embedding.dim > MAX_WIDTH || self.embedding.hidden.iter().any(|&w| w > MAX_WIDTH) {
                    return Err(ModelError::InvalidConfig(format!("embedding widths must be at most {MAX_WIDTH}")));
                }
                self.generator.validate("generator")?;
                self.restructor.validate("restructor")
            }
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Self::for_mode(Mode::default())
    }
}

/// Errors at the model boundary: configs, inputs, and the exported files.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The hyper-parameters do not describe a buildable network.
    #[error("invalid model config: {0}")]
    InvalidConfig(String),
    /// A tensor handed to the model has the wrong shape or kind.
    #[error("input of shape {got:?} and kind {kind} does not fit the model: expected {expected}")]
    InputShape { expected: String, got: Vec<i64>, kind: String },
    /// A model file does not exist.
    #[error("model file {} is missing", path.display())]
    MissingFile { path: PathBuf },
    /// Reading or writing a file failed.
    #[error("cannot access {}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file exists but cannot be decoded.
    #[error("model file {} is corrupt or not in the expected format: {reason}", path.display())]
    CorruptFile { path: PathBuf, reason: String },
    /// The metadata and the weights (or the TorchScript file) disagree.
    #[error("{}: the model's files disagree: {detail}", path.display())]
    Mismatch { path: PathBuf, detail: String },
    /// A sound model of a kind the command cannot use (a DIGDL model where an Embedding is needed).
    #[error("{}: {detail}", path.display())]
    WrongKind { path: PathBuf, detail: String },
    /// An IMU name the model has no Ĉ_ω for.
    #[error("IMU calibration {name:?}: {detail}")]
    UnknownImu { name: String, detail: String },
    /// Any other libtorch error.
    #[error("libtorch: {}", torch_message(.0))]
    Torch(tch::TchError),
}

// By hand, not `#[from]`: that would also make the error a source, and printers that walk the
// chain would print libtorch's backtrace after all.
impl From<tch::TchError> for ModelError {
    fn from(e: tch::TchError) -> Self {
        Self::Torch(e)
    }
}

/// libtorch's message without the C++ backtrace it appends ("Exception raised from …", then a
/// line per stack frame): the first lines say what went wrong, the frames are addresses.
/// How far an IMU's rate may be from a model's `rate_hz` (TUM-VI's 199.37 Hz under a 200-Hz
/// model is 0.3 % off): the network counts samples, so beyond this its window spans another time.
pub const RATE_TOLERANCE: f64 = 0.05;

/// True when an IMU at `imu_rate_hz` is off a model's `model_rate_hz` by more than
/// [`RATE_TOLERANCE`]: the model must run on it in its own periods ([`crate::resample`]).
pub fn rate_is_off(model_rate_hz: f64, imu_rate_hz: f64) -> bool {
    imu_rate_hz > 0.0 && model_rate_hz > 0.0 && (imu_rate_hz / model_rate_hz - 1.0).abs() > RATE_TOLERANCE
}

/// Why a model for `model_rate_hz` is out of its domain on an IMU at `imu_rate_hz`, if it is.
pub fn rate_mismatch(model_rate_hz: f64, imu_rate_hz: f64, window_n: i64) -> Option<String> {
    rate_is_off(model_rate_hz, imu_rate_hz).then(|| {
        format!(
            "the model is for a {model_rate_hz:.0} Hz IMU and this one runs at {imu_rate_hz:.1} Hz: its {window_n}-sample window spans {:.2} s instead of {:.2} s",
            window_n as f64 / imu_rate_hz,
            window_n as f64 / model_rate_hz
        )
    })
}

pub fn torch_message(e: &tch::TchError) -> String {
    without_torch_backtrace(&e.to_string()).to_string()
}

/// `text` up to libtorch's backtrace, if it has one (see [`torch_message`]).
pub fn without_torch_backtrace(text: &str) -> &str {
    text.find("Exception raised from").map_or(text, |end| text[..end].trim_end())
}
