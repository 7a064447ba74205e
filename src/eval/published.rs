//! Scoring the attitude a node published (its orientation and covariance) against ground
//! truth: tilt and heading errors and their consistency (NEES).

use nalgebra::{Matrix2, UnitQuaternion, Vector2, Vector3};

use crate::core::{PoseSample, PublishedAttitude};
use crate::so3::{log, slerp_at, wrap_pi};

use super::{EvalError, EvalOptions};

/// χ² with two degrees of freedom at 95 %: a tilt error consistent with its stated 2×2
/// covariance has a NEES below this 95 % of the time.
pub const CHI2_2DOF_95: f64 = 5.991;

/// How far the attitude a node published (`/imu/denoised`) is from the ground truth, and
/// whether its stated covariance says so. Degrees unless named otherwise.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct PublishedAttitudeErrors {
    /// Seconds from the topic's first message to its first attitude (the start-up wait).
    pub first_attitude_s: f64,
    /// Attitudes compared with ground truth, and those left out in ground-truth gaps.
    pub evaluated: usize,
    pub in_gaps: usize,
    /// Seconds from the first scored attitude to the last.
    pub seconds: f64,
    /// Tilt: the swing of E = R̂ R_gtᵀ off world z, at the first scored attitude, RMS, largest, last.
    pub tilt_initial_deg: f64,
    pub tilt_rmse_deg: f64,
    pub tilt_max_deg: f64,
    pub tilt_final_deg: f64,
    /// Heading against the ground truth's, aligned at the first scored attitude: gravity gives
    /// no yaw, so the node starts it at 0 and what it owes is the drift from there.
    pub heading_rmse_deg: f64,
    pub heading_final_deg: f64,
    /// AOE: RMS of the whole error rotation's angle (tilt and heading together), heading
    /// aligned at the first scored attitude, as the attitude is compared with another filter's.
    pub aoe_deg: f64,
    /// Median of the stated tilt σ (the root of the mean of its x and y variances).
    pub tilt_sigma_median_deg: f64,
    /// Mean NEES of the tilt error against its stated 2×2 covariance: 2 when the covariance is
    /// consistent, below when it is wider than the error, above when it is overconfident.
    pub tilt_nees_mean: f64,
    /// Share of scored attitudes with the tilt NEES within [`CHI2_2DOF_95`] (0.95 when consistent).
    pub tilt_within_95: f64,
    /// Attitudes whose stated tilt covariance is not positive definite: no NEES for them.
    pub tilt_covariance_invalid: usize,
}

/// Compare published attitudes (in stamp order) with the ground truth slerped at their stamps
/// (never across a gap longer than [`EvalOptions::max_gap_ns`]). The covariance is taken
/// about world axes (REP 145), as the error of a left perturbation: R̂ = Exp(δ) R_gt.
pub fn evaluate_published(
    name: &str,
    ground_truth: &[PoseSample],
    published: &[PublishedAttitude],
    first_message_ns: i64,
    opts: &EvalOptions,
) -> Result<PublishedAttitudeErrors, EvalError> {
    let (Some(g0), Some(g1)) = (ground_truth.first(), ground_truth.last()) else {
        return Err(EvalError::NoGroundTruth(name.into()));
    };
    let gt = slerp_at(ground_truth, published.iter().map(|a| a.stamp_ns), opts.max_gap_ns);
    let covered = gt.iter().filter(|g| g.is_some()).count();
    let (Some(k0), true) = (gt.iter().position(Option::is_some), covered >= 2) else {
        let span = |a: Option<&PublishedAttitude>| a.map_or(0.0, |a| a.stamp_ns as f64 * 1e-9);
        return Err(EvalError::PublishedNotCovered {
            name: name.into(),
            covered,
            count: published.len(),
            start: span(published.first()),
            end: span(published.last()),
            gt_start: g0.stamp_ns as f64 * 1e-9,
            gt_end: g1.stamp_ns as f64 * 1e-9,
        });
    };
    let (_, first_heading) = swing_twist(&(published[k0].world_from_body * gt[k0].expect("k0 is covered").inverse()));
    let align = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -first_heading);
    let a = align.to_rotation_matrix().into_inner();
    let mut out =
        PublishedAttitudeErrors { first_attitude_s: (published[0].stamp_ns - first_message_ns) as f64 * 1e-9, ..Default::default() };
    let (mut sq_tilt, mut sq_heading, mut sq_angle, mut nees_sum, mut nees_n, mut within) = (0.0, 0.0, 0.0, 0.0, 0usize, 0usize);
    let mut sigmas = Vec::with_capacity(published.len() - k0);
    let mut last = k0;
    let mut gaps_since_last = 0;
    for (n, (p, g)) in published.iter().zip(&gt).enumerate().skip(k0) {
        let Some(g) = g else {
            gaps_since_last += 1;
            continue;
        };
        // Attitudes after the ground truth's end are not in one of its gaps.
        out.in_gaps += std::mem::take(&mut gaps_since_last);
        let error = align * p.world_from_body * g.inverse();
        let (swing, heading) = swing_twist(&error);
        let tilt = swing.norm();
        sq_angle += error.angle().powi(2);
        if out.evaluated == 0 {
            out.tilt_initial_deg = tilt.to_degrees();
        }
        out.evaluated += 1;
        sq_tilt += tilt * tilt;
        sq_heading += heading * heading;
        out.tilt_max_deg = out.tilt_max_deg.max(tilt.to_degrees());
        (out.tilt_final_deg, out.heading_final_deg) = (tilt.to_degrees(), heading.abs().to_degrees());
        last = n;
        // The covariance in the aligned world frame; its horizontal block is the tilt's.
        let cov = a * p.covariance * a.transpose();
        let horizontal: Matrix2<f64> = cov.fixed_view::<2, 2>(0, 0).into_owned();
        match horizontal.cholesky() {
            Some(c) => {
                let t = Vector2::new(swing.x, swing.y);
                let nees = t.dot(&c.solve(&t));
                nees_sum += nees;
                nees_n += 1;
                within += usize::from(nees <= CHI2_2DOF_95);
                sigmas.push((0.5 * (horizontal[(0, 0)] + horizontal[(1, 1)])).sqrt().to_degrees());
            }
            None => out.tilt_covariance_invalid += 1,
        }
    }
    let n = out.evaluated as f64;
    out.tilt_rmse_deg = (sq_tilt / n).sqrt().to_degrees();
    out.heading_rmse_deg = (sq_heading / n).sqrt().to_degrees();
    out.aoe_deg = (sq_angle / n).sqrt().to_degrees();
    out.seconds = (published[last].stamp_ns - published[k0].stamp_ns) as f64 * 1e-9;
    if nees_n > 0 {
        out.tilt_nees_mean = nees_sum / nees_n as f64;
        out.tilt_within_95 = within as f64 / nees_n as f64;
        sigmas.sort_by(f64::total_cmp);
        out.tilt_sigma_median_deg = sigmas[sigmas.len() / 2];
    }
    Ok(out)
}

/// Swing–twist split of a world-frame error rotation about world z: (tilt, heading) in rad.
pub fn tilt_heading(e: &UnitQuaternion<f64>) -> (f64, f64) {
    let (swing, heading) = swing_twist(e);
    (swing.norm(), heading.abs())
}

/// e = Exp(swing) · twist about world z: the swing's rotation vector (horizontal) and the
/// twist's signed angle, rad.
fn swing_twist(e: &UnitQuaternion<f64>) -> (Vector3<f64>, f64) {
    // Twist about z: the quaternion's (w, z) part; swing = e · twist⁻¹.
    let heading = wrap_pi(2.0 * e.k.atan2(e.w));
    let twist = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading);
    (log(&(e * twist.inverse())), heading)
}
