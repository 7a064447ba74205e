//! Export and loading of trained models (the deployment side of §III; DIGDL ships
//! `weights.pt` + `net_params.yaml` the same way). One model is three files in one
//! directory:
//!
//! - `<name>.pt` — TorchScript, traced from [`InferenceNet`] (eval mode, BatchNorm folded,
//!   f32): `forward(u: [B, T, 6] raw IMU) → [B, T, 3]` corrected gyro, rad/s; normalisation,
//!   Ĉ_ω and σ inside. Traced modules keep weights as constants: it runs anywhere
//!   (`torch.jit.load`, `tch::CModule::load`) but cannot be fine-tuned.
//! - `<name>.ot` — the VarStore (every variable of [`Net`], Restructor and BatchNorm
//!   statistics included) in libtorch's named-tensor format, for fine-tuning / adaptation
//!   and for building the [`StreamingDenoiser`].
//! - `<name>.json` — [`ModelMetadata`]: mode, window N, rate, normalisation, the full
//!   [`Config`], parameter counts, training data, code revision, metrics.
//!
//! Loading checks everything it can and returns a [`ModelError`], never panics: missing
//! file, undecodable file, weights that do not fit the metadata's config (names, shapes,
//! normalisation, σ), a TorchScript file that does not produce `[B, T, 3]`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tch::nn::VarStore;
use tch::{CModule, Device, Kind, Tensor};

use super::net::{InferenceNet, Net, ParameterCounts};
use super::streaming::StreamingDenoiser;
use super::{Config, Mode, ModelError, INPUT_CHANNELS, OUTPUT_CHANNELS};

/// Version of the file layout written by [`export_model`].
pub const FORMAT_VERSION: u32 = 1;

/// The input normalisation, per channel (gyro x, y, z in rad/s; accel x, y, z in m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    pub mean: [f64; 6],
    pub std: [f64; 6],
}

/// File names of one exported model, relative to the metadata's directory.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExportFiles {
    pub torchscript: String,
    pub weights: String,
}

/// `<name>.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelMetadata {
    /// [`FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    pub name: String,
    pub mode: Mode,
    /// Receptive field N, samples: the output at n depends on inputs n−N+1 … n.
    pub window_n: i64,
    /// IMU rate the model was trained for, Hz.
    pub rate_hz: f64,
    pub normalization: Normalization,
    /// Human-readable I/O contract of the TorchScript file.
    pub input: String,
    pub output: String,
    pub config: Config,
    pub parameter_counts: ParameterCounts,
    /// Ĉ_ω (row-major) of each IMU in `config.imu_calibrations`. The TorchScript file applies
    /// [`ModelMetadata::torchscript_gyro_calibration`] C₀ (I as trained: an unknown IMU); for
    /// IMU k, `ω̂ = forward(u) + (Ĉ_k − C₀) ω`, what [`TorchScriptModel::select_imu`] does.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub imu_gyro_calibrations: BTreeMap<String, [[f64; 3]; 3]>,
    /// The Ĉ_ω traced into the TorchScript file (models with per-IMU calibrations).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torchscript_gyro_calibration: Option<[[f64; 3]; 3]>,
    /// The share g_k of the model's correction applied on IMU k, `ω + g_k (ω̂ − ω)`, fitted by
    /// the trainer to the full-length AOE of that IMU's validation recordings
    /// (`train.correction_gains`). The TorchScript file and the streamed weights give g = 1 (an
    /// unknown IMU); naming the IMU applies its g_k ([`TorchScriptModel::select_imu`],
    /// [`LoadedNet::select_imu`]).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub imu_correction_gains: BTreeMap<String, f64>,
    /// Set on a few-shot adapted model: the model it was adapted from. Its Ĉ_ω is its own
    /// (adapted): selecting an IMU leaves it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adapted_from: Option<String>,
    /// Set on a model adapted after its support's power-on gyro bias (measured at standstills,
    /// [`crate::standstill`]) was removed: the node removes this power-on's before it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub power_on_bias_removed: bool,
    /// A model trained with each recording's power-on bias removed (`dataset.power_on_bias:
    /// remove`): the bias its standstills measured in each training recording, per IMU. They are
    /// earlier power-ons of that IMU: until a new power-on's first standstill the pipeline
    /// removes what they predict, as it does from a bias memory file.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub trained_power_on_biases: BTreeMap<String, Vec<TrainedPowerOn>>,
    /// The networks' correction is exactly 0 ([`crate::model::Net::correction_networks_off`]):
    /// the model is its Ĉ_ω alone, a gyro calibration (read from the weights at export).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub correction_networks_off: bool,
    /// The networks' correction is this constant, rad/s ([`crate::model::Net::correction_constant`]):
    /// the model is its Ĉ_ω and a bias offset in motion (read from the weights at export).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub correction_constant_rad_s: Option<[f64; 3]>,
    /// Sequences / bags the model was trained on (filled by the trainer).
    pub training_data: Vec<String>,
    /// The IMUs those recordings were made with (each source's `imu`, else its dataset folder:
    /// `euroc/MH_01_easy` → `euroc`; the trainer's rule). Naming one of them runs the model as
    /// trained on it. Files written before this field: read from `training_data`
    /// ([`ModelMetadata::trained_imus`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trained_imus: Vec<String>,
    /// Evaluation figures (filled by the trainer), e.g. `"MH_04_difficult/aoe_deg"`. A figure
    /// that could not be measured (NaN, written by JSON as `null`) is left out on reading.
    #[serde(deserialize_with = "finite_metrics")]
    pub metrics: BTreeMap<String, f64>,
    /// Git revision of the code that wrote the model, when known.
    pub code_revision: Option<String>,
    pub crate_version: String,
    /// Seconds since the Unix epoch.
    pub created_unix_s: u64,
    pub files: ExportFiles,
}

/// One training recording's power-on bias, as its standstills measured it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainedPowerOn {
    pub recording: String,
    pub bias_rad_s: [f64; 3],
    pub stddev_rad_s: [f64; 3],
    pub still_s: f64,
}

impl ModelMetadata {
    /// The IMUs this model has a Ĉ_ω or correction gain of their own for (per-IMU tables).
    pub fn imu_names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self.imu_gyro_calibrations.keys().chain(self.imu_correction_gains.keys()).map(String::as_str).collect();
        names.sort_unstable();
        names.dedup();
        names
    }

    /// The IMUs the model was trained on: [`ModelMetadata::trained_imus`], or for a file
    /// written before that field, the dataset folder of each `training_data` entry that has
    /// one (`euroc/MH_01_easy (support …)` → `euroc`). None for an adapted model, which knows
    /// its IMU by `adapted_from`.
    pub fn trained_imus(&self) -> Vec<&str> {
        if self.adapted_from.is_some() {
            return Vec::new();
        }
        let mut names: Vec<&str> = if self.trained_imus.is_empty() {
            self.training_data.iter().filter_map(|d| d.split_once('/').map(|(dataset, _)| dataset)).filter(|d| !d.is_empty()).collect()
        } else {
            self.trained_imus.iter().map(String::as_str).collect()
        };
        names.sort_unstable();
        names.dedup();
        names
    }

    /// Every IMU the model knows by name: those with a Ĉ_ω or gain of their own, and those it
    /// was trained on.
    pub fn known_imus(&self) -> Vec<&str> {
        let mut names = self.imu_names();
        names.extend(self.trained_imus());
        names.sort_unstable();
        names.dedup();
        names
    }

    /// The model was trained on IMU `name`, or fitted a Ĉ_ω or gain for it: naming it runs the
    /// model as on an IMU it knows.
    pub fn knows_imu(&self, name: &str) -> bool {
        self.known_imus().contains(&name)
    }

    /// The correction gain for IMU `imu` (1 for none, or an adapted model, or an IMU it was
    /// trained on with no gain of its own), or `UnknownImu` when the model knows the name
    /// neither from a Ĉ_ω, a gain nor its training recordings.
    pub fn correction_gain(&self, imu: Option<&str>) -> Result<f64, ModelError> {
        let Some(name) = self.imu_to_apply(imu) else {
            return Ok(1.0);
        };
        if let Some(&g) = self.imu_correction_gains.get(name) {
            // A share of the network's correction: a value outside [0, 1] is a damaged file.
            if !(0.0..=1.0).contains(&g) {
                return Err(ModelError::UnknownImu {
                    name: name.into(),
                    detail: format!("its correction gain in the metadata is {g:e}, not a share in [0, 1]: the file is damaged"),
                });
            }
            return Ok(g);
        }
        if self.imu_gyro_calibrations.contains_key(name) || self.trained_imus().contains(&name) {
            return Ok(1.0);
        }
        let detail = match (self.imu_names().is_empty(), self.trained_imus().is_empty()) {
            (true, true) => "this model has one Ĉ_ω shared by every IMU and no per-IMU correction gain".to_string(),
            (true, false) => format!("the model was trained on {:?} (one Ĉ_ω, no per-IMU gain)", self.trained_imus()),
            (false, _) => format!("the model knows {:?}", self.imu_names()),
        };
        Err(ModelError::UnknownImu { name: name.into(), detail })
    }

    /// The IMU whose Ĉ_ω to apply when `imu` is asked for: none for an adapted model, which
    /// keeps its own (adapted) Ĉ_ω.
    fn imu_to_apply<'a>(&self, imu: Option<&'a str>) -> Option<&'a str> {
        match (imu, &self.adapted_from) {
            (Some(name), Some(from)) => {
                tracing::info!("{} was adapted from {from}: its own Ĉ_ω is kept (IMU {name:?} not applied)", self.name);
                None
            }
            (imu, _) => imu,
        }
    }

    /// The IMU whose own Ĉ_ω to apply when `imu` is asked for: none for an adapted model, or
    /// for a name with only a correction gain (it runs with the model's Ĉ_ω, as fitted).
    fn calibration_to_apply<'a>(&self, imu: Option<&'a str>) -> Option<&'a str> {
        self.imu_to_apply(imu).filter(|n| self.imu_gyro_calibrations.contains_key(*n))
    }
}

fn finite_metrics<'de, D: serde::Deserializer<'de>>(d: D) -> Result<BTreeMap<String, f64>, D::Error> {
    let m: BTreeMap<String, Option<f64>> = serde::Deserialize::deserialize(d)?;
    Ok(m.into_iter().filter_map(|(k, v)| Some((k, v?))).collect())
}

/// What the trainer adds to the metadata.
#[derive(Debug, Clone, Default)]
pub struct ExportInfo {
    pub training_data: Vec<String>,
    /// [`ModelMetadata::trained_imus`].
    pub trained_imus: Vec<String>,
    pub metrics: BTreeMap<String, f64>,
    /// Overrides the revision found at build time (`IMU_FSDA_GIT_REV`) or from `git`.
    pub code_revision: Option<String>,
    /// [`ModelMetadata::adapted_from`].
    pub adapted_from: Option<String>,
    /// [`ModelMetadata::imu_correction_gains`].
    pub imu_correction_gains: BTreeMap<String, f64>,
    /// [`ModelMetadata::power_on_bias_removed`].
    pub power_on_bias_removed: bool,
    /// [`ModelMetadata::trained_power_on_biases`].
    pub trained_power_on_biases: BTreeMap<String, Vec<TrainedPowerOn>>,
    /// Text files written with the model as one set (`<name>.<suffix>`, contents), e.g. an
    /// adaptation report: all of them or none replace what was there.
    pub side_files: Vec<(String, String)>,
}

/// The three paths of a model `name` in `dir`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportPaths {
    pub torchscript: PathBuf,
    pub weights: PathBuf,
    pub metadata: PathBuf,
}

impl ExportPaths {
    pub fn new(dir: &Path, name: &str) -> Self {
        Self {
            torchscript: dir.join(format!("{name}.pt")),
            weights: dir.join(format!("{name}.ot")),
            metadata: dir.join(format!("{name}.json")),
        }
    }
}

const INPUT_CONTRACT: &str =
    "[B, T, 6] f32, raw IMU: gyro x, y, z (rad/s), accel x, y, z (m/s^2); causal, first sample replicated to the left";
const OUTPUT_CONTRACT: &str = "[B, T, 3] f32, corrected gyro x, y, z (rad/s)";

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> ModelError + '_ {
    move |source| ModelError::Io { path: path.to_path_buf(), source }
}

/// Writes through `write(tmp)` then renames, so a reader never sees a half-written file.
fn write_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<(), ModelError>) -> Result<(), ModelError> {
    let mut staged = Staged::default();
    staged.write(path, write)?;
    staged.commit()
}

/// The code revision: `IMU_FSDA_GIT_REV` at build time, else `git rev-parse HEAD` in the
/// crate's source tree (`-dirty` when tracked files changed), else None.
pub fn code_revision() -> Option<String> {
    if let Some(rev) = option_env!("IMU_FSDA_GIT_REV") {
        return Some(rev.to_string());
    }
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .arg("-C")
            .arg(env!("CARGO_MANIFEST_DIR"))
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
    };
    let rev = git(&["rev-parse", "HEAD"])?;
    let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
    Some(if dirty { format!("{rev}-dirty") } else { rev })
}

/// Traces the eval-mode model (f32) to TorchScript.
pub fn trace(inference: &InferenceNet) -> Result<CModule, ModelError> {
    let model = inference.to_kind(Kind::Float);
    let example = Tensor::zeros([1, model.receptive_field(), INPUT_CHANNELS], (Kind::Float, Device::Cpu));
    let module = tch::no_grad(|| CModule::create_by_tracing("ImuDenoiser", "forward", &[example], &mut |xs| vec![model.forward(&xs[0])]))?;
    Ok(module)
}

/// Writes `<name>.pt`, `<name>.ot` and `<name>.json` into `dir` (created if needed).
/// `vs` must be the VarStore `net` was built in. The training VarStore is left as it was
/// (the traced copy is detached; no `freeze` needed).
pub fn export_model(dir: &Path, name: &str, vs: &VarStore, net: &Net, info: &ExportInfo) -> Result<ExportPaths, ModelError> {
    crate::core::create_dir_all(dir).map_err(io_err(dir))?;
    let paths = ExportPaths::new(dir, name);
    let module = trace(&net.inference())?;
    // Every file is written beside its final name first and the set renamed only when all are
    // written: a failure (disk full, a folder in the way, Ctrl-C) leaves the earlier model whole.
    let mut staged = Staged::default();
    // libtorch's own message only (its stack trace says nothing to a user).
    let torch_io =
        |tmp: &Path, e: tch::TchError| ModelError::Io { path: tmp.to_path_buf(), source: std::io::Error::other(super::torch_message(&e)) };
    staged.write(&paths.torchscript, |tmp| module.save(tmp).map_err(|e| torch_io(tmp, e)))?;
    staged.write(&paths.weights, |tmp| vs.save(tmp).map_err(|e| torch_io(tmp, e)))?;
    let (mean, std) = net.normalization();
    let cfg = net.config().clone();
    let per_imu = !cfg.imu_calibrations.is_empty();
    let file_name = |p: &Path| p.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
    let metadata = ModelMetadata {
        format_version: FORMAT_VERSION,
        name: name.to_string(),
        mode: cfg.mode,
        window_n: net.receptive_field(),
        rate_hz: cfg.rate_hz,
        normalization: Normalization { mean, std },
        input: INPUT_CONTRACT.into(),
        output: OUTPUT_CONTRACT.into(),
        config: cfg,
        parameter_counts: net.parameter_counts(),
        imu_gyro_calibrations: net.imu_calibration_matrices(),
        torchscript_gyro_calibration: per_imu.then(|| super::net::matrix3(&net.gyro_calibration())),
        imu_correction_gains: info.imu_correction_gains.clone(),
        adapted_from: info.adapted_from.clone(),
        power_on_bias_removed: info.power_on_bias_removed,
        trained_power_on_biases: info.trained_power_on_biases.clone(),
        correction_networks_off: net.correction_networks_off(),
        correction_constant_rad_s: net.correction_constant(),
        training_data: info.training_data.clone(),
        trained_imus: info.trained_imus.clone(),
        metrics: info.metrics.iter().filter(|(_, v)| v.is_finite()).map(|(k, v)| (k.clone(), *v)).collect(),
        code_revision: info.code_revision.clone().or_else(code_revision),
        crate_version: env!("CARGO_PKG_VERSION").into(),
        created_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0),
        files: ExportFiles { torchscript: file_name(&paths.torchscript), weights: file_name(&paths.weights) },
    };
    let json = serde_json::to_string_pretty(&metadata)
        .map_err(|e| ModelError::CorruptFile { path: paths.metadata.clone(), reason: e.to_string() })?;
    staged.write(&paths.metadata, |tmp| std::fs::write(tmp, json + "\n").map_err(io_err(tmp)))?;
    for (suffix, text) in &info.side_files {
        staged.write(&dir.join(format!("{name}.{suffix}")), |tmp| std::fs::write(tmp, text).map_err(io_err(tmp)))?;
    }
    staged.commit()?;
    Ok(paths)
}

/// Files written to `<path>.tmp` and renamed together by [`Staged::commit`]; dropped without
/// a commit, the temporaries are removed.
#[derive(Default)]
struct Staged {
    files: Vec<(PathBuf, PathBuf)>,
}

impl Staged {
    fn write(&mut self, path: &Path, write: impl FnOnce(&Path) -> Result<(), ModelError>) -> Result<(), ModelError> {
        if path.is_dir() {
            return Err(ModelError::Io { path: path.to_path_buf(), source: std::io::Error::other("is a directory") });
        }
        let mut tmp = path.as_os_str().to_owned();
        tmp.push(".tmp");
        let tmp = PathBuf::from(tmp);
        self.files.push((tmp.clone(), path.to_path_buf()));
        write(&tmp)
    }

    fn commit(mut self) -> Result<(), ModelError> {
        for (tmp, path) in std::mem::take(&mut self.files) {
            std::fs::rename(&tmp, &path).map_err(io_err(&path))?;
        }
        Ok(())
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        for (tmp, _) in &self.files {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// Writes (or rewrites, e.g. to add metrics) a metadata file.
pub fn write_metadata(path: &Path, metadata: &ModelMetadata) -> Result<(), ModelError> {
    let json =
        serde_json::to_string_pretty(metadata).map_err(|e| ModelError::CorruptFile { path: path.to_path_buf(), reason: e.to_string() })?;
    write_atomically(path, |tmp| std::fs::write(tmp, json + "\n").map_err(io_err(tmp)))
}

fn require_file(path: &Path) -> Result<(), ModelError> {
    let refuse = |why: String| Err(ModelError::Io { path: path.to_path_buf(), source: std::io::Error::other(why) });
    if path.is_dir() {
        // Name the models it holds: `--model models/` is a common slip.
        let mut models: Vec<String> = std::fs::read_dir(path)
            .map(|entries| {
                entries
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    // A model is its `.json` with the `.pt` or the `.ot` beside it.
                    .filter(|p| p.extension().is_some_and(|x| x == "json") && ["pt", "ot"].iter().any(|e| p.with_extension(e).is_file()))
                    .filter_map(|p| p.file_name().map(|f| f.to_string_lossy().into_owned()))
                    .collect()
            })
            .unwrap_or_default();
        models.sort();
        return refuse(if models.is_empty() {
            "a folder, not a model file".into()
        } else {
            format!("a folder, not a model file; it holds {}", models.join(", "))
        });
    }
    if path.to_str().is_none() {
        // libtorch takes UTF-8 paths only; its own error reads as a corrupt file.
        return refuse("not valid UTF-8, and libtorch opens UTF-8 paths only: rename the file or its folders".into());
    }
    if path.is_file() {
        Ok(())
    } else {
        Err(ModelError::MissingFile { path: path.to_path_buf() })
    }
}

/// Reads `<name>.json`.
pub fn load_metadata(path: &Path) -> Result<ModelMetadata, ModelError> {
    require_file(path)?;
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let metadata: ModelMetadata =
        serde_json::from_str(&text).map_err(|e| ModelError::CorruptFile { path: path.to_path_buf(), reason: e.to_string() })?;
    let mismatch = |detail: String| Err(ModelError::Mismatch { path: path.to_path_buf(), detail });
    if metadata.format_version != FORMAT_VERSION {
        return mismatch(format!("format_version {} (this build reads {FORMAT_VERSION})", metadata.format_version));
    }
    if metadata.mode != metadata.config.mode {
        return mismatch(format!("mode {:?} but config.mode {:?}", metadata.mode, metadata.config.mode));
    }
    if metadata.rate_hz != metadata.config.rate_hz {
        return mismatch(format!("rate_hz {} but config.rate_hz {}", metadata.rate_hz, metadata.config.rate_hz));
    }
    metadata.config.validate()?;
    if metadata.window_n != metadata.config.receptive_field() {
        return mismatch(format!(
            "window_n {} but the config's receptive field is {}",
            metadata.window_n,
            metadata.config.receptive_field()
        ));
    }
    Ok(metadata)
}

/// A model file beside its metadata, named by the metadata's own stem (`mine.json` →
/// `mine.pt`, `mine.ot`): the files the user named, even after a rename. The names recorded at
/// export (`files`) are not used, so a renamed model loads and a stale file of the old name
/// lying beside it is never picked up instead.
fn sibling(metadata_path: &Path, extension: &str) -> PathBuf {
    metadata_path.with_extension(extension)
}

/// A model rebuilt for fine-tuning or adaptation: its VarStore, the [`Net`] and the metadata.
#[derive(Debug)]
pub struct LoadedNet {
    pub vs: VarStore,
    pub net: Net,
    pub metadata: ModelMetadata,
    /// The selected IMU's correction gain ([`LoadedNet::select_imu`]; 1 until then).
    correction_gain: std::cell::Cell<f64>,
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * (1.0 + b.abs())
}

/// Loads `<name>.json` + `<name>.ot` into a fresh VarStore on `device` (f32, trainable).
pub fn load_net(metadata_path: &Path, device: Device) -> Result<LoadedNet, ModelError> {
    let metadata = load_metadata(metadata_path)?;
    let weights_path = sibling(metadata_path, "ot");
    require_file(&weights_path)?;
    let loaded = Tensor::load_multi_with_device(&weights_path, device)
        .map_err(|e| ModelError::CorruptFile { path: weights_path.clone(), reason: super::torch_message(&e) })?;
    let loaded: BTreeMap<String, Tensor> = loaded.into_iter().collect();
    let vs = VarStore::new(device);
    let net = Net::new(&metadata.config, &vs.root())?;
    let mismatch = |detail: String| ModelError::Mismatch { path: weights_path.clone(), detail };
    let variables = vs.variables();
    for (name, var) in &variables {
        let src = loaded.get(name).ok_or_else(|| mismatch(format!("no variable `{name}` (the config expects it)")))?;
        if src.size() != var.size() {
            return Err(mismatch(format!("`{name}` has shape {:?}, the config expects {:?}", src.size(), var.size())));
        }
        if !src.is_floating_point() {
            return Err(mismatch(format!("`{name}` is {:?}, not floating point", src.kind())));
        }
        if !bool::try_from(src.isfinite().all()).map_err(ModelError::from)? {
            return Err(ModelError::CorruptFile { path: weights_path.clone(), reason: format!("`{name}` has non-finite values") });
        }
        tch::no_grad(|| var.shallow_clone().f_copy_(&src.to_kind(var.kind())))?;
    }
    if let Some(extra) = loaded.keys().find(|k| !variables.contains_key(*k)) {
        return Err(mismatch(format!("unexpected variable `{extra}` (not in a {:?} model with this config)", metadata.mode)));
    }
    let (mean, std) = net.normalization();
    let norm = &metadata.normalization;
    if !(mean.iter().zip(&norm.mean).all(|(a, b)| close(*a, *b)) && std.iter().zip(&norm.std).all(|(a, b)| close(*a, *b))) {
        return Err(mismatch(format!("normalisation in the weights (mean {mean:?}, std {std:?}) differs from the metadata ({norm:?})")));
    }
    let sigma = Vec::<f64>::try_from(&variables["output_scale.sigma"].to_kind(Kind::Double))?;
    if !sigma.iter().zip(metadata.config.output_scale_rad_s()).all(|(a, b)| close(*a, b)) {
        return Err(mismatch(format!(
            "σ in the weights {sigma:?} rad/s differs from the config's {:?} deg/s",
            metadata.config.output_scale_deg_s
        )));
    }
    Ok(LoadedNet::new(vs, net, metadata))
}

impl LoadedNet {
    /// A model in memory (gain 1 until [`LoadedNet::select_imu`]).
    pub fn new(vs: VarStore, net: Net, metadata: ModelMetadata) -> Self {
        LoadedNet { vs, net, metadata, correction_gain: std::cell::Cell::new(1.0) }
    }

    /// Runs the model as deployed on IMU `imu`: its Ĉ_ω ([`Net::select_imu`]) when the model
    /// has one per IMU, and its correction gain ([`LoadedNet::correction_gain`]); `None` keeps
    /// the model's own (I for a trained per-IMU model, the adapted one for an adapted model,
    /// gain 1). An IMU the model does not know is `UnknownImu`.
    pub fn select_imu(&self, imu: Option<&str>) -> Result<(), ModelError> {
        let gain = self.metadata.correction_gain(imu)?;
        if let Some(name) = self.metadata.calibration_to_apply(imu) {
            self.net.select_imu(name)?;
        }
        self.correction_gain.set(gain);
        Ok(())
    }

    /// The share of the network's correction applied on the selected IMU (see
    /// [`ModelMetadata::imu_correction_gains`]); 1 until [`LoadedNet::select_imu`] names one.
    pub fn correction_gain(&self) -> f64 {
        self.correction_gain.get()
    }
}

/// Loads the streaming form (f32 networks, no tch at run time) from `<name>.json` + `<name>.ot`,
/// with IMU `imu`'s Ĉ_ω ([`LoadedNet::select_imu`]).
pub fn load_streaming(metadata_path: &Path, imu: Option<&str>) -> Result<(StreamingDenoiser, ModelMetadata), ModelError> {
    let loaded = load_net(metadata_path, Device::Cpu)?;
    loaded.select_imu(imu)?;
    let mut denoiser = StreamingDenoiser::from_net(&loaded.net)?;
    denoiser.set_correction_gain(loaded.correction_gain());
    Ok((denoiser, loaded.metadata))
}

/// The TorchScript model with its metadata and an input check.
#[derive(Debug)]
pub struct TorchScriptModel {
    module: CModule,
    pub metadata: ModelMetadata,
    /// `(Ĉ_k − C₀)ᵀ`, f32, after [`TorchScriptModel::select_imu`].
    calibration_change: Option<Tensor>,
    /// The selected IMU's correction gain (1: none).
    correction_gain: f64,
}

impl TorchScriptModel {
    /// `u: [B, T, 6]` f32 raw IMU → `[B, T, 3]` corrected gyro, rad/s.
    pub fn forward(&self, u: &Tensor) -> Result<Tensor, ModelError> {
        let size = u.size();
        if size.len() != 3 || size[2] != INPUT_CHANNELS || size[0] < 1 || size[1] < 1 || u.kind() != Kind::Float {
            return Err(ModelError::InputShape { expected: INPUT_CONTRACT.into(), got: size, kind: format!("{:?}", u.kind()) });
        }
        let out = tch::no_grad(|| self.module.forward_ts(&[u]))?;
        let out = match &self.calibration_change {
            Some(change) => out + tch::no_grad(|| u.narrow(2, 0, 3).matmul(change)),
            None => out,
        };
        Ok(if self.correction_gain == 1.0 {
            out
        } else {
            let raw = u.narrow(2, 0, 3);
            tch::no_grad(|| &raw + (out - &raw) * self.correction_gain)
        })
    }

    /// Runs the model as deployed on IMU `imu`: its Ĉ_ω (see
    /// [`ModelMetadata::imu_gyro_calibrations`]) and its correction gain
    /// ([`ModelMetadata::imu_correction_gains`]); `None` keeps the traced Ĉ_ω and gain 1.
    pub fn select_imu(&mut self, imu: Option<&str>) -> Result<(), ModelError> {
        self.calibration_change = None;
        // Refuses a name the model knows neither a Ĉ_ω nor a gain for.
        self.correction_gain = self.metadata.correction_gain(imu)?;
        let Some(name) = self.metadata.calibration_to_apply(imu) else {
            return Ok(());
        };
        let m = &self.metadata;
        let (Some(c0), Some(ck)) = (m.torchscript_gyro_calibration, m.imu_gyro_calibrations.get(name)) else {
            let detail = "the metadata has per-IMU Ĉ_ω but not the one traced into the TorchScript file".to_string();
            return Err(ModelError::UnknownImu { name: name.into(), detail });
        };
        // Row-major Ĉ_k − C₀, transposed for `ω [.., 3] · changeᵀ`.
        let diff: Vec<f64> = (0..3).flat_map(|r| (0..3).map(move |c| ck[c][r] - c0[c][r])).collect();
        self.calibration_change = Some(Tensor::from_slice(&diff).reshape([3, 3]).to_kind(Kind::Float));
        Ok(())
    }
}

/// Loads `<name>.json` + `<name>.pt` (CPU) and checks the module maps `[1, 8, 6]` to `[1, 8, 3]`.
pub fn load_torchscript(metadata_path: &Path) -> Result<TorchScriptModel, ModelError> {
    let metadata = load_metadata(metadata_path)?;
    let path = sibling(metadata_path, "pt");
    require_file(&path)?;
    let module = CModule::load(&path).map_err(|e| ModelError::CorruptFile { path: path.clone(), reason: super::torch_message(&e) })?;
    let model = TorchScriptModel { module, metadata, calibration_change: None, correction_gain: 1.0 };
    let probe = Tensor::zeros([1, 8, INPUT_CHANNELS], (Kind::Float, Device::Cpu));
    let out =
        model.forward(&probe).map_err(|e| ModelError::CorruptFile { path: path.clone(), reason: format!("probe forward failed: {e}") })?;
    if out.size() != [1, 8, OUTPUT_CHANNELS] {
        return Err(ModelError::Mismatch { path, detail: format!("maps [1, 8, 6] to {:?}, expected [1, 8, 3]", out.size()) });
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unmeasured_metrics_are_left_out_on_reading() {
        #[derive(Deserialize)]
        struct M {
            #[serde(deserialize_with = "finite_metrics")]
            metrics: BTreeMap<String, f64>,
        }
        let m: M = serde_json::from_str(r#"{"metrics": {"a": 1.5, "seconds_per_epoch": null}}"#).unwrap();
        assert_eq!(m.metrics["a"], 1.5);
        assert!(!m.metrics.contains_key("seconds_per_epoch"));
    }

    /// `--model models/` names the models in the folder; a path libtorch cannot open (not
    /// UTF-8) says so instead of reading as a corrupt file.
    #[test]
    fn a_folder_or_a_non_utf8_path_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        for f in ["a.pt", "a.json", "b.pt"] {
            std::fs::write(dir.path().join(f), "").unwrap();
        }
        let e = load_metadata(&crate::model::predict::metadata_path(dir.path())).unwrap_err().to_string();
        assert!(e.contains("a folder, not a model file; it holds a.json") && !e.contains("b."), "{e}");
        #[cfg(unix)]
        {
            use std::os::unix::ffi::OsStrExt;
            let odd = dir.path().join(std::ffi::OsStr::from_bytes(b"m\xff.json"));
            std::fs::write(&odd, "{}").unwrap();
            let e = load_metadata(&odd).unwrap_err().to_string();
            assert!(e.contains("UTF-8 paths only"), "{e}");
        }
    }
}
