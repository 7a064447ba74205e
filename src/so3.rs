//! SO(3): exponential and logarithm maps, open-loop gyro integration, slerp of
//! ground truth at IMU stamps, and ZYX Euler angles.
//!
//! Conventions: rotations are Hamilton unit quaternions; `world_from_body` maps body
//! vectors to the world. Integration is right-multiplicative with the gyro sample at the
//! start of each interval and the real interval from the stamps:
//! R(t_{n+1}) = R(t_n) · Exp(ω_n (t_{n+1} − t_n)).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

use crate::core::{ImuSample, PoseSample};

/// Below this angle (rad) the series expansions are used; the closed forms lose precision.
const SMALL_ANGLE: f64 = 1e-8;

/// Exp: rotation vector (axis × angle, rad) → unit quaternion. Exact at 0.
pub fn exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta = phi.norm();
    let half = 0.5 * theta;
    // sin(θ/2)/θ, with its Taylor series near 0.
    let k = if theta < SMALL_ANGLE { 0.5 - theta * theta / 48.0 } else { half.sin() / theta };
    UnitQuaternion::new_unchecked(Quaternion::new(half.cos(), k * phi.x, k * phi.y, k * phi.z))
}

/// Log: unit quaternion → rotation vector with angle in [0, π].
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    // q and −q are the same rotation; take w ≥ 0 so the angle is ≤ π.
    let (w, v) = if q.w < 0.0 { (-q.w, -q.imag()) } else { (q.w, q.imag()) };
    let s = v.norm();
    if s < SMALL_ANGLE {
        // θ ≈ 2s, and θ/s ≈ 2/w to second order.
        return v * (2.0 / w);
    }
    let theta = 2.0 * s.atan2(w);
    v * (theta / s)
}

/// Skew-symmetric matrix: `hat(a) * b == a × b`.
pub fn hat(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// Angle of the rotation, degrees.
pub fn angle_deg(q: &UnitQuaternion<f64>) -> f64 {
    log(q).norm().to_degrees()
}

/// ZYX (yaw, pitch, roll) Euler angles of `world_from_body`, radians, returned as
/// (roll, pitch, yaw): R = Rz(yaw) Ry(pitch) Rx(roll).
pub fn euler_zyx(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let r = q.to_rotation_matrix();
    let m = r.matrix();
    let pitch = (-m[(2, 0)]).clamp(-1.0, 1.0).asin();
    let roll = m[(2, 1)].atan2(m[(2, 2)]);
    let yaw = m[(1, 0)].atan2(m[(0, 0)]);
    Vector3::new(roll, pitch, yaw)
}

/// Wrap an angle to [−π, π).
pub fn wrap_pi(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let w = (a + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    // rem_euclid can return exactly 2π for tiny negative inputs.
    if w >= std::f64::consts::PI {
        w - two_pi
    } else {
        w
    }
}

/// Open-loop integration of a gyro stream from `initial` (`world_from_body` at
/// `imu[0].stamp_ns`). Returns one attitude per IMU sample. `gyro` gives the (corrected)
/// angular velocity of each sample, so raw and denoised streams share the code.
pub fn integrate_gyro<F>(imu: &[ImuSample], initial: UnitQuaternion<f64>, mut gyro: F) -> Vec<UnitQuaternion<f64>>
where
    F: FnMut(usize) -> Vector3<f64>,
{
    let mut out = Vec::with_capacity(imu.len());
    let mut r = initial;
    for n in 0..imu.len() {
        out.push(r);
        if n + 1 < imu.len() {
            let dt = (imu[n + 1].stamp_ns - imu[n].stamp_ns) as f64 * 1e-9;
            r = renormalize(r * exp(&(gyro(n) * dt)));
        }
    }
    out
}

/// Keep a long product of quaternions on the unit sphere.
pub fn renormalize(q: UnitQuaternion<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::new_normalize(q.into_inner())
}

/// Ground truth interpolated at query stamps: slerp between the two bracketing poses when
/// they are at most `max_gap_ns` apart, `None` otherwise (a tracking gap is never bridged).
/// `poses` must be sorted by stamp; `stamps` must be sorted too (one linear pass).
pub fn slerp_at(poses: &[PoseSample], stamps: impl IntoIterator<Item = i64>, max_gap_ns: i64) -> Vec<Option<UnitQuaternion<f64>>> {
    let mut out = Vec::new();
    let mut j = 0usize;
    for t in stamps {
        while j + 1 < poses.len() && poses[j + 1].stamp_ns <= t {
            j += 1;
        }
        let v = if poses.is_empty() || t < poses[0].stamp_ns {
            None
        } else if poses[j].stamp_ns == t {
            Some(poses[j].world_from_body)
        } else if j + 1 < poses.len() {
            let (a, b) = (&poses[j], &poses[j + 1]);
            let gap = b.stamp_ns - a.stamp_ns;
            if gap > max_gap_ns || gap <= 0 {
                None
            } else {
                let s = (t - a.stamp_ns) as f64 / gap as f64;
                Some(slerp(&a.world_from_body, &b.world_from_body, s))
            }
        } else {
            None
        };
        out.push(v);
    }
    out
}

/// Shortest-path spherical interpolation, s ∈ [0, 1].
pub fn slerp(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, s: f64) -> UnitQuaternion<f64> {
    let delta = a.inverse() * b;
    a * exp(&(log(&delta) * s))
}

/// Wahba's problem for a correlation `B = Σ a bᵀ`: the rotation `R` minimising `Σ ‖a − R b‖²`
/// (`U diag(1, 1, d) Vᵀ` of `B = U S Vᵀ`, the sign `d` on the smallest singular direction), the
/// orthogonal map of either sign that does (`U Vᵀ`: a mirror image where `d` < 0), the
/// singular values largest first, and the dominant singular pair (`a`-side, `b`-side).
#[derive(Debug, Clone, Copy)]
pub struct Wahba {
    pub rotation: Matrix3<f64>,
    pub orthogonal: Matrix3<f64>,
    pub mirrored: bool,
    pub singular_values: [f64; 3],
    pub dominant: (Vector3<f64>, Vector3<f64>),
}

/// [`Wahba`] of `b`; `None` where the SVD fails.
pub fn wahba(b: &Matrix3<f64>) -> Option<Wahba> {
    let svd = b.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // nalgebra does not sort singular values: order them.
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&x, &y| svd.singular_values[y].total_cmp(&svd.singular_values[x]));
    let d = (u.determinant() * v_t.determinant()).signum();
    let mut fix = Matrix3::identity();
    fix[(idx[2], idx[2])] = d;
    Some(Wahba {
        rotation: u * fix * v_t,
        orthogonal: u * v_t,
        mirrored: d < 0.0,
        singular_values: idx.map(|k| svd.singular_values[k]),
        dominant: (u.column(idx[0]).into_owned(), v_t.row(idx[0]).transpose()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn vec3(max: f64) -> impl Strategy<Value = Vector3<f64>> {
        (-max..max, -max..max, -max..max).prop_map(|(x, y, z)| Vector3::new(x, y, z))
    }

    proptest! {
        #[test]
        fn log_inverts_exp(phi in vec3(1.8)) {
            prop_assume!(phi.norm() < std::f64::consts::PI - 1e-6);
            let back = log(&exp(&phi));
            prop_assert!((back - phi).norm() < 1e-10, "{phi:?} -> {back:?}");
        }

        #[test]
        fn exp_inverts_log(phi in vec3(3.0)) {
            let q = exp(&phi);
            let q2 = exp(&log(&q));
            prop_assert!(q.angle_to(&q2) < 1e-10);
        }

        #[test]
        fn exp_matches_nalgebra(phi in vec3(3.0)) {
            let q = exp(&phi);
            let r = UnitQuaternion::from_scaled_axis(phi);
            prop_assert!(q.angle_to(&r) < 1e-10);
        }

        #[test]
        fn tiny_angles_are_exact(phi in vec3(1e-9)) {
            let q = exp(&phi);
            prop_assert!((q.norm() - 1.0).abs() < 1e-15);
            prop_assert!((log(&q) - phi).norm() <= 1e-15 + 1e-9 * phi.norm());
        }

        #[test]
        fn euler_zyx_reconstructs(roll in -3.1..3.1f64, pitch in -1.5..1.5f64, yaw in -3.1..3.1f64) {
            let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
            let e = euler_zyx(&q);
            prop_assert!((e - Vector3::new(roll, pitch, yaw)).norm() < 1e-9);
        }

        #[test]
        fn constant_rate_integrates_exactly(w in vec3(3.0), rate in 50.0..1000.0f64, n in 2usize..400) {
            let dt_ns = (1e9 / rate).round() as i64;
            let imu: Vec<ImuSample> = (0..n).map(|k| ImuSample { stamp_ns: 1_000 + k as i64 * dt_ns, gyro: w, accel: Vector3::zeros() }).collect();
            let q0 = exp(&Vector3::new(0.3, -0.2, 1.0));
            let path = integrate_gyro(&imu, q0, |k| imu[k].gyro);
            let total = (n - 1) as f64 * dt_ns as f64 * 1e-9;
            let expected = q0 * exp(&(w * total));
            prop_assert!(path.last().unwrap().angle_to(&expected) < 1e-8);
        }

        #[test]
        fn slerp_endpoints_and_midpoint(a in vec3(2.0), b in vec3(0.5)) {
            let qa = exp(&a);
            let qb = qa * exp(&b);
            prop_assert!(slerp(&qa, &qb, 0.0).angle_to(&qa) < 1e-10);
            prop_assert!(slerp(&qa, &qb, 1.0).angle_to(&qb) < 1e-10);
            let mid = slerp(&qa, &qb, 0.5);
            prop_assert!((mid.angle_to(&qa) - mid.angle_to(&qb)).abs() < 1e-9);
        }
    }

    #[test]
    fn wrap_pi_range() {
        for a in [-10.0, -std::f64::consts::PI, 0.0, std::f64::consts::PI, 7.0, -1e-17] {
            let w = wrap_pi(a);
            assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&w), "{a} -> {w}");
            assert!(((a - w) / std::f64::consts::TAU - ((a - w) / std::f64::consts::TAU).round()).abs() < 1e-12);
        }
    }

    #[test]
    fn slerp_never_bridges_a_gap() {
        let pose = |t: i64, yaw: f64| PoseSample {
            stamp_ns: t,
            position_in_world: Vector3::zeros(),
            world_from_body: exp(&Vector3::new(0.0, 0.0, yaw)),
        };
        let gt = vec![pose(0, 0.0), pose(10, 0.1), pose(1000, 0.2)];
        let out = slerp_at(&gt, [-5, 0, 5, 10, 500, 1000, 1001], 100);
        assert!(out[0].is_none());
        assert!(out[1].is_some());
        assert!((log(&out[2].unwrap()).z - 0.05).abs() < 1e-12);
        assert!(out[3].is_some());
        assert!(out[4].is_none(), "gap of 990 ns > 100 ns must not be bridged");
        assert!(out[5].is_some());
        assert!(out[6].is_none());
    }

    /// A known rotation comes back from noiseless pairs; a mirrored set is said to be one.
    #[test]
    fn wahba_finds_the_rotation_and_a_mirror() {
        let r = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1).to_rotation_matrix().into_inner();
        let bs = [Vector3::new(1.0, 0.2, -0.3), Vector3::new(-0.4, 1.0, 0.5), Vector3::new(0.1, -0.6, 1.0), Vector3::new(0.7, 0.7, 0.1)];
        let corr = |m: &Matrix3<f64>| bs.iter().fold(Matrix3::zeros(), |acc, b| acc + (m * b) * b.transpose());
        let w = wahba(&corr(&r)).unwrap();
        assert!((w.rotation - r).amax() < 1e-12 && !w.mirrored);
        assert!(w.singular_values[0] >= w.singular_values[1] && w.singular_values[1] >= w.singular_values[2]);
        let flip = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let m = wahba(&corr(&(r * flip))).unwrap();
        assert!(m.mirrored && (m.orthogonal - r * flip).amax() < 1e-12 && (m.rotation.determinant() - 1.0).abs() < 1e-12);
    }
}
