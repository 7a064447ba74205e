//! Ground truth that stood still while the IMU moved: an INS repeating its last pose in a
//! tunnel, or publishing the identity while it aligns. Such poses were trained and scored on as
//! the truth (a car turning tens of degrees against a frozen pose); they are left out as a gap
//! when a recording is read (`bag::read_recording`, `dataset::load_sequence`).

use nalgebra::Vector3;

use crate::core::{ImuSample, Recording};
use crate::standstill::{InMotion, PowerOnBias, StandstillConfig, WindowVerdict};

/// Shortest run of one repeated ground-truth orientation that can be frozen, s.
pub const FROZEN_MIN_S: f64 = 0.5;

/// Leaves out the frozen poses of `rec`'s ground truth. A run of [`FROZEN_MIN_S`] or more of
/// one orientation (to 1e-12 in the quaternion's dot product, far below any real sensor's
/// noise) counts when it ends in a jump the gyro cannot make in that interval, or the gyro
/// turned under it ([`gyro_moves`]): the run's last real pose (its first) is kept unless the
/// run opens the recording or is the identity. A platform at rest under a frozen pose keeps
/// it: it is right. Returns the poses left out.
pub fn drop_frozen_ground_truth(rec: &mut Recording) -> usize {
    let gt = &rec.ground_truth;
    if gt.len() < 3 || rec.imu.len() < 10 {
        return 0;
    }
    let median = |axis: usize| {
        let mut v: Vec<f64> = rec.imu.iter().map(|s| s.gyro[axis]).collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let typical = Vector3::new(median(0), median(1), median(2));
    let mut keep = vec![true; gt.len()];
    let mut i = 0;
    while i < gt.len() {
        let q = gt[i].world_from_body;
        let mut j = i + 1;
        while j < gt.len() && gt[j].world_from_body.coords.dot(&q.coords).abs() > 1.0 - 1e-12 {
            j += 1;
        }
        let long = j - i >= 3 && gt[j - 1].stamp_ns - gt[i].stamp_ns >= (FROZEN_MIN_S * 1e9) as i64;
        // It ends in a jump the gyro cannot account for (the motion it hid), or the gyro
        // moved under it.
        let jumps = j < gt.len() && {
            // The gyro's own rotation between the two poses (vibration included).
            let (t0, t1) = (gt[j - 1].stamp_ns, gt[j].stamp_ns);
            let turned: Vector3<f64> =
                imu_between(&rec.imu, t0, t1).windows(2).map(|w| w[0].gyro * ((w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9)).sum();
            gt[j].world_from_body.angle_to(&q) > 0.02 + turned.norm() + 0.2 * (t1 - t0) as f64 * 1e-9
        };
        if long && (jumps || gyro_moves(&rec.imu, gt[i].stamp_ns, gt[j - 1].stamp_ns, &typical)) {
            let first = if i == 0 || q.angle() < 1e-9 { i } else { i + 1 };
            keep[first..j].iter_mut().for_each(|k| *k = false);
        }
        i = j;
    }
    let before = rec.ground_truth.len();
    let mut k = keep.iter();
    rec.ground_truth.retain(|_| *k.next().unwrap_or(&true));
    before - rec.ground_truth.len()
}

/// The IMU samples stamped from `t0` to `t1`, both included (`imu` in stamp order).
fn imu_between(imu: &[ImuSample], t0: i64, t1: i64) -> &[ImuSample] {
    let a = imu.partition_point(|s| s.stamp_ns < t0);
    let b = imu.partition_point(|s| s.stamp_ns <= t1);
    &imu[a.min(b)..b]
}

/// Whether the gyro between two stamps turned, in either of two ways a bias cannot mimic:
/// its rate less the span's own mean, integrated, reaches 0.035 rad (2°) at some point (a turn
/// there and back), or that mean is 0.02 rad/s (far above a gyro's bias instability) from the
/// recording's median rate and turns 0.035 rad over the span (a steady bend). A standing
/// platform's vibration integrates to nothing, and a bias that moved between a stop and the
/// drive is far under 0.02 rad/s; where a frozen pose is dropped, the span is unscored, not
/// wrong.
fn gyro_moves(imu: &[ImuSample], t0: i64, t1: i64, typical: &Vector3<f64>) -> bool {
    let span = imu_between(imu, t0, t1);
    if span.len() < 10 {
        return false;
    }
    // Up to the last pose's sample, not with it: the motion may start there.
    if stands_still(&span[..span.len() - 1]) {
        // The IMU stood still under the pose (its turn-on bias far from the recording's median
        // rate read as a steady bend): the pose is right. A simulated rest was dropped so, and
        // `adapt` found no standstill in its support.
        return false;
    }
    let mean = span.iter().map(|s| s.gyro).sum::<Vector3<f64>>() / span.len() as f64;
    let steady = (mean - typical).norm();
    if steady > 0.02 && steady * (t1 - t0) as f64 * 1e-9 > 0.035 {
        return true;
    }
    let mut turned = Vector3::zeros();
    let mut furthest: f64 = 0.0;
    for w in span.windows(2) {
        turned += (w[0].gyro - mean) * ((w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9);
        furthest = furthest.max(turned.norm());
    }
    furthest > 0.035
}

/// The span is a standstill by the node's own rule ([`crate::standstill`], its defaults): every
/// window it closes is still, and it closes one. A standing robot's vibration is a rest there
/// (its accelerometer's spread limit follows the scatter inside the blocks); until 2026-12-07
/// this used the fixed 0.2 m/s² alone, and a simulated quadruped's rest with its motors on
/// was read as the IMU moving under a frozen pose and left unscored.
fn stands_still(span: &[ImuSample]) -> bool {
    let mut detector = PowerOnBias::new(StandstillConfig { in_motion: InMotion::Off, ..StandstillConfig::default() });
    let mut still = 0;
    for s in span {
        match detector.push(s) {
            Some(WindowVerdict::Still { .. }) => still += 1,
            Some(WindowVerdict::NotStill(_)) => return false,
            None => {}
        }
    }
    still > 0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::PoseSample;
    use nalgebra::UnitQuaternion;

    /// A car turning at 0.3 rad/s for 60 s at 200 Hz, ground truth at 50 Hz, with `freeze`
    /// applied to the poses.
    fn turning_car(w: f64, freeze: impl Fn(f64, UnitQuaternion<f64>) -> UnitQuaternion<f64>) -> Recording {
        let imu: Vec<ImuSample> = (0..12_000)
            .map(|k| ImuSample { stamp_ns: k * 5_000_000, gyro: Vector3::new(0.001, -0.002, w), accel: Vector3::new(0.0, 0.0, 9.81) })
            .collect();
        let ground_truth = (0..3000)
            .map(|k| {
                let t = k as f64 * 0.02;
                PoseSample {
                    stamp_ns: k * 20_000_000,
                    position_in_world: Vector3::zeros(),
                    world_from_body: freeze(t, UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, w * t))),
                }
            })
            .collect();
        Recording { name: "car".into(), imu, ground_truth, temperature: vec![] }
    }

    #[test]
    fn frozen_ground_truth_is_left_out_while_the_imu_moves() {
        // A tunnel from 20 to 35 s: the INS repeats its last pose; the run's first pose is real.
        let tunnel = |t: f64, q: UnitQuaternion<f64>| {
            if (20.0..35.0).contains(&t) {
                UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.3 * 20.0))
            } else {
                q
            }
        };
        let mut r = turning_car(0.3, tunnel);
        assert_eq!(drop_frozen_ground_truth(&mut r), 749);
        assert!(r.ground_truth.iter().all(|p| !(20.01..35.0).contains(&(p.stamp_ns as f64 * 1e-9))));
        assert!(r.ground_truth.iter().any(|p| p.stamp_ns == 20_000_000_000), "the last real pose is kept");
        // Aligning: the identity for the first 10 s, all of it left out.
        let aligning = |t: f64, q: UnitQuaternion<f64>| if t < 10.0 { UnitQuaternion::identity() } else { q };
        let mut r = turning_car(0.3, aligning);
        assert_eq!(drop_frozen_ground_truth(&mut r), 500);
        assert_eq!(r.ground_truth[0].stamp_ns, 10_000_000_000);
        // At rest, a pose that does not change is right, and kept, vibrating or not; so is a
        // moving one.
        let mut r = turning_car(0.0, |_, q| q);
        assert_eq!(drop_frozen_ground_truth(&mut r), 0);
        r.imu.iter_mut().enumerate().for_each(|(k, s)| s.gyro += Vector3::new(0.04, -0.03, 0.05) * (k as f64 * 2.1).sin());
        assert_eq!(drop_frozen_ground_truth(&mut r), 0);
        let mut r = turning_car(0.3, |_, q| q);
        assert_eq!(drop_frozen_ground_truth(&mut r), 0);
        // A simulated rest for 3 s (the pose repeated exactly) under a gyro that reads only a
        // consumer turn-on bias, far from the recording's median rate, then a turn: kept.
        let mut r = turning_car(0.3, |t, _| UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.3 * (t - 3.0).max(0.0))));
        let bias = Vector3::new(0.05, -0.07, 0.01);
        r.imu
            .iter_mut()
            .for_each(|s| s.gyro = bias + if s.stamp_ns < 3_000_000_000 { Vector3::zeros() } else { Vector3::new(0.0, 0.0, 0.3) });
        assert_eq!(drop_frozen_ground_truth(&mut r), 0);
    }

    /// A quadruped standing with its motors on under a simulated pose (repeated exactly) for
    /// 4 s, its consumer gyro's turn-on bias far from the recording's median rate, its
    /// accelerometer shaken ±2 m/s² at 23 Hz, then a turn: the rest is a rest, the pose kept.
    #[test]
    fn a_vibrating_rest_under_a_repeated_pose_is_kept() {
        let mut r = turning_car(0.3, |t, _| UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.3 * (t - 4.0).max(0.0))));
        let bias = Vector3::new(-0.07, 0.05, -0.06);
        for s in r.imu.iter_mut() {
            let t = s.stamp_ns as f64 * 1e-9;
            let shake = 2.0 * (2.0 * std::f64::consts::PI * 23.0 * t).sin();
            s.gyro = bias + if t < 4.0 { Vector3::zeros() } else { Vector3::new(0.0, 0.0, 0.3) };
            s.accel = Vector3::new(0.6 * shake, -0.4 * shake, 9.81 + shake);
        }
        assert_eq!(drop_frozen_ground_truth(&mut r), 0);
        // The same span rocking under the pose (a frozen INS) is still left out.
        for s in r.imu.iter_mut().filter(|s| s.stamp_ns < 4_000_000_000) {
            s.gyro.x += 0.2 * (std::f64::consts::PI * s.stamp_ns as f64 * 1e-9).sin();
        }
        assert!(drop_frozen_ground_truth(&mut r) > 150);
    }
}
