//! True kinematics from ground-truth poses, and a Gazebo-like simulation from them (white
//! noise and a bias walk only) — the "sim" side when only a real bag is given.
//!
//! At the ground-truth stamps: ω from central differences of the attitude on SO(3)
//! (Log(R_{k−1}ᵀ R_{k+1}) / (t_{k+1} − t_{k−1})), the world acceleration from second
//! differences of the positions — or, for a measured ground truth, both from a local cubic
//! fit over ±h s of poses ([`ideal_from_poses_with`]); both are then carried to the IMU stamps by cubic Hermite
//! interpolation (a C¹ spline), ω̇ is the derivative of the interpolated ω, and the specific
//! force is f = R_wiᵀ (a + g e_z).

use nalgebra::{Matrix4, UnitQuaternion, Vector3, Vector4};

use super::align::interpolate;
use super::DiagnoseError;
use crate::core::{PoseSample, Recording};
use crate::physics::NoiseModel;
use crate::physics::{apply_terms, ImuSignals, TermContext, NOMINAL_GRAVITY};

/// Ground-truth kinematics at the ground-truth stamps.
struct GtKinematics {
    /// Seconds since the first pose.
    t: Vec<f64>,
    /// Attitude (smoothed when a smoother was used).
    att: Vec<UnitQuaternion<f64>>,
    /// Body-frame angular rate, rad/s.
    omega: Vec<Vector3<f64>>,
    /// World-frame acceleration, m/s².
    acc: Vec<Vector3<f64>>,
}

/// ω by central differences on SO(3), acceleration by second differences of the positions.
fn by_differences(poses: &[PoseSample], t: &[f64]) -> GtKinematics {
    let n = poses.len();
    let mut omega = Vec::with_capacity(n);
    let mut acc = Vec::with_capacity(n);
    for k in 0..n {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        let d = crate::so3::log(&(poses[a].world_from_body.inverse() * poses[b].world_from_body)) / (t[b] - t[a]);
        omega.push(d);
        let (a, m, b) = (k.saturating_sub(1).min(n - 3), k.saturating_sub(1).min(n - 3) + 1, k.saturating_sub(1).min(n - 3) + 2);
        let (h1, h2) = (t[m] - t[a], t[b] - t[m]);
        let acc_k = 2.0
            * ((poses[b].position_in_world - poses[m].position_in_world) / h2
                - (poses[m].position_in_world - poses[a].position_in_world) / h1)
            / (h1 + h2);
        acc.push(acc_k);
    }
    GtKinematics { t: t.to_vec(), att: poses.iter().map(|p| p.world_from_body).collect(), omega, acc }
}

/// Local cubic regression (a Savitzky–Golay smoother on non-uniform stamps) over the poses
/// within ±`half_window_s` of each pose: the attitude in the tangent space at that pose,
/// x_j = Log(R_kᵀ R_j), and the position, each fitted by x(τ) = c₀ + c₁τ + c₂τ² + c₃τ³.
/// R̂_k = R_k Exp(c₀), ω_k = c₁ (to first order in c₀, which is at the noise level), p̂_k,
/// a_k = 2c₂.
///
/// Why: a real recording's ground truth is a measurement (motion capture or an estimator's
/// output), and differentiating it sample to sample multiplies its noise by 1/dt (ω) and
/// 1/dt² (acceleration): 1 mm of position noise at 200 Hz is ~100 m/s² of acceleration noise,
/// 1 mrad of attitude noise ~0.15 rad/s of rate noise, far above the IMU's own noise. That
/// noise then sits in both the simulated signal and the regressors built from it, and biases
/// every scale-like term towards zero (errors in variables). A local cubic over ±h passes the
/// motion up to ≈ 4/(3.2·M − 4.6) · f_s/2 (Schafer 2011, M = h·f_s samples; ≈ 15 Hz for
/// h = 50 ms at 200 Hz) and, at that width, cuts the noise of ω ≈ 8× and that of the
/// acceleration ≈ 180× against central and second differences (white pose noise; a quadratic
/// would cut ω's noise more, but bias it on curved motion: the cubic's first derivative is
/// exact for cubic motion).
/// Near the ends the window is one-sided (the same fit, evaluated off-centre).
fn by_local_cubic(poses: &[PoseSample], t: &[f64], half_window_s: f64) -> GtKinematics {
    let n = poses.len();
    let fallback = by_differences(poses, t);
    let mut out = GtKinematics { t: t.to_vec(), att: Vec::with_capacity(n), omega: Vec::with_capacity(n), acc: Vec::with_capacity(n) };
    let (mut lo, mut hi) = (0usize, 0usize);
    for k in 0..n {
        while t[k] - t[lo] > half_window_s {
            lo += 1;
        }
        while hi + 1 < n && t[hi + 1] - t[k] <= half_window_s {
            hi += 1;
        }
        if hi + 1 - lo < 6 {
            // Too few poses for a cubic with residual degrees of freedom (a tracking gap).
            out.att.push(fallback.att[k]);
            out.omega.push(fallback.omega[k]);
            out.acc.push(fallback.acc[k]);
            continue;
        }
        let rk = poses[k].world_from_body;
        let pk = poses[k].position_in_world;
        let mut vtv = Matrix4::<f64>::zeros();
        let mut vtx = nalgebra::Matrix4x6::<f64>::zeros();
        for j in lo..=hi {
            let tau = (t[j] - t[k]) / half_window_s;
            let row = Vector4::new(1.0, tau, tau * tau, tau * tau * tau);
            let x = crate::so3::log(&(rk.inverse() * poses[j].world_from_body));
            let p = poses[j].position_in_world - pk;
            vtv += row * row.transpose();
            for c in 0..3 {
                for r in 0..4 {
                    vtx[(r, c)] += row[r] * x[c];
                    vtx[(r, 3 + c)] += row[r] * p[c];
                }
            }
        }
        let Some(coef) = vtv.cholesky().map(|ch| ch.solve(&vtx)) else {
            out.att.push(fallback.att[k]);
            out.omega.push(fallback.omega[k]);
            out.acc.push(fallback.acc[k]);
            continue;
        };
        let c0 = Vector3::new(coef[(0, 0)], coef[(0, 1)], coef[(0, 2)]);
        let c1 = Vector3::new(coef[(1, 0)], coef[(1, 1)], coef[(1, 2)]) / half_window_s;
        let smoothed = rk * crate::so3::exp(&c0);
        out.att.push(smoothed);
        // ω in the smoothed body frame (c₀ is tiny; the rotation keeps the frames consistent).
        out.omega.push(crate::so3::exp(&c0).inverse_transform_vector(&c1));
        out.acc.push(Vector3::new(coef[(2, 3)], coef[(2, 4)], coef[(2, 5)]) * (2.0 / (half_window_s * half_window_s)));
    }
    out
}

/// The clean signals at `stamps_ns` from ground-truth poses (body = IMU frame), derivatives
/// by differences (see [`ideal_from_poses_with`]).
pub fn ideal_from_poses(poses: &[PoseSample], stamps_ns: &[i64]) -> Result<ImuSignals, DiagnoseError> {
    ideal_from_poses_with(poses, stamps_ns, None)
}

/// The clean signals at `stamps_ns` from ground-truth poses (body = IMU frame). With
/// `smoothing = Some(h)` the poses are first fitted by a local cubic over ±h s
/// ([`by_local_cubic`]: for a measured ground truth), otherwise differentiated sample to
/// sample (exact enough for a simulator's noise-free poses).
pub fn ideal_from_poses_with(poses: &[PoseSample], stamps_ns: &[i64], smoothing: Option<f64>) -> Result<ImuSignals, DiagnoseError> {
    if poses.len() < 4 {
        return Err(DiagnoseError::Input(format!("ground truth has {} poses; at least 4 are needed to differentiate it", poses.len())));
    }
    let t0 = poses[0].stamp_ns;
    let t: Vec<f64> = poses.iter().map(|p| (p.stamp_ns - t0) as f64 * 1e-9).collect();
    let n = poses.len();
    let kin = match smoothing {
        Some(h) if h > 0.0 => by_local_cubic(poses, &t, h),
        _ => by_differences(poses, &t),
    };
    let GtKinematics { t, att: gt_att, omega, acc } = kin;
    let att_poses: Vec<PoseSample> = poses.iter().zip(&gt_att).map(|(p, q)| PoseSample { world_from_body: *q, ..*p }).collect();
    let poses = &att_poses[..];
    let q: Vec<f64> = stamps_ns.iter().map(|s| (s - t0) as f64 * 1e-9).collect();
    let comp = |v: &[Vector3<f64>], i: usize| -> Vec<f64> { interpolate(&t, &v.iter().map(|x| x[i]).collect::<Vec<_>>(), &q) };
    let w: [Vec<f64>; 3] = std::array::from_fn(|i| comp(&omega, i));
    let a: [Vec<f64>; 3] = std::array::from_fn(|i| comp(&acc, i));
    let att: Vec<UnitQuaternion<f64>> = crate::so3::slerp_at(poses, stamps_ns.iter().copied(), i64::MAX)
        .into_iter()
        .map(|o| {
            o.unwrap_or_else(|| {
                if stamps_ns.first().is_some_and(|s| *s < t0) {
                    poses[0].world_from_body
                } else {
                    poses[n - 1].world_from_body
                }
            })
        })
        .collect();
    let m = stamps_ns.len();
    let gyro: Vec<Vector3<f64>> = (0..m).map(|k| Vector3::new(w[0][k], w[1][k], w[2][k])).collect();
    let alpha = (0..m)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(m - 1));
            if a == b {
                Vector3::zeros()
            } else {
                (gyro[b] - gyro[a]) / (q[b] - q[a])
            }
        })
        .collect();
    let accel = (0..m)
        .map(|k| att[k].inverse_transform_vector(&(Vector3::new(a[0][k], a[1][k], a[2][k]) + Vector3::z() * NOMINAL_GRAVITY)))
        .collect();
    Ok(ImuSignals { stamps_ns: stamps_ns.to_vec(), world_from_imu: att, alpha_in_imu: alpha, temperature_c: vec![25.0; m], gyro, accel })
}

/// A ground-truth interval longer than this many times its median is a dropout (tracking
/// lost), not jitter: a motion-capture system that misses one frame leaves twice its interval.
pub const DROPOUT_INTERVALS: f64 = 1.5;

/// The median interval between poses, s (0 for fewer than two): a dropout does not move it.
pub fn median_interval_s(poses: &[PoseSample]) -> f64 {
    let mut dt: Vec<i64> = poses.windows(2).map(|w| w[1].stamp_ns - w[0].stamp_ns).collect();
    if dt.is_empty() {
        return 0.0;
    }
    let mid = dt.len() / 2;
    *dt.select_nth_unstable(mid).1 as f64 * 1e-9
}

/// The dropouts of a ground truth: (last pose before, first pose after) in ns, for every
/// interval longer than [`DROPOUT_INTERVALS`] times the median interval.
pub fn reference_dropouts(poses: &[PoseSample]) -> Vec<(i64, i64)> {
    let median_ns = median_interval_s(poses) * 1e9;
    poses
        .windows(2)
        .filter(|w| (w[1].stamp_ns - w[0].stamp_ns) as f64 > DROPOUT_INTERVALS * median_ns)
        .map(|w| (w[0].stamp_ns, w[1].stamp_ns))
        .collect()
}

/// How far from a dropout a simulation from these poses is still made up: the smoother's
/// half-width (its window reaches across) plus two pose intervals (the interpolant's
/// derivative at the dropout's edge poses).
pub fn dropout_margin_s(poses: &[PoseSample], smoothing: Option<f64>) -> f64 {
    smoothing.unwrap_or(0.0) + 2.0 * median_interval_s(poses)
}

/// Per stamp: true where a simulation from this ground truth is not a simulation: inside a
/// dropout, or within `margin_s` of one (where the smoother's window, or the interpolant's
/// derivative, reaches across it). Sorted stamps and dropouts; O(n + gaps).
pub fn near_dropouts(stamps_ns: &[i64], dropouts: &[(i64, i64)], margin_s: f64) -> Vec<bool> {
    let margin = (margin_s * 1e9) as i64;
    let mut out = vec![false; stamps_ns.len()];
    let mut g = 0;
    for (i, &t) in stamps_ns.iter().enumerate() {
        while g < dropouts.len() && dropouts[g].1 + margin < t {
            g += 1;
        }
        out[i] = g < dropouts.len() && t > dropouts[g].0 - margin;
    }
    out
}

/// How far a ground truth's clock lags the IMU's, s (> 0: a pose is stamped later than the
/// IMU samples of the same motion), to whole IMU samples within ±`max_s`: the lag that best
/// lines up the gyro's norm with that of the rate differentiated from the poses. A stamp
/// offset of a separate tracking system is common (motion capture on its own clock); a
/// remainder below one sample is `time_offset`'s. 0 for a lag of at most one sample.
pub fn reference_lag_s(real: &Recording, smoothing: Option<f64>, max_s: f64) -> Result<f64, DiagnoseError> {
    let (Some(first), Some(last)) = (real.ground_truth.first(), real.ground_truth.last()) else { return Ok(0.0) };
    let imu: Vec<&crate::core::ImuSample> =
        real.imu.iter().filter(|s| s.stamp_ns >= first.stamp_ns && s.stamp_ns <= last.stamp_ns).collect();
    if imu.len() < 200 || real.imu.len() < 2 {
        return Ok(0.0);
    }
    let stamps: Vec<i64> = imu.iter().map(|s| s.stamp_ns).collect();
    let from_poses = ideal_from_poses_with(&real.ground_truth, &stamps, smoothing)?;
    let t0 = stamps[0];
    let t: Vec<f64> = stamps.iter().map(|s| (s - t0) as f64 * 1e-9).collect();
    let dt = 1.0 / real.nominal_imu_rate_hz();
    let pose_norm: Vec<f64> = from_poses.gyro.iter().map(|w| w.norm()).collect();
    let imu_norm: Vec<f64> = imu.iter().map(|s| s.gyro.norm()).collect();
    // coarse_lag: the IMU ("real") later than the poses ("sim") by `lag` samples.
    let lag = super::align::coarse_lag(&t, &pose_norm, &t, &imu_norm, dt, (max_s / dt).round() as i64);
    // One sample either way is time_offset's (its plausible range) and the norm's
    // correlation peak is that broad on smooth motion: only a clock offset beyond it moves.
    Ok(if lag.abs() >= 2 { -(lag as f64) * dt } else { 0.0 })
}

/// Drop the IMU samples outside the ground truth's span shrunk by `margin_s` at both ends
/// (where a simulation from it would be extrapolated, and where a smoother's window is
/// one-sided); returns how many were dropped at the start and at the end.
pub fn crop_to_ground_truth(real: &mut Recording, margin_s: f64) -> (usize, usize) {
    let (Some(first), Some(last)) = (real.ground_truth.first(), real.ground_truth.last()) else { return (0, 0) };
    let margin = (margin_s * 1e9) as i64;
    let (lo, hi) = (first.stamp_ns + margin, last.stamp_ns - margin);
    let before = real.imu.iter().take_while(|s| s.stamp_ns < lo).count();
    let n = real.imu.len();
    real.imu.retain(|s| s.stamp_ns >= lo && s.stamp_ns <= hi);
    (before, n - before - real.imu.len())
}

/// Simulate the real recording's IMU the way a Gazebo-like simulator would: the clean
/// signals from its ground truth (smoothed over ±`smoothing` s first when given, see
/// [`ideal_from_poses_with`]), plus white noise and a bias walk of `noise`.
pub fn simulate_from_ground_truth(
    real: &Recording,
    noise: &NoiseModel,
    seed: u64,
    smoothing: Option<f64>,
) -> Result<(Recording, (f64, f64)), DiagnoseError> {
    if real.ground_truth.is_empty() {
        return Err(DiagnoseError::Input("the real bag has no ground truth (/ground_truth/pose): cannot simulate it".into()));
    }
    let stamps: Vec<i64> = real.imu.iter().map(|s| s.stamp_ns).collect();
    let mut s = ideal_from_poses_with(&real.ground_truth, &stamps, smoothing)?;
    apply_terms(&noise.terms(), &mut s, &mut TermContext::new(seed))?;
    let variance = noise.per_sample_variance(s.nominal_dt());
    let rec = Recording {
        name: format!("{} simulated from ground truth", real.name),
        imu: s.to_samples(),
        ground_truth: real.ground_truth.clone(),
        temperature: real.temperature.clone(),
    };
    Ok((rec, variance))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Poses of a known motion at 200 Hz: attitude Exp(φ(t)) with φ = (0.3 sin 2πt·0.7,
    /// 0.2 sin 2πt·1.3, 0.5 t), position (sin t, cos 0.5t, 0.1 t²); optional noise.
    fn poses(noise_rad: f64, noise_m: f64, seed: u64) -> (Vec<PoseSample>, Vec<f64>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut g = |s: f64| s * (rng.gen::<f64>() - 0.5) * 12f64.sqrt();
        let n = 2000;
        let t: Vec<f64> = (0..n).map(|k| k as f64 / 200.0).collect();
        let ps = t
            .iter()
            .map(|&t| {
                let phi =
                    Vector3::new(0.3 * (std::f64::consts::TAU * 0.7 * t).sin(), 0.2 * (std::f64::consts::TAU * 1.3 * t).sin(), 0.5 * t);
                let q = crate::so3::exp(&phi) * crate::so3::exp(&Vector3::new(g(noise_rad), g(noise_rad), g(noise_rad)));
                let p = Vector3::new(t.sin() + g(noise_m), (0.5 * t).cos() + g(noise_m), 0.1 * t * t + g(noise_m));
                PoseSample { stamp_ns: (t * 1e9).round() as i64, position_in_world: p, world_from_body: q }
            })
            .collect();
        (ps, t)
    }

    fn rms_err(a: &GtKinematics, b: &GtKinematics, k0: usize, k1: usize) -> (f64, f64) {
        let m = (k1 - k0) as f64;
        let w = (k0..k1).map(|k| (a.omega[k] - b.omega[k]).norm_squared()).sum::<f64>() / m;
        let acc = (k0..k1).map(|k| (a.acc[k] - b.acc[k]).norm_squared()).sum::<f64>() / m;
        (w.sqrt(), acc.sqrt())
    }

    #[test]
    fn local_cubic_keeps_the_motion_and_cuts_the_derivative_noise() {
        let (clean, t) = poses(0.0, 0.0, 0);
        let (noisy, _) = poses(1e-3, 1e-3, 1);
        let truth = by_differences(&clean, &t);
        let (k0, k1) = (50, t.len() - 50);
        // Noise-free motion (≤ 1.3 Hz): the smoother's own error is small.
        let (w, a) = rms_err(&by_local_cubic(&clean, &t, 0.05), &truth, k0, k1);
        assert!(w < 2e-3 && a < 2e-2, "smoothing error on clean poses: ω {w}, a {a}");
        // 1 mrad / 1 mm of noise: differences are swamped, the local cubic is not.
        let (wd, ad) = rms_err(&by_differences(&noisy, &t), &truth, k0, k1);
        let (ws, as_) = rms_err(&by_local_cubic(&noisy, &t, 0.05), &truth, k0, k1);
        assert!(wd > 0.1 && ad > 50.0, "differences: ω {wd}, a {ad}");
        assert!(ws < wd / 5.0 && as_ < ad / 100.0, "local cubic: ω {ws} (differences {wd}), a {as_} (differences {ad})");
    }

    #[test]
    fn dropouts_are_found_and_the_stamps_near_them_left_out() {
        // 120 Hz poses with one missed frame at 1 s and a 0.5 s hole at 2 s.
        let stamp = |t: f64| (t * 1e9).round() as i64;
        let mut ts: Vec<f64> = (0..480).map(|k| k as f64 / 120.0).filter(|t| (*t - 1.0).abs() > 1e-9).collect();
        ts.retain(|t| !(*t > 2.0 + 1e-9 && *t < 2.5 - 1e-9));
        let poses: Vec<PoseSample> = ts
            .iter()
            .map(|&t| PoseSample { stamp_ns: stamp(t), position_in_world: Vector3::zeros(), world_from_body: UnitQuaternion::identity() })
            .collect();
        assert!((median_interval_s(&poses) - 1.0 / 120.0).abs() < 1e-9);
        let d = reference_dropouts(&poses);
        assert_eq!(d.len(), 2, "{d:?}");
        assert_eq!(d[1], (stamp(2.0), stamp(2.5)));
        let imu: Vec<i64> = (0..800).map(|k| stamp(k as f64 / 200.0)).collect();
        let near = near_dropouts(&imu, &d, 0.05);
        let at = |t: f64| near[(t * 200.0).round() as usize];
        assert!(at(2.2) && at(1.96) && at(2.54) && at(1.0), "inside a hole and within the margin");
        assert!(!at(1.9) && !at(2.6) && !at(0.5) && !at(3.5), "away from the holes");
    }
}
