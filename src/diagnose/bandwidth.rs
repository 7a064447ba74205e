//! The comparison at the bandwidth where a measured reference is good.
//!
//! A simulation made from a measured ground truth (motion capture, an estimator's poses)
//! carries the reference's own errors: its jitter differentiated (1 mrad of attitude noise is
//! ≈ 0.15 rad/s at 200 Hz), the smoother's rounding of fast motion, and both in the
//! regressors too. At full rate those dominate the residual where the fit is made, and every
//! scale-like term is pulled towards −1 (errors in variables: a BMI160 recording gave gyro
//! scales of −28 % to −52 %). Over windows of T the mean rate is the attitude increment over
//! T, whose reference error is ≈ √2 σ_att / T, and the motion's power stays. So the
//! recordings are compared as block means over T: every linear term's effect averages
//! exactly (the model real = sim + Σ βⱼ atomⱼ + noise holds for block means), the white noise
//! falls by the block length, and the terms that live above 1/T — a low-pass's noise shape,
//! a vibration, the white-noise level, quantisation, saturation — are not judged (a
//! low-pass's mean effect, its delay, is still `time_offset`).

use nalgebra::{UnitQuaternion, Vector3};

use super::align::Aligned;

/// The shortest comparison window for a measured reference, s. The reference's error in a
/// window mean falls as 1/T and pulls a fitted scale by −σ²_ref/⟨ω̄²⟩ (errors in variables):
/// on TUM-VI's calibrated BMI160 against its motion capture, windows of 0.05 / 0.1 / 0.2 s
/// gave gyro scales of up to −1.5 / −0.6 / 0 % (none in 5 of 6 rooms) while the injected
/// terms were found as well at 0.2 s as at 0.1 s (docs/diagnosis.md).
pub const REFERENCE_WINDOW_S: f64 = 0.2;

/// The window needs this many reference intervals (a 10 Hz reference: 0.4 s).
pub const REFERENCE_INTERVALS_PER_WINDOW: f64 = 4.0;

/// Terms a comparison at reduced bandwidth does not judge, and why.
pub const NOT_JUDGED: [&str; 5] = ["low_pass", "vibration", "gyro_noise_density", "quantization", "saturation"];

/// The comparison window for a reference of median pose interval `reference_interval_s`.
pub fn window_for(reference_interval_s: f64) -> f64 {
    REFERENCE_WINDOW_S.max(REFERENCE_INTERVALS_PER_WINDOW * reference_interval_s)
}

/// ẋ of the window means, per window: (gyro, accelerometer).
pub type WindowDerivatives = (Vec<Vector3<f64>>, Vec<Vector3<f64>>);

/// The time derivatives of the window means (gyro, accelerometer): the mean of ẋ over a
/// window is (x(end) − x(start)) / T, exactly what a time shift of the window means needs
/// (ω̇ at the centre is not: at 3 Hz and T = 0.1 s it is 15 % larger; and a derivative of the
/// means themselves, at the window rate, is 10–25 % smaller at 2–3 Hz). x at the windows'
/// edges from the ground truth; `None` when it cannot be differentiated or `a` is at full
/// rate.
pub fn window_mean_derivatives(a: &Aligned, gt_smoothing: Option<f64>) -> Option<WindowDerivatives> {
    let n = a.len();
    let (edges, t) = window_edges(a)?;
    if a.sim_recording.ground_truth.len() < 4 {
        return None;
    }
    let s = super::kinematics::ideal_from_poses_with(&a.sim_recording.ground_truth, &edges, gt_smoothing).ok()?;
    let d = |x: &[Vector3<f64>]| (0..n).map(|b| (x[b + 1] - x[b]) / t).collect();
    Some((d(&s.gyro), d(&s.accel)))
}

/// The cutoff (Hz) of the first-order low-pass y ← y + (1 − a)(x − y) at sample interval
/// `dt` whose delay, a/(1 − a)·dt, is `delay_s`; `None` for no delay or a lead.
pub fn equivalent_low_pass_hz(delay_s: f64, dt: f64) -> Option<f64> {
    (delay_s > 0.0 && dt > 0.0).then(|| -(delay_s / (delay_s + dt)).ln() / (std::f64::consts::TAU * dt))
}

/// The delay (s) of a first-order low-pass at `cutoff_hz` sampled every `dt` s: what a
/// comparison at reduced bandwidth sees of it.
pub fn low_pass_delay_s(cutoff_hz: f64, dt: f64) -> f64 {
    let a = (-std::f64::consts::TAU * cutoff_hz * dt).exp();
    a / (1.0 - a) * dt
}

/// The windows' edges, ns: each window's centre ∓ half its length (n + 1 stamps), and the
/// window's length, s.
fn window_edges(a: &Aligned) -> Option<(Vec<i64>, f64)> {
    let n = a.len();
    let rate = a.sim_recording.nominal_imu_rate_hz();
    let window_ns = (a.samples_per_point as f64 / rate * 1e9).round() as i64;
    if n < 2 || a.samples_per_point < 2 || window_ns <= 0 {
        return None;
    }
    let edges = (0..=n).map(|b| if b < n { a.stamps_ns[b] - window_ns / 2 } else { a.stamps_ns[n - 1] + window_ns / 2 }).collect();
    Some((edges, window_ns as f64 * 1e-9))
}

impl Aligned {
    /// The same recordings as means over consecutive windows of `window_s` (whole samples;
    /// the last partial window is dropped). A window with any sample left out (a gap of
    /// either stream) is left out whole. Stamps and attitude are the window's centre, the
    /// white-noise variances those of a mean of the window's samples.
    pub fn block_means(&self, window_s: f64) -> Aligned {
        let m = ((window_s / self.dt()).round() as usize).max(1);
        if m == 1 {
            return self.clone();
        }
        let blocks = self.len() / m;
        let mean = |x: &[f64], b: usize| x[b * m..(b + 1) * m].iter().sum::<f64>() / m as f64;
        let centre = |b: usize| b * m + m / 2;
        let mut notes = self.notes.clone();
        notes.push(format!(
            "compared at the reference's bandwidth: means over windows of {m} samples ({:.3} s), {blocks} windows; low_pass, vibration, gyro_noise_density, quantization and saturation live above it and are not judged",
            m as f64 * self.dt()
        ));
        let sample_left_out = self.left_out();
        let left_out: Vec<bool> = (0..blocks).map(|b| sample_left_out[b * m..(b + 1) * m].iter().any(|f| *f)).collect();
        Aligned {
            stamps_ns: (0..blocks).map(|b| (self.stamps_ns[b * m] + self.stamps_ns[(b + 1) * m - 1]) / 2).collect(),
            sim: std::array::from_fn(|c| (0..blocks).map(|b| mean(&self.sim[c], b)).collect()),
            real: std::array::from_fn(|c| (0..blocks).map(|b| mean(&self.real[c], b)).collect()),
            sim_variance: (self.sim_variance.0 / m as f64, self.sim_variance.1 / m as f64),
            real_variance: (self.real_variance.0 / m as f64, self.real_variance.1 / m as f64),
            world_from_imu: self.world_from_imu.as_ref().map(|q| (0..blocks).map(|b| q[centre(b)]).collect::<Vec<UnitQuaternion<f64>>>()),
            temperature_c: self.temperature_c.as_ref().map(|t| (0..blocks).map(|b| mean(t, b)).collect()),
            notes,
            artefacts: self.artefacts.clone(),
            in_real_gap: vec![],
            in_reference_gap: if left_out.iter().any(|f| *f) { left_out } else { vec![] },
            sim_recording: self.sim_recording.clone(),
            samples_per_point: self.samples_per_point * m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::Recording;

    fn aligned(n: usize) -> Aligned {
        let ramp: Vec<f64> = (0..n).map(|i| i as f64).collect();
        Aligned {
            stamps_ns: (0..n as i64).map(|i| i * 5_000_000).collect(),
            sim: std::array::from_fn(|_| ramp.clone()),
            real: std::array::from_fn(|c| ramp.iter().map(|v| v * (1.0 + c as f64)).collect()),
            sim_variance: (2e-4, 4e-2),
            real_variance: (2e-4, 4e-2),
            world_from_imu: None,
            temperature_c: None,
            notes: vec![],
            artefacts: vec![],
            in_real_gap: vec![],
            in_reference_gap: (0..n).map(|i| i == 25).collect(),
            sim_recording: Recording { name: "t".into(), imu: vec![], ground_truth: vec![], temperature: vec![] },
            samples_per_point: 1,
        }
    }

    #[test]
    fn block_means_average_the_channels_and_the_noise_and_leave_out_a_window_with_a_gap() {
        let a = aligned(105);
        let b = a.block_means(0.1); // 20 samples of 5 ms
        assert_eq!(b.len(), 5, "the partial last window is dropped");
        assert_eq!(b.samples_per_point, 20);
        assert!((b.sim[0][0] - 9.5).abs() < 1e-12 && (b.real[2][1] - 3.0 * 29.5).abs() < 1e-12);
        assert!((b.sim_variance.0 - 1e-5).abs() < 1e-18 && (b.real_variance.1 - 2e-3).abs() < 1e-15);
        assert_eq!(b.in_reference_gap, vec![false, true, false, false, false]);
        assert_eq!(b.stamps_ns[0], 19 * 5_000_000 / 2);
    }

    #[test]
    fn a_delay_and_its_low_pass_are_one_effect() {
        let dt = 1.0 / 200.0;
        for f_c in [5.0, 40.0, 80.0] {
            let tau = low_pass_delay_s(f_c, dt);
            assert!((equivalent_low_pass_hz(tau, dt).unwrap() - f_c).abs() < 1e-9 * f_c);
        }
        assert!(equivalent_low_pass_hz(-1e-3, dt).is_none());
    }

    #[test]
    fn the_window_holds_enough_reference_intervals() {
        assert_eq!(window_for(1.0 / 120.0), REFERENCE_WINDOW_S);
        assert!((window_for(0.1) - 0.4).abs() < 1e-12, "a 10 Hz reference: four of its intervals");
    }
}
