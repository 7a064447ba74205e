//! Adaptation settings (`adapt --config`, the node's `adapt:` parameters) and their checks.

use crate::setting::InvalidSetting;
use serde::{Deserialize, Serialize};

use crate::model::loss::LossConfig;

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
    /// Set from another thread to stop the adaptation at its next step or phase (the node at
    /// shutdown): not a setting, never read from a file.
    #[serde(skip)]
    pub cancel: CancelFlag,
}

/// A flag another thread sets to stop an adaptation between two steps; clones share it.
#[derive(Debug, Clone, Default)]
pub struct CancelFlag(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl CancelFlag {
    pub fn cancel(&self) {
        self.0.store(true, std::sync::atomic::Ordering::Relaxed);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// Settings compare equal whatever their flags: the flag is not a setting.
impl PartialEq for CancelFlag {
    fn eq(&self, _: &Self) -> bool {
        true
    }
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
            cancel: CancelFlag::default(),
        }
    }
}

impl AdaptConfig {
    /// Refuses settings the inner loop cannot run with, naming the key (as `train`'s config).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.loss.validate("adapt.loss")?;
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !(self.inner_lr.is_finite() && self.inner_lr >= 0.0) {
            return Err(format!("adapt.inner_lr = {}: must be finite and ≥ 0", self.inner_lr).into());
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
            )
            .into());
        }
        let min_window = self.loss.min_window_samples() as usize;
        if self.window_samples <= min_window {
            return Err(format!(
                "adapt.window_samples = {}: must exceed {min_window} samples (every increment length must score one increment after its skip)",
                self.window_samples
            ).into());
        }
        for (key, v) in [
            ("min_support_seconds", self.min_support_seconds),
            ("min_query_seconds", self.min_query_seconds),
            ("max_interpolation_gap_ms", self.max_interpolation_gap_ms),
            ("max_nearest_gt_ms", self.max_nearest_gt_ms),
            ("max_seconds", self.max_seconds),
        ] {
            if !positive(v) {
                return Err(format!("adapt.{key} = {v}: must be finite and > 0").into());
            }
        }
        if !(self.frame_tolerance_deg.is_finite() && self.frame_tolerance_deg >= 0.0) {
            return Err(format!("adapt.frame_tolerance_deg = {}: must be finite and ≥ 0", self.frame_tolerance_deg).into());
        }
        if self.keep == Keep::GyroCalibration && !self.power_on_bias {
            return Err(
                "adapt.keep = gyro_calibration needs power_on_bias: the calibration is fitted on the gyro minus its power-on bias".into()
            );
        }
        Ok(())
    }
}
