//! A reference on a clock that drifts against the IMU's (a motion-capture system's own
//! oscillator, tens of ppm): the IMU's lag behind the reference changes along the recording.
//! A constant lag is the IMU's own delay (`time_offset`, a sensor term, with whole samples taken
//! out by [`super::kinematics::reference_lag_s`]); a lag that grows linearly is the reference's
//! clock, a recording artefact. Measured piece by piece (the sub-sample lag of the gyro against
//! the rate differentiated from the poses, with each piece's own bias), fitted by a line, and
//! taken out of the reference's stamps about the recording's middle, so what is constant stays
//! `time_offset`'s.

use nalgebra::{Matrix4, Vector3, Vector4};

use super::kinematics::{ideal_from_poses_with, near_dropouts, reference_dropouts};
use super::DiagnoseError;
use crate::core::Recording;

/// Length of one piece the lag is measured on, s.
pub const PIECE_S: f64 = 20.0;
/// A drift is taken out where its slope is this many σ from zero …
const MIN_Z: f64 = 4.0;
/// … and it moves the lag by at least this share of an IMU interval over the recording.
const MIN_SPAN_INTERVALS: f64 = 0.25;

/// The reference's clock against the IMU's.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockDrift {
    /// Slope of the IMU's lag behind the reference, s per s (×1e6: ppm; > 0: the lag grows).
    pub rate: f64,
    /// Its 1 σ from the pieces' scatter.
    pub rate_sigma: f64,
    /// The recording's middle, ns: the drift is taken out about it.
    pub middle_ns: i64,
    /// Pieces measured: (their middle s from the first, lag s, 1 σ s).
    pub pieces: Vec<(f64, f64, f64)>,
    /// Seconds covered from the first piece's middle to the last's.
    pub span_s: f64,
}

impl ClockDrift {
    /// Whether it is taken out: significant, and large enough to matter at the IMU's rate.
    pub fn significant(&self, imu_interval_s: f64) -> bool {
        self.rate.abs() > MIN_Z * self.rate_sigma && (self.rate * self.span_s).abs() >= MIN_SPAN_INTERVALS * imu_interval_s
    }

    /// The reference's stamps corrected: a pose stamped `t` is moved so that the IMU's lag is
    /// what it is at the middle.
    pub fn take_out(&self, real: &mut Recording) {
        for p in &mut real.ground_truth {
            let from_middle = (p.stamp_ns - self.middle_ns) as f64 * 1e-9;
            p.stamp_ns += (self.rate * from_middle * 1e9).round() as i64;
        }
    }

    pub fn sentence(&self) -> String {
        format!(
            "the ground truth's clock drifts against the IMU's: the IMU's lag behind it changes by {:+.1} ppm (± {:.1}, from {} pieces of {PIECE_S} s: {:+.2} ms over the recording): taken out of its stamps about the recording's middle; the constant lag is left to time_offset",
            self.rate * 1e6,
            self.rate_sigma * 1e6,
            self.pieces.len(),
            self.rate * self.span_s * 1e3
        )
    }
}

/// The IMU's lag behind the reference in pieces of [`PIECE_S`], and the line through them.
/// `None` with fewer than 3 pieces that tell a lag (motion too smooth, a short recording).
pub fn reference_clock_drift(real: &Recording, smoothing: Option<f64>) -> Result<Option<ClockDrift>, DiagnoseError> {
    let (Some(first), Some(last)) = (real.ground_truth.first(), real.ground_truth.last()) else { return Ok(None) };
    let margin = (smoothing.unwrap_or(0.0) * 1e9) as i64;
    let imu: Vec<_> = real.imu.iter().filter(|s| s.stamp_ns >= first.stamp_ns + margin && s.stamp_ns <= last.stamp_ns - margin).collect();
    if imu.len() < 200 {
        return Ok(None);
    }
    let stamps: Vec<i64> = imu.iter().map(|s| s.stamp_ns).collect();
    let poses = ideal_from_poses_with(&real.ground_truth, &stamps, smoothing)?;
    let dropouts = reference_dropouts(&real.ground_truth);
    let interval = real.ground_truth.windows(2).map(|w| (w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9).fold(0.0, f64::max);
    let out = near_dropouts(&stamps, &dropouts, smoothing.unwrap_or(0.0) + 2.0 * interval.min(0.1));
    let gyro: Vec<Vector3<f64>> = imu.iter().map(|s| s.gyro).collect();
    // ω̇ from the IMU's own gyro (a slope over ±25 ms): the poses' second derivative carries
    // the reference's noise, which as a regressor pulls every lag towards 0.
    let alpha = slopes(&stamps, &gyro, (0.025 * real.nominal_imu_rate_hz()).round().max(2.0) as usize);
    let t0 = stamps[0];
    let piece_ns = (PIECE_S * 1e9) as i64;
    let n_pieces = ((stamps[stamps.len() - 1] - t0) / piece_ns) as usize;
    let mut pieces = Vec::new();
    for k in 0..n_pieces {
        let (lo, hi) = (t0 + k as i64 * piece_ns, t0 + (k as i64 + 1) * piece_ns);
        let idx: Vec<usize> = (0..stamps.len()).filter(|&i| stamps[i] >= lo && stamps[i] < hi && !out[i]).collect();
        if let Some((lag, sigma)) = piece_lag(&idx, &gyro, &poses.gyro, &alpha) {
            pieces.push(((lo + piece_ns / 2 - t0) as f64 * 1e-9, lag, sigma));
        }
    }
    if pieces.len() < 3 {
        return Ok(None);
    }
    let Some((_, rate, rate_sigma)) = line(&pieces) else { return Ok(None) };
    let span_s = pieces[pieces.len() - 1].0 - pieces[0].0;
    let middle_ns = t0 + ((pieces[0].0 + pieces[pieces.len() - 1].0) * 0.5 * 1e9) as i64;
    Ok(Some(ClockDrift { rate, rate_sigma, middle_ns, pieces, span_s }))
}

/// The least-squares slope of `x` over ±`k` samples about each (zero at the ends).
fn slopes(stamps: &[i64], x: &[Vector3<f64>], k: usize) -> Vec<Vector3<f64>> {
    let n = x.len();
    (0..n)
        .map(|i| {
            if i < k || i + k >= n {
                return Vector3::zeros();
            }
            let (mut stt, mut stx) = (0.0, Vector3::zeros());
            for j in i - k..=i + k {
                let dt = (stamps[j] - stamps[i]) as f64 * 1e-9;
                stt += dt * dt;
                stx += x[j] * dt;
            }
            stx / stt
        })
        .collect()
}

/// One piece's lag (s, > 0: the IMU later) and its 1 σ: imu − poses = b − τ ω̇ by least squares
/// with the piece's own bias b. `None` where ω̇ does not determine τ.
fn piece_lag(idx: &[usize], imu: &[Vector3<f64>], poses: &[Vector3<f64>], alpha: &[Vector3<f64>]) -> Option<(f64, f64)> {
    if idx.len() < 100 {
        return None;
    }
    let (mut ata, mut atb) = (Matrix4::<f64>::zeros(), Vector4::<f64>::zeros());
    for &i in idx {
        let d = imu[i] - poses[i];
        for axis in 0..3 {
            let mut a = Vector4::zeros();
            a[axis] = 1.0;
            a[3] = -alpha[i][axis];
            ata += a * a.transpose();
            atb += a * d[axis];
        }
    }
    let inv = ata.try_inverse()?;
    let x = inv * atb;
    let mut rss = 0.0;
    for &i in idx {
        let d = imu[i] - poses[i];
        for axis in 0..3 {
            rss += (d[axis] - x[axis] + x[3] * alpha[i][axis]).powi(2);
        }
    }
    let dof = (3 * idx.len()).saturating_sub(4).max(1) as f64;
    let sigma = (rss / dof * inv[(3, 3)]).sqrt();
    sigma.is_finite().then_some((x[3], sigma))
}

/// Weighted least-squares line through (t, y, σ): intercept, slope and the slope's σ, widened
/// by the scatter where it exceeds the σs (a reduced χ² above 1).
fn line(points: &[(f64, f64, f64)]) -> Option<(f64, f64, f64)> {
    let (mut sw, mut st, mut sy, mut stt, mut sty) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(t, y, s) in points {
        let w = 1.0 / (s * s).max(1e-30);
        sw += w;
        st += w * t;
        sy += w * y;
        stt += w * t * t;
        sty += w * t * y;
    }
    let det = sw * stt - st * st;
    if det.abs() < 1e-30 {
        return None;
    }
    let slope = (sw * sty - st * sy) / det;
    let intercept = (sy - slope * st) / sw;
    let chi2: f64 = points.iter().map(|&(t, y, s)| ((y - intercept - slope * t) / s).powi(2)).sum();
    let reduced = chi2 / (points.len() as f64 - 2.0).max(1.0);
    Some((intercept, slope, (sw / det * reduced.max(1.0)).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_through_drifting_lags_gives_its_slope() {
        let pts: Vec<(f64, f64, f64)> = (0..7).map(|k| (10.0 + 20.0 * k as f64, 1e-3 + 25e-6 * (10.0 + 20.0 * k as f64), 1e-4)).collect();
        let (c, m, s) = line(&pts).unwrap();
        assert!((m - 25e-6).abs() < 1e-12 && (c - 1e-3).abs() < 1e-9, "{c} {m}");
        assert!(s < 1e-6, "{s}");
    }
}
