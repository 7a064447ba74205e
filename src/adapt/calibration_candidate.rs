//! The calibration candidate (docs/adaptation.md, step 6): the model with Ĉ_ω fitted in closed
//! form on the support ([`super::calibration`]), its networks' correction off, scored on the
//! query whole and piece by piece.

use std::collections::BTreeMap;

use tch::Tensor;

use super::{
    calibration, copy_net, dataset_cfg, networks::calibration_head_names, pieces, AdaptConfig, AdaptError, FrameCheck, PieceConfidence,
};
use crate::eval::{EvalOptions, OrientationErrors};
use crate::model::export::{LoadedNet, ModelMetadata};
use crate::model::ModelError;
use crate::train::data::{self, Task};

/// Ĉ_ω's prior per entry: MEMS datasheets give ±3 % sensitivity and ±2 % cross-axis.
const CALIBRATION_PRIOR_STDDEV: f64 = 0.05;
/// The calibration's increments, s (as the calibration head's).
const CALIBRATION_INCREMENT_S: f64 = 0.25;

/// A calibration candidate: the model holding the fit (`net`), scored on the query whole and
/// piece by piece against the gyro minus its power-on bias.
pub(super) struct Calibrated {
    pub(super) fit: calibration::GyroCalibrationFit,
    pub(super) net: LoadedNet,
    pub(super) query: OrientationErrors,
    pub(super) pieces: Option<PieceConfidence>,
}

/// The two candidates one fit makes: Ĉ_ω alone (or why not), and Ĉ_ω with the support's bias
/// offset in motion, where the support determines it.
pub(super) struct CalibrationCandidates {
    pub(super) alone: Result<Calibrated, String>,
    pub(super) with_offset: Option<Calibrated>,
}

pub(super) fn calibration_candidates(
    loaded: &LoadedNet,
    support: &Task,
    query: &Task,
    eopts: &EvalOptions,
    cfg: &AdaptConfig,
) -> Result<CalibrationCandidates, AdaptError> {
    let fit = match fitted(support, cfg) {
        Ok(fit) => fit,
        Err(why) => return Ok(CalibrationCandidates { alone: Err(why), with_offset: None }),
    };
    let alone = alone(loaded, &fit, query, eopts)?;
    let with_offset = if fit.determines_leftover_bias() { scored(loaded, &fit, true, query, eopts)? } else { None };
    Ok(CalibrationCandidates { alone, with_offset })
}

/// Ĉ_ω and the leftover constant fitted on the support, or why not.
fn fitted(support: &Task, cfg: &AdaptConfig) -> Result<calibration::GyroCalibrationFit, String> {
    let rec = &support.rec;
    let (gt, valid) = data::ground_truth_at_imu(rec, &dataset_cfg(cfg));
    let span = (CALIBRATION_INCREMENT_S * rec.nominal_imu_rate_hz()).round().max(1.0) as usize;
    let fit = calibration::fit_gyro_calibration(&rec.imu, &gt, &valid, span, CALIBRATION_PRIOR_STDDEV).map_err(|e| e.to_string())?;
    tracing::info!(
        "gyro calibration on {} increments: Ĉ_ω {:?}, leftover bias {:?} rad/s (σ {:?}), residual {:.3} → {:.3} °/s",
        fit.increments,
        fit.matrix,
        fit.leftover_bias_rad_s,
        fit.leftover_bias_stddev_rad_s,
        fit.residual_before_deg_s,
        fit.residual_after_deg_s
    );
    Ok(fit)
}

/// The calibration alone, scored on the query, where the fit determines some entry of Ĉ_ω.
fn alone(
    loaded: &LoadedNet,
    fit: &calibration::GyroCalibrationFit,
    query: &Task,
    eopts: &EvalOptions,
) -> Result<Result<Calibrated, String>, AdaptError> {
    if !fit.determines_matrix() {
        // Only the offset is determined (the fit refuses a support that determines neither).
        let max_stddev = calibration::MAX_KEPT_STDDEV_OF_PRIOR * CALIBRATION_PRIOR_STDDEV;
        return Ok(Err(format!(
            "no scale or cross-axis error is determined by the support (each within 3 σ of none, or σ above {:.2} %); only its bias offset in motion is",
            100.0 * max_stddev
        )));
    }
    Ok(scored(loaded, fit, false, query, eopts)?.ok_or_else(|| NO_HEAD.to_string()))
}

/// Ĉ_ω fitted on the support's ground truth turned into the IMU's frame (the frame check's
/// rotation taken out): what is kept in place of the calibration where no other power-on
/// judges it ([`super::keep_without_judge`]). Against one reference, a rotation of the gyro
/// and the reference's own mounting (its body frame a degree off the IMU's) fit the same
/// Ĉ_ω; only power-ons with other references tell them apart, so without them the rotation
/// is left to the reference. Scored on the query as recorded, as the power-on bias is.
pub(super) struct WithoutRotation {
    /// The rotation taken out, °.
    pub(super) rotation_deg: f64,
    pub(super) calibration: Result<Calibrated, String>,
}

pub(super) fn calibration_without_rotation(
    loaded: &LoadedNet,
    support: &Task,
    query: &Task,
    eopts: &EvalOptions,
    cfg: &AdaptConfig,
    frame: &FrameCheck,
) -> Result<WithoutRotation, AdaptError> {
    let mut rec = support.rec.clone();
    super::apply_frame(&mut rec, &frame.rotation());
    let turned = super::to_task(&rec, "support", cfg)?;
    tracing::info!("gyro calibration on the ground truth turned {:.2}° into the IMU's frame:", frame.angle_deg);
    // The calibration alone: the offset is never kept without a judge.
    let calibration = match fitted(&turned, cfg) {
        Ok(fit) => alone(loaded, &fit, query, eopts)?,
        Err(why) => Err(why),
    };
    Ok(WithoutRotation { rotation_deg: frame.angle_deg, calibration })
}

const NO_HEAD: &str = "the model has no Ĉ_ω or Generator output layer to hold a calibration";

/// The model holding `fit`: Ĉ_ω, the Generator's last layer's weight zero and its bias the
/// leftover constant over σ (`with_offset`) or zero, so its correction σ ⊙ g is exactly that
/// constant or nothing; scored on the query. `None`: the model has no such layers.
fn scored(
    loaded: &LoadedNet,
    fit: &calibration::GyroCalibrationFit,
    with_offset: bool,
    query: &Task,
    eopts: &EvalOptions,
) -> Result<Option<Calibrated>, AdaptError> {
    let (vs, net) = copy_net(loaded)?;
    {
        let vars = vs.variables();
        let head = calibration_head_names(&vs).into_iter().find(|n| n.starts_with("generator."));
        let weight = head.as_ref().and_then(|b| vars.get(&b.replace(".bias", ".weight")));
        let (Some(delta), Some(bias), Some(weight)) = (vars.get("gyro_calib.delta"), head.as_ref().and_then(|b| vars.get(b)), weight)
        else {
            return Ok(None);
        };
        let m = fit.matrix;
        let flat: Vec<f64> = (0..9).map(|k| m[k / 3][k % 3] - if k / 3 == k % 3 { 1.0 } else { 0.0 }).collect();
        let sigma = loaded.metadata.config.output_scale_rad_s();
        let offset: Vec<f64> = (0..3).map(|k| if with_offset { fit.leftover_bias_rad_s[k] / sigma[k] } else { 0.0 }).collect();
        tch::no_grad(|| -> Result<(), ModelError> {
            delta.shallow_clone().f_copy_(&Tensor::from_slice(&flat).reshape([3, 3]).to_kind(delta.kind()))?;
            bias.shallow_clone().f_copy_(&Tensor::from_slice(&offset).to_kind(bias.kind()))?;
            let _ = weight.shallow_clone().f_zero_()?;
            Ok(())
        })?;
    }
    let gyro = crate::train::fit::corrected_gyro(&net, query)?;
    let without: Vec<_> = query.rec.imu.iter().map(|s| s.gyro).collect();
    let pieces = pieces::piece_confidence(&query.rec, &gyro, &without, eopts);
    let errors = crate::eval::evaluate(&query.rec, &gyro, eopts)?;
    tracing::info!(
        "gyro calibration{}: query AOE {:.3}°",
        if with_offset { " with the bias offset in motion" } else { " alone" },
        errors.aoe_deg
    );
    let metadata = ModelMetadata { imu_correction_gains: BTreeMap::new(), power_on_bias_removed: true, ..loaded.metadata.clone() };
    Ok(Some(Calibrated { fit: fit.clone(), net: LoadedNet::new(vs, net, metadata), query: errors, pieces }))
}
