//! The orientation integrated from the corrected gyro, open loop, with its covariance, and its
//! start from gravity: the mean specific force over an interval at rest.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::PipelineConfig;
use crate::core::{ImuSample, STANDARD_GRAVITY};
use crate::so3::exp;

/// Mean rate over the initial-attitude interval above which the platform is turning, rad/s:
/// above a consumer gyro's bias (EuRoC's uncalibrated ADIS16448: 0.08 rad/s), below a car's
/// bend.
pub const INIT_TURN_RATE: f64 = 0.15;
/// Intervals the initial attitude waits for a turn to end; then it is taken anyway, its tilt
/// variance covering the horizontal acceleration.
pub const TURNING_INTERVALS: u32 = 20;

/// Open-loop attitude from the corrected gyro, with the same convention as evaluation:
/// R(t_{n+1}) = R(t_n)·Exp(ω̂_n (t_{n+1} − t_n)).
#[derive(Debug, Clone)]
pub(super) struct Attitude {
    pub(super) world_from_body: Option<UnitQuaternion<f64>>,
    pub(super) covariance: Matrix3<f64>,
    /// Seconds integrated since the attitude was set (the bias term's t).
    pub(super) since_set_s: f64,
    gravity_sum: Vector3<f64>,
    /// The same sum kept in the current body frame (each sample's gravity turned with the body).
    gravity_sum_turned: Vector3<f64>,
    gravity_sq_sum: f64,
    gravity_count: u32,
    gravity_start_ns: Option<i64>,
    /// The raw gyro summed over the same interval: a turn's centripetal acceleration reads as
    /// a tilt of gravity.
    turn_sum: Vector3<f64>,
    /// Intervals passed over because the platform was turning.
    turning_intervals: u32,
}

impl Attitude {
    pub(super) fn new() -> Self {
        Attitude {
            world_from_body: None,
            covariance: Matrix3::zeros(),
            since_set_s: 0.0,
            gravity_sum: Vector3::zeros(),
            gravity_sum_turned: Vector3::zeros(),
            gravity_sq_sum: 0.0,
            gravity_count: 0,
            gravity_start_ns: None,
            turn_sum: Vector3::zeros(),
            turning_intervals: 0,
        }
    }

    /// Grows the covariance over `dt` s: the gyro's white noise (a random walk) and its
    /// residual bias (an error growing as σ_b·t: variance σ_b²·((t+dt)² − t²)).
    pub(super) fn grow(&mut self, dt: f64, noise_stddev: f64, bias_stddev: f64) {
        let t = self.since_set_s;
        let noise = noise_stddev * dt;
        let bias = bias_stddev * bias_stddev * (2.0 * t * dt + dt * dt);
        self.covariance += Matrix3::identity() * (noise * noise + bias);
        self.since_set_s = t + dt;
    }

    /// Roll and pitch that put the measured specific force on world +z; yaw 0.
    fn from_gravity(f: &Vector3<f64>) -> UnitQuaternion<f64> {
        let roll = f.y.atan2(f.z);
        let pitch = (-f.x).atan2((f.y * f.y + f.z * f.z).sqrt());
        UnitQuaternion::from_euler_angles(roll, pitch, 0.0)
    }

    /// `turned`: the body's rotation vector since the previous sample, from the corrected gyro.
    pub(super) fn accumulate_gravity(&mut self, s: &ImuSample, turned: Option<Vector3<f64>>, cfg: &PipelineConfig) {
        let att = self;
        if att.world_from_body.is_some() {
            return;
        }
        let t0 = *att.gravity_start_ns.get_or_insert(s.stamp_ns);
        // Also kept in the current body frame: the earlier samples' gravity turned with the
        // body, so a platform that rotates while it is averaged is not tilted by the smear (the
        // mean lags the interval's end by half its turn: 8.6° at 0.6 rad/s over 0.5 s).
        if let Some(phi) = turned.filter(|_| att.gravity_count > 0) {
            att.gravity_sum_turned = exp(&phi).inverse() * att.gravity_sum_turned;
        }
        att.gravity_sum += s.accel;
        att.gravity_sum_turned += s.accel;
        att.gravity_sq_sum += s.accel.norm_squared();
        att.gravity_count += 1;
        att.turn_sum += s.gyro;
        if (s.stamp_ns - t0) as f64 * 1e-9 >= cfg.gravity_init_seconds {
            let n = att.gravity_count as f64;
            // Turned with the body where it turned by more than any gyro's bias: below, a
            // bias's turn (EuRoC's raw ADIS16448: 0.08 rad/s) would tilt the sum instead.
            let rotating = (att.turn_sum / n).norm() > INIT_TURN_RATE;
            let f = if rotating { att.gravity_sum_turned } else { att.gravity_sum } / n;
            // A turn (a mean rate above any gyro's bias, and a specific force 2 % off g) puts its
            // centripetal acceleration into the mean specific force: a car starting in a bend
            // came out 21° off, stated as 6°. Wait for the turn to end, for up to
            // TURNING_INTERVALS intervals.
            let pulled = (f.norm() - STANDARD_GRAVITY).abs() > 0.02 * STANDARD_GRAVITY;
            let turning = pulled && rotating && att.turning_intervals < TURNING_INTERVALS;
            if (f.norm() - STANDARD_GRAVITY).abs() < 0.1 * STANDARD_GRAVITY && !turning {
                // Moving, the mean specific force is not gravity: its tilt is off by about the
                // motion's share of it (the samples' spread, and the mean's distance from g;
                // above g, a horizontal acceleration a of |f|² = g² + a² tilts it by acos(g/|f|)).
                let spread = (att.gravity_sq_sum / n - f.norm_squared()).max(0.0) / (STANDARD_GRAVITY * STANDARD_GRAVITY);
                let off = ((f.norm() - STANDARD_GRAVITY) / STANDARD_GRAVITY).powi(2);
                let horizontal = if att.turning_intervals > 0 { (STANDARD_GRAVITY / f.norm()).min(1.0).acos().powi(2) } else { 0.0 };
                let tilt = cfg.initial_tilt_variance + spread + off.max(horizontal);
                att.world_from_body = Some(Attitude::from_gravity(&f));
                att.covariance = Matrix3::from_diagonal(&Vector3::new(tilt, tilt, cfg.initial_yaw_variance));
                att.since_set_s = 0.0;
            } else {
                // Not at rest (or not in gravity, or turning): try again over the next interval.
                att.turning_intervals += u32::from(turning);
                att.gravity_sum = Vector3::zeros();
                att.gravity_sum_turned = Vector3::zeros();
                att.gravity_sq_sum = 0.0;
                att.gravity_count = 0;
                att.gravity_start_ns = None;
                att.turn_sum = Vector3::zeros();
            }
        }
    }
}
