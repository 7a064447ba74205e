//! `NoiseModel`: an IMU's white noise and bias random walk as one model, the two noise terms
//! ([`WhiteNoise`], [`BiasRandomWalk`]) it stands for and the per-sample variances it states.

use serde::{Deserialize, Serialize};

use super::{BiasRandomWalk, Term, WhiteNoise};

/// An IMU's noise model: white noise and bias random walk, continuous-time densities (a grade's
/// datasheet figures, the simulator's `simulator_noise`, a real IMU's `--noise-model`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseModel {
    /// Gyro white-noise density, rad/s/√Hz.
    pub gyro_noise_density: f64,
    /// Accelerometer white-noise density, m/s²/√Hz.
    pub accel_noise_density: f64,
    /// Gyro bias random-walk density, rad/s²/√Hz.
    pub gyro_bias_random_walk: f64,
    /// Accelerometer bias random-walk density, m/s³/√Hz.
    pub accel_bias_random_walk: f64,
}

impl NoiseModel {
    /// The model as the two noise terms, in that order.
    pub fn terms(&self) -> [Term; 2] {
        [
            Term::WhiteNoise(WhiteNoise { gyro_noise_density: self.gyro_noise_density, accel_noise_density: self.accel_noise_density }),
            Term::BiasRandomWalk(BiasRandomWalk {
                gyro_bias_random_walk: self.gyro_bias_random_walk,
                accel_bias_random_walk: self.accel_bias_random_walk,
            }),
        ]
    }

    /// Per-sample white-noise variances (gyro (rad/s)², accel (m/s²)²) at interval `dt` s:
    /// what the IMU messages carry on their covariance diagonals.
    pub fn per_sample_variance(&self, dt: f64) -> (f64, f64) {
        let white = WhiteNoise { gyro_noise_density: self.gyro_noise_density, accel_noise_density: self.accel_noise_density };
        let (g, a) = white.per_sample_std(dt);
        (g * g, a * a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_per_sample_variance_is_the_density_squared_over_the_interval() {
        let m =
            NoiseModel { gyro_noise_density: 2e-3, accel_noise_density: 3e-2, gyro_bias_random_walk: 1e-5, accel_bias_random_walk: 1e-4 };
        let (g, a) = m.per_sample_variance(0.005);
        assert!((g - 4e-6 / 0.005).abs() < 1e-15 && (a - 9e-4 / 0.005).abs() < 1e-12, "{g} {a}");
        let names: Vec<&str> = m.terms().iter().map(|t| t.name()).collect();
        assert_eq!(names, ["white_noise", "bias_random_walk"]);
    }
}
