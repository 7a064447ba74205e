//! IMU grades: datasheet figures of the sensors the project meets, in SI units.
//!
//! Sources, per grade, in the comments. Where a datasheet gives only a bias instability
//! (the flat floor of the Allan deviation), the bias random-walk density is set so that the
//! walk's Allan deviation reaches that floor at τ = 100 s: σ_RRW = B·√(3/100 s) (a random
//! walk of density K has Allan deviation K·√(τ/3)). That is a modelling choice, not a
//! datasheet figure.

use serde::{Deserialize, Serialize};

use crate::physics::{AccelBias, GyroBias, NoiseModel, Quantization, Saturation, Term};

const DEG: f64 = std::f64::consts::PI / 180.0;
/// One degree per hour in rad/s.
const DEG_PER_HOUR: f64 = DEG / 3600.0;
/// Standard gravity for datasheet conversions (datasheets use g = 9.80665 m/s²).
const G0: f64 = 9.80665;
const MICRO_G: f64 = 1e-6 * G0;
/// τ at which the bias random walk reaches the bias-instability floor, s.
const INSTABILITY_TAU_S: f64 = 100.0;

/// An IMU model the simulator knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
pub enum Grade {
    /// Advanced Navigation CERTUS-EVO (FOG-class MEMS; the paper's high-precision IMU).
    #[serde(rename = "certus-evo")]
    #[value(name = "certus-evo")]
    CertusEvo,
    /// Xsens MTi-600 series (industrial MEMS).
    #[serde(rename = "mti-600")]
    #[value(name = "mti-600")]
    Mti600,
    /// TDK InvenSense MPU-9250 (consumer MEMS).
    #[serde(rename = "mpu-9250")]
    #[value(name = "mpu-9250")]
    Mpu9250,
    /// Analog Devices ADIS16448 (the EuRoC MAV's IMU).
    #[serde(rename = "adis16448")]
    #[value(name = "adis16448")]
    Adis16448,
    /// Bosch BMI160 (the TUM-VI headset's IMU).
    #[serde(rename = "bmi160")]
    #[value(name = "bmi160")]
    Bmi160,
}

/// Datasheet figures of one grade. Densities are continuous-time; ranges and LSBs are
/// `None` where the source gives none.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradeSpec {
    pub name: &'static str,
    /// Gyro white-noise density, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// Accelerometer white-noise density, m/s²/√Hz.
    pub accel_noise_density: f64,
    /// Gyro bias random-walk density, rad/s²/√Hz.
    pub gyro_bias_random_walk: f64,
    /// Accelerometer bias random-walk density, m/s³/√Hz.
    pub accel_bias_random_walk: f64,
    /// Gyro bias instability, rad/s (`None` when the source gives none).
    pub gyro_bias_instability: Option<f64>,
    /// Accelerometer bias instability, m/s².
    pub accel_bias_instability: Option<f64>,
    /// Turn-on bias: each axis drawn uniformly in ±this, rad/s.
    pub gyro_turn_on_bias: f64,
    /// Turn-on bias: each axis drawn uniformly in ±this, m/s².
    pub accel_turn_on_bias: f64,
    /// Gyro full-scale range, rad/s.
    pub gyro_range: Option<f64>,
    /// Accelerometer full-scale range, m/s².
    pub accel_range: Option<f64>,
    /// Gyro resolution (one LSB), rad/s.
    pub gyro_lsb: Option<f64>,
    /// Accelerometer resolution (one LSB), m/s².
    pub accel_lsb: Option<f64>,
    /// Where the figures come from.
    pub source: &'static str,
}

/// Bias random-walk density that reaches `instability` at τ = [`INSTABILITY_TAU_S`].
fn walk_from_instability(instability: f64) -> f64 {
    instability * (3.0 / INSTABILITY_TAU_S).sqrt()
}

impl Grade {
    pub const ALL: [Grade; 5] = [Grade::CertusEvo, Grade::Mti600, Grade::Mpu9250, Grade::Adis16448, Grade::Bmi160];

    /// The name used in configs and on the command line.
    pub fn name(self) -> &'static str {
        self.spec().name
    }

    pub fn spec(self) -> GradeSpec {
        match self {
            // Paper (fsda_imu_denoising.tex, sec. experiments): gyro bias instability 0.2 °/h,
            // noise density 6 °/h/√Hz; accelerometer bias instability 8 µg, noise density
            // 2 µg/√Hz. Turn-on bias: a calibrated navigation unit, taken as the instability
            // ×10 (assumption). Range and resolution: not given in the paper; left open.
            Grade::CertusEvo => GradeSpec {
                name: "certus-evo",
                gyro_noise_density: 6.0 * DEG_PER_HOUR,
                accel_noise_density: 2.0 * MICRO_G,
                gyro_bias_random_walk: walk_from_instability(0.2 * DEG_PER_HOUR),
                accel_bias_random_walk: walk_from_instability(8.0 * MICRO_G),
                gyro_bias_instability: Some(0.2 * DEG_PER_HOUR),
                accel_bias_instability: Some(8.0 * MICRO_G),
                gyro_turn_on_bias: 2.0 * DEG_PER_HOUR,
                accel_turn_on_bias: 80.0 * MICRO_G,
                gyro_range: None,
                accel_range: None,
                gyro_lsb: None,
                accel_lsb: None,
                source: "paper (fsda_imu_denoising.tex): 0.2 deg/h, 6 deg/h/rtHz; 8 ug, 2 ug/rtHz",
            },
            // Paper: gyro bias instability 8 °/h, noise density 0.007 °/s/√Hz; accelerometer
            // bias instability 15 µg, noise density 60 µg/√Hz. Range: Xsens MTi 600-series
            // datasheet, standard full range ±2000 °/s and ±10 g. Turn-on bias: 0.2 °/s and
            // 5 mg (assumption for a factory-calibrated unit). Output is floating point: no LSB.
            Grade::Mti600 => GradeSpec {
                name: "mti-600",
                gyro_noise_density: 0.007 * DEG,
                accel_noise_density: 60.0 * MICRO_G,
                gyro_bias_random_walk: walk_from_instability(8.0 * DEG_PER_HOUR),
                accel_bias_random_walk: walk_from_instability(15.0 * MICRO_G),
                gyro_bias_instability: Some(8.0 * DEG_PER_HOUR),
                accel_bias_instability: Some(15.0 * MICRO_G),
                gyro_turn_on_bias: 0.2 * DEG,
                accel_turn_on_bias: 5e-3 * G0,
                gyro_range: Some(2000.0 * DEG),
                accel_range: Some(10.0 * G0),
                gyro_lsb: None,
                accel_lsb: None,
                source: "paper: 8 deg/h, 0.007 deg/s/rtHz; 15 ug, 60 ug/rtHz; ranges from the Xsens MTi-600 datasheet",
            },
            // Paper: gyro noise density 0.01 °/s/√Hz, accelerometer 300 µg/√Hz (no bias
            // instability given). TDK PS-MPU-9250A-01 datasheet: initial zero-rate output
            // tolerance ±5 °/s, zero-g offset ±60 mg (x, y; ±80 mg z, taken as ±60 mg),
            // full scale configured here as ±2000 °/s (16.4 LSB/(°/s)) and ±16 g (2048 LSB/g).
            // Bias walk: not in the datasheet; typical consumer-MEMS figures (instability
            // ~20 °/h, ~100 µg) are assumed.
            Grade::Mpu9250 => GradeSpec {
                name: "mpu-9250",
                gyro_noise_density: 0.01 * DEG,
                accel_noise_density: 300.0 * MICRO_G,
                gyro_bias_random_walk: walk_from_instability(20.0 * DEG_PER_HOUR),
                accel_bias_random_walk: walk_from_instability(100.0 * MICRO_G),
                gyro_bias_instability: None,
                accel_bias_instability: None,
                gyro_turn_on_bias: 5.0 * DEG,
                accel_turn_on_bias: 60e-3 * G0,
                gyro_range: Some(2000.0 * DEG),
                accel_range: Some(16.0 * G0),
                gyro_lsb: Some(DEG / 16.4),
                accel_lsb: Some(G0 / 2048.0),
                source: "paper: 0.01 deg/s/rtHz, 300 ug/rtHz; TDK PS-MPU-9250A-01 (ZRO +-5 deg/s, +-60 mg, FS 2000 deg/s, 16 g)",
            },
            // EuRoC MAV dataset, sensor.yaml of the ADIS16448 (Kalibr noise model):
            // gyroscope_noise_density 1.6968e-4, gyroscope_random_walk 1.9393e-5,
            // accelerometer_noise_density 2.0e-3, accelerometer_random_walk 3.0e-3.
            // ADI ADIS16448 datasheet: ±1000 °/s at 0.04 °/s/LSB, ±18 g at 0.833 mg/LSB,
            // in-run bias stability 14.5 °/h and 0.25 mg; the EuRoC unit is uncalibrated, so a
            // turn-on bias of ±0.5 °/s and ±50 mg is assumed.
            Grade::Adis16448 => GradeSpec {
                name: "adis16448",
                gyro_noise_density: 1.6968e-4,
                accel_noise_density: 2.0e-3,
                gyro_bias_random_walk: 1.9393e-5,
                accel_bias_random_walk: 3.0e-3,
                gyro_bias_instability: Some(14.5 * DEG_PER_HOUR),
                accel_bias_instability: Some(0.25e-3 * G0),
                gyro_turn_on_bias: 0.5 * DEG,
                accel_turn_on_bias: 50e-3 * G0,
                gyro_range: Some(1000.0 * DEG),
                accel_range: Some(18.0 * G0),
                gyro_lsb: Some(0.04 * DEG),
                accel_lsb: Some(0.833e-3 * G0),
                source: "EuRoC sensor.yaml (Kalibr densities); ADI ADIS16448 datasheet (ranges, LSBs, in-run stability)",
            },
            // TUM-VI dataset, calibrated BMI160 (Kalibr noise model of the dataset's IMU
            // calibration): gyroscope_noise_density 1.6e-4, gyroscope_random_walk 2.2e-5,
            // accelerometer_noise_density 2.8e-3, accelerometer_random_walk 8.6e-4.
            // Bosch BMI160 datasheet: zero-rate offset ±3 °/s, zero-g offset ±40 mg; full
            // scale configured here as ±2000 °/s (16.4 LSB/(°/s)) and ±16 g (2048 LSB/g).
            // TUM-VI's IMU is calibrated: turn-on bias assumed 10× smaller than the datasheet's.
            Grade::Bmi160 => GradeSpec {
                name: "bmi160",
                gyro_noise_density: 1.6e-4,
                accel_noise_density: 2.8e-3,
                gyro_bias_random_walk: 2.2e-5,
                accel_bias_random_walk: 8.6e-4,
                gyro_bias_instability: None,
                accel_bias_instability: None,
                gyro_turn_on_bias: 0.3 * DEG,
                accel_turn_on_bias: 4e-3 * G0,
                gyro_range: Some(2000.0 * DEG),
                accel_range: Some(16.0 * G0),
                gyro_lsb: Some(DEG / 16.4),
                accel_lsb: Some(G0 / 2048.0),
                source: "TUM-VI IMU calibration (Kalibr densities); Bosch BMI160 datasheet (offsets, FS 2000 deg/s, 16 g)",
            },
        }
    }
}

impl std::fmt::Display for Grade {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Grade {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Grade::ALL
            .into_iter()
            .find(|g| g.name() == s)
            .ok_or_else(|| format!("unknown IMU grade `{s}`, expected one of: {}", Grade::ALL.map(|g| g.name()).join(", ")))
    }
}

impl GradeSpec {
    /// The simulator's noise model of this grade.
    pub fn noise(&self) -> NoiseModel {
        NoiseModel {
            gyro_noise_density: self.gyro_noise_density,
            accel_noise_density: self.accel_noise_density,
            gyro_bias_random_walk: self.gyro_bias_random_walk,
            accel_bias_random_walk: self.accel_bias_random_walk,
        }
    }

    /// The deterministic datasheet errors beyond noise: saturation at the range and
    /// quantisation at the LSB, where the datasheet gives them. (The turn-on bias is random;
    /// the simulator draws it, see [`GradeSpec::turn_on_bias`].)
    pub fn range_and_resolution(&self) -> Vec<Term> {
        let mut out = Vec::new();
        if self.gyro_lsb.is_some() || self.accel_lsb.is_some() {
            out.push(Term::Quantization(Quantization { gyro_lsb: self.gyro_lsb.unwrap_or(0.0), accel_lsb: self.accel_lsb.unwrap_or(0.0) }));
        }
        if self.gyro_range.is_some() || self.accel_range.is_some() {
            out.push(Term::Saturation(Saturation {
                gyro_range: self.gyro_range.unwrap_or(f64::INFINITY),
                accel_range: self.accel_range.unwrap_or(f64::INFINITY),
            }));
        }
        out
    }

    /// A turn-on bias drawn uniformly within the datasheet's ± range on every axis.
    pub fn turn_on_bias(&self, rng: &mut impl rand::Rng) -> [Term; 2] {
        let mut draw = |range: f64| -> [f64; 3] { std::array::from_fn(|_| rng.gen_range(-1.0..=1.0) * range) };
        let gyro = draw(self.gyro_turn_on_bias);
        let accel = draw(self.accel_turn_on_bias);
        [Term::GyroBias(GyroBias::new(gyro)), Term::AccelBias(AccelBias::new(accel))]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_figures_in_si() {
        let c = Grade::CertusEvo.spec();
        assert!((c.gyro_noise_density - 2.9089e-5).abs() < 1e-8, "6 deg/h/rtHz");
        assert!((c.accel_noise_density - 1.9613e-5).abs() < 1e-8, "2 ug/rtHz");
        let m = Grade::Mti600.spec();
        assert!((m.gyro_noise_density - 1.2217e-4).abs() < 1e-8, "0.007 deg/s/rtHz");
        assert!((m.gyro_bias_instability.unwrap() - 3.8785e-5).abs() < 1e-9, "8 deg/h");
        let p = Grade::Mpu9250.spec();
        assert!((p.gyro_noise_density - 1.7453e-4).abs() < 1e-8, "0.01 deg/s/rtHz");
        assert!((p.accel_noise_density - 2.942e-3).abs() < 1e-6, "300 ug/rtHz");
        // High grade is quieter than low grade on every figure.
        assert!(c.gyro_noise_density < m.gyro_noise_density && m.gyro_noise_density < p.gyro_noise_density);
    }

    #[test]
    fn names_round_trip_and_unknown_is_clear() {
        for g in Grade::ALL {
            assert_eq!(g.name().parse::<Grade>().unwrap(), g);
            assert_eq!(serde_yaml::from_str::<Grade>(g.name()).unwrap(), g);
            let s = g.spec();
            assert!(s.gyro_noise_density > 0.0 && s.accel_bias_random_walk > 0.0 && !s.source.is_empty());
        }
        let e = "mpu6050".parse::<Grade>().unwrap_err();
        assert!(e.contains("mpu-9250") && e.contains("bmi160"), "{e}");
    }

    #[test]
    fn walk_reaches_the_instability_floor_at_100_s() {
        let k = walk_from_instability(1e-5);
        assert!((k * (100.0f64 / 3.0).sqrt() - 1e-5).abs() < 1e-18);
    }
}
