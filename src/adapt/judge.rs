//! Judging an adapted model on *other* recordings of the same IMU: another power-on, the case
//! a robot that reboots meets. The query set judges the power-on adapted on; this judges
//! whether what was learned carries over, beside what the node would run without it.

use serde::{Deserialize, Serialize};

use super::{to_task, AdaptConfig, AdaptError};
use crate::core::Recording;
use crate::eval::{EvalOptions, OrientationErrors};
use crate::model::export::LoadedNet;
use crate::standstill::BiasTrack;
use crate::train::fit::{evaluate_net, evaluate_net_with_gain, evaluate_raw};

/// One other recording's figures (AOE over all of it).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Judged {
    pub recording: String,
    pub raw: OrientationErrors,
    /// The gyro minus this recording's own power-on bias: what the node runs on a new IMU
    /// (`None`: no standstill in it).
    pub power_on_bias: Option<OrientationErrors>,
    /// The starting model as deployed on the IMU named (its correction gain).
    pub before: OrientationErrors,
    /// The adapted model, after this recording's power-on bias where it was adapted so.
    pub after: OrientationErrors,
}

impl Judged {
    /// What the node runs without the adapted model: the power-on bias where there is one
    /// (a new IMU), else the better of raw and the starting model.
    pub fn without_adaptation_deg(&self) -> f64 {
        self.power_on_bias.as_ref().map_or(self.raw.aoe_deg.min(self.before.aoe_deg), |e| e.aoe_deg)
    }
}

/// Scores `start` and `adapted` on `rec` (the whole recording, covered by ground truth).
pub fn judge(start: &LoadedNet, adapted: &LoadedNet, rec: &Recording, cfg: &AdaptConfig) -> Result<Judged, AdaptError> {
    let mut rec = rec.clone();
    let rate = rec.nominal_imu_rate_hz();
    if rec.imu.len() >= 2 && crate::model::rate_is_off(start.metadata.rate_hz, rate) {
        rec.imu = crate::resample::to_model_rate(&rec.imu, start.metadata.rate_hz).0;
    }
    let eopts = EvalOptions { max_gap_ns: (cfg.max_interpolation_gap_ms * 1e6) as i64 };
    let task = to_task(&rec, "judge", cfg)?;
    let raw = evaluate_raw(&task, &eopts)?;
    let before = evaluate_net_with_gain(&start.net, &task, &eopts, start.correction_gain())?;
    let track = BiasTrack::over(&rec.imu, &cfg.standstill);
    let debiased = Recording { imu: track.debiased(&rec.imu), ..rec.clone() };
    let debiased_task = to_task(&debiased, "judge", cfg)?;
    let power_on_bias = match track.last {
        Some(_) => Some(evaluate_raw(&debiased_task, &eopts)?),
        None => None,
    };
    let after_task = if adapted.metadata.power_on_bias_removed { &debiased_task } else { &task };
    let after = evaluate_net(&adapted.net, after_task, &eopts)?;
    Ok(Judged { recording: rec.name.clone(), raw, power_on_bias, before, after })
}
