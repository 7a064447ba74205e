//! Each training recording's power-on constant taken out before the networks see it
//! (`dataset.power_on_bias: remove`): what the model learns is then the IMU's lasting errors,
//! and the node removes each new power-on's bias before it, as for an adapted model
//! (docs/training.md, "Power-on bias in training").
//!
//! The rule is the node's, seen from after the first standstill: from the end of a
//! recording's first standstill on, the bias its standstills have measured by then
//! ([`crate::standstill::BiasTrack`], causal); before it, the bias known when that standstill
//! ended (the node has no better before, and a platform that sets off before it stands would
//! otherwise teach its whole turn-on bias). A recording without a standstill has its constant
//! fitted to its ground truth instead (the least-squares rate error, a nuisance of that
//! recording); it is removed but not remembered, since a standstill did not measure it.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::core::Recording;
use crate::standstill::{BiasTrack, StandstillConfig};

/// What the trainer does with each recording's power-on gyro bias.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PowerOnBiasInTraining {
    /// The recordings as recorded: each power-on's constant is in the data, and the model
    /// learns their mean as part of the IMU (the paper's and the bundled model's way).
    #[default]
    Keep,
    /// Each recording's power-on bias removed first; the model is marked
    /// `power_on_bias_removed` and run after the node's power-on bias.
    Remove,
}

/// The constant a recording had taken out.
#[derive(Debug, Clone, PartialEq)]
pub enum RemovedConstant {
    /// Measured at its standstills: the estimate at the end, its σ per axis and the seconds of
    /// standstill behind it (remembered with the model as one power-on of its IMU).
    Standstill { bias: Vector3<f64>, stddev: Vector3<f64>, still_s: f64 },
    /// No standstill: the constant fitted to the ground truth.
    GroundTruth { bias: Vector3<f64> },
}

impl RemovedConstant {
    pub fn bias(&self) -> Vector3<f64> {
        match self {
            RemovedConstant::Standstill { bias, .. } | RemovedConstant::GroundTruth { bias } => *bias,
        }
    }

    pub fn describe(&self) -> String {
        let b = self.bias();
        match self {
            RemovedConstant::Standstill { stddev, still_s, .. } => format!(
                "power-on bias [{:.5}, {:.5}, {:.5}] rad/s (σ {:.1e}) from {still_s:.1} s of standstill",
                b.x,
                b.y,
                b.z,
                stddev.max()
            ),
            RemovedConstant::GroundTruth { .. } => {
                format!("no standstill: the constant [{:.5}, {:.5}, {:.5}] rad/s fitted to the ground truth", b.x, b.y, b.z)
            }
        }
    }
}

/// Takes `rec`'s power-on bias out of its gyro (the rule above) and says what it was.
pub fn remove_power_on_bias(rec: &mut Recording, cfg: &StandstillConfig) -> Result<RemovedConstant, crate::eval::EvalError> {
    let track = BiasTrack::over(&rec.imu, cfg);
    let Some(last) = track.last else {
        let gyro: Vec<Vector3<f64>> = rec.imu.iter().map(|s| s.gyro).collect();
        let bias = crate::eval::mean_rate_error(rec, &gyro, &crate::eval::EvalOptions::default())?;
        for s in rec.imu.iter_mut() {
            s.gyro -= bias;
        }
        return Ok(RemovedConstant::GroundTruth { bias });
    };
    let first_known = track.still.first().map_or(0, |&(_, end)| end).min(rec.imu.len().saturating_sub(1));
    let before = track.bias[first_known];
    for (i, (s, b)) in rec.imu.iter_mut().zip(&track.bias).enumerate() {
        s.gyro -= if i < first_known { before } else { *b };
    }
    Ok(RemovedConstant::Standstill { bias: last.bias, stddev: last.variance.map(f64::sqrt), still_s: last.still_s })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ImuSample, PoseSample};
    use nalgebra::UnitQuaternion;

    /// `rest_s` at rest, then a turn about a tilted axis, at 200 Hz with the ground truth of
    /// the true motion; the gyro reads the rate plus `bias`.
    fn recording(rest_s: f64, bias: Vector3<f64>) -> Recording {
        let rate = Vector3::new(0.3, -0.2, 0.5);
        let (mut q, mut imu, mut ground_truth) = (UnitQuaternion::identity(), Vec::new(), Vec::new());
        for k in 0..4000i64 {
            let t = k as f64 / 200.0;
            let w = if t < rest_s { Vector3::zeros() } else { rate * (t * 1.3).sin() };
            let stamp_ns = k * 5_000_000;
            ground_truth.push(PoseSample { stamp_ns, position_in_world: Vector3::zeros(), world_from_body: q });
            let accel = q.inverse() * Vector3::new(0.0, 0.0, 9.81);
            imu.push(ImuSample { stamp_ns, gyro: w + bias, accel });
            q *= UnitQuaternion::from_scaled_axis(w / 200.0);
        }
        Recording { name: "r".into(), imu, ground_truth, temperature: vec![] }
    }

    #[test]
    fn a_recordings_rest_measures_the_constant_taken_out_from_its_first_sample() {
        let bias = Vector3::new(0.03, -0.05, 0.08);
        let mut rec = recording(3.0, bias);
        let truth: Vec<Vector3<f64>> = rec.imu.iter().map(|s| s.gyro - bias).collect();
        let removed = remove_power_on_bias(&mut rec, &StandstillConfig::default()).unwrap();
        let RemovedConstant::Standstill { bias: measured, stddev, still_s } = removed else { panic!("{removed:?}") };
        assert!((measured - bias).norm() < 1e-3 && still_s >= 2.0, "{measured} {still_s}");
        assert!(stddev.max() < 1e-3);
        // Every sample, those of the rest before it was measured included.
        let worst = rec.imu.iter().zip(&truth).map(|(s, t)| (s.gyro - t).norm()).fold(0.0, f64::max);
        assert!(worst < 2e-3, "{worst}");
    }

    #[test]
    fn without_a_rest_the_constant_is_fitted_to_the_ground_truth() {
        let bias = Vector3::new(-0.02, 0.04, 0.01);
        let mut rec = recording(0.0, bias);
        let removed = remove_power_on_bias(&mut rec, &StandstillConfig::default()).unwrap();
        assert!(matches!(removed, RemovedConstant::GroundTruth { .. }), "{removed:?}");
        assert!((removed.bias() - bias).norm() < 1e-3, "{}", removed.bias());
        assert!(removed.describe().contains("ground truth"));
    }
}
