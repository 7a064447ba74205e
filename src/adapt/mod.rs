//! On-demand few-shot adaptation (paper §III-B at test time): from a model's meta-learned
//! initialisation, a few to some tens of first-order steps of the inner loop on the
//! Embedding θ_e only (`θ_e ← θ_e − α ∇_{θ_e} L_support`, `L = L^R + γ L^D`, the trainer's own
//! [`crate::train::fit::embedding_inner_step`]) on a support recording with ground truth;
//! the Restructor, Generator and Ĉ_ω are frozen. The adapted model is accepted only if its
//! open-loop orientation error (AOE, [`crate::eval::evaluate`]) on a held-back query
//! recording is lower than the starting model's; otherwise it is rejected with the figures.
//!
//! Files: [`frame`] (is the ground truth in the IMU's frame?), [`calibration`] (Ĉ_ω in closed
//! form), [`judge`] (other power-ons), [`pieces`] and [`keep`] (what is kept without them),
//! [`swap`] (the node's between-two-samples model swap). See docs/adaptation.md.

pub mod calibration;
pub mod frame;
pub mod judge;
pub mod keep;
pub mod pieces;
pub mod swap;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use tch::{nn::VarStore, Device, Tensor};

use crate::core::Recording;
use crate::eval::{EvalOptions, OrientationErrors};
use crate::model::export::{export_model, ExportInfo, ExportPaths, LoadedNet, ModelMetadata};
use crate::model::loss::LossConfig;
use crate::model::{ModelError, Net};
use crate::train::config::{DatasetConfig, SourceConfig};
use crate::train::data::{self, DataError, Task};
use crate::train::fit::{embedding_and_extra_grads, embedding_inner_step, evaluate_net, evaluate_net_with_gain, evaluate_raw};

pub use frame::{check_frame, FrameCheck};
pub use judge::{judge, judge_each, CarryOver, Judged};
pub use keep::keep_without_judge;
pub use pieces::PieceConfidence;

/// What to do when the ground truth's body frame differs from the IMU's by a constant rotation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum FramePolicy {
    /// Refuse with the rotation found (the default: a frame mix-up is a set-up error).
    #[default]
    Error,
    /// Re-express the ground truth in the IMU's frame (`R_gt ← R_gt R_x`) and go on.
    Apply,
    /// Do not check for another frame (mirrored axes and inverted quaternions, which no
    /// rotation explains, are still refused).
    Ignore,
}

/// The inner loop's update rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Optimizer {
    /// Plain gradient descent, the paper's inner loop (`θ_e − α ∇L`).
    Sgd,
    /// Adam (β 0.9, 0.999) on the same gradient: far less sensitive to α (the default).
    #[default]
    Adam,
}

/// Adaptation settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptConfig {
    /// Inner steps (first-order gradient descent on θ_e).
    pub steps: usize,
    /// α, the inner learning rate.
    pub inner_lr: f64,
    pub optimizer: Optimizer,
    /// Each step's batch: this many random windows of `window_samples` from the support set
    /// (the whole support set when it is shorter than one window).
    pub windows: usize,
    pub window_samples: usize,
    /// The loss (the trainer's defaults).
    pub loss: LossConfig,
    /// Shortest support set accepted, s.
    pub min_support_seconds: f64,
    /// Shortest query set accepted, s.
    pub min_query_seconds: f64,
    /// Ground-truth interpolation: longest pose gap, and farthest nearest pose for a sample to count (ms).
    pub max_interpolation_gap_ms: f64,
    pub max_nearest_gt_ms: f64,
    /// Ground truth in another frame: error, apply or ignore; a rotation above this many
    /// degrees counts as "another frame".
    pub frame_policy: FramePolicy,
    pub frame_tolerance_deg: f64,
    /// Seed of the window sampler.
    pub seed: u64,
    /// Stop stepping after this many seconds (the steps done so far are kept).
    pub max_seconds: f64,
    /// Also adapt the calibration head (default): a closed-form step of the Generator's output
    /// bias, then Ĉ_ω and that bias by gradient beside θ_e. `false` is the paper's θ_e-only
    /// step: a model meta-trained on one IMU has seen one bias, so its Generator may have no
    /// input that maps to another IMU's bias, and a new IMU is first of all a new bias and
    /// scale (docs/adaptation.md measures both: θ_e only was rejected on 6 of 8 unseen domains).
    pub calibration: bool,
    /// Remove the support's power-on gyro bias (measured at its standstills, as the node
    /// measures it) before adapting, and mark the model so the node removes each later
    /// power-on's: what is learned is the IMU's lasting errors, not this power-on's constant.
    /// A support without a standstill is refused. `false` writes the support's constant into
    /// the weights: the model is then for that power-on only (docs/poweron.md).
    pub power_on_bias: bool,
    /// How a standstill is recognised (the node's `pipeline.standstill`).
    pub standstill: crate::standstill::StandstillConfig,
    /// Which candidates may be kept: the adapted networks, the gyro calibration alone
    /// (Ĉ_ω fitted in closed form, with `power_on_bias` only), or either (`auto`).
    pub keep: Keep,
}

/// Which adaptation candidates may be kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Keep {
    /// Either: with other power-ons to judge on (`adapt --judge`), the one that carries over
    /// better; without, the gyro calibration where its query gain holds piece by piece, and
    /// never the networks (their query gain did not carry over to another power-on in any
    /// measured case: docs/poweron.md; [`keep_without_judge`]).
    #[default]
    Auto,
    /// The adapted networks only (the inner loop on θ_e and the calibration head).
    Networks,
    /// The gyro calibration alone.
    GyroCalibration,
}

impl Default for AdaptConfig {
    fn default() -> Self {
        AdaptConfig {
            steps: 100,
            inner_lr: 1e-2,
            optimizer: Optimizer::Adam,
            windows: 2,
            window_samples: 2000,
            loss: LossConfig::default(),
            min_support_seconds: 20.0,
            min_query_seconds: 10.0,
            max_interpolation_gap_ms: 50.0,
            max_nearest_gt_ms: 10.0,
            frame_policy: FramePolicy::Error,
            frame_tolerance_deg: 5.0,
            seed: 0,
            max_seconds: 25.0,
            calibration: true,
            power_on_bias: true,
            standstill: crate::standstill::StandstillConfig::default(),
            keep: Keep::Auto,
        }
    }
}

impl AdaptConfig {
    /// Refuses settings the inner loop cannot run with, naming the key (as `train`'s config).
    pub fn validate(&self) -> Result<(), String> {
        self.loss.validate("adapt.loss")?;
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !(self.inner_lr.is_finite() && self.inner_lr >= 0.0) {
            return Err(format!("adapt.inner_lr = {}: must be finite and ≥ 0", self.inner_lr));
        }
        if self.windows == 0 {
            return Err("adapt.windows must be ≥ 1".into());
        }
        // One batch of windows × samples × channels in memory, with its gradients.
        const MAX_BATCH_SAMPLES: usize = 1 << 24;
        if self.windows.saturating_mul(self.window_samples) > MAX_BATCH_SAMPLES {
            return Err(format!(
                "adapt.windows × adapt.window_samples = {} × {}: at most {MAX_BATCH_SAMPLES} samples in one batch",
                self.windows, self.window_samples
            ));
        }
        let min_window = self.loss.min_window_samples() as usize;
        if self.window_samples <= min_window {
            return Err(format!(
                "adapt.window_samples = {}: must exceed {min_window} samples (every increment length must score one increment after its skip)",
                self.window_samples
            ));
        }
        for (key, v) in [
            ("min_support_seconds", self.min_support_seconds),
            ("min_query_seconds", self.min_query_seconds),
            ("max_interpolation_gap_ms", self.max_interpolation_gap_ms),
            ("max_nearest_gt_ms", self.max_nearest_gt_ms),
            ("max_seconds", self.max_seconds),
        ] {
            if !positive(v) {
                return Err(format!("adapt.{key} = {v}: must be finite and > 0"));
            }
        }
        if !(self.frame_tolerance_deg.is_finite() && self.frame_tolerance_deg >= 0.0) {
            return Err(format!("adapt.frame_tolerance_deg = {}: must be finite and ≥ 0", self.frame_tolerance_deg));
        }
        if self.keep == Keep::GyroCalibration && !self.power_on_bias {
            return Err(
                "adapt.keep = gyro_calibration needs power_on_bias: the calibration is fitted on the gyro minus its power-on bias".into()
            );
        }
        Ok(())
    }
}

/// Why adaptation could not run.
#[derive(Debug, thiserror::Error)]
pub enum AdaptError {
    #[error("the model is {0:?}: only FSDA / FSDA-F models have an Embedding to adapt")]
    NoEmbedding(crate::model::Mode),
    #[error("{what}: {detail}")]
    TooLittleData { what: &'static str, detail: String },
    #[error(
        "ground truth is in another frame: a constant rotation of {:.1}° (quaternion w,x,y,z {:.4?}) takes the IMU's \
         increments onto the ground truth's (residual {:.2}° with it, {:.2}° without, {} increments{}); express the ground \
         truth in the IMU frame, or allow it to be re-expressed (frame policy `apply`)",
        .0.angle_deg, .0.gt_from_imu, .0.residual_deg, .0.residual_identity_deg, .0.increments,
        if .0.fully_observable { "" } else { "; only the tilt between the motion axes is observable" })]
    OtherFrame(Box<FrameCheck>),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Eval(#[from] crate::eval::EvalError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(
        "{0}: no standstill in the support set ({1}): its power-on gyro bias cannot be told from the IMU's lasting errors, \
         and adapting would write it into the model; record a few seconds at rest first, or adapt without the power-on \
         rule (power_on_bias: false: the model is then for this power-on only)"
    )]
    NoStandstill(String, String),
    #[error("{0}")]
    Other(String),
}

impl From<anyhow::Error> for AdaptError {
    fn from(e: anyhow::Error) -> Self {
        AdaptError::Other(format!("{e:#}"))
    }
}

/// The figures of one adaptation (also written beside an adapted model).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AdaptReport {
    pub model: String,
    pub support: String,
    pub query: String,
    /// Seconds of the support (query) set covered by ground truth (gaps left out).
    pub support_seconds: f64,
    pub support_samples: usize,
    pub query_seconds: f64,
    pub query_samples: usize,
    /// Query AOE of the raw gyro, the starting model, and the adapted one.
    pub query_raw: OrientationErrors,
    /// The starting model as deployed on the IMU named (with its correction gain).
    pub query_before: OrientationErrors,
    pub query_after: OrientationErrors,
    pub accepted: bool,
    /// The starting model's correction gain on the IMU named (1: none; the adapted model
    /// applies all of its correction).
    #[serde(default = "one")]
    pub start_correction_gain: f64,
    /// With the calibration head: the model's constant gyro error on the support set (rad/s),
    /// removed from the output bias before the steps.
    pub initial_bias_rad_s: Option<[f64; 3]>,
    /// Why it was rejected (empty when accepted).
    pub verdict: String,
    /// Support loss at each step (before that step's update).
    pub losses: Vec<f64>,
    pub steps: usize,
    pub inner_lr: f64,
    /// Wall time of the inner loop, and of everything (data, evaluations), s.
    pub step_seconds: f64,
    pub total_seconds: f64,
    pub frame: Option<FrameCheck>,
    pub frame_applied: bool,
    /// The support's power-on bias, removed before adapting (with `power_on_bias`).
    #[serde(default)]
    pub support_power_on_bias: Option<crate::standstill::BiasEstimate>,
    /// Query AOE of the raw gyro minus its power-on bias: what the node runs on a new IMU.
    #[serde(default)]
    pub query_power_on_bias: Option<OrientationErrors>,
    /// Other recordings of the IMU it was judged on (`adapt --judge`).
    #[serde(default)]
    pub judged: Vec<Judged>,
    /// The candidate not kept, on the same recordings (where both passed the query).
    #[serde(default)]
    pub judged_runner_up: Vec<Judged>,
    /// How the one kept (or refused) carries over to them.
    #[serde(default)]
    pub carry_over: Option<CarryOver>,
    /// The lasting linear gyro error fitted on the support (with `power_on_bias`).
    #[serde(default)]
    pub calibration: Option<calibration::GyroCalibrationFit>,
    /// Query AOE of that calibration alone, the networks' correction off.
    #[serde(default)]
    pub query_calibrated: Option<OrientationErrors>,
    /// The same piece by piece against the gyro minus its power-on bias: without `--judge`,
    /// the calibration is kept only where its gain holds ([`pieces`]).
    #[serde(default)]
    pub query_calibrated_pieces: Option<PieceConfidence>,
    /// Why no calibration was fitted (too few increments, a departure no gyro has, nothing
    /// the support determines).
    #[serde(default)]
    pub calibration_refused: Option<String>,
    /// Which candidate was kept (`None`: rejected).
    #[serde(default)]
    pub kind: Option<AdaptedKind>,
    pub config: AdaptConfig,
}

/// What an adaptation changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AdaptedKind {
    /// The Embedding (and the calibration head) adapted by the inner loop.
    Network,
    /// Ĉ_ω fitted in closed form, the networks' correction off ([`calibration`]).
    Calibration,
}

impl AdaptReport {
    /// The query figures of the candidate kept (`None`: rejected).
    pub fn kept_query(&self) -> Option<&OrientationErrors> {
        match self.kind? {
            AdaptedKind::Network => Some(&self.query_after),
            AdaptedKind::Calibration => self.query_calibrated.as_ref(),
        }
    }
}

impl AdaptedKind {
    pub fn name(self) -> &'static str {
        match self {
            AdaptedKind::Network => "the adapted networks",
            AdaptedKind::Calibration => "the gyro calibration alone",
        }
    }
}

fn one() -> f64 {
    1.0
}

/// An adaptation's result: the figures, and the adapted model when accepted.
pub struct AdaptOutcome {
    pub report: AdaptReport,
    /// The adapted model (a fresh VarStore; the input model is untouched). `None` when rejected.
    pub adapted: Option<LoadedNet>,
    /// The other candidate, where it passed the query too, with its kind.
    pub runner_up: Option<(AdaptedKind, LoadedNet)>,
}

/// Ĉ_ω's prior per entry: MEMS datasheets give ±3 % sensitivity and ±2 % cross-axis.
const CALIBRATION_PRIOR_STDDEV: f64 = 0.05;
/// The calibration's increments, s (as the calibration head's).
const CALIBRATION_INCREMENT_S: f64 = 0.25;

/// The calibration candidate: the model with Ĉ_ω fitted on the support, its networks'
/// correction off (the Generator's last layer zero), scored on the query; or why there is none.
struct Calibrated {
    fit: calibration::GyroCalibrationFit,
    net: LoadedNet,
    query: OrientationErrors,
    pieces: Option<PieceConfidence>,
}

fn calibration_candidate(
    loaded: &LoadedNet,
    support: &Task,
    query: &Task,
    eopts: &EvalOptions,
    cfg: &AdaptConfig,
) -> Result<Result<Calibrated, String>, AdaptError> {
    let rec = &support.rec;
    let (gt, valid) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let span = (CALIBRATION_INCREMENT_S * rec.nominal_imu_rate_hz()).round().max(1.0) as usize;
    let fit = match calibration::fit_gyro_calibration(&rec.imu, &gt, &valid, span, CALIBRATION_PRIOR_STDDEV) {
        Ok(fit) => fit,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let (vs, net) = copy_net(loaded)?;
    {
        let vars = vs.variables();
        // The Generator's last layer zeroed: its output g, so σ ⊙ g, is exactly 0.
        let head = calibration_head_names(&vs).into_iter().find(|n| n.starts_with("generator."));
        let weight = head.as_ref().and_then(|b| vars.get(&b.replace(".bias", ".weight")));
        let (Some(delta), Some(bias), Some(weight)) = (vars.get("gyro_calib.delta"), head.as_ref().and_then(|b| vars.get(b)), weight)
        else {
            return Ok(Err("the model has no Ĉ_ω or Generator output layer to hold a calibration".into()));
        };
        let m = fit.matrix;
        let flat: Vec<f64> = (0..9).map(|k| m[k / 3][k % 3] - if k / 3 == k % 3 { 1.0 } else { 0.0 }).collect();
        tch::no_grad(|| -> Result<(), ModelError> {
            delta.shallow_clone().f_copy_(&Tensor::from_slice(&flat).reshape([3, 3]).to_kind(delta.kind()))?;
            let _ = bias.shallow_clone().f_zero_()?;
            let _ = weight.shallow_clone().f_zero_()?;
            Ok(())
        })?;
    }
    let gyro = crate::train::fit::corrected_gyro(&net, query)?;
    let without: Vec<_> = query.rec.imu.iter().map(|s| s.gyro).collect();
    let pieces = pieces::piece_confidence(&query.rec, &gyro, &without, eopts);
    let query_task = query;
    let query = crate::eval::evaluate(&query_task.rec, &gyro, eopts)?;
    tracing::info!(
        "gyro calibration on {} increments: Ĉ_ω {:?}, residual {:.3} → {:.3} °/s; query AOE {:.3}°",
        fit.increments,
        fit.matrix,
        fit.residual_before_deg_s,
        fit.residual_after_deg_s,
        query.aoe_deg
    );
    let metadata = ModelMetadata { imu_correction_gains: BTreeMap::new(), power_on_bias_removed: true, ..loaded.metadata.clone() };
    Ok(Ok(Calibrated { fit, net: LoadedNet::new(vs, net, metadata), query, pieces }))
}

fn dataset_cfg(cfg: &AdaptConfig) -> DatasetConfig {
    DatasetConfig {
        root: PathBuf::from("."),
        train: vec![],
        validation: vec![],
        test: vec![],
        monitor: vec![],
        support_seconds: 0.0,
        max_interpolation_gap_ms: cfg.max_interpolation_gap_ms,
        max_nearest_gt_ms: cfg.max_nearest_gt_ms,
    }
}

fn to_task(rec: &Recording, what: &'static str, cfg: &AdaptConfig) -> Result<Task, AdaptError> {
    if rec.imu.len() < 2 {
        return Err(AdaptError::TooLittleData { what, detail: format!("{} IMU samples", rec.imu.len()) });
    }
    if rec.ground_truth.is_empty() {
        return Err(AdaptError::Data(DataError::NoGroundTruth(format!("{what} {}", rec.name))));
    }
    let src = SourceConfig { bag: Some(rec.name.clone()), name: Some(rec.name.clone()), ..Default::default() };
    Ok(data::task_from_recording(rec.clone(), &src, &dataset_cfg(cfg), None)?)
}

/// At least `min_seconds` of the task covered by ground truth.
fn require_covered(task: &Task, what: &'static str, min_seconds: f64) -> Result<(), AdaptError> {
    if task.covered_seconds() >= min_seconds {
        return Ok(());
    }
    Err(AdaptError::TooLittleData {
        what,
        detail: format!(
            "{:.3} s of IMU with ground truth ({:.3} s span, {} samples), at least {min_seconds:.0} s needed",
            task.covered_seconds(),
            task.seconds(),
            task.len()
        ),
    })
}

/// The calibration head's VarStore names: Ĉ_ω's `gyro_calib.delta` and the bias of the
/// Generator's last conv (its output is scaled by σ and added to the gyro: a constant offset).
fn calibration_head_names(vs: &VarStore) -> Vec<String> {
    let vars = vs.variables();
    let last_conv = vars.keys().filter_map(|n| n.strip_prefix("generator.conv")?.strip_suffix(".bias")?.parse::<usize>().ok()).max();
    let mut names: Vec<String> = last_conv.map(|l| format!("generator.conv{l}.bias")).into_iter().collect();
    if vars.contains_key("gyro_calib.delta") {
        names.push("gyro_calib.delta".into());
    }
    names
}

/// Closed-form first step of the calibration head: the constant gyro error e of the model on
/// the support set, from 0.25 s increments (`Log(δR_gtᵀ δR̂) ≈ j·dt·e` for a small constant
/// e), removed from the Generator's output bias (`ω̂ = Ĉ_ω ω + σ ⊙ g`, so bias −= e / σ). A
/// gradient step moves that bias by about lr·σ, far too slowly for a new IMU's bias of
/// several °/s; the steps that follow refine it. Returns e (rad/s).
fn init_output_bias(vs: &VarStore, head_names: &[String], net: &Net, support: &Task, cfg: &AdaptConfig) -> Result<[f64; 3], AdaptError> {
    const J: usize = 50;
    let rec = &support.rec;
    let corrected = crate::model::predict::correct_with_net(&net.inference(), &rec.imu)?;
    let (gt, valid) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let mut sum = nalgebra::Vector3::zeros();
    let mut count = 0usize;
    let mut k = 0usize;
    while k + J < rec.imu.len() {
        let span_ok = valid[k..=k + J].iter().all(|v| *v);
        if let (true, Some(a), Some(b)) = (span_ok, gt[k], gt[k + J]) {
            let mut est = nalgebra::UnitQuaternion::identity();
            let mut secs = 0.0;
            for (w, pair) in corrected[k..k + J].iter().zip(rec.imu[k..=k + J].windows(2)) {
                let dt = (pair[1].stamp_ns - pair[0].stamp_ns) as f64 * 1e-9;
                est *= crate::so3::exp(&(w * dt));
                secs += dt;
            }
            let r = crate::so3::log(&((a.inverse() * b).inverse() * est));
            if secs > 0.0 && r.iter().all(|x| x.is_finite()) {
                sum += r / secs;
                count += 1;
            }
        }
        k += J;
    }
    if count < 10 {
        return Err(AdaptError::TooLittleData {
            what: "support",
            detail: format!(
                "{count} ground-truth-covered 0.25 s increments to estimate the gyro bias from, at least 10 needed (a ground truth \
                 slower than {:.0} Hz covers none: raise max_nearest_gt_ms in an `adapt --config` to half its period)",
                500.0 / cfg.max_nearest_gt_ms.max(1e-3)
            ),
        });
    }
    let e = sum / count as f64;
    let sigma = Vec::<f64>::try_from(&net.output_scale().to_kind(tch::Kind::Double)).map_err(ModelError::from)?;
    if let Some(bias_name) = head_names.iter().find(|n| n.starts_with("generator.")) {
        let vars = vs.variables();
        let delta: Vec<f64> = (0..3).map(|i| -e[i] / sigma[i].max(1e-12)).collect();
        let var = &vars[bias_name];
        tch::no_grad(|| {
            let d = Tensor::from_slice(&delta).to_kind(var.kind());
            let _ = var.shallow_clone().g_add_(&d);
        });
    }
    tracing::info!(
        "calibration head: constant gyro error of the model on the support set ({count} increments): [{:.4}, {:.4}, {:.4}] °/s, removed before the steps",
        e[0].to_degrees(),
        e[1].to_degrees(),
        e[2].to_degrees()
    );
    Ok([e[0], e[1], e[2]])
}

/// A copy of `loaded` in a fresh VarStore (everything frozen: only the fast weights train).
fn copy_net(loaded: &LoadedNet) -> Result<(VarStore, Net), ModelError> {
    let mut vs = VarStore::new(Device::Cpu);
    let net = Net::new(&loaded.metadata.config, &vs.root())?;
    let src = loaded.vs.variables();
    tch::no_grad(|| -> Result<(), ModelError> {
        for (name, var) in vs.variables() {
            let s = src.get(&name).ok_or_else(|| ModelError::InvalidConfig(format!("variable {name} missing from the loaded model")))?;
            var.shallow_clone().f_copy_(s)?;
        }
        Ok(())
    })?;
    vs.freeze();
    Ok((vs, net))
}

/// Re-expresses the ground truth in the IMU's frame: `R_gt ← R_gt R_x`.
pub fn apply_frame(rec: &mut Recording, gt_from_imu: &nalgebra::UnitQuaternion<f64>) {
    for p in &mut rec.ground_truth {
        p.world_from_body *= gt_from_imu;
    }
}

/// Runs the frame check on a recording (ground truth slerped at the IMU stamps).
pub fn frame_check(rec: &Recording, cfg: &AdaptConfig) -> Option<FrameCheck> {
    let (gt, _) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let rate = rec.nominal_imu_rate_hz().max(1.0);
    frame::check_frame_on(&frame::turning_increments(&rec.imu, &gt, rate, 0.05, 10), 0.05)
}

/// Adapts `loaded`'s Embedding on `support`, judges on `query` (see the module doc).
/// `loaded` is not modified. Errors: not an FSDA model, too little support or query data,
/// ground truth missing / not overlapping the IMU / in another frame (policy `error`).
pub fn adapt(loaded: &LoadedNet, support: &Recording, query: &Recording, cfg: &AdaptConfig) -> Result<AdaptOutcome, AdaptError> {
    adapt_knowing(loaded, support, query, cfg, None)
}

/// [`adapt`], with the power-on bias the caller measured earlier in this power-on (the node's,
/// from a standstill its buffer no longer holds): used where the support has no standstill.
pub fn adapt_knowing(
    loaded: &LoadedNet,
    support: &Recording,
    query: &Recording,
    cfg: &AdaptConfig,
    known_power_on_bias: Option<&crate::standstill::BiasEstimate>,
) -> Result<AdaptOutcome, AdaptError> {
    let t_all = Instant::now();
    cfg.validate().map_err(AdaptError::Other)?;
    let meta = &loaded.metadata;
    let mode = loaded.metadata.mode;
    if !mode.has_embedding() {
        return Err(AdaptError::NoEmbedding(mode));
    }
    let mut support = support.clone();
    let mut query = query.clone();
    // The model adapts at its own rate, on the input's periods, as the node runs it.
    for rec in [&mut support, &mut query] {
        let rate = rec.nominal_imu_rate_hz();
        if rec.imu.len() >= 2 && crate::model::rate_is_off(meta.rate_hz, rate) {
            tracing::info!("{}: the {rate:.1} Hz IMU is adapted on in the model's {:.0} Hz periods", rec.name, meta.rate_hz);
            rec.imu = crate::resample::to_model_rate(&rec.imu, meta.rate_hz).0;
        }
    }
    // This power-on's bias out of both sets, as the node removes it (causal over the recording).
    let query_as_recorded = cfg.power_on_bias.then(|| query.clone());
    let support_power_on_bias =
        if cfg.power_on_bias { Some(remove_power_on_bias(&mut support, &mut query, &cfg.standstill, known_power_on_bias)?) } else { None };
    let s_task0 = to_task(&support, "support", cfg)?;
    // Seconds with ground truth, not the span: gaps in it are not data to adapt on.
    require_covered(&s_task0, "support", cfg.min_support_seconds)?;
    // The query's length first: on a few seconds the clock check can find a false peak.
    let q_task0 = to_task(&query, "query", cfg)?;
    require_covered(&q_task0, "query", cfg.min_query_seconds)?;
    crate::train::data::check_clock(&support)?;
    crate::train::data::check_clock(&query)?;
    crate::train::data::check_plausible(&support)?;
    crate::train::data::check_plausible(&query)?;
    crate::train::data::check_accel_units(&support)?;
    crate::train::data::check_ground_truth_follows_gyro(&support, false)?;
    let (frame, frame_applied) = check_ground_truth_frame(&s_task0, &mut support, &mut query, cfg)?;
    let s_task = if frame_applied { to_task(&support, "support", cfg)? } else { s_task0 };
    let q_task = if frame_applied { to_task(&query, "query", cfg)? } else { q_task0 };
    let eopts = EvalOptions { max_gap_ns: (cfg.max_interpolation_gap_ms * 1e6) as i64 };
    // The query as recorded (its bias added back), and as the node runs a new IMU (without it).
    let query_power_on_bias = if cfg.power_on_bias { Some(evaluate_raw(&q_task, &eopts)?) } else { None };
    let query_raw = match query_as_recorded {
        Some(mut rec) => {
            if let (true, Some(f)) = (frame_applied, &frame) {
                apply_frame(&mut rec, &f.rotation());
            }
            evaluate_raw(&to_task(&rec, "query", cfg)?, &eopts)?
        }
        None => evaluate_raw(&q_task, &eopts)?,
    };
    let start_correction_gain = loaded.correction_gain();
    let query_before = evaluate_net_with_gain(&loaded.net, &q_task, &eopts, start_correction_gain)?;

    let AdaptedNetworks { vs, net, losses, step_seconds, initial_bias } = adapt_networks(loaded, &s_task, cfg)?;
    let query_after = evaluate_net(&net, &q_task, &eopts)?;
    // The second candidate: the lasting linear gyro error alone, the networks off.
    let (calibrated, calibration_refused) = if cfg.power_on_bias && cfg.keep != Keep::Networks {
        match calibration_candidate(loaded, &s_task, &q_task, &eopts, cfg)? {
            Ok(c) => (Some(c), None),
            Err(why) => (None, Some(why)),
        }
    } else {
        (None, None)
    };
    // Better than the starting model, and than what the node runs without it on a new IMU.
    let floor = query_power_on_bias.as_ref().map_or(f64::INFINITY, |e| e.aoe_deg);
    let passes = |e: &OrientationErrors| e.aoe_deg < query_before.aoe_deg && e.aoe_deg < floor;
    let network_passes = cfg.keep != Keep::GyroCalibration && passes(&query_after);
    let calibration_passes = calibrated.as_ref().is_some_and(|c| passes(&c.query));
    let accepted = network_passes || calibration_passes;
    let calibrated_aoe = calibrated.as_ref().map(|c| c.query.aoe_deg);
    let verdict = if accepted { String::new() } else { query_verdict(query_before.aoe_deg, query_after.aoe_deg, calibrated_aoe, floor) };
    let mut report = AdaptReport {
        model: loaded.metadata.name.clone(),
        support: s_task.source.clone(),
        query: q_task.source.clone(),
        support_seconds: s_task.covered_seconds(),
        support_samples: s_task.len(),
        query_seconds: q_task.covered_seconds(),
        query_samples: q_task.len(),
        query_raw,
        query_before,
        query_after,
        accepted,
        start_correction_gain,
        initial_bias_rad_s: initial_bias,
        verdict,
        steps: losses.len(),
        losses,
        inner_lr: cfg.inner_lr,
        step_seconds,
        total_seconds: t_all.elapsed().as_secs_f64(),
        frame,
        frame_applied,
        support_power_on_bias,
        query_power_on_bias,
        judged: Vec::new(),
        judged_runner_up: Vec::new(),
        carry_over: None,
        calibration: calibrated.as_ref().map(|c| c.fit.clone()),
        query_calibrated: calibrated.as_ref().map(|c| c.query.clone()),
        query_calibrated_pieces: calibrated.as_ref().and_then(|c| c.pieces),
        calibration_refused,
        kind: None,
        config: cfg.clone(),
    };
    let network = network_passes.then(|| {
        // Its own weights, all of its correction: the starting model's gains do not apply.
        let metadata =
            ModelMetadata { imu_correction_gains: BTreeMap::new(), power_on_bias_removed: cfg.power_on_bias, ..loaded.metadata.clone() };
        (AdaptedKind::Network, LoadedNet::new(vs, net, metadata))
    });
    let calibration = calibrated.filter(|_| calibration_passes).map(|c| (AdaptedKind::Calibration, c.net));
    // Both passed: the calibration first (the query is this power-on's, where the networks'
    // gain has not carried over); `adapt --judge` keeps whichever carries over better,
    // [`keep_without_judge`] what lasts.
    let (adapted, runner_up) = match (calibration, network) {
        (Some(c), Some(n)) => (Some(c), Some(n)),
        (c, n) => (c.or(n), None),
    };
    report.kind = adapted.as_ref().map(|(k, _)| *k);
    Ok(AdaptOutcome { report, adapted: adapted.map(|(_, m)| m), runner_up })
}

/// The frame check on the support (docs/adaptation.md, step 2): a rotation between the IMU
/// and ground-truth frames is an error, or re-expressed in both sets (`frame_policy`).
fn check_ground_truth_frame(
    s_task: &Task,
    support: &mut Recording,
    query: &mut Recording,
    cfg: &AdaptConfig,
) -> Result<(Option<FrameCheck>, bool), AdaptError> {
    let mut frame = None;
    let mut frame_applied = false;
    if cfg.frame_policy != FramePolicy::Ignore {
        frame = frame_check(&s_task.rec, cfg);
        if let Some(f) = frame.filter(|f| f.angle_deg > cfg.frame_tolerance_deg && !f.is_other_frame(cfg.frame_tolerance_deg)) {
            tracing::warn!(
                "a rotation of {:.1}° between the IMU and ground-truth frames fits, but explains little (residual {:.2}° with it, {:.2}° without): the gyro's own errors, not another frame",
                f.angle_deg,
                f.residual_deg,
                f.residual_identity_deg
            );
        }
        if let Some(f) = frame.filter(|f| f.is_other_frame(cfg.frame_tolerance_deg)) {
            match cfg.frame_policy {
                FramePolicy::Error => return Err(AdaptError::OtherFrame(Box::new(f))),
                FramePolicy::Apply => {
                    tracing::warn!("ground truth re-expressed in the IMU frame: rotation of {:.1}°", f.angle_deg);
                    apply_frame(support, &f.rotation());
                    apply_frame(query, &f.rotation());
                    frame_applied = true;
                }
                FramePolicy::Ignore => {}
            }
        }
    }
    Ok((frame, frame_applied))
}

/// The networks adapted by the inner loop, with what it did.
struct AdaptedNetworks {
    vs: VarStore,
    net: Net,
    losses: Vec<f64>,
    step_seconds: f64,
    initial_bias: Option<[f64; 3]>,
}

/// The inner loop (docs/adaptation.md, step 4): first order, eval mode, on a copy's fast
/// weights only (θ_e, and the calibration head with `calibration`).
fn adapt_networks(loaded: &LoadedNet, s_task: &Task, cfg: &AdaptConfig) -> Result<AdaptedNetworks, AdaptError> {
    let (mut vs, net) = copy_net(loaded)?;
    let mut fast: Vec<Tensor> = net.embedding_parameters().iter().map(|p| p.detach().copy().set_requires_grad(true)).collect();
    let head_names = if cfg.calibration { calibration_head_names(&vs) } else { Vec::new() };
    let head: Vec<Tensor> = {
        let vars = vs.variables();
        head_names.iter().map(|n| vars[n].shallow_clone().set_requires_grad(true)).collect()
    };
    let initial_bias = if cfg.calibration { Some(init_output_bias(&vs, &head_names, &net, s_task, cfg)?) } else { None };
    let mut head_adam = TensorAdam::new(&head);
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let win = cfg.window_samples.min(s_task.len());
    let refs = [s_task];
    let mut losses = Vec::with_capacity(cfg.steps);
    let mut adam = TensorAdam::new(&fast);
    let t_steps = Instant::now();
    for step in 0..cfg.steps {
        if t_steps.elapsed().as_secs_f64() > cfg.max_seconds {
            tracing::warn!("adaptation stopped after {step} steps: time budget of {} s reached", cfg.max_seconds);
            break;
        }
        let count = if win == s_task.len() { 1 } else { cfg.windows.max(1) };
        let batch = data::sample_windows(&refs, |t| (0, t.len()), count, win, &mut rng);
        let (l, next) = match cfg.optimizer {
            Optimizer::Sgd => {
                let (terms, next) = embedding_inner_step(&net, &cfg.loss, &batch, &fast, cfg.inner_lr, false, false);
                (terms.total.double_value(&[]), next)
            }
            Optimizer::Adam => {
                let (terms, grads) = embedding_and_extra_grads(&net, &cfg.loss, &batch, &fast, &head, false, false);
                let (g_fast, g_head) = grads.split_at(fast.len());
                let new_head = head_adam.step(&head, g_head, cfg.inner_lr);
                tch::no_grad(|| {
                    for (h, n) in head.iter().zip(&new_head) {
                        h.shallow_clone().copy_(n);
                    }
                });
                (terms.total.double_value(&[]), adam.step(&fast, g_fast, cfg.inner_lr))
            }
        };
        if !l.is_finite() {
            return Err(AdaptError::Other(format!("step {step}: the support loss is {l}: lower the inner learning rate")));
        }
        losses.push(l);
        fast = next.iter().map(|t| t.detach().set_requires_grad(true)).collect();
        tracing::debug!("adapt step {step}: support loss {l:.4}");
    }
    let step_seconds = t_steps.elapsed().as_secs_f64();
    {
        let vars = vs.variables();
        tch::no_grad(|| -> Result<(), ModelError> {
            for (name, f) in net.embedding_parameter_names().iter().zip(&fast) {
                vars[name].shallow_clone().f_copy_(f)?;
            }
            Ok(())
        })?;
    }
    vs.unfreeze();
    Ok(AdaptedNetworks { vs, net, losses, step_seconds, initial_bias })
}

/// Why neither candidate passed the query.
fn query_verdict(before: f64, after: f64, calibrated: Option<f64>, floor: f64) -> String {
    let calibration = calibrated.map_or(String::new(), |c| format!(", the gyro calibration alone {c:.3}°"));
    if after >= before {
        format!("rejected: the adapted model is not better on the query data (AOE {before:.3}° → {after:.3}°{calibration}); the previous model is kept")
    } else {
        format!(
            "rejected: the adapted model ({after:.3}°{calibration}) is not better on the query data than the gyro minus its power-on bias ({floor:.3}°), what the node runs on a new IMU; the previous model is kept"
        )
    }
}

/// Writes an accepted adapted model as `<dir>/<name>.{pt,ot,json}` (metadata: the original's
/// training data plus what it was adapted on; its metrics plus `adapt.*` figures) and the
/// full report as `<dir>/<name>.adapt.json`.
pub fn save_adapted(adapted: &LoadedNet, report: &AdaptReport, dir: &Path, name: &str) -> Result<ExportPaths, AdaptError> {
    let mut training_data = adapted.metadata.training_data.clone();
    let what = match report.kind {
        Some(AdaptedKind::Calibration) => {
            let c = report.calibration.as_ref().map_or(0, |c| c.increments);
            format!("gyro calibration (Ĉ_ω, the networks off) fitted on {c} increments")
        }
        _ => format!("{} steps", report.steps),
    };
    training_data.push(format!(
        "few-shot adapted from {} on {} ({:.1} s support, {what}); judged on {} ({:.1} s)",
        report.model, report.support, report.support_seconds, report.query, report.query_seconds
    ));
    // The starting model's figures (its test scores, its per-IMU gains) do not describe the
    // adapted one: only what the adaptation measured is kept.
    let mut metrics: BTreeMap<String, f64> = BTreeMap::new();
    metrics.insert("adapt.query_raw_aoe_deg".into(), report.query_raw.aoe_deg);
    metrics.insert("adapt.query_aoe_before_deg".into(), report.query_before.aoe_deg);
    metrics.insert("adapt.query_aoe_after_deg".into(), report.kept_query().unwrap_or(&report.query_after).aoe_deg);
    metrics.insert("adapt.support_seconds".into(), report.support_seconds);
    metrics.insert("adapt.query_seconds".into(), report.query_seconds);
    metrics.insert("adapt.steps".into(), report.steps as f64);
    metrics.insert("adapt.step_seconds".into(), report.step_seconds);
    let json = serde_json::to_string_pretty(report).map_err(|e| AdaptError::Other(e.to_string()))?;
    let paths = export_model(
        dir,
        name,
        &adapted.vs,
        &adapted.net,
        &ExportInfo {
            training_data,
            metrics,
            code_revision: None,
            adapted_from: Some(report.model.clone()),
            power_on_bias_removed: report.support_power_on_bias.is_some(),
            side_files: vec![("adapt.json".into(), json + "\n")],
            ..Default::default()
        },
    )?;
    Ok(paths)
}

/// Removes the power-on bias in force at each sample (the node's [`crate::standstill`] rule,
/// run over support then query as one stream) from both sets; the support's estimate. A
/// support without a standstill takes `known` (measured earlier in this power-on) off every
/// sample instead, or is refused with [`AdaptError::NoStandstill`].
pub fn remove_power_on_bias(
    support: &mut Recording,
    query: &mut Recording,
    cfg: &crate::standstill::StandstillConfig,
    known: Option<&crate::standstill::BiasEstimate>,
) -> Result<crate::standstill::BiasEstimate, AdaptError> {
    let in_support = crate::standstill::BiasTrack::over(&support.imu, cfg);
    let Some(estimate) = in_support.last else {
        let Some(known) = known else {
            return Err(AdaptError::NoStandstill(support.name.clone(), in_support.note()));
        };
        tracing::info!(
            "the support has no standstill: the power-on bias measured earlier ([{:.5}, {:.5}, {:.5}] rad/s) is removed",
            known.bias.x,
            known.bias.y,
            known.bias.z
        );
        for s in support.imu.iter_mut().chain(query.imu.iter_mut()) {
            s.gyro -= known.bias;
        }
        return Ok(*known);
    };
    // The bias in force at each sample of the one stream, as the node would have it.
    let whole: Vec<_> = support.imu.iter().chain(&query.imu).copied().collect();
    let track = crate::standstill::BiasTrack::over(&whole, cfg);
    for (s, b) in support.imu.iter_mut().chain(query.imu.iter_mut()).zip(&track.bias) {
        s.gyro -= b;
    }
    Ok(estimate)
}

/// Splits a recording at `support_seconds` after its first ground-truth-covered IMU sample:
/// (support, query), the query limited to `query_seconds` when given. Both keep all the
/// ground truth (it is only read at their IMU stamps).
pub fn split_recording(rec: &Recording, support_seconds: f64, query_seconds: Option<f64>, cfg: &AdaptConfig) -> (Recording, Recording) {
    let (gt, _) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let first = gt.iter().position(Option::is_some).unwrap_or(0);
    let t0 = rec.imu.get(first).map_or(0, |s| s.stamp_ns);
    let cut = t0 + (support_seconds * 1e9) as i64;
    let end = query_seconds.map_or(i64::MAX, |q| cut + (q * 1e9) as i64);
    let part = |a: i64, b: i64, tag: &str| Recording {
        name: format!("{} [{tag}]", rec.name),
        imu: rec.imu.iter().filter(|s| s.stamp_ns >= a && s.stamp_ns < b).copied().collect(),
        ground_truth: rec.ground_truth.clone(),
        temperature: Vec::new(),
    };
    let q_tag = match query_seconds {
        Some(q) => format!("{support_seconds}–{} s", support_seconds + q),
        None => format!("{support_seconds} s–end"),
    };
    (part(t0, cut, &format!("0–{support_seconds} s")), part(cut, end, &q_tag))
}

/// Adam (PyTorch's, no weight decay) over a list of plain tensors (the fast weights).
struct TensorAdam {
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    t: i32,
}

impl TensorAdam {
    fn new(params: &[Tensor]) -> Self {
        let z = || params.iter().map(|p| p.detach().zeros_like()).collect();
        TensorAdam { m: z(), v: z(), t: 0 }
    }

    fn step(&mut self, params: &[Tensor], grads: &[Tensor], lr: f64) -> Vec<Tensor> {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8);
        self.t += 1;
        let (c1, c2) = (1.0 - b1.powi(self.t), 1.0 - b2.powi(self.t));
        tch::no_grad(|| {
            params
                .iter()
                .zip(grads)
                .zip(self.m.iter_mut().zip(self.v.iter_mut()))
                .map(|((p, g), (m, v))| {
                    let g = g.detach();
                    *m = &*m * b1 + &g * (1.0 - b1);
                    *v = &*v * b2 + g.square() * (1.0 - b2);
                    p.detach() - (&*m / c1) / ((&*v / c2).sqrt() + eps) * lr
                })
                .collect()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::ImuSample;
    use nalgebra::Vector3;

    fn moving(from_s: f64, seconds: f64, bias: Vector3<f64>) -> Recording {
        let imu = (0..(seconds * 200.0) as i64)
            .map(|k| {
                let t = from_s + k as f64 * 0.005;
                ImuSample {
                    stamp_ns: (t * 1e9) as i64,
                    gyro: Vector3::new(0.5 * (3.0 * t).sin(), 0.4 * (2.0 * t).cos(), 0.3) + bias,
                    accel: Vector3::new(0.0, 0.0, 9.81) + Vector3::new(3.0 * (5.0 * t).sin(), 0.0, 0.0),
                }
            })
            .collect();
        Recording { name: "moving".into(), imu, ..Default::default() }
    }

    /// The node's buffer after its rest scrolled out: refused without what the node measured,
    /// that bias off every sample with it.
    #[test]
    fn a_support_without_a_standstill_takes_the_bias_measured_earlier() {
        let bias = Vector3::new(0.02, -0.01, 0.03);
        let cfg = crate::standstill::StandstillConfig { in_motion: crate::standstill::InMotion::Off, ..Default::default() };
        let (mut support, mut query) = (moving(1.0, 10.0, bias), moving(11.0, 5.0, bias));
        let err = remove_power_on_bias(&mut support.clone(), &mut query.clone(), &cfg, None).unwrap_err();
        assert!(matches!(err, AdaptError::NoStandstill(..)), "{err}");
        let known = crate::standstill::BiasEstimate { bias, variance: Vector3::repeat(1e-8), at_ns: 0, still_s: 3.0 };
        let raw = (support.clone(), query.clone());
        let used = remove_power_on_bias(&mut support, &mut query, &cfg, Some(&known)).unwrap();
        assert_eq!(used, known);
        for (after, before) in support.imu.iter().chain(&query.imu).zip(raw.0.imu.iter().chain(&raw.1.imu)) {
            assert!((before.gyro - after.gyro - bias).amax() < 1e-15);
        }
    }
}
