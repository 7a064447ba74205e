//! The samples everything else passes around: IMU readings, ground-truth poses and
//! temperatures, each stamped in integer nanoseconds (ROS time), SI units throughout.

use nalgebra::{UnitQuaternion, Vector3};

/// Standard gravity, m/s².
pub const STANDARD_GRAVITY: f64 = 9.81;

/// One IMU reading in the sensor frame (`imu_link`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Sample time, ns.
    pub stamp_ns: i64,
    /// Angular velocity of the sensor frame, rad/s.
    pub gyro: Vector3<f64>,
    /// Specific force (accelerometer reading), m/s².
    pub accel: Vector3<f64>,
}

impl ImuSample {
    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.gyro.iter().chain(self.accel.iter()).all(|v| v.is_finite())
    }
}

/// One ground-truth pose: the body (IMU) frame in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// Sample time, ns.
    pub stamp_ns: i64,
    /// Position of the body origin in the world frame, m.
    pub position_in_world: Vector3<f64>,
    /// Rotation taking body-frame vectors to the world frame.
    pub world_from_body: UnitQuaternion<f64>,
}

/// One temperature reading of the IMU die, °C.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemperatureSample {
    pub stamp_ns: i64,
    pub celsius: f64,
}

/// A recording: the IMU stream with its ground truth, as read from a bag or dataset.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// Where it came from (bag path or sequence name), for messages.
    pub name: String,
    pub imu: Vec<ImuSample>,
    pub ground_truth: Vec<PoseSample>,
    pub temperature: Vec<TemperatureSample>,
}

impl Recording {
    /// Duration of the IMU stream, s.
    pub fn imu_seconds(&self) -> f64 {
        match (self.imu.first(), self.imu.last()) {
            (Some(a), Some(b)) => (b.stamp_ns - a.stamp_ns) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// Mean IMU rate from the stamps, Hz (0 when fewer than two samples).
    pub fn imu_rate_hz(&self) -> f64 {
        let s = self.imu_seconds();
        if s > 0.0 {
            (self.imu.len() - 1) as f64 / s
        } else {
            0.0
        }
    }
}

/// Nanoseconds to seconds.
pub fn ns_to_s(ns: i64) -> f64 {
    ns as f64 * 1e-9
}
