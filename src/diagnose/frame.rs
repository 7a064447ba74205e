//! A gross rotation between the sim's frame and the real sensor's, found before the fit: an
//! IMU mounted sideways or upside down, a driver in FRD beside a simulation in FLU. The
//! catalogue's `mount_rotation` is linear in its rotation vector, so it is right to a few
//! degrees only; past that, the fit gives scales below −1 and nonsense terms.
//!
//! Wahba's problem on the paired samples: the rotation R = body_from_imu minimising
//! Σ ‖sim − R real‖² over both sensors (each scaled by its mean square, so the gyro's
//! rotations and the accelerometer's gravity both count), by the SVD of their correlation.
//! A mirror image (det −1: an axis sign or the order of two axes wrong in a driver) is no
//! rotation and no physics; it is refused, naming the axis mapping. A rotation the linear fit
//! finds above [`REFIT_ANGLE_RAD`] is taken out the same way and the fit run again.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::align::Aligned;
use super::{DiagnoseError, Sensors};

/// Rotations below this are left to the catalogue's linear `mount_rotation`, rad (≈ 11°).
pub const GROSS_ANGLE_RAD: f64 = 0.2;

/// A linear `mount_rotation` fitted above this is taken out exactly and the fit run again,
/// rad (≈ 0.6°: its second-order effect, θ²/2 ≈ 5e-5, is below the smallest scale a
/// recording shows).
pub const REFIT_ANGLE_RAD: f64 = 0.01;

/// How much of the no-rotation misfit the rotation (or a mirror image) must remove to be
/// believed: what is left is at most this share.
const MISFIT_KEPT: f64 = 0.5;

/// The rotation is identifiable only when the paired samples span at least two directions:
/// the second singular value against the first.
const MIN_SPREAD: f64 = 0.02;

/// A rotation found between the frames.
#[derive(Debug, Clone, Copy)]
pub struct GrossRotation {
    /// The sim's (body) frame from the real sensor's: sim ≈ R real.
    pub body_from_imu: UnitQuaternion<f64>,
    /// Misfit after the rotation over the misfit without it.
    pub misfit_ratio: f64,
}

impl GrossRotation {
    pub fn angle_deg(&self) -> f64 {
        self.body_from_imu.angle().to_degrees()
    }
}

/// The gross rotation between `a.sim` and `a.real`, if there is one beyond
/// [`GROSS_ANGLE_RAD`]; an error when the real axes are a mirror image of the sim's. Only the
/// judged sensors' channels count.
pub fn gross_rotation(a: &Aligned, sensors: Sensors) -> Result<Option<GrossRotation>, DiagnoseError> {
    let (h, energy) = correlation(a, sensors);
    // H = Σ real simᵀ: Wahba's R takes sim onto real; its transpose maps real onto sim.
    let Some(w) = crate::so3::wahba(&h) else { return Ok(None) };
    let s = w.singular_values;
    // No signal, or samples along one direction only: the rotation about it is free.
    if s[0].is_nan() || s[0] <= 0.0 || s[1] < MIN_SPREAD * s[0] {
        return Ok(None);
    }
    // Misfit of R: energy − 2 tr(R H); the identity's, the best rotation's, the best mirror's.
    let cost = |r: &Matrix3<f64>| misfit(&h, energy, r);
    let free = w.orthogonal.transpose(); // the best orthogonal matrix, either sign
    let mirrored = w.mirrored;
    let rotation = w.rotation.transpose();
    let none = cost(&Matrix3::identity());
    if mirrored && cost(&free) < MISFIT_KEPT * cost(&rotation).min(none) {
        return Err(DiagnoseError::Input(format!(
            "the real sensor's axes are a mirror image of the sim's ({}): an axis sign or the order of two axes is wrong in a driver or a frame convention, not physics the simulation left out; fix the frame and diagnose again",
            describe_mapping(&free)
        )));
    }
    let body_from_imu = UnitQuaternion::from_matrix(&rotation);
    let misfit_ratio = cost(&rotation) / none.max(f64::MIN_POSITIVE);
    if body_from_imu.angle() < GROSS_ANGLE_RAD || misfit_ratio > MISFIT_KEPT {
        return Ok(None);
    }
    Ok(Some(GrossRotation { body_from_imu, misfit_ratio }))
}

/// `body_from_imu` as a [`GrossRotation`] of `a`, with its misfit ratio.
pub fn rotation(a: &Aligned, body_from_imu: UnitQuaternion<f64>, sensors: Sensors) -> GrossRotation {
    let (h, energy) = correlation(a, sensors);
    let cost = |r: &Matrix3<f64>| misfit(&h, energy, r);
    let r = body_from_imu.to_rotation_matrix().into_inner();
    GrossRotation { body_from_imu, misfit_ratio: cost(&r) / cost(&Matrix3::identity()).max(f64::MIN_POSITIVE) }
}

/// H = Σ w real simᵀ over both sensors, each weighted by 1 / its mean square, and the energy
/// Σ w (‖real‖² + ‖sim‖²): the misfit of R is energy − 2 tr(R H).
fn correlation(a: &Aligned, sensors: Sensors) -> (Matrix3<f64>, f64) {
    let n = a.len();
    let mean_square = |ch: &[Vec<f64>]| ch.iter().map(|c| c.iter().map(|v| v * v).sum::<f64>()).sum::<f64>() / n.max(1) as f64;
    // Correlation H = Σ w real simᵀ and the misfit without rotation, per sensor weight w.
    let mut h = Matrix3::zeros();
    let mut energy = 0.0;
    for s in (0..2).filter(|s| sensors.judges(*s)) {
        let (sim, real) = (&a.sim[3 * s..3 * s + 3], &a.real[3 * s..3 * s + 3]);
        let w = 1.0 / mean_square(sim).max(f64::MIN_POSITIVE);
        for i in 0..n {
            let (x, y) = (Vector3::new(real[0][i], real[1][i], real[2][i]), Vector3::new(sim[0][i], sim[1][i], sim[2][i]));
            if x.iter().chain(y.iter()).all(|v| v.is_finite()) {
                h += w * x * y.transpose();
                energy += w * (x.norm_squared() + y.norm_squared());
            }
        }
    }
    (h, energy)
}

/// Σ w ‖sim − R real‖² from the correlation: energy − 2 tr(R H).
fn misfit(h: &Matrix3<f64>, energy: f64, r: &Matrix3<f64>) -> f64 {
    (energy - 2.0 * (r * h).trace()).max(0.0)
}

/// "real x = sim y, real y = −sim x, …" when `m` (sim ≈ m real) is close to a signed
/// permutation, else its rows.
fn describe_mapping(m: &Matrix3<f64>) -> String {
    let axes = ["x", "y", "z"];
    let mut parts = Vec::new();
    for j in 0..3 {
        // real_j = Σ_i m[i][j] sim_i (m orthogonal).
        let (i, v) = (0..3).map(|i| (i, m[(i, j)])).max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())).expect("three rows");
        if (v.abs() - 1.0).abs() > 0.1 {
            return format!("real = M sim with M = {:.2?}", m.transpose());
        }
        parts.push(format!("real {} = {}sim {}", axes[j], if v < 0.0 { "−" } else { "" }, axes[i]));
    }
    parts.join(", ")
}

/// `a` with its sim put in the real sensor's frame: channels Rᵀ v, the attitude and the
/// ground truth's world_from_body · R (positions unchanged), so every other term is fitted in
/// the frame the real sensor measures in.
pub fn into_real_frame(a: &Aligned, g: &GrossRotation) -> Aligned {
    let r = g.body_from_imu;
    let imu_from_body = r.inverse();
    let mut out = a.clone();
    for s in 0..2 {
        for i in 0..a.len() {
            let v = imu_from_body * Vector3::new(a.sim[3 * s][i], a.sim[3 * s + 1][i], a.sim[3 * s + 2][i]);
            for k in 0..3 {
                out.sim[3 * s + k][i] = v[k];
            }
        }
    }
    if let Some(q) = &mut out.world_from_imu {
        q.iter_mut().for_each(|q| *q *= r);
    }
    for s in &mut out.sim_recording.imu {
        s.gyro = imu_from_body * s.gyro;
        s.accel = imu_from_body * s.accel;
    }
    for p in &mut out.sim_recording.ground_truth {
        p.world_from_body *= r;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::Recording;

    /// Paired sim / real channels: a tumbling body with gravity, the real seen through
    /// `real_from_sim`.
    fn aligned(real_from_sim: Matrix3<f64>) -> Aligned {
        let n = 2000;
        let mut sim: [Vec<f64>; 6] = Default::default();
        let mut real: [Vec<f64>; 6] = Default::default();
        for i in 0..n {
            let t = i as f64 * 0.005;
            let w = Vector3::new((0.7 * t).sin(), 0.5 * (1.3 * t).cos(), 0.3 * (0.4 * t).sin() + 0.1);
            let q = UnitQuaternion::from_euler_angles(0.3 * (0.2 * t).sin(), 0.2 * (0.3 * t).cos(), 0.5 * t);
            let f = q.inverse() * Vector3::new(0.0, 0.0, 9.81) + Vector3::new(0.2 * (2.0 * t).sin(), 0.0, 0.0);
            for (k, v) in [w, f].iter().enumerate() {
                let rv = real_from_sim * v;
                for c in 0..3 {
                    sim[3 * k + c].push(v[c]);
                    real[3 * k + c].push(rv[c]);
                }
            }
        }
        Aligned {
            stamps_ns: (0..n as i64).map(|i| i * 5_000_000).collect(),
            sim,
            real,
            sim_variance: (1e-6, 1e-4),
            real_variance: (1e-6, 1e-4),
            world_from_imu: None,
            temperature_c: None,
            notes: vec![],
            artefacts: vec![],
            in_real_gap: vec![],
            in_reference_gap: vec![],
            sim_recording: Recording { name: "t".into(), imu: vec![], ground_truth: vec![], temperature: vec![] },
            samples_per_point: 1,
        }
    }

    #[test]
    fn small_rotations_are_left_to_the_fit() {
        let r = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.05, 0.0));
        assert!(gross_rotation(&aligned(*r.inverse().to_rotation_matrix().matrix()), Sensors::Both).unwrap().is_none());
        assert!(gross_rotation(&aligned(Matrix3::identity()), Sensors::Both).unwrap().is_none());
    }

    #[test]
    fn a_quarter_turn_and_a_half_turn_are_found() {
        for rotvec in [
            Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
            Vector3::new(std::f64::consts::PI, 0.0, 0.0),
            Vector3::new(0.3, -0.4, 0.2),
        ] {
            let body_from_imu = UnitQuaternion::from_scaled_axis(rotvec);
            let g =
                gross_rotation(&aligned(*body_from_imu.inverse().to_rotation_matrix().matrix()), Sensors::Both).unwrap().expect("found");
            assert!(g.body_from_imu.angle_to(&body_from_imu) < 1e-9, "{rotvec:?}: {:?}", g.body_from_imu);
            assert!(g.misfit_ratio < 1e-9);
            // In the real frame the sim is the real.
            let a = aligned(*body_from_imu.inverse().to_rotation_matrix().matrix());
            let b = into_real_frame(&a, &g);
            for c in 0..6 {
                assert!(b.sim[c].iter().zip(&b.real[c]).all(|(s, r)| (s - r).abs() < 1e-9));
            }
        }
    }

    #[test]
    fn a_mirror_image_is_refused_naming_the_axes() {
        // A driver that swapped x and y.
        let swap = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let e = gross_rotation(&aligned(swap), Sensors::Both).unwrap_err().to_string();
        assert!(e.contains("mirror image") && e.contains("real x = sim y, real y = sim x, real z = sim z"), "{e}");
        // One sign flipped.
        let flip = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let e = gross_rotation(&aligned(flip), Sensors::Both).unwrap_err().to_string();
        assert!(e.contains("real z = −sim z"), "{e}");
    }
}
