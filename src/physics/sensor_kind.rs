//! The two sensors of an IMU as types, for the terms both have (`*_bias`, `*_scale`,
//! `*_misalignment`): each such term is written once, generic over the sensor it acts on, and
//! keeps the vocabulary's two names (`GyroScale` = [`super::Scale`]`<Gyro>`, `gyro_scale`).

use nalgebra::Vector3;

use super::{ImuSignals, Sensor};

/// A sensor a term written once for both can act on: [`Gyro`] or [`Accel`].
pub trait SensorKind: Clone + Copy + std::fmt::Debug + Default + PartialEq + Send + Sync + 'static {
    const SENSOR: Sensor;
    /// The vocabulary's names of its terms.
    const BIAS: &'static str;
    const SCALE: &'static str;
    const MISALIGNMENT: &'static str;

    /// Its channel of the signals.
    fn channel(s: &mut ImuSignals) -> &mut Vec<Vector3<f64>> {
        match Self::SENSOR {
            Sensor::Gyro => &mut s.gyro,
            Sensor::Accel => &mut s.accel,
        }
    }
}

/// The gyro (rad/s).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Gyro;

/// The accelerometer (m/s²).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Accel;

impl SensorKind for Gyro {
    const SENSOR: Sensor = Sensor::Gyro;
    const BIAS: &'static str = "gyro_bias";
    const SCALE: &'static str = "gyro_scale";
    const MISALIGNMENT: &'static str = "gyro_misalignment";
}

impl SensorKind for Accel {
    const SENSOR: Sensor = Sensor::Accel;
    const BIAS: &'static str = "accel_bias";
    const SCALE: &'static str = "accel_scale";
    const MISALIGNMENT: &'static str = "accel_misalignment";
}
