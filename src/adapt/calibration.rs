//! The IMU's lasting linear gyro error from a support recording's ground truth: the matrix
//! Ĉ_ω with `Ĉ_ω (ω − b)` the body rate (scale and cross-axis errors), where b is the
//! power-on bias already removed. It carries to the next power-on where a network's
//! adaptation carries the support's motion and its leftover constant (docs/poweron.md).
//!
//! Fitted by Gauss–Newton on attitude increments of `span` samples: the residual
//! `Log(δR_gtᵀ Π exp((Ĉ ω_i + c) dt_i))` is linear in a change of Ĉ and c through the
//! suffix products of the increment (`P exp(Σ B_i δφ_i)`, `B_i = (E_{i+1}⋯E_J)ᵀ`), so coning
//! is modelled, not approximated away. c is the support's leftover constant (the power-on
//! bias's error, its drift): fitted as a nuisance and not kept. Ĉ is drawn toward I by a
//! prior of `prior_stddev` per entry, so an axis the support did not turn about stays at I.

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::core::ImuSample;

/// Unknowns: Ĉ row-major (9), then c (3).
const N: usize = 12;
const GAUSS_NEWTON_ITERATIONS: usize = 4;
/// Increments needed for the 12 unknowns to be more than the prior.
pub const MIN_INCREMENTS: usize = 20;
/// (1 µrad)²: the residual scatter below which the prior's weight stops shrinking.
const MIN_RESIDUAL_VARIANCE: f64 = 1e-12;
/// An entry is kept only where the support determines it: σ below a tenth of the prior and
/// the departure from I beyond 3 σ (as the bias seen in motion is applied); the rest stays I.
pub const MAX_KEPT_STDDEV_OF_PRIOR: f64 = 0.1;
const MIN_SIGNIFICANCE: f64 = 3.0;
/// Beyond every MEMS datasheet's sensitivity and cross-axis tolerance (±3 % and ±2 % are
/// typical): a fitted departure this large is the reference's error (a drifting pose, a
/// clock), not the gyro's, and the fit is refused.
pub const MAX_LASTING_ERROR: f64 = 0.1;
/// A pinned entry's weight toward I: far above any data term.
const PINNED: f64 = 1e12;

/// What the fit found on the support.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GyroCalibrationFit {
    /// Ĉ_ω, row-major.
    pub matrix: [[f64; 3]; 3],
    /// 1 σ of each entry (from the normal matrix and the residual's scatter), before pinning.
    pub stddev: [[f64; 3]; 3],
    /// Entries the support determines (the others are pinned at I).
    pub kept: [[bool; 3]; 3],
    /// The support's leftover constant c, rad/s: the bias in motion less the power-on bias
    /// measured at rest (kept only by the candidate that carries it, where other power-ons
    /// show it lasts).
    pub leftover_bias_rad_s: [f64; 3],
    /// Its 1 σ per axis, rad/s.
    #[serde(default)]
    pub leftover_bias_stddev_rad_s: [f64; 3],
    pub increments: usize,
    /// RMS increment residual, °/s: with Ĉ = I and c = 0, and with the fit.
    pub residual_before_deg_s: f64,
    pub residual_after_deg_s: f64,
}

impl GyroCalibrationFit {
    /// Some entry of Ĉ_ω is determined by the support (the others are I).
    pub fn determines_matrix(&self) -> bool {
        self.kept.iter().flatten().any(|k| *k)
    }

    /// The leftover constant departs from none beyond 3 σ on some axis.
    pub fn determines_leftover_bias(&self) -> bool {
        (0..3).any(|k| self.leftover_bias_rad_s[k].abs() > MIN_SIGNIFICANCE * self.leftover_bias_stddev_rad_s[k])
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CalibrationError {
    #[error("{found} ground-truth-covered increments of {span} samples, at least {MIN_INCREMENTS} needed to fit the gyro's scale and cross-axis errors")]
    TooFewIncrements { found: usize, span: usize },
    #[error("the normal equations of the gyro calibration are singular (the support holds no rotation)")]
    Singular,
    #[error("Ĉ_ω[{row}][{col}] departs from I by {departure:+.3}, beyond any gyro's scale or cross-axis error (±{MAX_LASTING_ERROR}): the ground truth does not follow this gyro well enough on the support")]
    Implausible { row: usize, col: usize, departure: f64 },
    #[error("no scale or cross-axis error is determined by the support (each within 3 σ of none, or σ above {:.2} %), nor a bias offset in motion", 100.0 * .max_stddev)]
    NothingDetermined { max_stddev: f64 },
}

/// One increment: the IMU samples `[start, end)` and the ground truth's rotation over them.
struct Increment {
    start: usize,
    end: usize,
    gt_delta: UnitQuaternion<f64>,
}

fn increments(imu: &[ImuSample], gt: &[Option<UnitQuaternion<f64>>], valid: &[bool], span: usize) -> Vec<Increment> {
    let mut out = Vec::new();
    let mut k = 0usize;
    while k + span < imu.len().min(gt.len()).min(valid.len()) {
        if let (true, Some(a), Some(b)) = (valid[k..=k + span].iter().all(|v| *v), gt[k], gt[k + span]) {
            out.push(Increment { start: k, end: k + span, gt_delta: a.inverse() * b });
        }
        k += span;
    }
    out
}

fn dt_s(imu: &[ImuSample], i: usize) -> f64 {
    (imu[i + 1].stamp_ns - imu[i].stamp_ns) as f64 * 1e-9
}

/// Residual of one increment at (Ĉ, c), with its Jacobian in the unknowns.
fn linearise(imu: &[ImuSample], inc: &Increment, c_hat: &Matrix3<f64>, c: &Vector3<f64>) -> (Vector3<f64>, SMatrix<f64, 3, N>) {
    let mut jac = SMatrix::<f64, 3, N>::zeros();
    let mut suffix = UnitQuaternion::identity();
    for i in (inc.start..inc.end).rev() {
        let dt = dt_s(imu, i);
        let w = imu[i].gyro;
        let b = suffix.to_rotation_matrix().into_inner().transpose();
        for row in 0..3 {
            for col in 0..3 {
                // ∂(Ĉ ω)/∂Ĉ[row][col] = ω[col] e_row, through B.
                let mut column = jac.fixed_view_mut::<3, 1>(0, 3 * row + col);
                column += b.column(row) * (w[col] * dt);
            }
        }
        let mut constant = jac.fixed_view_mut::<3, 3>(0, 9);
        constant += b * dt;
        suffix = crate::so3::exp(&((c_hat * w + c) * dt)) * suffix;
    }
    (crate::so3::log(&(inc.gt_delta.inverse() * suffix)), jac)
}

fn unpack(x: &SVector<f64, N>) -> (Matrix3<f64>, Vector3<f64>) {
    (Matrix3::from_row_slice(&x.as_slice()[..9]), Vector3::new(x[9], x[10], x[11]))
}

fn identity_unknowns() -> SVector<f64, N> {
    let mut x = SVector::<f64, N>::zeros();
    x[0] = 1.0;
    x[4] = 1.0;
    x[8] = 1.0;
    x
}

fn rms_deg_s(imu: &[ImuSample], incs: &[Increment], x: &SVector<f64, N>) -> f64 {
    let (c_hat, c) = unpack(x);
    let sum: f64 = incs
        .iter()
        .map(|inc| {
            let secs: f64 = (inc.start..inc.end).map(|i| dt_s(imu, i)).sum();
            (linearise(imu, inc, &c_hat, &c).0 / secs.max(1e-9)).norm_squared()
        })
        .sum();
    (sum / (3 * incs.len().max(1)) as f64).sqrt().to_degrees()
}

/// Fits Ĉ_ω on `imu` (the power-on bias already removed) against `gt` (the ground truth at
/// the IMU's stamps, `valid` where it may be used), on increments of `span` samples.
pub fn fit_gyro_calibration(
    imu: &[ImuSample],
    gt: &[Option<UnitQuaternion<f64>>],
    valid: &[bool],
    span: usize,
    prior_stddev: f64,
) -> Result<GyroCalibrationFit, CalibrationError> {
    let incs = increments(imu, gt, valid, span.max(1));
    if incs.len() < MIN_INCREMENTS {
        return Err(CalibrationError::TooFewIncrements { found: incs.len(), span });
    }
    let prior = identity_unknowns();
    let (x, normal, residual_variance) = solve(imu, &incs, prior_stddev, &[false; 9])?;
    let covariance = normal.try_inverse().ok_or(CalibrationError::Singular)? * residual_variance;
    let sd = |k: usize| covariance[(k, k)].max(0.0).sqrt();
    if let Some(k) = (0..9).find(|&k| (x[k] - prior[k]).abs() > MAX_LASTING_ERROR) {
        return Err(CalibrationError::Implausible { row: k / 3, col: k % 3, departure: x[k] - prior[k] });
    }
    let kept: [bool; 9] =
        std::array::from_fn(|k| sd(k) < MAX_KEPT_STDDEV_OF_PRIOR * prior_stddev && (x[k] - prior[k]).abs() > MIN_SIGNIFICANCE * sd(k));
    tracing::debug!("Ĉ_ω before pinning: {:?}, σ {:?}", &x.as_slice()[..9], (0..9).map(sd).collect::<Vec<_>>());
    let pinned = kept.map(|k| !k);
    // The leftover's σ with the pinned entries held (what it is fitted beside), not free.
    let (x, leftover_covariance) = if pinned.iter().any(|p| *p) {
        let (x, normal, residual_variance) = solve(imu, &incs, prior_stddev, &pinned)?;
        (x, normal.try_inverse().ok_or(CalibrationError::Singular)? * residual_variance)
    } else {
        (x, covariance)
    };
    let leftover_sd = |k: usize| leftover_covariance[(9 + k, 9 + k)].max(0.0).sqrt();
    let (c_hat, c) = unpack(&x);
    let fit = GyroCalibrationFit {
        matrix: std::array::from_fn(|r| std::array::from_fn(|col| c_hat[(r, col)])),
        stddev: std::array::from_fn(|r| std::array::from_fn(|col| sd(3 * r + col))),
        kept: std::array::from_fn(|r| std::array::from_fn(|col| kept[3 * r + col])),
        leftover_bias_rad_s: [c[0], c[1], c[2]],
        leftover_bias_stddev_rad_s: [leftover_sd(0), leftover_sd(1), leftover_sd(2)],
        increments: incs.len(),
        residual_before_deg_s: rms_deg_s(imu, &incs, &prior),
        residual_after_deg_s: rms_deg_s(imu, &incs, &x),
    };
    tracing::debug!("leftover bias {:?} rad/s, σ {:?}", fit.leftover_bias_rad_s, fit.leftover_bias_stddev_rad_s);
    if !fit.determines_matrix() && !fit.determines_leftover_bias() {
        return Err(CalibrationError::NothingDetermined { max_stddev: MAX_KEPT_STDDEV_OF_PRIOR * prior_stddev });
    }
    Ok(fit)
}

/// Gauss–Newton with the prior toward I (`pinned` entries held at I): the unknowns, the
/// last normal matrix, and the residual variance per component.
fn solve(
    imu: &[ImuSample],
    incs: &[Increment],
    prior_stddev: f64,
    pinned: &[bool; 9],
) -> Result<(SVector<f64, N>, SMatrix<f64, N, N>, f64), CalibrationError> {
    let prior = identity_unknowns();
    let mut x = prior;
    let mut normal = SMatrix::<f64, N, N>::zeros();
    let mut residual_variance = 0.0;
    for _ in 0..GAUSS_NEWTON_ITERATIONS {
        let (c_hat, c) = unpack(&x);
        let mut h = SMatrix::<f64, N, N>::zeros();
        let mut g = SVector::<f64, N>::zeros();
        let mut sum_sq = 0.0;
        for inc in incs {
            let (r, jac) = linearise(imu, inc, &c_hat, &c);
            h += jac.transpose() * jac;
            g += jac.transpose() * r;
            sum_sq += r.norm_squared();
        }
        // The prior's weight against this iteration's residual scatter (per component).
        // Floored so a noise-free support keeps the prior on what it cannot see.
        residual_variance = (sum_sq / (3 * incs.len()) as f64).max(MIN_RESIDUAL_VARIANCE);
        let ridge = residual_variance / (prior_stddev * prior_stddev);
        let mut lhs = h;
        let mut rhs = -g;
        for k in 0..9 {
            let w = if pinned[k] { PINNED } else { ridge };
            lhs[(k, k)] += w;
            rhs[k] -= w * (x[k] - prior[k]);
        }
        let step = lhs.lu().solve(&rhs).ok_or(CalibrationError::Singular)?;
        x += step;
        normal = lhs;
    }
    Ok((x, normal, residual_variance))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A body turning about every axis, its true rate, and a gyro reading `(I + E) ω + c`.
    fn tumbling(e: Matrix3<f64>, c: Vector3<f64>, noise: f64, seed: u64) -> (Vec<ImuSample>, Vec<Option<UnitQuaternion<f64>>>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (n, dt) = (12_000usize, 0.005);
        let mut q = UnitQuaternion::identity();
        let mut imu = Vec::with_capacity(n);
        let mut gt = Vec::with_capacity(n);
        for i in 0..n {
            let t = i as f64 * dt;
            let w = Vector3::new((1.3 * t).sin() * 1.5, (0.7 * t + 1.0).cos() * 1.2, (0.45 * t).sin() * 2.0);
            gt.push(Some(q));
            let measured = (Matrix3::identity() + e) * w + c + Vector3::from_fn(|_, _| rng.gen_range(-1.0..1.0) * noise);
            imu.push(ImuSample { stamp_ns: (t * 1e9) as i64, gyro: measured, accel: Vector3::new(0.0, 0.0, 9.81) });
            q *= crate::so3::exp(&(w * dt));
        }
        (imu, gt)
    }

    #[test]
    fn recovers_scale_and_cross_axis_errors_with_a_leftover_constant() {
        let e = Matrix3::new(0.021, 0.012, -0.008, -0.015, -0.027, 0.010, 0.006, -0.011, 0.014);
        let c = Vector3::new(0.004, -0.002, 0.003);
        let (imu, gt) = tumbling(e, c, 0.01, 1);
        let valid = vec![true; imu.len()];
        let fit = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap();
        let truth = (Matrix3::identity() + e).try_inverse().unwrap();
        for r in 0..3 {
            for col in 0..3 {
                let err = fit.matrix[r][col] - truth[(r, col)];
                assert!(err.abs() < 1e-3, "Ĉ[{r}][{col}] = {} against {}", fit.matrix[r][col], truth[(r, col)]);
                assert!(err.abs() < 5.0 * fit.stddev[r][col] + 1e-4, "σ {} does not cover {err}", fit.stddev[r][col]);
            }
        }
        let leftover = truth * c;
        for k in 0..3 {
            assert!((fit.leftover_bias_rad_s[k] + leftover[k]).abs() < 5e-4, "leftover {k}: {:?}", fit.leftover_bias_rad_s);
        }
        assert!(fit.residual_after_deg_s < 0.2 * fit.residual_before_deg_s, "{fit:?}");
    }

    #[test]
    fn an_axis_never_turned_about_stays_at_identity() {
        let (mut imu, mut gt) = tumbling(Matrix3::zeros(), Vector3::zeros(), 0.0, 2);
        // Only about z: the body's x and y rates are removed from the motion.
        let mut q = UnitQuaternion::identity();
        for (i, s) in imu.iter_mut().enumerate() {
            let w = Vector3::new(0.0, 0.0, s.gyro[2]);
            gt[i] = Some(q);
            s.gyro = Vector3::new(0.0, 0.0, 1.02 * w[2]);
            q *= crate::so3::exp(&(w * 0.005));
        }
        let valid = vec![true; imu.len()];
        let fit = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap();
        assert!((fit.matrix[2][2] - 1.0 / 1.02).abs() < 1e-3, "{:?}", fit.matrix);
        for (r, col) in [(0, 0), (1, 1), (0, 1), (1, 0)] {
            assert!((fit.matrix[r][col] - if r == col { 1.0 } else { 0.0 }).abs() < 1e-6, "{:?}", fit.matrix);
        }
    }

    #[test]
    fn a_departure_no_gyro_has_is_refused_and_an_undetermined_one_is_not_kept() {
        let valid = vec![true; 12_000];
        let (imu, gt) = tumbling(Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, 0.25)), Vector3::zeros(), 0.01, 4);
        let err = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap_err();
        assert!(matches!(err, CalibrationError::Implausible { row: 2, col: 2, .. }), "{err}");
        // 0.05 % under 0.3 rad/s of noise on 60 s: not determined, so nothing is kept.
        let (imu, gt) = tumbling(Matrix3::from_diagonal(&Vector3::new(5e-4, 0.0, 0.0)), Vector3::zeros(), 0.3, 5);
        let err = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap_err();
        assert!(matches!(err, CalibrationError::NothingDetermined { .. }), "{err}");
        // One determined axis among undetermined ones: only it departs from I.
        let (imu, gt) = tumbling(Matrix3::from_diagonal(&Vector3::new(0.03, 0.0, 0.0)), Vector3::zeros(), 0.3, 6);
        let fit = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap();
        assert!(fit.kept[0][0] && (fit.matrix[0][0] - 1.0 / 1.03).abs() < 3.0 * fit.stddev[0][0], "{fit:?}");
        for (r, c) in [(1, 1), (2, 2), (0, 1), (1, 0), (2, 0), (1, 2)] {
            assert!(!fit.kept[r][c] && (fit.matrix[r][c] - f64::from(u8::from(r == c))).abs() < 1e-9, "[{r}][{c}]: {fit:?}");
        }
    }

    /// A gyro with no lasting linear error whose bias in motion is off the one removed at rest:
    /// nothing of Ĉ_ω is determined, the offset is, and its σ covers it.
    #[test]
    fn a_bias_offset_in_motion_alone_is_determined_without_a_matrix() {
        let offset = Vector3::new(0.0, 0.002, -0.001);
        let (imu, gt) = tumbling(Matrix3::zeros(), offset, 0.05, 7);
        let valid = vec![true; imu.len()];
        let fit = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap();
        assert!(!fit.determines_matrix() && fit.determines_leftover_bias(), "{fit:?}");
        for k in 0..3 {
            let err = fit.leftover_bias_rad_s[k] + offset[k];
            assert!(err.abs() < 5.0 * fit.leftover_bias_stddev_rad_s[k], "axis {k}: {:?} against {offset:?}", fit.leftover_bias_rad_s);
        }
        // Nothing in motion beyond the noise: neither is determined.
        let (imu, gt) = tumbling(Matrix3::zeros(), Vector3::zeros(), 0.05, 8);
        let err = fit_gyro_calibration(&imu, &gt, &valid, 50, 0.05).unwrap_err();
        assert!(matches!(err, CalibrationError::NothingDetermined { .. }), "{err}");
    }

    #[test]
    fn too_few_increments_is_an_error() {
        let (imu, gt) = tumbling(Matrix3::zeros(), Vector3::zeros(), 0.0, 3);
        let valid = vec![true; 500];
        let err = fit_gyro_calibration(&imu[..500], &gt[..500], &valid, 50, 0.05).unwrap_err();
        assert_eq!(err, CalibrationError::TooFewIncrements { found: 9, span: 50 });
    }
}
