//! The trainer's typed configuration: one YAML file with three sections,
//! `model` (a [`crate::model::Config`], starting from the mode's defaults), `dataset`
//! (where the recordings are and how they are split) and `train` (optimiser, schedule,
//! windows, augmentation, loss, MAML). Unknown keys are errors.

use crate::setting::InvalidSetting;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::model::{Config as ModelConfig, LossConfig, Mode};

/// The whole file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// The network (`mode: digdl | fsda | fsda_f` picks the training strategy too).
    pub model: ModelConfig,
    pub dataset: DatasetConfig,
    pub train: TrainSettings,
}

/// One recording: an ASL sequence folder (EuRoC / TUM-VI) or an MCAP bag.
#[derive(Debug, Clone, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// ASL sequence folder (`<seq>/mav0/imu0/data.csv` …), relative to `dataset.root`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sequence: Option<String>,
    /// MCAP bag, relative to `dataset.root`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bag: Option<String>,
    /// A simulated recording: an `imu-fsda simulate` config (YAML, `params/sim/`), relative to
    /// the training config's folder, simulated in memory when the data loads (the same config
    /// and seed give the same samples). Its domain and IMU are `sim`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulate: Option<String>,
    /// IMU topic of a bag (default `/imu/data`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imu_topic: Option<String>,
    /// Ground-truth topic of a bag (default `/ground_truth/pose`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ground_truth_topic: Option<String>,
    /// Keep only IMU samples from this many seconds after the first ground-truth-covered one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start_s: Option<f64>,
    /// … up to this many seconds after it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end_s: Option<f64>,
    /// Display name (default: the folder or file name, with the crop appended).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Which IMU recorded it, for a model with `model.imu_calibrations` (default: the first
    /// path component, the dataset: `euroc/MH_01_easy` → `euroc`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub imu: Option<String>,
}

/// The domain, and IMU name, of every `simulate` source.
pub const SIM_DOMAIN: &str = "sim";

/// `params/sim/aerial.yaml` → `aerial`.
pub fn file_stem(path: &str) -> String {
    Path::new(path).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| path.to_string())
}

/// `euroc/MH_01_easy` → `euroc`: the dataset of a source path (its first component).
/// The IMU name of bags given without a dataset folder ([`SourceConfig::imu_name`]).
pub const BAG_IMU: &str = "bags";

pub fn first_path_component(path: &str) -> &str {
    let s = path.trim_start_matches("./");
    s.split(['/', '\\']).next().unwrap_or(s)
}

impl SourceConfig {
    /// The IMU's name: `imu`, else the first component of the sequence or bag path (`sim` for
    /// a simulation); a bag given by an absolute path or with no folder is [`BAG_IMU`].
    pub fn imu_name(&self) -> String {
        if let Some(imu) = &self.imu {
            return imu.clone();
        }
        let path = self.path();
        let first = first_path_component(&path);
        if self.bag.is_some() && (first.is_empty() || first == path.trim_start_matches("./")) {
            // No dataset folder names its IMU: not the file's own name (every bag its own IMU,
            // each with a gain of its own no other recording can use), nor "" (an absolute path).
            return BAG_IMU.to_string();
        }
        first.to_string()
    }

    /// The source as a dataset path: the sequence or bag, or `sim/<config stem>`, whose first
    /// component is the domain ([`crate::train::fit::task_domain`]).
    pub fn path(&self) -> String {
        match (&self.sequence, &self.bag, &self.simulate) {
            (Some(p), _, _) | (None, Some(p), _) => p.clone(),
            (None, None, Some(sim)) => format!("{SIM_DOMAIN}/{}", file_stem(sim)),
            (None, None, None) => "?".into(),
        }
    }

    pub fn describe(&self) -> String {
        let what = self.path();
        match (self.start_s, self.end_s) {
            (None, None) => what.to_string(),
            (a, b) => format!("{what} [{}–{} s]", a.unwrap_or(0.0), b.map_or("end".to_string(), |b| b.to_string())),
        }
    }
}

/// Where the data is and how it is split.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    /// Base of relative source paths; relative to the config file's folder.
    #[serde(default = "default_root")]
    pub root: PathBuf,
    /// Training tasks (one per recording; the paper's tasks are sequences / domains).
    pub train: Vec<SourceConfig>,
    /// Held out, evaluated every `train.eval_every` epochs (and used to pick the best model
    /// when `train.select_best`).
    #[serde(default)]
    pub validation: Vec<SourceConfig>,
    /// Evaluated once, with the final (exported) model.
    #[serde(default)]
    pub test: Vec<SourceConfig>,
    /// Evaluated with the validation recordings (every `train.eval_every` epochs) and recorded
    /// in the checkpoint and `<name>.train.json`, never used to select anything: to study how
    /// a selection criterion tracks held-out data without letting that data choose.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub monitor: Vec<SourceConfig>,
    /// Support set: the first this-many seconds of each training task (the paper: ~60 s);
    /// the rest is the query set. Only FSDA-F splits; the other modes train on everything.
    #[serde(default = "default_support_s")]
    pub support_seconds: f64,
    /// Ground truth is interpolated between poses at most this far apart, ms.
    #[serde(default = "default_interp_gap")]
    pub max_interpolation_gap_ms: f64,
    /// An IMU sample's ground truth counts (in the loss) only if the nearest ground-truth
    /// pose is at most this far away, ms (DIGDL on TUM-VI: 10 ms).
    #[serde(default = "default_nearest")]
    pub max_nearest_gt_ms: f64,
    /// `keep` (default): the recordings as recorded. `remove`: each recording's power-on gyro
    /// bias taken out first (its standstills', else the constant its ground truth fits), so
    /// the model learns the IMU's lasting errors and is run after the node's power-on bias
    /// ([`super::power_on`]).
    #[serde(default, skip_serializing_if = "is_keep")]
    pub power_on_bias: super::power_on::PowerOnBiasInTraining,
}

fn is_keep(p: &super::power_on::PowerOnBiasInTraining) -> bool {
    *p == super::power_on::PowerOnBiasInTraining::Keep
}

impl DatasetConfig {
    /// Every source of every list (train, validation, test, monitor).
    /// `a` and `b` read some of the same samples: one recording (the same sequence folder or
    /// bag, however spelt, and IMU topic, or the same simulation config) over overlapping crops.
    pub fn same_samples(&self, a: &SourceConfig, b: &SourceConfig) -> bool {
        let topic = |s: &SourceConfig| s.imu_topic.clone().unwrap_or_else(|| crate::bag::IMU_TOPIC.to_string());
        if a.bag.is_some() && b.bag.is_some() && topic(a) != topic(b) {
            // Two IMUs of one bag are two recordings.
            return false;
        }
        let key = |s: &SourceConfig| -> Option<(u8, PathBuf)> {
            let (kind, p) = match (&s.sequence, &s.bag, &s.simulate) {
                (Some(p), _, _) => (0, self.root.join(p)),
                (None, Some(p), _) => (1, self.root.join(p)),
                (None, None, Some(p)) => (2, PathBuf::from(p)),
                _ => return None,
            };
            // Resolved where it exists (symlinks, `..`); else spelt without `.` and trailing `/`.
            Some((kind, std::fs::canonicalize(&p).unwrap_or_else(|_| p.components().collect())))
        };
        if key(a).is_none() || key(a) != key(b) {
            return false;
        }
        let span = |s: &SourceConfig| (s.start_s.unwrap_or(0.0), s.end_s.unwrap_or(f64::INFINITY));
        let ((a0, a1), (b0, b1)) = (span(a), span(b));
        a0 < b1 && b0 < a1
    }

    fn sources_mut(&mut self) -> impl Iterator<Item = &mut SourceConfig> {
        self.train.iter_mut().chain(self.validation.iter_mut()).chain(self.test.iter_mut()).chain(self.monitor.iter_mut())
    }
}

fn default_root() -> PathBuf {
    PathBuf::from(".")
}
fn default_support_s() -> f64 {
    60.0
}
fn default_interp_gap() -> f64 {
    50.0
}
fn default_nearest() -> f64 {
    10.0
}

/// Learning-rate schedule, stepped once per epoch.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Schedule {
    Constant,
    /// PyTorch's `CosineAnnealingWarmRestarts(T_0, T_mult, eta_min)` (DIGDL: 600, 2, 1e-3).
    CosineWarmRestarts {
        t0: usize,
        t_mult: usize,
        #[serde(default)]
        eta_min: f64,
    },
}

impl Schedule {
    /// Learning rate for `epoch` (0-based) from base rate `lr`.
    pub fn lr(&self, lr: f64, epoch: usize) -> f64 {
        match *self {
            Schedule::Constant => lr,
            Schedule::CosineWarmRestarts { t0, t_mult, eta_min } => {
                let (mut t_i, mut t_cur) = (t0.max(1), epoch);
                while t_cur >= t_i {
                    t_cur -= t_i;
                    t_i *= t_mult.max(1);
                }
                eta_min + (lr - eta_min) * (1.0 + (std::f64::consts::PI * t_cur as f64 / t_i as f64).cos()) / 2.0
            }
        }
    }
}

/// Noise added to the training inputs (DIGDL's augmentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Augment {
    /// White noise on the gyro, rad/s (std).
    pub gyro_noise_std: f64,
    /// White noise on the accelerometer, m/s² (std).
    pub accel_noise_std: f64,
    /// A constant gyro offset per window, uniform in ±this, rad/s.
    pub gyro_offset: f64,
    /// A constant accelerometer offset per window, uniform in ±this, m/s². DIGDL's code
    /// draws its "bias repeatability" for all six channels and then scales only a slice of an
    /// axis of length one, so every channel gets ±1e-3: its config sets this to 1e-3.
    pub accel_offset: f64,
}

impl Default for Augment {
    fn default() -> Self {
        Self { gyro_noise_std: 8e-5, accel_noise_std: 1e-3, gyro_offset: 1e-3, accel_offset: 0.0 }
    }
}

/// The few-shot (MAML) strategy of FSDA-F.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MamlConfig {
    /// α: inner (task) learning rate of plain gradient descent on θ_e.
    pub inner_lr: f64,
    /// Inner gradient steps per task.
    pub inner_steps: usize,
    /// First-order MAML (no gradient through the inner gradient).
    pub first_order: bool,
    /// Windows drawn from each task's support set per epoch, and their length (samples).
    pub support_windows: usize,
    pub support_window_samples: usize,
    /// Windows drawn from each task's query set per epoch, and their length (samples).
    pub query_windows: usize,
    pub query_window_samples: usize,
    /// Run all tasks' windows through the Restructor and Generator in one batch (each task
    /// still has its own fast Embedding weights), so BatchNorm's training statistics span
    /// every task and domain — as in DIGDL's one-batch step and as the folded running
    /// statistics used at test time. `false`: one forward per task, whose BatchNorm
    /// statistics are that one task's (a domain's constant features are normalised away in
    /// training but not at test time).
    pub batch_tasks: bool,
    /// λ_s: the same for the support windows (the first `support_seconds` of each task, which
    /// the paper's outer loss never scores; the shipped model runs over them too). Free: it
    /// reuses the inner step's forward at θ_e.
    pub unadapted_support_weight: f64,
    /// With `batch_tasks` and one inner step: every task takes the same step,
    /// θ_e − α ∇_θe Σ_i L_support,i (the task batch's summed support losses), instead of the
    /// paper's per-task θ_e − α ∇ L_support,i. Not MAML; it is how the bundled v9 model was
    /// trained (a bug until `f55eb49`), kept so that `params/train/fsda-f.yaml` reproduces it.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub shared_inner_step: bool,
}

impl Default for MamlConfig {
    fn default() -> Self {
        Self {
            inner_lr: 1e-3,
            inner_steps: 1,
            first_order: false,
            support_windows: 1,
            support_window_samples: 4000,
            query_windows: 1,
            query_window_samples: 4000,
            batch_tasks: false,
            unadapted_support_weight: 0.0,
            shared_inner_step: false,
        }
    }
}

/// Optimisation.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSettings {
    /// Seed of everything random (tch and the window sampler); `--seed` overrides.
    #[serde(default)]
    pub seed: u64,
    /// Restarts: `imu-fsda train` trains one run per seed (`<name>-s<seed>`, several at once)
    /// and exports the one with the lowest validation score at its exported epoch as
    /// `<name>` (`train::seeds`). Empty (default): one run with `seed`. `--seed` trains that
    /// one seed only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub seeds: Vec<u64>,
    /// Epochs; one epoch = one optimiser step on one batch (DIGDL's definition).
    pub epochs: usize,
    /// Adam (PyTorch semantics: L2 weight decay added to the gradient).
    #[serde(default = "default_lr")]
    pub lr: f64,
    #[serde(default = "default_wd")]
    pub weight_decay: f64,
    #[serde(default = "default_schedule")]
    pub schedule: Schedule,
    /// Windows per training sequence per epoch (DIGDL and FSDA), and their length (DIGDL:
    /// 16000 samples, one window per sequence, all sequences in one batch).
    #[serde(default = "default_one")]
    pub windows_per_sequence: usize,
    #[serde(default = "default_window")]
    pub window_samples: usize,
    /// DIGDL and FSDA: each window starts at a random sample among the first this many of its
    /// recording, so every epoch trains on (nearly) the same first `window_samples` of every
    /// sequence, its start included (DIGDL's `max_train_freq`: 32). Absent: anywhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window_start_within: Option<usize>,
    #[serde(default)]
    pub augment: Augment,
    #[serde(default)]
    pub loss: LossConfig,
    #[serde(default)]
    pub maml: MamlConfig,
    /// Held-out evaluation period, epochs (0: only at the end).
    #[serde(default)]
    pub eval_every: usize,
    /// Checkpoint period, epochs (0: only at the end).
    #[serde(default)]
    pub checkpoint_every: usize,
    /// Export the epoch with the lowest validation AOE instead of the last one. The score is
    /// the validation recordings' mean AOE weighted like `task_weighting` (`per_domain`: each
    /// dataset's mean counts once), so one dataset's larger angles do not choose alone.
    #[serde(default)]
    pub select_best: bool,
    /// libtorch intra-op threads. 1 is the fastest on these shared 2-core machines (measured:
    /// FSDA-F 2.3 s/epoch at 1 thread vs 15 s at 2 with libgomp's default spinning wait
    /// policy, 2.6 s at 2 with `OMP_WAIT_POLICY=passive`; docs/training.md).
    #[serde(default = "default_threads")]
    pub threads: i32,
    /// How the FSDA-F tasks' query losses are averaged: `uniform` (mean over tasks) or
    /// `per_domain` (each domain — the first path component of the source, e.g. `euroc`,
    /// `tumvi` — gets the same total weight, split evenly among its tasks).
    #[serde(default)]
    pub task_weighting: TaskWeighting,
    /// Start the learned correction ω' at zero (the last conv of the Generator / DIGDL CNN
    /// initialised to 0), so the untrained model is the raw gyro through Ĉ_ω = I.
    #[serde(default)]
    pub zero_init_correction: bool,
    /// IMUs whose data is already calibrated (TUM-VI's BMI160 is published corrected): their
    /// recordings train with Ĉ_ω = I, and with `model.imu_calibrations` their own Ĉ_ω stays I
    /// (it gets no gradient). Names as `SourceConfig::imu_name`.
    #[serde(default)]
    pub calibrated_imus: Vec<String>,
    /// Wall-time budget of the training loop, seconds (0: none), counted over the whole run (a
    /// resumed run starts from its checkpoint's seconds). When an epoch ends past it, training
    /// stops there and that epoch is exported (recorded as `stopped_at_budget` in the metrics);
    /// the schedule is not rescaled, so size `epochs` to fit and keep this a guard.
    #[serde(default)]
    pub max_train_seconds: f64,
    /// After training, fit one correction gain per IMU of `dataset.validation`
    /// ([`crate::train::fit::fit_correction_gains`]) and export it with the model
    /// (`ModelMetadata::imu_correction_gains`); the test recordings are scored with their IMU's.
    #[serde(default)]
    pub correction_gains: bool,
    /// Start from a trained model's weights (its `<name>.json`, relative to the config file),
    /// normalisation included, instead of a fresh initialisation: a fine-tune. The model's
    /// config must equal `model`. Adam starts afresh; `zero_init_correction` is not applied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<PathBuf>,
}

/// See [`TrainSettings::task_weighting`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskWeighting {
    #[default]
    Uniform,
    PerDomain,
}

fn default_lr() -> f64 {
    0.01
}
fn default_wd() -> f64 {
    0.1
}
fn default_schedule() -> Schedule {
    Schedule::CosineWarmRestarts { t0: 600, t_mult: 2, eta_min: 0.0 }
}
fn default_one() -> usize {
    1
}
fn default_window() -> usize {
    16000
}
fn default_threads() -> i32 {
    1
}

/// A config file that could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {msg}")]
    Parse { path: PathBuf, msg: String },
    #[error("{path}: {msg}")]
    Invalid { path: PathBuf, msg: String },
}

impl TrainConfig {
    /// The keys (`section.key`) in which `other` trains a different run from `self`: all but
    /// how long it runs and how it is watched (epochs, time budget, seed and seeds, evaluation
    /// and checkpoint cadence, threads, the validation, monitor and test lists). A resumed or
    /// reused run must not differ in any of them.
    pub fn run_differences(&self, other: &TrainConfig) -> Vec<String> {
        const WATCHING: [&str; 10] = [
            "train.epochs",
            "train.max_train_seconds",
            "train.seed",
            "train.seeds",
            "train.eval_every",
            "train.checkpoint_every",
            "train.threads",
            "dataset.validation",
            "dataset.monitor",
            "dataset.test",
        ];
        // The data root by any spelling of the same folder.
        let canonical = |c: &TrainConfig| {
            let mut c = c.clone();
            c.dataset.root = std::fs::canonicalize(&c.dataset.root).unwrap_or(c.dataset.root);
            serde_json::to_value(c).unwrap_or_default()
        };
        let (a, b) = (canonical(self), canonical(other));
        let mut out = Vec::new();
        for section in ["model", "dataset", "train"] {
            let (sa, sb) = (&a[section], &b[section]);
            let keys: BTreeSet<&String> = sa.as_object().into_iter().chain(sb.as_object()).flat_map(|o| o.keys()).collect();
            for k in keys {
                let key = format!("{section}.{k}");
                if !WATCHING.contains(&key.as_str()) && sa.get(k) != sb.get(k) {
                    out.push(key);
                }
            }
        }
        out
    }

    /// Reads and checks a config file; `dataset.root` is made absolute against the file's
    /// folder. The `model` section starts from [`ModelConfig::for_mode`] of its `mode`, so
    /// `model: {mode: digdl}` gets all of DIGDL's published settings.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io { path: path.into(), source })?;
        let mut cfg = Self::parse(&text).map_err(|msg| ConfigError::Parse { path: path.into(), msg })?;
        let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        if cfg.dataset.root.is_relative() {
            cfg.dataset.root = base.join(&cfg.dataset.root);
        }
        if let Some(init) = cfg.train.init_from.as_mut().filter(|p| p.is_relative()) {
            *init = base.join(&*init);
        }
        for src in cfg.dataset.sources_mut() {
            if let Some(sim) = src.simulate.as_mut().filter(|s| Path::new(s.as_str()).is_relative()) {
                *sim = base.join(sim.as_str()).to_string_lossy().into_owned();
            }
        }
        cfg.validate().map_err(|e| ConfigError::Invalid { path: path.into(), msg: e.to_string() })?;
        Ok(cfg)
    }

    /// Parses YAML text (no path resolution).
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut doc: serde_yaml::Value = serde_yaml::from_str(text).map_err(|e| e.to_string())?;
        let map = doc.as_mapping_mut().ok_or("expected a mapping with model, dataset and train")?;
        let mut model = map.get("model").cloned().unwrap_or(serde_yaml::Value::Mapping(Default::default()));
        // The CLI spelling `fsda-f` is accepted beside serde's `fsda_f`.
        if let Some(m) = model.as_mapping_mut().and_then(|m| m.get_mut("mode")) {
            if m.as_str() == Some("fsda-f") {
                *m = "fsda_f".into();
            }
        }
        let mode: Mode = match model.get("mode") {
            Some(m) => serde_yaml::from_value(m.clone()).map_err(|e| format!("model.mode: {e}"))?,
            None => Mode::FsdaF,
        };
        let mut merged = serde_yaml::to_value(ModelConfig::for_mode(mode)).map_err(|e| e.to_string())?;
        if let (Some(base), Some(over)) = (merged.as_mapping_mut(), model.as_mapping()) {
            for (k, v) in over {
                if base.get(k).is_none() {
                    return Err(format!("model: unknown key {k:?}"));
                }
                base.insert(k.clone(), v.clone());
            }
        }
        map.insert("model".into(), merged);
        // Keys serde would take and then not use: `seed` beside `seeds` (which one trains?),
        // `seeds: []` (read as absent: one run with seed 0), MAML settings outside fsda_f.
        if let Some(train) = map.get("train").and_then(|t| t.as_mapping()) {
            // A key left empty (`seeds:`) is YAML's null: absent, as serde reads it.
            let given = |k: &str| train.get(k).filter(|v| !v.is_null());
            let seeds = given("seeds");
            if given("seed").is_some() && seeds.is_some() {
                return Err(
                    "train.seed and train.seeds: give one (seeds trains one run per seed and exports the best; seed trains one run)".into(),
                );
            }
            if seeds.and_then(|s| s.as_sequence()).is_some_and(|s| s.is_empty()) {
                return Err("train.seeds is empty: list the seeds to train, or give train.seed for one run".into());
            }
            if given("maml").is_some() && mode != Mode::FsdaF {
                return Err(format!(
                    "train.maml: the few-shot settings apply to model.mode fsda_f only, and this config's mode is {}: remove the section",
                    serde_yaml::to_value(mode).ok().and_then(|v| v.as_str().map(str::to_string)).unwrap_or_default()
                ));
            }
        }
        serde_yaml::from_value(doc).map_err(|e| {
            // A value's error has no place in the file; the text's own, where it fails too,
            // names the key and the line.
            // (Not for the `model` section: the text's lacks the mode's defaults.)
            // `fsda-f` → `fsda_f` as above (same length: lines and columns stay).
            match serde_yaml::from_str::<TrainConfig>(&text.replace("fsda-f", "fsda_f")) {
                Err(located) if !located.to_string().starts_with("model") => located.to_string(),
                _ => e.to_string(),
            }
        })
    }

    /// Checks values that serde cannot.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.model.validate().map_err(|e| format!("model: {e}"))?;
        self.validate_recordings()?;
        self.validate_optimisation()?;
        self.validate_ground_truth()?;
        self.validate_maml()?;
        self.validate_selection_and_budget()
    }

    /// The recording lists: one source each, crops in order, no test recording trained on.
    fn validate_recordings(&self) -> Result<(), InvalidSetting> {
        if self.dataset.train.is_empty() {
            return Err("dataset.train is empty".into());
        }
        for (what, list) in [
            ("train", &self.dataset.train),
            ("validation", &self.dataset.validation),
            ("test", &self.dataset.test),
            ("monitor", &self.dataset.monitor),
        ] {
            for (i, s) in list.iter().enumerate() {
                if [s.sequence.is_some(), s.bag.is_some(), s.simulate.is_some()].iter().filter(|x| **x).count() != 1 {
                    return Err(format!("dataset.{what}[{i}]: give exactly one of `sequence`, `bag` or `simulate`").into());
                }
                if let Some(v) = [s.start_s, s.end_s].into_iter().flatten().find(|v| !(v.is_finite() && *v >= 0.0)) {
                    return Err(
                        format!("dataset.{what}[{i}]: start_s / end_s {v}: seconds from the first sample with ground truth, ≥ 0").into()
                    );
                }
                if let (Some(a), Some(b)) = (s.start_s, s.end_s) {
                    if !is_after(a, b) {
                        return Err(format!("dataset.{what}[{i}]: end_s {b} must be after start_s {a}").into());
                    }
                }
            }
        }
        // A test recording trained on scores the model on what it has seen, under a heading
        // that says held out. (Validation may repeat training recordings: the shipped recipe
        // chooses its seed on them.)
        for (i, test) in self.dataset.test.iter().enumerate() {
            if let Some(train) = self.dataset.train.iter().find(|tr| self.dataset.same_samples(tr, test)) {
                return Err(format!(
                    "dataset.test[{i}] ({}) overlaps dataset.train's {}: a test recording must be held out (crop them apart with start_s / end_s, or score training data with `imu-fsda eval`)",
                    test.describe(),
                    train.describe()
                ).into());
            }
        }
        Ok(())
    }

    /// Epochs, learning rate, the windows drawn and their lengths, augmentation, the loss.
    fn validate_optimisation(&self) -> Result<(), InvalidSetting> {
        let t = &self.train;
        if t.epochs == 0 {
            return Err("train.epochs must be ≥ 1".into());
        }
        if !positive(t.lr) || !non_negative(t.weight_decay) {
            return Err("train.lr must be > 0 and train.weight_decay ≥ 0".into());
        }
        if t.windows_per_sequence == 0 || t.maml.support_windows == 0 || t.maml.query_windows == 0 {
            return Err("window counts must be ≥ 1".into());
        }
        if t.window_start_within == Some(0) {
            return Err("train.window_start_within must be ≥ 1 (absent: windows start anywhere)".into());
        }
        if t.window_start_within.is_some() && self.model.mode == Mode::FsdaF {
            return Err("train.window_start_within applies to digdl and fsda (fsda_f draws support and query windows)".into());
        }
        let augment_ok = |a: &Augment| [a.gyro_noise_std, a.accel_noise_std, a.gyro_offset, a.accel_offset].into_iter().all(non_negative);
        if !augment_ok(&t.augment) {
            return Err("train.augment: every noise std and offset must be finite and ≥ 0".into());
        }
        let loss = &self.train.loss;
        loss.validate("train.loss")?;
        let min_window = loss.min_window_samples() as usize;
        // Only the windows this mode trains on (fsda_f: the MAML ones; the others: window_samples).
        let windows = if self.model.mode == Mode::FsdaF {
            vec![
                ("train.maml.support_window_samples", t.maml.support_window_samples),
                ("train.maml.query_window_samples", t.maml.query_window_samples),
            ]
        } else {
            vec![("train.window_samples", t.window_samples)]
        };
        for (what, w) in windows {
            if w <= min_window {
                return Err(format!(
                    "{what} = {w}: must exceed {min_window} samples (every increment length must score one increment after its skip)"
                )
                .into());
            }
        }
        Ok(())
    }

    /// How ground truth is matched to the IMU, and the support set's length.
    fn validate_ground_truth(&self) -> Result<(), InvalidSetting> {
        if !positive(self.dataset.max_interpolation_gap_ms) || !positive(self.dataset.max_nearest_gt_ms) {
            return Err(format!(
                "dataset.max_interpolation_gap_ms ({}) and max_nearest_gt_ms ({}) must be finite and > 0",
                self.dataset.max_interpolation_gap_ms, self.dataset.max_nearest_gt_ms
            )
            .into());
        }
        if self.model.mode == Mode::FsdaF && !positive(self.dataset.support_seconds) {
            return Err("dataset.support_seconds must be > 0 for fsda_f".into());
        }
        Ok(())
    }

    /// The few-shot inner loop.
    fn validate_maml(&self) -> Result<(), InvalidSetting> {
        let t = &self.train;
        if !non_negative(t.maml.inner_lr) || t.maml.inner_steps == 0 {
            return Err("train.maml.inner_lr must be ≥ 0 and inner_steps ≥ 1".into());
        }
        if t.maml.shared_inner_step && (!t.maml.batch_tasks || t.maml.inner_steps != 1) {
            return Err("train.maml.shared_inner_step needs batch_tasks: true and inner_steps: 1".into());
        }
        if !non_negative(t.maml.unadapted_support_weight) {
            return Err("train.maml.unadapted_support_weight must be ≥ 0".into());
        }
        Ok(())
    }

    /// The epoch and seed selection, the schedule, the time budget, threads.
    fn validate_selection_and_budget(&self) -> Result<(), InvalidSetting> {
        let t = &self.train;
        if t.select_best && self.dataset.validation.is_empty() {
            return Err("train.select_best chooses the epoch by dataset.validation, which is empty".into());
        }
        if t.correction_gains && self.dataset.validation.is_empty() {
            return Err("train.correction_gains fits on dataset.validation, which is empty".into());
        }
        if let Schedule::CosineWarmRestarts { t0, t_mult, eta_min } = t.schedule {
            if t0 < 1 || t_mult < 1 || !non_negative(eta_min) || eta_min > t.lr {
                return Err(format!(
                    "train.schedule: cosine_warm_restarts needs t0 ≥ 1, t_mult ≥ 1 and 0 ≤ eta_min ≤ train.lr, got t0 {t0}, t_mult {t_mult}, eta_min {eta_min}"
                ).into());
            }
        }
        if !non_negative(t.max_train_seconds) {
            return Err(format!("train.max_train_seconds must be finite and ≥ 0 (0: no budget), got {}", t.max_train_seconds).into());
        }
        if t.threads < 1 {
            return Err("train.threads must be ≥ 1".into());
        }
        if !t.seeds.is_empty() {
            let mut s = t.seeds.clone();
            s.sort_unstable();
            s.dedup();
            if s.len() != t.seeds.len() {
                return Err(format!("train.seeds {:?} repeats a seed", t.seeds).into());
            }
            if self.dataset.validation.is_empty() {
                return Err("train.seeds picks a run by its validation score: dataset.validation is empty".into());
            }
        }
        Ok(())
    }
}

/// Finite and > 0 (NaN is not).
fn positive(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

/// Finite and ≥ 0 (NaN is not).
fn non_negative(x: f64) -> bool {
    x.is_finite() && x >= 0.0
}

/// `b` strictly after `a`, both finite.
fn is_after(a: f64, b: f64) -> bool {
    a.is_finite() && b.is_finite() && b > a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every shipped training config parses and validates (paths are not opened).
    #[test]
    fn every_config_in_params_train_is_valid() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("params/train");
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "yaml") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                n += 1;
            }
        }
        assert!(n >= 6, "{n} configs in {}", dir.display());
    }

    #[test]
    fn cosine_warm_restarts_match_pytorch() {
        let s = Schedule::CosineWarmRestarts { t0: 600, t_mult: 2, eta_min: 0.0 };
        assert_eq!(s.lr(0.01, 0), 0.01);
        assert!((s.lr(0.01, 300) - 0.005).abs() < 1e-12);
        assert_eq!(s.lr(0.01, 600), 0.01); // restart
        assert!((s.lr(0.01, 600 + 600) - 0.005).abs() < 1e-12); // half of the 1200-epoch cycle
        assert_eq!(s.lr(0.01, 1800), 0.01);
    }

    /// DIGDL's schedule floors at eta_min = 1e-3 (its main_EUROC.py), not at 0.
    #[test]
    fn cosine_warm_restarts_respect_eta_min() {
        let s = Schedule::CosineWarmRestarts { t0: 600, t_mult: 2, eta_min: 1e-3 };
        assert!((s.lr(0.01, 300) - 0.0055).abs() < 1e-12);
        assert!(s.lr(0.01, 599) > 1e-3 && s.lr(0.01, 1799) > 1e-3);
        assert!((s.lr(0.01, 600) - 0.01).abs() < 1e-15); // restart
    }

    /// A cosine schedule that cannot run, and a wall-time budget that is not one, are refused.
    #[test]
    fn schedule_and_budget_out_of_range_are_refused() {
        let with = |train: &str| {
            TrainConfig::parse(&format!(
                "model: {{mode: fsda_f}}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 3, lr: 0.01, {train}}}\n"
            ))
            .unwrap()
            .validate()
        };
        assert!(with("schedule: {kind: cosine_warm_restarts, t0: 600, t_mult: 2, eta_min: 1.0e-3}").is_ok());
        for bad in [
            "schedule: {kind: cosine_warm_restarts, t0: 0, t_mult: 2}",
            "schedule: {kind: cosine_warm_restarts, t0: 600, t_mult: 0}",
            "schedule: {kind: cosine_warm_restarts, t0: 600, t_mult: 2, eta_min: .nan}",
            "schedule: {kind: cosine_warm_restarts, t0: 600, t_mult: 2, eta_min: 0.1}",
        ] {
            assert!(with(bad).unwrap_err().to_string().contains("train.schedule"), "{bad}");
        }
        for bad in ["max_train_seconds: -1", "max_train_seconds: .nan", "max_train_seconds: .inf"] {
            assert!(with(bad).unwrap_err().to_string().contains("train.max_train_seconds"), "{bad}");
        }
    }

    /// DIGDL's sampling (windows from a recording's first samples) and its all-channel offset
    /// parse; nonsense is refused before any data is read.
    #[test]
    fn window_start_and_offsets_are_checked() {
        let with = |model: &str, train: &str| {
            TrainConfig::parse(&format!("model: {{mode: {model}}}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 3, {train}}}\n"))
                .unwrap()
                .validate()
        };
        assert!(with("digdl", "window_start_within: 32, augment: {accel_offset: 1.0e-3}").is_ok());
        assert!(with("fsda", "window_start_within: 1").is_ok());
        assert!(with("digdl", "window_start_within: 0").unwrap_err().to_string().contains("window_start_within"));
        assert!(with("fsda_f", "window_start_within: 32").unwrap_err().to_string().contains("digdl and fsda"));
        assert!(with("digdl", "augment: {gyro_offset: -1.0e-3}").unwrap_err().to_string().contains("augment"));
        assert!(with("digdl", "augment: {accel_offset: .nan}").unwrap_err().to_string().contains("augment"));
    }

    /// A bad value names its key and line (the merged document's error had neither).
    #[test]
    fn a_bad_value_names_its_key_and_line() {
        let e = TrainConfig::parse("model: {mode: fsda}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: -5}\n").unwrap_err();
        assert!(e.contains("train.epochs") && e.contains("line 3"), "{e}");
        let e =
            TrainConfig::parse("model: {mode: fsda-f}\ndataset: {train: [{sequence: a, end_s: sixty}]}\ntrain: {epochs: 5}\n").unwrap_err();
        assert!(e.contains("end_s") && e.contains("line 2"), "{e}");
        let e = TrainConfig::parse("model: {mode: fsda, hidden: x}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 5}\n").unwrap_err();
        assert!(e.contains("hidden"), "{e}");
    }

    /// Keys that would be read and then not used are refused by name.
    #[test]
    fn unused_seed_and_maml_keys_are_refused() {
        let parse = |model: &str, train: &str| {
            TrainConfig::parse(&format!(
                "model: {{mode: {model}}}\ndataset: {{train: [{{sequence: a}}], validation: [{{sequence: a}}]}}\ntrain: {{epochs: 3, {train}}}\n"
            ))
        };
        assert!(parse("fsda_f", "seed: 1, seeds: [2, 3]").unwrap_err().contains("give one"));
        assert!(parse("fsda_f", "seeds: []").unwrap_err().contains("train.seeds is empty"));
        assert!(parse("fsda_f", "seeds: [2, 3]").is_ok() && parse("fsda_f", "seed: 2").is_ok());
        let e = parse("digdl", "maml: {inner_lr: 0.1}").unwrap_err();
        assert!(e.contains("fsda_f only") && e.contains("is digdl"), "{e}");
        assert!(parse("fsda", "maml: {}").unwrap_err().contains("is fsda:"));
        assert!(parse("fsda_f", "maml: {inner_lr: 0.1}").is_ok());
        // Left empty, they are absent.
        assert!(parse("fsda_f", "seed: 1, seeds: null").is_ok() && parse("fsda", "maml: null").is_ok());
    }

    /// A test recording that is also trained on is refused, however its path is spelt; crops
    /// that do not overlap are not.
    #[test]
    fn a_test_recording_must_not_be_trained_on() {
        let with = |train: &str, test: &str| {
            TrainConfig::parse(&format!("model: {{mode: fsda}}\ndataset: {{train: [{train}], test: [{test}]}}\ntrain: {{epochs: 3}}\n"))
                .unwrap()
                .validate()
        };
        let e = with("{sequence: euroc/MH_01_easy}", "{sequence: ./euroc/MH_01_easy/}").unwrap_err();
        assert!(e.to_string().contains("dataset.test[0]") && e.to_string().contains("held out"), "{e}");
        assert!(with("{bag: b/x.mcap, end_s: 60}", "{bag: b/x.mcap, start_s: 30}").is_err());
        assert!(with("{bag: b/x.mcap, end_s: 60}", "{bag: b/x.mcap, start_s: 60}").is_ok());
        assert!(with("{sequence: b/x.mcap}", "{bag: b/x.mcap}").is_ok(), "a folder and a bag are not one recording");
        assert!(with("{sequence: euroc/MH_01_easy}", "{sequence: euroc/MH_02_easy}").is_ok());
        assert!(with("{bag: b/x.mcap}", "{bag: b/x.mcap, imu_topic: /imu2/data}").is_ok(), "another IMU of the bag");
        assert!(with("{bag: b/x.mcap}", "{bag: b/x.mcap, imu_topic: /imu/data}").is_err());
    }

    #[test]
    fn model_section_starts_from_mode_defaults() {
        let text = "model: {mode: digdl}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 3}\n";
        let cfg = TrainConfig::parse(text).unwrap();
        assert_eq!(cfg.model, ModelConfig::for_mode(Mode::Digdl));
        assert!(TrainConfig::parse("model: {mode: digdl, nope: 1}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 3}\n").is_err());
        // Every model key a config may set is known to the merge, optional ones included.
        let rbn = "model: {batch_norm: false, restructor_batch_norm: true}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 3}\n";
        let cfg = TrainConfig::parse(rbn).unwrap();
        assert_eq!((cfg.model.batch_norm, cfg.model.restructor_batch_norm), (false, Some(true)));
        assert!(TrainConfig::parse("model: {}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 3, bogus: 1}\n").is_err());
        let both = TrainConfig::parse("model: {}\ndataset: {train: [{sequence: a, bag: b}]}\ntrain: {epochs: 3}\n").unwrap();
        assert!(both.validate().unwrap_err().to_string().contains("exactly one"));
    }

    /// `train.seeds` chooses by validation score: it needs a validation set and distinct seeds.
    #[test]
    fn seed_lists_need_a_validation_set_and_distinct_seeds() {
        let with = |dataset: &str, seeds: &str| {
            TrainConfig::parse(&format!("model: {{}}\ndataset: {dataset}\ntrain: {{epochs: 3, seeds: {seeds}}}\n")).unwrap().validate()
        };
        let with_val = "{train: [{sequence: a}], validation: [{sequence: a}]}";
        assert!(with(with_val, "[0, 1, 2]").is_ok());
        assert!(with(with_val, "[0, 1, 0]").unwrap_err().to_string().contains("repeats"));
        assert!(with("{train: [{sequence: a}]}", "[0, 1]").unwrap_err().to_string().contains("dataset.validation is empty"));
        assert!(with("{train: [{sequence: a}], monitor: [{sequence: b}]}", "[0, 1]").unwrap_err().to_string().contains("validation"));
    }

    #[test]
    fn bad_loss_settings_are_refused() {
        let with = |loss: &str| {
            TrainConfig::parse(&format!("model: {{}}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 3, loss: {loss}}}\n"))
                .unwrap()
                .validate()
        };
        assert!(with("{skip_first_samples: 517}").is_ok());
        assert!(with("{skip_first_samples: -1}").unwrap_err().to_string().contains("skip_first_samples"));
        assert!(with("{skip_first_increments: -2}").unwrap_err().to_string().contains("skip_first_increments"));
        assert!(with("{increments: []}").unwrap_err().to_string().contains("increments"));
        assert!(with("{increments: [{samples: 0, weight: 1.0}]}").unwrap_err().to_string().contains("increments"));
        assert!(with("{increments: [{samples: 16, weight: -1.0}]}").unwrap_err().to_string().contains("increments"));
        assert!(with("{huber_delta_rad: 0.0}").unwrap_err().to_string().contains("huber_delta_rad"));
        assert!(with("{increments: [{samples: 16, weight: 1.0, huber_delta_rad: 0.0}]}")
            .unwrap_err()
            .to_string()
            .contains("huber_delta_rad"));
        assert!(with("{increments: [{samples: 16, weight: 1.0, huber_delta_rad: .nan}]}")
            .unwrap_err()
            .to_string()
            .contains("huber_delta_rad"));
        assert!(with("{gamma: -1.0}").unwrap_err().to_string().contains("gamma"));
        assert!(with("{reconstruction_weight: -0.5}").unwrap_err().to_string().contains("reconstruction_weight"));
        let maml = |m: &str| {
            TrainConfig::parse(&format!("model: {{}}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 3, maml: {m}}}\n"))
                .unwrap()
                .validate()
        };
        let removed =
            TrainConfig::parse("model: {}\ndataset: {train: [{sequence: a}]}\ntrain: {epochs: 3, maml: {unadapted_query_weight: 1.0}}\n");
        assert!(removed.unwrap_err().contains("unknown field"), "an experiment's key, removed");
        assert!(maml("{unadapted_support_weight: -1.0}").unwrap_err().to_string().contains("unadapted_support_weight"));
    }

    /// A fine-tune's start (`init_from`) is read against the config's folder.
    #[test]
    fn fine_tune_settings_are_checked() {
        let dir = std::env::temp_dir().join(format!("imu-fsda-init-from-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("c.yaml");
        let with = |model: &str, train: &str| {
            std::fs::write(&path, format!("model: {model}\ndataset: {{train: [{{sequence: a}}]}}\ntrain: {{epochs: 10, {train}}}\n"))
                .unwrap();
            TrainConfig::load(&path).map_err(|e| e.to_string())
        };
        let cfg = with("{mode: fsda_f}", "init_from: ../m/fsda-f.json, maml: {batch_tasks: true}").unwrap();
        assert_eq!(cfg.train.init_from.as_deref(), Some(dir.join("../m/fsda-f.json").as_path()));
        let abs = with("{mode: fsda_f}", "init_from: /m/x.json").unwrap();
        assert_eq!(abs.train.init_from.as_deref(), Some(Path::new("/m/x.json")));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
