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
    /// RMS angle between `φ_gt` and `R_x (φ_imu − b T)`, degrees (how well a constant rotation
    /// explains the data).
    pub residual_deg: f64,
    /// RMS angle between `φ_gt` and `φ_imu − b₀ T` without the rotation (`b₀` the bias that fits
    /// best without it), degrees.
    pub residual_identity_deg: f64,
    /// The constant gyro bias `b` fitted with `R_x`, rad/s (absent in older reports).
    #[serde(default)]
    pub gyro_bias_rad_s: [f64; 3],
    /// The gyro's axes are a mirror image of the ground truth's (one or three axes' signs
    /// flipped, a left-handed driver frame): an orthogonal map with determinant −1 explains the
    /// increments at most half as far off as the best rotation. No rotation fixes that.
    #[serde(default)]
    pub mirrored: bool,
    /// That map, row-major (ground truth's body from the gyro's axes), when `mirrored`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mirror_map: Option<[[f64; 3]; 3]>,
    /// RMS angle between `φ_gt` and the mirror map's image of the gyro's, degrees, when
    /// `mirrored`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mirror_residual_deg: Option<f64>,
}

impl FrameCheck {
    /// The ground truth is in another frame: the rotation exceeds `tolerance_deg` **and**
    /// explains the mismatch (it at least halves the residual). A gyro with large errors of its
    /// own (a scale error, noise over 0.25 s increments) also makes Wahba's fit return some
    /// rotation, but one that barely lowers the residual: that is the gyro, not the frame.
    pub fn is_other_frame(&self, tolerance_deg: f64) -> bool {
        !self.mirrored && self.angle_deg > tolerance_deg && self.residual_deg < 0.5 * self.residual_identity_deg
    }

    /// The mirror map as the axes it sends each gyro axis to, e.g. `x→x, y→y, z→−z`, where it
    /// is one (within 0.2 of a signed permutation), else the matrix.
    pub fn mirror_axes(&self) -> Option<String> {
        let m = self.mirror_map?;
        let names = ["x", "y", "z"];
        let mut parts = Vec::new();
        for c in 0..3 {
            let (r, v) = (0..3).map(|r| (r, m[r][c])).max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))?;
            if v.abs() < 0.8 {
                return Some(format!("{m:.2?}"));
            }
            parts.push(format!("{}→{}{}", names[c], if v < 0.0 { "−" } else { "" }, names[r]));
        }
        Some(parts.join(", "))
    }

    pub fn rotation(&self) -> UnitQuaternion<f64> {
        let [w, x, y, z] = self.gt_from_imu;
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(w, x, y, z))
    }
}

/// One increment of `window` samples: the ground truth's rotation and the raw gyro's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Increment {
    /// `Log(R_aᵀ R_b)`: the ground truth's rotation over the increment, in its body frame.
    pub gt: Vector3<f64>,
    /// `−Log(R_b R_aᵀ)`: the same rotation if the quaternions were stored inverted (world in
    /// body); then this, not `gt`, is what the gyro measures.
    pub gt_if_inverted: Vector3<f64>,
    /// The gyro's integrated rotation, body frame.
    pub imu: Vector3<f64>,
    /// Duration, s.
    pub seconds: f64,
}

/// Consecutive `window`-sample increments wherever the ground truth covers both ends. `gt[k]`
/// is the ground-truth attitude at `imu[k]` (None where there is none).
pub fn increments(imu: &[ImuSample], gt: &[Option<UnitQuaternion<f64>>], window: usize) -> Vec<Increment> {
    let window = window.max(2);
    let mut out = Vec::new();
    // A window across a hole in the IMU stream is no increment of the gyro's (its rotation over
    // the hole is unknown): skipped, as the ground truth's gaps are.
    let longest_ns = (2.0 * window as f64 * 1e9 / crate::core::nominal_rate_hz(imu).max(1e-9)) as i64;
    let mut k = 0;
    while k + window < imu.len() {
        let spans_hole = imu[k + window].stamp_ns - imu[k].stamp_ns > longest_ns;
        if let (Some(a), Some(b), false) = (gt[k], gt[k + window], spans_hole) {
            let mut d = UnitQuaternion::identity();
            for n in k..k + window {
                let dt = (imu[n + 1].stamp_ns - imu[n].stamp_ns) as f64 * 1e-9;
                d *= exp(&(imu[n].gyro * dt));
            }
            out.push(Increment {
                gt: log(&(a.inverse() * b)),
                gt_if_inverted: -log(&(b * a.inverse())),
                imu: log(&d),
                seconds: (imu[k + window].stamp_ns - imu[k].stamp_ns) as f64 * 1e-9,
            });
        }
        k += window;
    }
    out
}

/// Increment lengths the frame check tries, s, shortest first: a gently driven car (yaw
/// under 0.15 rad/s) turns by less than 0.05 rad in 0.25 s, and had no frame check at all.
pub const FRAME_INCREMENT_SECONDS: [f64; 5] = [0.25, 0.5, 1.0, 2.0, 4.0];

/// Increments of the shortest length in [`FRAME_INCREMENT_SECONDS`] of which at least `enough`
/// turn by `min_angle_rad` (in the gyro and the ground truth); the 0.25-s ones if none has.
/// The fit takes a constant bias, so longer increments cost nothing but fewer of them.
pub fn turning_increments(
    imu: &[ImuSample],
    gt: &[Option<UnitQuaternion<f64>>],
    rate_hz: f64,
    min_angle_rad: f64,
    enough: usize,
) -> Vec<Increment> {
    let mut shortest = None;
    for seconds in FRAME_INCREMENT_SECONDS {
        let inc = increments(imu, gt, ((seconds * rate_hz).round() as usize).max(2));
        if inc.iter().filter(|p| p.gt.norm() >= min_angle_rad && p.imu.norm() >= min_angle_rad).count() >= enough {
            return inc;
        }
        shortest.get_or_insert(inc);
    }
    shortest.unwrap_or_default()
}

/// The frame check on increments of `window` samples ([`increments`]).
pub fn check_frame(imu: &[ImuSample], gt: &[Option<UnitQuaternion<f64>>], window: usize, min_angle_rad: f64) -> Option<FrameCheck> {
    check_frame_on(&increments(imu, gt, window), min_angle_rad)
}

/// The frame check on increments, the rotation fitted on those where both turn by at least
/// `min_angle_rad`, jointly with a constant gyro bias fitted on all of them: an uncalibrated
/// consumer gyro's bias (0.05 rad/s is common) otherwise reads as a tilt of the frame when the
/// motion is mostly about one axis (a car), and the fitted rotation would be wrong.
pub fn check_frame_on(all: &[Increment], min_angle_rad: f64) -> Option<FrameCheck> {
    check_frame_with(all, min_angle_rad, |p| p.gt)
}

/// Whether the ground truth's quaternions are stored inverted (world in body): the increments
/// read that way follow the gyro (after any constant rotation and bias) at most half as far
/// off as the increments read as stored. Unlike another frame, no constant rotation fixes it.
/// `stored`: [`check_frame_on`] of the same increments.
pub fn inverted_quaternions(all: &[Increment], min_angle_rad: f64, stored: &FrameCheck) -> bool {
    // A mirror image of the axes (a flipped gyro axis) can also read better inverted than as
    // stored: inverted only if that reading beats the mirror's too.
    check_frame_with(all, min_angle_rad, |p| p.gt_if_inverted).is_some_and(|inverted| {
        inverted.residual_deg < 0.5 * stored.residual_deg && stored.mirror_residual_deg.is_none_or(|m| inverted.residual_deg < m)
    })
}

fn check_frame_with(all: &[Increment], min_angle_rad: f64, gt_of: impl Fn(&Increment) -> Vector3<f64>) -> Option<FrameCheck> {
    let sum_t2: f64 = all.iter().map(|p| p.seconds * p.seconds).sum();
    if sum_t2 <= 0.0 {
        return None;
    }
    // The bias that fits best for a given orthogonal map M, a rotation or a mirror image
    // (least squares on φ_imu − b T − Mᵀ φ_gt).
    let bias_for = |m: &Matrix3<f64>| -> Vector3<f64> {
        all.iter().map(|p| (p.imu - m.transpose() * gt_of(p)) * p.seconds).sum::<Vector3<f64>>() / sum_t2
    };
    let selected = |b: &Vector3<f64>| -> Vec<(Vector3<f64>, Vector3<f64>)> {
        all.iter()
            .map(|p| (gt_of(p), p.imu - b * p.seconds))
            .filter(|(g, i)| g.norm() >= min_angle_rad && i.norm() >= min_angle_rad)
            .collect()
    };
    // Alternate: R for the bias, the bias for R (each step lowers the same squared error).
    let mut bias = Vector3::zeros();
    let mut fit = None;
    for _ in 0..50 {
        let pairs = selected(&bias);
        let (q, fully_observable) = wahba(&pairs)?;
        let next = bias_for(q.to_rotation_matrix().matrix());
        let moved = (next - bias).norm();
        bias = next;
        fit = Some((q, fully_observable));
        if moved < 1e-9 {
            break;
        }
    }
    let (q, fully_observable) = fit?;
    let pairs = selected(&bias);
    // Every residual is taken over the increments the fit used, each reading with its own
    // bias: the identity's bias could leave none of them above `min_angle_rad` (a car whose
    // ground truth is turned 180° read "0.00° without the rotation" and passed).
    let kept: Vec<&Increment> =
        all.iter().filter(|p| gt_of(p).norm() >= min_angle_rad && (p.imu - bias * p.seconds).norm() >= min_angle_rad).collect();
    let rms = |b: &Vector3<f64>, f: &dyn Fn(&Vector3<f64>) -> Vector3<f64>| {
        let s: f64 = kept.iter().map(|p| gt_of(p).angle(&f(&(p.imu - b * p.seconds))).powi(2)).sum();
        (s / kept.len().max(1) as f64).sqrt().to_degrees()
    };
    let bias_identity = bias_for(&Matrix3::identity());
    let residual_deg = rms(&bias, &|i| q * i);
    // A mirror image: fitted with its own bias (it moves the bias as a rotation would).
    let mirror = wahba_with_mirror(&pairs).and_then(|(_, _, m)| m).and_then(|m0| {
        let mut m = m0;
        let mut b = bias;
        for _ in 0..20 {
            b = bias_for(&m);
            m = wahba_with_mirror(&selected(&b))?.2?;
        }
        let r = rms(&b, &|i| m * i);
        (r < 0.5 * residual_deg).then_some((m, r))
    });
    Some(FrameCheck {
        gt_from_imu: [q.w, q.i, q.j, q.k],
        angle_deg: q.angle().to_degrees(),
        increments: pairs.len(),
        fully_observable,
        residual_deg,
        residual_identity_deg: rms(&bias_identity, &|i| *i),
        gyro_bias_rad_s: [bias.x, bias.y, bias.z],
        mirrored: mirror.is_some(),
        mirror_map: mirror
            .map(|(m, _)| [[m[(0, 0)], m[(0, 1)], m[(0, 2)]], [m[(1, 0)], m[(1, 1)], m[(1, 2)]], [m[(2, 0)], m[(2, 1)], m[(2, 2)]]]),
        mirror_residual_deg: mirror.map(|(_, r)| r),
    })
}

/// Wahba's problem on (ground truth's, gyro's) rotation vectors: the rotation `R` minimising
/// `Σ |φ_gt − R φ_imu|²`, and whether it is fully observable (else the smallest rotation taking
/// the dominant gyro axis onto the ground truth's). `None` with fewer than 3 pairs.
fn wahba(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<(UnitQuaternion<f64>, bool)> {
    wahba_with_mirror(pairs).map(|(q, full, _)| (q, full))
}

/// [`wahba`], and the orthogonal map with determinant −1 (`U Vᵀ`) where that is the
/// unconstrained optimum.
fn wahba_with_mirror(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<(UnitQuaternion<f64>, bool, Option<Matrix3<f64>>)> {
    if pairs.len() < 3 {
        return None;
    }
    let mut b = Matrix3::zeros();
    for (g, i) in pairs {
        b += g * i.transpose();
    }
    let w = crate::so3::wahba(&b)?;
    let s = w.singular_values;
    let fully_observable = s[1] > 0.05 * s[0];
    // The unconstrained optimum is a mirror image where det(U Vᵀ) < 0; on weakly observable
    // motion (a car) too, where only the weak axes can tell it from a half turn.
    let mirror = w.mirrored.then_some(w.orthogonal);
    let rot = if fully_observable {
        Rotation3::from_matrix_unchecked(w.rotation)
    } else {
        let (ug, vi) = w.dominant;
        // Opposite axes (a frame flipped upside down) have no unique smallest rotation: a half
        // turn about an axis across them.
        let base = Rotation3::rotation_between(&vi, &ug).unwrap_or_else(|| {
            let across = vi.cross(&Vector3::x()).try_normalize(1e-6).unwrap_or_else(|| vi.cross(&Vector3::y()).normalize());
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(across), std::f64::consts::PI)
        });
        about_dominant_axis(pairs, base, &ug)
    };
    Some((UnitQuaternion::from_rotation_matrix(&rot), fully_observable, mirror))
}

/// The turn `ψ` about the ground truth's dominant axis `u` that best fits the weak motion about
/// the other axes (a car's pitch and roll), applied after `base`. Any `ψ` maps the dominant
/// axes onto each other, so `base` alone guesses the rest: a frame turned 180° about the
/// car's forward axis came out turned about its lateral axis, and the roll and pitch it applied
/// were mirrored. `Σ φ_gtᵀ Rot(u, ψ) a` (a = base φ_imu) is `A cos ψ + B sin ψ` plus a constant,
/// so `ψ = atan2(B, A)`. Kept only where it lowers the squared error by a quarter and by 1e-4
/// of the motion's own: fitted to noise alone (a car that only yaws) it would turn the frame
/// at random.
fn about_dominant_axis(pairs: &[(Vector3<f64>, Vector3<f64>)], base: Rotation3<f64>, u: &Vector3<f64>) -> Rotation3<f64> {
    let (mut a_sum, mut b_sum, mut cost, mut motion) = (0.0, 0.0, 0.0, 0.0);
    for (g, i) in pairs {
        motion += g.norm_squared();
        let a = base * i;
        a_sum += g.dot(&a) - g.dot(u) * u.dot(&a);
        b_sum += g.dot(&u.cross(&a));
        cost += (g - a).norm_squared();
    }
    // Σ |g − Rot a|² = const − 2 (A cos ψ + B sin ψ): the best ψ lowers it by 2 (√(A² + B²) − A).
    let gain = 2.0 * (a_sum.hypot(b_sum) - a_sum);
    if gain > 0.25 * cost && gain > 1e-4 * motion {
        let turn = Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(*u), b_sum.atan2(a_sum));
        turn * base
    } else {
        base
    }
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

    /// A car: [`motion`]'s yaw with a little roll and pitch (amplitudes in rad/s), as a road
    /// gives, and its attitude.
    fn car(n: usize, roll: f64, pitch: f64) -> (Vec<ImuSample>, Vec<UnitQuaternion<f64>>) {
        let (mut imu, _) = motion(n, 1);
        let mut q = UnitQuaternion::identity();
        let mut att = Vec::new();
        for (k, s) in imu.iter_mut().enumerate() {
            let t = k as f64 * 0.005;
            s.gyro.x = roll * (2.3 * t).sin();
            s.gyro.y = pitch * (1.7 * t).cos();
            att.push(q);
            q *= exp(&(s.gyro * 0.005));
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

    /// A consumer gyro's bias on a car that mostly yaws: no rotation is reported, and a real
    /// one is found to within 0.2° despite the bias (the bias is fitted with it).
    #[test]
    fn a_bias_on_mostly_one_axis_is_not_a_tilt() {
        let (imu, att2) = car(30_000, 0.05, 0.04);
        let bias = Vector3::new(0.04, 0.01, 0.064);
        let biased: Vec<ImuSample> = imu.iter().map(|s| ImuSample { gyro: s.gyro + bias, ..*s }).collect();
        let same: Vec<_> = att2.iter().map(|q| Some(*q)).collect();
        let c = check_frame(&biased, &same, 50, 0.05).unwrap();
        assert!(c.angle_deg < 1.0 && !c.is_other_frame(5.0), "{c:?}");
        let b = Vector3::from(c.gyro_bias_rad_s);
        assert!((b - bias).norm() < 2e-3, "bias {b:?}");
        let rx = UnitQuaternion::from_euler_angles(0.2, -0.3, 0.5);
        let rotated: Vec<_> = att2.iter().map(|q| Some(q * rx.inverse())).collect();
        let c = check_frame(&biased, &rotated, 50, 0.05).unwrap();
        assert!(c.is_other_frame(5.0), "{c:?}");
        assert!(c.rotation().angle_to(&rx).to_degrees() < 0.2 || !c.fully_observable, "{c:?} vs {rx:?}");
    }

    fn reads_inverted(pairs: &[Increment]) -> bool {
        inverted_quaternions(pairs, 0.05, &check_frame_on(pairs, 0.05).unwrap())
    }

    /// Inverted quaternions (world in body) are told from another frame.
    #[test]
    fn inverted_quaternions_are_told_from_another_frame() {
        let (imu, att) = motion(20_000, 3);
        let inverted: Vec<_> = att.iter().map(|q| Some(q.inverse())).collect();
        assert!(reads_inverted(&increments(&imu, &inverted, 40)));
        let rx = UnitQuaternion::from_euler_angles(0.1, -0.4, 1.2);
        let rotated: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
        assert!(!reads_inverted(&increments(&imu, &rotated, 40)));
        let same: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        assert!(!reads_inverted(&increments(&imu, &same, 40)));
    }

    /// A car that mostly yaws, its IMU mounted upside down (a half turn about the forward
    /// axis): the half turn is found from the little pitch and roll, not guessed about another
    /// axis that maps the yaw axis the same way.
    /// A gently driven car (yaw under 0.15 rad/s, a little roll and pitch): no 0.25-s
    /// increment turns by 0.05 rad, so the check takes longer ones and still finds a half turn.
    #[test]
    fn a_gentle_car_is_checked_on_longer_increments() {
        let (mut imu, _) = car(40_000, 0.01, 0.008);
        let mut q = UnitQuaternion::identity();
        let mut att = Vec::new();
        for s in imu.iter_mut() {
            s.gyro.z *= 0.13;
            att.push(q);
            q *= exp(&(s.gyro * 0.005));
        }
        let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let gt: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
        assert!(check_frame(&imu, &gt, 50, 0.05).is_none(), "no 0.25-s increment turns enough");
        let inc = turning_increments(&imu, &gt, 200.0, 0.05, 10);
        assert!(inc[0].seconds > 0.4, "{}", inc[0].seconds);
        let c = check_frame_on(&inc, 0.05).unwrap();
        assert!(c.is_other_frame(5.0) && c.rotation().angle_to(&rx).to_degrees() < 2.0, "{c:?}");
        // The same car in the ground truth's frame: nothing found.
        let same: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        let c = check_frame_on(&turning_increments(&imu, &same, 200.0, 0.05, 10), 0.05).unwrap();
        assert!(!c.is_other_frame(5.0) && !c.mirrored, "{c:?}");
    }

    #[test]
    fn a_half_turn_on_a_car_is_found_about_its_own_axis() {
        let (imu, att) = car(30_000, 0.04, 0.03);
        for axis in [Vector3::x_axis(), Vector3::y_axis()] {
            let rx = UnitQuaternion::from_axis_angle(&axis, std::f64::consts::PI);
            let gt: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
            let c = check_frame(&imu, &gt, 50, 0.05).unwrap();
            assert!(!c.fully_observable && c.is_other_frame(5.0), "{c:?}");
            assert!(c.rotation().angle_to(&rx).to_degrees() < 2.0, "{axis:?}: {c:?}");
            assert!(c.residual_deg < 1.0, "{c:?}");
        }
        // Its z axis flipped instead (or x and y swapped): a mirror image, which only the
        // weak pitch and roll tell from a half turn.
        let gt: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        for (map, axes) in [
            (Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)), "x→x, y→y, z→−z"),
            (Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0), "x→y, y→x, z→z"),
        ] {
            let mirrored: Vec<ImuSample> = imu.iter().map(|s| ImuSample { gyro: map * s.gyro, ..*s }).collect();
            let c = check_frame(&mirrored, &gt, 50, 0.05).unwrap();
            assert!(c.mirrored && !c.is_other_frame(5.0), "{axes}: {c:?}");
            assert_eq!(c.mirror_axes().unwrap(), axes);
        }
        // Yaw alone: nothing to fit the turn on, and none is made up.
        let (imu, att) = motion(20_000, 1);
        let same: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        assert!(check_frame(&imu, &same, 40, 0.05).unwrap().angle_deg < 0.1);
    }

    /// A driver that flips one axis (or all three) gives a mirror image of the motion: named
    /// as such, not as another frame that `--frame apply` would "fix".
    #[test]
    fn mirrored_axes_are_not_another_frame() {
        let (imu, att) = motion(20_000, 3);
        let gt: Vec<_> = att.iter().map(|q| Some(*q)).collect();
        for flip in [Vector3::new(1.0, 1.0, -1.0), Vector3::new(-1.0, -1.0, -1.0)] {
            let flipped: Vec<ImuSample> = imu.iter().map(|s| ImuSample { gyro: s.gyro.component_mul(&flip), ..*s }).collect();
            let c = check_frame(&flipped, &gt, 40, 0.05).unwrap();
            assert!(c.mirrored && !c.is_other_frame(5.0), "{c:?}");
            let want = if flip.z < 0.0 && flip.x > 0.0 { "x→x, y→y, z→−z" } else { "x→−x, y→−y, z→−z" };
            assert_eq!(c.mirror_axes().unwrap(), want);
        }
        // A rotation is not a mirror image.
        let rx = UnitQuaternion::from_euler_angles(0.1, -0.4, 1.2);
        let rotated: Vec<_> = att.iter().map(|q| Some(q * rx.inverse())).collect();
        let c = check_frame(&imu, &rotated, 40, 0.05).unwrap();
        assert!(!c.mirrored && c.is_other_frame(5.0), "{c:?}");
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
