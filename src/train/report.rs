//! What a training run records: per-epoch losses, held-out evaluations, the summary written
//! to `<out>/<name>.train.json`.

use serde::{Deserialize, Serialize};

use crate::eval::OrientationErrors;

/// One epoch's numbers (losses are the batch means that were back-propagated).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpochRecord {
    pub epoch: usize,
    pub lr: f64,
    /// FSDA-F: mean over tasks of the query loss with adapted θ_e'; otherwise the batch loss.
    pub loss: f64,
    /// `L^D` part (before γ).
    pub increment: f64,
    /// `L^R` part (FSDA modes).
    pub reconstruction: Option<f64>,
    /// FSDA-F: mean support loss before adaptation.
    pub support_loss: Option<f64>,
    pub grad_norm: f64,
    pub seconds: f64,
}

/// A held-out recording's raw-gyro errors and its evaluations during training.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SequenceEvals {
    pub name: String,
    pub source: String,
    pub raw: OrientationErrors,
    /// (epochs completed, errors).
    pub evals: Vec<(usize, OrientationErrors)>,
}

/// A test recording: raw gyro against the exported model.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TestResult {
    pub name: String,
    pub source: String,
    pub raw: OrientationErrors,
    /// The exported model as deployed on the recording's IMU (with its correction gain).
    pub model: OrientationErrors,
    /// With a correction gain ≠ 1: the model without it (all of its correction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model_without_gain: Option<OrientationErrors>,
}

/// One training recording as used.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TaskInfo {
    pub name: String,
    pub source: String,
    pub samples: usize,
    pub seconds: f64,
    /// FSDA-F: support-set samples (the rest is the query set).
    pub support_samples: usize,
    pub valid_fraction: f64,
}

/// `<name>.train.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainSummary {
    pub name: String,
    pub mode: crate::model::Mode,
    pub seed: u64,
    /// Epochs trained (fewer than the config's when the time budget stopped the run).
    pub epochs: usize,
    /// The config's epochs, where the wall-time budget (`train.max_train_seconds`) stopped the
    /// run before them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epochs_planned: Option<usize>,
    pub resumed_from_epoch: Option<usize>,
    /// The epoch count of the exported weights.
    pub exported_epoch: usize,
    /// Mean loss over the first and last min(5, epochs/4) epochs.
    pub loss_first: f64,
    pub loss_last: f64,
    pub train_seconds: f64,
    pub seconds_per_epoch: f64,
    pub threads: i32,
    pub tasks: Vec<TaskInfo>,
    pub validation: Vec<SequenceEvals>,
    /// `dataset.monitor`: evaluated with the validation set, never selected on.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub monitor: Vec<SequenceEvals>,
    /// `train.correction_gains`: the gain per IMU ([`crate::model::ModelMetadata::imu_correction_gains`]).
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub correction_gains: std::collections::BTreeMap<String, f64>,
    /// The validation recordings scored with those gains at the exported epoch (what the
    /// model does as deployed; `train.seeds` chooses on it when present).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub validation_with_gain: Vec<SequenceEvals>,
    pub test: Vec<TestResult>,
    pub history: Vec<EpochRecord>,
    pub model_json: String,
    pub config: super::config::TrainConfig,
}
