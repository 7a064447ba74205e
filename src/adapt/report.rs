//! What an adaptation found: the report written beside an adapted model, the kind of
//! candidate kept, and the outcome handed to the CLI and the node.

use serde::{Deserialize, Serialize};

use super::{calibration, AdaptConfig, CarryOver, FrameCheck, Judged, PieceConfidence};
use crate::eval::OrientationErrors;
use crate::model::export::LoadedNet;

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
    /// The candidates not kept (those that passed the query too), on the same recordings.
    #[serde(default)]
    pub judged_others: Vec<JudgedCandidate>,
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
    /// Query AOE of the calibration with the support's bias offset in motion (its leftover
    /// constant), where the support determines that offset.
    #[serde(default)]
    pub query_calibrated_with_offset: Option<OrientationErrors>,
    /// Why no calibration was fitted (too few increments, a departure no gyro has, nothing
    /// the support determines).
    #[serde(default)]
    pub calibration_refused: Option<String>,
    /// Without `--judge`: the rotation between the ground truth's frame and the IMU's (°)
    /// left out of the calibration kept or refused: one power-on cannot tell it from the
    /// reference's mounting ([`super::keep_without_judge`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration_rotation_left_out_deg: Option<f64>,
    /// Which candidate was kept (`None`: rejected).
    #[serde(default)]
    pub kind: Option<AdaptedKind>,
    /// Who asked for it, where someone else than the command line did: the `~/adapt`
    /// caller's DDS identity (accountability for the model a node runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub requested_by: Option<String>,
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
    /// The same Ĉ_ω (I where the support determines none of it) and the support's bias offset
    /// in motion: the gyro's bias while moving less the power-on bias measured at rest (rotor
    /// vibration, a warm-up under load). Lasting on a platform, or this power-on's drift: only
    /// other power-ons tell, so it is kept only where judged on them.
    CalibrationWithOffset,
}

/// A candidate judged on the other recordings but not kept.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JudgedCandidate {
    pub kind: AdaptedKind,
    pub carry_over: CarryOver,
    pub judged: Vec<Judged>,
}

impl AdaptReport {
    /// "the … rotation … left to the reference", where the calibration was fitted so.
    pub fn rotation_left_out_said(&self) -> Option<String> {
        self.calibration_rotation_left_out_deg.map(rotation_left_out_said)
    }

    /// The query figures of the candidate kept (`None`: rejected).
    pub fn kept_query(&self) -> Option<&OrientationErrors> {
        match self.kind? {
            AdaptedKind::Network => Some(&self.query_after),
            AdaptedKind::Calibration => self.query_calibrated.as_ref(),
            AdaptedKind::CalibrationWithOffset => self.query_calibrated_with_offset.as_ref(),
        }
    }
}

impl AdaptedKind {
    /// How much of the IMU a candidate claims to know, fewest lasting parameters first: the
    /// judge keeps a richer candidate only where it is better than a plainer one that also
    /// carries over.
    pub fn complexity(self) -> u8 {
        match self {
            AdaptedKind::Calibration => 0,
            AdaptedKind::CalibrationWithOffset => 1,
            AdaptedKind::Network => 2,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            AdaptedKind::Network => "the adapted networks",
            AdaptedKind::Calibration => "the gyro calibration alone",
            AdaptedKind::CalibrationWithOffset => "the gyro calibration with the support's bias offset in motion",
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
    /// The other candidates that passed the query too, with their kinds, in the order tried.
    pub others: Vec<(AdaptedKind, LoadedNet)>,
    /// The calibration with the reference's rotation left out, for [`super::keep_without_judge`].
    pub(super) without_rotation: Option<super::calibration_candidate::WithoutRotation>,
}

/// The rotation between the ground truth's frame and the IMU's that a calibration fitted
/// without a judge leaves to the reference, as said.
pub(super) fn rotation_left_out_said(deg: f64) -> String {
    format!("the {deg:.2}° rotation between the ground truth's frame and the IMU's left to the reference")
}
