//! The plain calibration every calibration tool starts from, as the diagnosis's yardstick:
//! the IMU's rate regressed on the reference's, per axis, `ω_imu ≈ A ω_ref + b` (a 3 × 3
//! matrix and a bias, 12 parameters), by ordinary least squares over window means of the
//! samples where the reference is good. A = I + S + M to first order: its diagonal is
//! gyro_scale, its off-diagonal gyro_misalignment, b gyro_bias. A term is reported when one of
//! its parameters' 95 % interval (1.96 σ from the fit's own residual, as a plain tool states
//! it) leaves out zero. What it cannot express (a delay, a low-pass, g-sensitivity, the
//! reference's errors) goes into its residual or into the 12 parameters.

use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

use super::{kinematics, DiagnoseError, Diagnosis};
use crate::core::Recording;
use crate::physics::{GyroBias, GyroMisalignment, GyroScale, Term};

/// How a term is reported, said in every report that carries the fit.
pub const RULE: &str = "ordinary least squares of the IMU's gyro on the rate differentiated from the reference, per axis (a 3x3 matrix A and a bias b), over the comparison's window means where the reference has no dropout; A's diagonal less 1 is gyro_scale, its off-diagonal gyro_misalignment, b gyro_bias; a term is reported when one of its parameters' 95 % interval (1.96 sigma from the fit's residual) leaves out zero";

/// z of a two-sided 95 % interval.
pub const Z_95: f64 = 1.96;

/// A fitted plain calibration and its 1σ per parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct PlainCalibration {
    /// A: row i is axis i of the IMU against the reference's x, y, z.
    pub matrix: Matrix3<f64>,
    /// b, rad/s.
    pub bias: Vector3<f64>,
    pub matrix_sigma: Matrix3<f64>,
    pub bias_sigma: Vector3<f64>,
    /// Window means fitted.
    pub windows: usize,
    /// RMS of each axis's residual over the windows, rad/s.
    pub residual_rms: Vector3<f64>,
    /// RMS of the reference's rate per axis over the windows, rad/s: beside `residual_rms`, how
    /// far errors in the reference could pull A's diagonal toward zero (regression dilution:
    /// at most ≈ residual² / reference² where the whole residual is the reference's).
    pub reference_rms: Vector3<f64>,
}

/// Fit `measured ≈ A reference + b` over means of `window` consecutive samples, every sample
/// of which is `used` (a window touching a reference dropout is left out whole).
pub fn fit(measured: &[Vector3<f64>], reference: &[Vector3<f64>], used: &[bool], window: usize) -> Result<PlainCalibration, DiagnoseError> {
    if measured.len() != reference.len() || used.len() != measured.len() || window == 0 {
        return Err(DiagnoseError::Input(format!(
            "plain calibration: {} measured, {} reference and {} flags, window {window}: lengths must agree, window ≥ 1",
            measured.len(),
            reference.len(),
            used.len()
        )));
    }
    let means = window_means(measured, reference, used, window);
    if means.len() < 16 {
        return Err(DiagnoseError::Input(format!(
            "plain calibration: {} windows where the reference is good, 16 needed for 12 parameters",
            means.len()
        )));
    }
    let mut xtx = Matrix4::zeros();
    let mut xty = [Vector4::zeros(); 3];
    for (y, x) in &means {
        let row = Vector4::new(x.x, x.y, x.z, 1.0);
        xtx += row * row.transpose();
        for (k, xty_k) in xty.iter_mut().enumerate() {
            *xty_k += row * y[k];
        }
    }
    let inv = xtx
        .try_inverse()
        .ok_or_else(|| DiagnoseError::Input("plain calibration: the reference's rate does not excite all three axes".into()))?;
    let (mut matrix, mut bias, mut matrix_sigma, mut bias_sigma, mut residual_rms) =
        (Matrix3::zeros(), Vector3::zeros(), Matrix3::zeros(), Vector3::zeros(), Vector3::zeros());
    let dof = (means.len() - 4) as f64;
    for k in 0..3 {
        let theta = inv * xty[k];
        let rss: f64 = means.iter().map(|(y, x)| (y[k] - (theta.x * x.x + theta.y * x.y + theta.z * x.z + theta.w)).powi(2)).sum();
        let s2 = rss / dof;
        for j in 0..3 {
            matrix[(k, j)] = theta[j];
            matrix_sigma[(k, j)] = (s2 * inv[(j, j)]).sqrt();
        }
        bias[k] = theta.w;
        bias_sigma[k] = (s2 * inv[(3, 3)]).sqrt();
        residual_rms[k] = (rss / means.len() as f64).sqrt();
    }
    let reference_rms = Vector3::from_fn(|k, _| (means.iter().map(|(_, x)| x[k] * x[k]).sum::<f64>() / means.len() as f64).sqrt());
    Ok(PlainCalibration { matrix, bias, matrix_sigma, bias_sigma, windows: means.len(), residual_rms, reference_rms })
}

/// The plain calibration of a real recording against its own ground truth (cropped to it, its
/// clock lined up): the reference's rate from its poses (smoothed as the diagnosis smooths
/// them), window means of `window_s` (one sample where 0), windows touching a dropout out.
pub fn of_recording(real: &Recording, smoothing: Option<f64>, window_s: f64) -> Result<PlainCalibration, DiagnoseError> {
    let stamps: Vec<i64> = real.imu.iter().map(|s| s.stamp_ns).collect();
    let ideal = kinematics::ideal_from_poses_with(&real.ground_truth, &stamps, smoothing)?;
    let margin = kinematics::dropout_margin_s(&real.ground_truth, smoothing);
    let used: Vec<bool> =
        kinematics::near_dropouts(&stamps, &kinematics::reference_dropouts(&real.ground_truth), margin).iter().map(|d| !d).collect();
    let window = ((window_s / ideal.nominal_dt().max(1e-12)).round() as usize).max(1);
    let measured: Vec<Vector3<f64>> = real.imu.iter().map(|s| s.gyro).collect();
    fit(&measured, &ideal.gyro, &used, window)
}

fn window_means(measured: &[Vector3<f64>], reference: &[Vector3<f64>], used: &[bool], window: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let n = measured.len() / window;
    (0..n)
        .map(|w| w * window..(w + 1) * window)
        .filter(|r| used[r.clone()].iter().all(|&u| u))
        .map(|r| {
            let k = window as f64;
            (measured[r.clone()].iter().sum::<Vector3<f64>>() / k, reference[r].iter().sum::<Vector3<f64>>() / k)
        })
        .collect()
}

impl PlainCalibration {
    /// The terms whose parameters' 95 % interval leaves out zero (any one parameter of a
    /// term), each with all its fitted values: gyro_bias, gyro_scale (A's diagonal − 1),
    /// gyro_misalignment (A's off-diagonal).
    pub fn terms(&self) -> Vec<Term> {
        let significant = |v: f64, s: f64| v.abs() > Z_95 * s;
        let mut out = Vec::new();
        if (0..3).any(|k| significant(self.bias[k], self.bias_sigma[k])) {
            out.push(Term::GyroBias(GyroBias::new([self.bias.x, self.bias.y, self.bias.z])));
        }
        if (0..3).any(|k| significant(self.matrix[(k, k)] - 1.0, self.matrix_sigma[(k, k)])) {
            out.push(Term::GyroScale(GyroScale::new(std::array::from_fn(|k| self.matrix[(k, k)] - 1.0))));
        }
        let off = |r: usize, c: usize| r != c && significant(self.matrix[(r, c)], self.matrix_sigma[(r, c)]);
        if (0..3).any(|r| (0..3).any(|c| off(r, c))) {
            let m = std::array::from_fn(|r| std::array::from_fn(|c| if r == c { 0.0 } else { self.matrix[(r, c)] }));
            out.push(Term::GyroMisalignment(GyroMisalignment::new(m)));
        }
        out
    }
}

/// A − I of several recordings of one IMU pooled, entry by entry, by inverse variance: the
/// lasting scale and cross-axis error no single recording may resolve (the biases are each
/// power-on's own and are not pooled). The value and its 1 σ; `None` for no recording.
pub fn pooled_lasting_error(fits: &[PlainCalibration]) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    if fits.is_empty() {
        return None;
    }
    let (mut mean, mut sigma) = (Matrix3::zeros(), Matrix3::zeros());
    for r in 0..3 {
        for c in 0..3 {
            let truth = if r == c { 1.0 } else { 0.0 };
            let values: Vec<(f64, f64)> = fits.iter().map(|f| (f.matrix[(r, c)] - truth, f.matrix_sigma[(r, c)])).collect();
            (mean[(r, c)], sigma[(r, c)]) = inverse_variance_mean(&values);
        }
    }
    Some((mean, sigma))
}

/// Values with their 1 σ, pooled by inverse variance: the mean and its 1 σ (a σ of zero is
/// taken as the smallest positive variance, not a division by zero).
pub fn inverse_variance_mean(values: &[(f64, f64)]) -> (f64, f64) {
    let (sw, swx) = values.iter().fold((0.0, 0.0), |(sw, swx), (v, s)| {
        let w = 1.0 / s.powi(2).max(1e-300);
        (sw + w, swx + w * v)
    });
    (swx / sw, 1.0 / sw.sqrt())
}

/// A 3 × 3 matrix as rows, for JSON.
pub fn rows(m: &Matrix3<f64>) -> Vec<Vec<f64>> {
    (0..3).map(|r| (0..3).map(|c| m[(r, c)]).collect()).collect()
}

impl PlainCalibration {
    /// `plain_calibration.json`: the fit, its σ, the terms it reports and its rule.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "rule": RULE,
            "matrix": rows(&self.matrix),
            "matrix_sigma": rows(&self.matrix_sigma),
            "bias_rad_s": self.bias.as_slice(),
            "bias_sigma_rad_s": self.bias_sigma.as_slice(),
            "windows": self.windows,
            "residual_rms_rad_s": self.residual_rms.as_slice(),
            "reference_rms_rad_s": self.reference_rms.as_slice(),
            "terms": self.terms(),
        })
    }

    /// A report section: each gyro term as the plain fit states it (value ± 1.96 σ) beside what
    /// the diagnosis found of it.
    pub fn markdown(&self, d: &Diagnosis) -> String {
        let pct = |v: f64| format!("{:+.2}", 100.0 * v);
        let ci = |v: f64, s: f64, k: f64| format!("{:+.2} ± {:.2}", k * v, k * Z_95 * s);
        let joined = |v: &mut dyn Iterator<Item = String>| v.collect::<Vec<_>>().join(" / ");
        let off = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)];
        let found = |name: &str| match d.terms.iter().find(|t| t.name() == name) {
            Some(Term::GyroScale(t)) => joined(&mut t.scale.iter().map(|v| pct(*v))),
            Some(Term::GyroBias(t)) => joined(&mut t.bias.iter().map(|v| format!("{:+.2}", 1e3 * v))),
            Some(Term::GyroMisalignment(t)) => joined(&mut off.iter().map(|&(r, c)| pct(t.matrix[r][c]))),
            _ => "–".to_string(),
        };
        let scale = (0..3).map(|k| ci(self.matrix[(k, k)] - 1.0, self.matrix_sigma[(k, k)], 100.0)).collect::<Vec<_>>().join(" / ");
        let bias = (0..3).map(|k| ci(self.bias[k], self.bias_sigma[k], 1e3)).collect::<Vec<_>>().join(" / ");
        let misalignment = off.iter().map(|&(r, c)| pct(self.matrix[(r, c)])).collect::<Vec<_>>().join(" / ");
        let reported: Vec<&str> = self.terms().iter().map(|t| t.name()).collect();
        format!(
            "\n## Beside it: the plain per-axis calibration\n\n{RULE}. {} windows; residual RMS {:.4} / {:.4} / {:.4} rad/s against the reference's {:.3} / {:.3} / {:.3} rad/s. \
             It reports [{}]; it has no term for a delay, a low-pass, g-sensitivity or the reference's own errors (they go into its 12 parameters).\n\n\
             | term | plain fit (95 %) | the diagnosis |\n|---|---|---|\n\
             | gyro_scale, % | {scale} | {} |\n\
             | gyro_bias, mrad/s | {bias} | {} |\n\
             | gyro_misalignment (xy / xz / yx / yz / zx / zy), % | {misalignment} | {} |\n",
            self.windows,
            self.residual_rms.x,
            self.residual_rms.y,
            self.residual_rms.z,
            self.reference_rms.x,
            self.reference_rms.y,
            self.reference_rms.z,
            reported.join(", "),
            found("gyro_scale"),
            found("gyro_bias"),
            found("gyro_misalignment"),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn motion(n: usize) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.005;
                Vector3::new((0.7 * t).sin(), 0.8 * (1.3 * t).cos(), 0.5 * (0.31 * t).sin() + 0.2 * (2.1 * t).cos())
            })
            .collect()
    }

    #[test]
    fn recovers_a_known_affine_map_and_states_its_error() {
        let reference = motion(40_000);
        let a = Matrix3::new(1.03, 0.004, -0.002, 0.003, 0.978, 0.006, -0.005, 0.001, 1.041);
        let b = Vector3::new(0.031, -0.047, 0.019);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let measured: Vec<_> = reference.iter().map(|w| a * w + b + Vector3::from_fn(|_, _| noise.sample(&mut rng))).collect();
        let used = vec![true; reference.len()];
        let c = fit(&measured, &reference, &used, 40).unwrap();
        for k in 0..3 {
            assert!((c.bias[k] - b[k]).abs() < 4.0 * c.bias_sigma[k], "bias {k}: {} against {}", c.bias[k], b[k]);
            for j in 0..3 {
                assert!((c.matrix[(k, j)] - a[(k, j)]).abs() < 4.0 * c.matrix_sigma[(k, j)], "A[{k},{j}]");
            }
        }
        let names: Vec<&str> = c.terms().iter().map(|t| t.name()).collect();
        assert_eq!(names, ["gyro_bias", "gyro_scale", "gyro_misalignment"]);
    }

    #[test]
    fn pooling_recordings_of_one_imu_narrows_its_lasting_error() {
        let reference = motion(8_000);
        let a = Matrix3::new(0.998, 0.0, 0.0, 0.0, 0.998, 0.0, 0.0, 0.0, 0.998);
        let fits: Vec<PlainCalibration> = (0..6)
            .map(|seed| {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let noise = Normal::new(0.0, 0.02).unwrap();
                // Each power-on its own bias; the scale lasts.
                let b = Vector3::new(0.01 * seed as f64, -0.02, 0.005);
                let measured: Vec<_> = reference.iter().map(|w| a * w + b + Vector3::from_fn(|_, _| noise.sample(&mut rng))).collect();
                fit(&measured, &reference, &vec![true; reference.len()], 40).unwrap()
            })
            .collect();
        let (mean, sigma) = pooled_lasting_error(&fits).unwrap();
        for k in 0..3 {
            assert!((mean[(k, k)] + 0.002).abs() < 4.0 * sigma[(k, k)], "scale {k}: {} ± {}", mean[(k, k)], sigma[(k, k)]);
            // Six recordings: σ about 1/√6 of one's.
            let ratio = sigma[(k, k)] / fits[0].matrix_sigma[(k, k)];
            assert!((0.3..0.55).contains(&ratio), "{ratio}");
        }
        assert!(pooled_lasting_error(&[]).is_none());
    }

    #[test]
    fn an_identity_is_found_within_its_stated_error_and_bad_input_is_an_error() {
        let reference = motion(8_000);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1e-3).unwrap();
        let measured: Vec<_> = reference.iter().map(|w| w + Vector3::from_fn(|_, _| noise.sample(&mut rng))).collect();
        let mut used = vec![true; reference.len()];
        // A reference dropout: its windows are left out whole.
        used[1000..1500].iter_mut().for_each(|u| *u = false);
        let c = fit(&measured, &reference, &used, 40).unwrap();
        assert_eq!(c.windows, 200 - 13);
        for k in 0..3 {
            assert!(c.bias[k].abs() < 4.0 * c.bias_sigma[k], "bias {k}");
            for j in 0..3 {
                let truth = if j == k { 1.0 } else { 0.0 };
                assert!((c.matrix[(k, j)] - truth).abs() < 4.0 * c.matrix_sigma[(k, j)], "A[{k},{j}]");
            }
        }
        assert!(fit(&measured, &reference[1..], &used, 40).is_err());
        assert!(fit(&measured[..100], &reference[..100], &used[..100], 40).is_err());
        let still = vec![Vector3::zeros(); 4000];
        assert!(fit(&still, &still, &vec![true; 4000], 40).is_err());
    }
}
