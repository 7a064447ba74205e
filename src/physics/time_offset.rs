//! `time_offset`: both sensors are late (or early) by τ: real(t) = x(t − τ); τ > 0 means the
//! real stream lags. Works on the whole arrays: each channel is resampled at t − τ with a
//! cubic Hermite interpolant whose tangents are central differences of the samples
//! (Catmull–Rom on the real, possibly uneven, stamps); outside the recording the end
//! samples are extended along their tangent.
//!
//! Applied to the noise-free signal (see the order in [`super`]).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::{check_finite, ErrorTerm, ImuSignals, PhysicsError, TermContext};

/// Time offset of the IMU stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimeOffset {
    /// τ, s (> 0: the real stream lags the truth).
    pub seconds: f64,
}

impl ErrorTerm for TimeOffset {
    const NAME: &'static str = "time_offset";

    fn identity() -> Self {
        TimeOffset { seconds: 0.0 }
    }

    fn validate(&self) -> Result<(), PhysicsError> {
        check_finite(Self::NAME, "seconds", &[self.seconds])
    }

    fn apply(&self, s: &mut ImuSignals, _ctx: &mut TermContext) {
        if self.seconds == 0.0 || s.len() < 2 {
            return;
        }
        let t: Vec<f64> = (0..s.len()).map(|i| s.seconds_since_start(i)).collect();
        s.gyro = resample(&t, &s.gyro, -self.seconds);
        s.accel = resample(&t, &s.accel, -self.seconds);
    }
}

/// Values of the series (t, x) at every t_i + shift, by cubic Hermite interpolation with
/// central-difference tangents. `t` strictly increasing, at least two samples.
pub fn resample(t: &[f64], x: &[Vector3<f64>], shift: f64) -> Vec<Vector3<f64>> {
    let n = t.len();
    let tangent = |k: usize| -> Vector3<f64> {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        (x[b] - x[a]) / (t[b] - t[a])
    };
    let mut k = 0usize;
    (0..n)
        .map(|i| {
            let q = t[i] + shift;
            if q <= t[0] {
                return x[0] + tangent(0) * (q - t[0]);
            }
            if q >= t[n - 1] {
                return x[n - 1] + tangent(n - 1) * (q - t[n - 1]);
            }
            // q moves forward with i, so the bracketing interval does too.
            while t[k + 1] <= q {
                k += 1;
            }
            while t[k] > q {
                k -= 1;
            }
            let h = t[k + 1] - t[k];
            let u = (q - t[k]) / h;
            let (u2, u3) = (u * u, u * u * u);
            let h00 = 2.0 * u3 - 3.0 * u2 + 1.0;
            let h10 = u3 - 2.0 * u2 + u;
            let h01 = -2.0 * u3 + 3.0 * u2;
            let h11 = u3 - u2;
            x[k] * h00 + tangent(k) * (h10 * h) + x[k + 1] * h01 + tangent(k + 1) * (h11 * h)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::test_support::*;
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn quadratics_are_delayed_exactly() {
        let mut s = signals(200);
        let tt = |i: usize| s.seconds_since_start(i);
        let f = |t: f64| Vector3::new(1.0 + 2.0 * t - 3.0 * t * t, 0.5 * t * t, -t);
        let clean: Vec<_> = (0..s.len()).map(|i| f(tt(i))).collect();
        s.gyro = clean.clone();
        s.accel = clean;
        let tau = 0.0123;
        let out = applied(&TimeOffset { seconds: tau }, &s);
        for i in 5..195 {
            let want = f(s.seconds_since_start(i) - tau);
            assert!((out.gyro[i] - want).norm() < 1e-12, "{i}: {:?} vs {want:?}", out.gyro[i]);
            assert!((out.accel[i] - want).norm() < 1e-12);
        }
    }

    #[test]
    fn small_offset_is_minus_tau_times_derivative() {
        let s = signals(400);
        let tau = 7e-5;
        let out = applied(&TimeOffset { seconds: tau }, &s);
        // s.gyro.x = 0.5 sin(2t): derivative cos(2t).
        for i in [10, 100, 300] {
            let t = s.seconds_since_start(i);
            let want = -tau * (2.0 * t).cos();
            assert!(((out.gyro[i].x - s.gyro[i].x) - want).abs() < 1e-3 * tau, "{i}");
        }
    }

    #[test]
    fn suite() {
        super::super::test_support::suite((-0.05..0.05f64).prop_map(|seconds| TimeOffset { seconds }));
    }
}
