//! Is the ground truth expressed in the IMU's frame? Attitude increments over short windows
//! from the raw gyro (`φ_imu`, body frame) and from the ground truth (`φ_gt`, the ground
//! truth's body frame) satisfy `φ_gt = R_x φ_imu` when the two bodies differ by a constant
//! rotation `R_x` (`δR_gt = R_x δR_imu R_xᵀ`). `R_x` is Wahba's problem on the increment
//! rotation vectors (SVD of `Σ φ_gt φ_imuᵀ`). When the motion excites only one axis
//! (a car that only yaws) the rotation about that axis is unobservable: the smallest rotation
//! taking the dominant gyro axis onto the ground truth's is reported instead.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::core::ImuSample;
use crate::so3::{exp, log};

/// What the check found.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameCheck {
    /// `R_x` (ground-truth body from IMU body), as a quaternion w, x, y, z.
    pub gt_from_imu: [f64; 4],
    /// Its angle, degrees.
    pub angle_deg: f64,
    /// Increment pairs used.
    pub increments: usize,
    /// Both singular values beyond the first are large enough: the full rotation is
    /// observable (else only the tilt between the dominant motion axes).
    pub fully_observable: bool,
    /// RMS angle between `φ_gt` and `R_x φ_imu`, degrees (how well a constant rotation explains the data).
    pub residual_deg: f64,
    /// RMS angle between `φ_gt` and `φ_imu` without the rotation, degrees.
    pub residual_identity_deg: f64,
}

impl FrameCheck {
    /// The ground truth is in another frame: the rotation exceeds `tolerance_deg` **and**
    /// explains the mismatch (it at least halves the residual). A gyro with large errors of its
    /// own (an uncalibrated bias over 0.25 s increments) also makes Wahba's fit return some
    /// rotation, but one that barely lowers the residual: that is the gyro, not the frame.
    pub fn is_other_frame(&self, tolerance_deg: f64) -> bool {
        self.angle_deg > tolerance_deg && self.residual_deg < 0.5 * self.residual_identity_deg
    }

    pub fn rotation(&self) -> UnitQuaternion<f64> {
        let [w, x, y, z] = self.gt_from_imu;
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
    }
}

/// Rotation vectors of consecutive `window`-sample increments, (ground truth's, raw gyro's),
/// wherever the ground truth covers both ends. `gt[k]` is the ground-truth attitude at `imu[k]`
/// (None where there is none).
pub fn increments(imu: &[ImuSample], gt: &[Option<UnitQuaternion<f64>>], window: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let window = window.max(2);
    let mut pairs = Vec::new();
    let mut k = 0;
    while k + window < imu.len() {
        if let (Some(a), Some(b)) = (gt[k], gt[k + window]) {
            let mut d = UnitQuaternion::identity();
            for n in k..k + window {
                let dt = (imu[n + 1].stamp_ns - imu[n].stamp_ns) as f64 * 1e-9;
                d *= exp(&(imu[n].gyro * dt));
            }
            pairs.push((log(&(a.inverse() * b)), log(&d)));
        }
        k += window;
    }
    pairs
}

/// The frame check on increments of `window` samples ([`increments`]).
pub fn check_frame(imu: &[ImuSample], gt: &[Option<UnitQuaternion<f64>>], window: usize, min_angle_rad: f64) -> Option<FrameCheck> {
    check_frame_on(&increments(imu, gt, window), min_angle_rad)
}

/// The frame check on increment pairs (ground truth's, gyro's), using those where both turn by
/// at least `min_angle_rad`.
pub fn check_frame_on(all: &[(Vector3<f64>, Vector3<f64>)], min_angle_rad: f64) -> Option<FrameCheck> {
    let pairs: Vec<&(Vector3<f64>, Vector3<f64>)> =
        all.iter().filter(|(g, i)| g.norm() >= min_angle_rad && i.norm() >= min_angle_rad).collect();
    if pairs.len() < 3 {
        return None;
    }
    let mut b = Matrix3::zeros();
    for (g, i) in &pairs {
        b += g * i.transpose();
    }
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // nalgebra does not sort singular values: order them.
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&x, &y| svd.singular_values[y].total_cmp(&svd.singular_values[x]));
    let s = svd.singular_values;
    let fully_observable = s[idx[1]] > 0.05 * s[idx[0]];
    let rot = if fully_observable {
        let d = (u.determinant() * v_t.determinant()).signum();
        let m = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
        // Put the sign on the smallest singular direction.
        let mut fix = Matrix3::identity();
        fix[(idx[2], idx[2])] = m[(2, 2)];
        Rotation3::from_matrix_unchecked(u * fix * v_t)
    } else {
        let ug = u.column(idx[0]).into_owned();
        let vi = v_t.row(idx[0]).transpose();
        Rotation3::rotation_between(&vi, &ug).unwrap_or_else(Rotation3::identity)
    };
    let q = UnitQuaternion::from_rotation_matrix(&rot);
    let rms = |f: &dyn Fn(&Vector3<f64>) -> Vector3<f64>| {
        let s: f64 = pairs.iter().map(|(g, i)| g.angle(&f(i)).powi(2)).sum();
        (s / pairs.len() as f64).sqrt().to_degrees()
    };
    Some(FrameCheck {
        gt_from_imu: [q.w, q.i, q.j, q.k],
        angle_deg: q.angle().to_degrees(),
        increments: pairs.len(),
        fully_observable,
        residual_deg: rms(&|i| q * i),
        residual_identity_deg: rms(&|i| *i),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(n: usize, axes: usize) -> (Vec<ImuSample>, Vec<UnitQuaternion<f64>>) {
        let mut q = UnitQuaternion::identity();
        let mut imu = Vec::new();
        let mut att = Vec::new();
        for k in 0..n {
            let t = k as f64 * 0.005;
            let w = Vector3::new(
                if axes > 1 { 0.8 * (1.1 * t).sin() } else { 0.0 },
                if axes > 1 { 0.6 * (0.7 * t).cos() } else { 0.0 },
                0.9 * (0.5 * t).sin() + 0.2,
            );
            imu.push(ImuSample { stamp_ns: k as i64 * 5_000_000, gyro: w, accel: Vector3::new(0.0, 0.0, 9.81) });
            att.push(q);
            q *= exp(&(w * 0.005));
        }
        (imu, att)
    }

    #[test]
    fn finds_a_constant_rotation() {
        let (imu, att) = motion(20_000, 3);
        let rx = UnitQuaternion::from_euler_angles(0.1, -0.4, 1.2);
        // The ground truth tracks a body rotated by R_x from the IMU: R_gt = R_imu R_xᵀ.
        let gt: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
        let c = check_frame(&imu, &gt, 40, 0.05).unwrap();
        assert!(c.fully_observable);
        assert!(c.rotation().angle_to(&rx) < 1e-3, "{:?} vs {:?}", c.rotation(), rx);
        assert!(c.residual_deg < 0.1 && c.residual_identity_deg > 10.0);
        let same: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        assert!(check_frame(&imu, &same, 40, 0.05).unwrap().angle_deg < 0.1);
        assert!(c.is_other_frame(5.0));
    }

    #[test]
    fn a_biased_gyro_is_not_another_frame() {
        // Same frame, but the gyro carries a large constant bias (an uncalibrated consumer IMU):
        // Wahba's fit tilts toward the bias, the residual barely drops.
        let (mut imu, att) = motion(20_000, 3);
        for s in &mut imu {
            s.gyro += Vector3::new(0.15, -0.1, 0.12);
        }
        let gt: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        let c = check_frame(&imu, &gt, 40, 0.05).unwrap();
        assert!(!c.is_other_frame(5.0), "{c:?}");
    }

    #[test]
    fn single_axis_motion_reports_the_tilt() {
        let (imu, att) = motion(20_000, 1);
        let rx = UnitQuaternion::from_euler_angles(0.3, 0.0, 0.0);
        let gt: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
        let c = check_frame(&imu, &gt, 40, 0.05).unwrap();
        assert!(!c.fully_observable);
        assert!((c.angle_deg - 0.3f64.to_degrees()).abs() < 0.5, "{}", c.angle_deg);
    }
}
