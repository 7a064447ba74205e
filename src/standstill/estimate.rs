//! The bias a standstill measured, with its variance; what earlier power-ons predict for this
//! one; and the two fused (an earlier estimate, grown by the random walk, with a new one).

use nalgebra::Vector3;

/// The turn-on bias as measured at standstills, with its variance.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BiasEstimate {
    /// rad/s, IMU axes.
    pub bias: Vector3<f64>,
    /// Per-axis variance at [`Self::at_ns`], (rad/s)².
    pub variance: Vector3<f64>,
    /// The end of the last still window measured, ns.
    pub at_ns: i64,
    /// Seconds of standstill it rests on.
    pub still_s: f64,
}

impl BiasEstimate {
    /// Per-axis variance at `t_ns`, grown by the random walk since it was measured.
    pub fn variance_at(&self, t_ns: i64, random_walk: f64) -> Vector3<f64> {
        let dt = ((t_ns - self.at_ns) as f64 * 1e-9).max(0.0);
        self.variance.add_scalar(random_walk * random_walk * dt)
    }

    /// The largest per-axis standard deviation at `t_ns`, rad/s.
    pub fn stddev_at(&self, t_ns: i64, random_walk: f64) -> f64 {
        self.variance_at(t_ns, random_walk).max().sqrt()
    }
}

/// What earlier power-ons of the IMU predict for this one's bias, per axis
/// ([`crate::bias_memory`] makes it).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BiasPrediction {
    /// The remembered mean on the axes it is removed from, 0 elsewhere, rad/s.
    pub bias: Vector3<f64>,
    /// The variance of this power-on's bias about [`Self::bias`], (rad/s)²: the prediction
    /// interval's on an axis removed, the mean's square plus it elsewhere.
    pub variance: Vector3<f64>,
    /// The axes whose remembered mean is removed.
    pub applied: [bool; 3],
    /// Earlier power-ons it rests on.
    pub power_ons: usize,
}

impl BiasPrediction {
    pub fn applies_any(&self) -> bool {
        self.applied.iter().any(|&a| a)
    }

    /// What it predicts, in words (the log, /diagnostics `power_on_bias_memory`).
    pub fn describe(&self) -> String {
        if !self.applies_any() {
            return format!(
                "{} earlier power-ons do not predict this one's bias (it changes more between them than it is large)",
                self.power_ons
            );
        }
        let axes: Vec<String> =
            (0..3).filter(|&k| self.applied[k]).map(|k| format!("{} {:.5}", ["x", "y", "z"][k], self.bias[k])).collect();
        format!(
            "{} earlier power-ons predict {} rad/s (σ {:.1e}): removed until the first standstill",
            self.power_ons,
            axes.join(", "),
            (0..3).filter(|&k| self.applied[k]).map(|k| self.variance[k]).fold(0.0, f64::max).sqrt()
        )
    }

    /// Where this power-on's standstills measured a bias outside the prediction (beyond 3 σ of
    /// the two together on an axis it was removed from): another IMU under the same memory, or
    /// one whose bias no longer repeats. Said, for the log and /diagnostics.
    pub fn contradicted_by(&self, measured: &BiasEstimate) -> Option<String> {
        let outside: Vec<String> = (0..3)
            .filter(|&k| self.applied[k])
            .filter(|&k| (measured.bias[k] - self.bias[k]).abs() > 3.0 * (self.variance[k] + measured.variance[k]).sqrt())
            .map(|k| format!("{} {:.5} against {:.5} ± {:.5}", ["x", "y", "z"][k], measured.bias[k], self.bias[k], self.variance[k].sqrt()))
            .collect();
        (!outside.is_empty()).then(|| {
            format!(
                "the standstills measured a bias outside what the earlier power-ons predicted ({} rad/s): another IMU, or one whose bias no longer repeats",
                outside.join(", ")
            )
        })
    }

    /// As a bias estimate in force at `now_ns` (no standstill of this power-on behind it).
    pub fn as_estimate(&self, now_ns: i64) -> BiasEstimate {
        BiasEstimate { bias: self.bias, variance: self.variance, at_ns: now_ns, still_s: 0.0 }
    }
}

/// Inverse-variance fusion of an earlier estimate (grown by the random walk up to the new one)
/// and a new standstill, per axis.
pub(super) fn fuse(prior: &BiasEstimate, new: &BiasEstimate, random_walk: f64) -> BiasEstimate {
    let vp = prior.variance_at(new.at_ns, random_walk);
    let vn = new.variance;
    let mut bias = Vector3::zeros();
    let mut variance = Vector3::zeros();
    for i in 0..3 {
        let (a, b) = (vp[i].max(1e-18), vn[i].max(1e-18));
        bias[i] = (prior.bias[i] * b + new.bias[i] * a) / (a + b);
        variance[i] = a * b / (a + b);
    }
    BiasEstimate { bias, variance, at_ns: new.at_ns, still_s: prior.still_s + new.still_s }
}
