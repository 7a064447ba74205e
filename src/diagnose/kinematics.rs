//! True kinematics from ground-truth poses, and a Gazebo-like simulation from them (white
//! noise and a bias walk only) — the "sim" side when only a real bag is given.
//!
//! At the ground-truth stamps: ω from central differences of the attitude on SO(3)
//! (Log(R_{k−1}ᵀ R_{k+1}) / (t_{k+1} − t_{k−1})), the world acceleration from second
//! differences of the positions; both are then carried to the IMU stamps by cubic Hermite
//! interpolation (a C¹ spline), ω̇ is the derivative of the interpolated ω, and the specific
//! force is f = R_wiᵀ (a + g e_z).

use nalgebra::{UnitQuaternion, Vector3};

use super::align::interpolate;
use super::DiagnoseError;
use crate::core::{PoseSample, Recording};
use crate::physics::{apply_terms, ImuSignals, TermContext, NOMINAL_GRAVITY};
use crate::sim::NoiseModel;

/// The clean signals at `stamps_ns` from ground-truth poses (body = IMU frame).
pub fn ideal_from_poses(poses: &[PoseSample], stamps_ns: &[i64]) -> Result<ImuSignals, DiagnoseError> {
    if poses.len() < 4 {
        return Err(DiagnoseError::Input(format!("ground truth has {} poses; at least 4 are needed to differentiate it", poses.len())));
    }
    let t0 = poses[0].stamp_ns;
    let t: Vec<f64> = poses.iter().map(|p| (p.stamp_ns - t0) as f64 * 1e-9).collect();
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

/// Simulate the real recording's IMU the way a Gazebo-like simulator would: the clean
/// signals from its ground truth, plus white noise and a bias walk of `noise`.
pub fn simulate_from_ground_truth(real: &Recording, noise: &NoiseModel, seed: u64) -> Result<(Recording, (f64, f64)), DiagnoseError> {
    if real.ground_truth.is_empty() {
        return Err(DiagnoseError::Input("the real bag has no ground truth (/ground_truth/pose): cannot simulate it".into()));
    }
    let stamps: Vec<i64> = real.imu.iter().map(|s| s.stamp_ns).collect();
    let mut s = ideal_from_poses(&real.ground_truth, &stamps)?;
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
