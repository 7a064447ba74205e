//! The calibration candidate (docs/adaptation.md, step 6): the model with Ĉ_ω fitted in closed
//! form on the support ([`super::calibration`]), its networks' correction off, scored on the
//! query whole and piece by piece.

use std::collections::BTreeMap;

use tch::Tensor;

use super::{calibration, copy_net, dataset_cfg, networks::calibration_head_names, pieces, AdaptConfig, AdaptError, PieceConfidence};
use crate::eval::{EvalOptions, OrientationErrors};
use crate::model::export::{LoadedNet, ModelMetadata};
use crate::model::ModelError;
use crate::train::data::{self, Task};

/// Ĉ_ω's prior per entry: MEMS datasheets give ±3 % sensitivity and ±2 % cross-axis.
const CALIBRATION_PRIOR_STDDEV: f64 = 0.05;
/// The calibration's increments, s (as the calibration head's).
const CALIBRATION_INCREMENT_S: f64 = 0.25;

/// The calibration candidate: the model with Ĉ_ω fitted on the support, its networks'
/// correction off (the Generator's last layer zero), scored on the query; or why there is none.
pub(super) struct Calibrated {
    pub(super) fit: calibration::GyroCalibrationFit,
    pub(super) net: LoadedNet,
    pub(super) query: OrientationErrors,
    pub(super) pieces: Option<PieceConfidence>,
}

pub(super) fn calibration_candidate(
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
