//! The pipeline's settings (the node reads them from its ROS parameters).

use crate::setting::InvalidSetting;

#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PipelineConfig {
    /// Nominal input rate, Hz; 0 = take the corrector's, else measure it from the first samples.
    pub nominal_rate_hz: f64,
    /// An interval longer than this many nominal periods is a gap: the corrector's window is
    /// reset (warm-up again) and the orientation is held and flagged, not integrated across.
    pub gap_periods: f64,
    /// A rate that differs from nominal by more than this fraction (smoothed) is reported.
    pub rate_tolerance: f64,
    /// Standard deviation of the corrected gyro, rad/s, per sample: its covariance, and the
    /// orientation covariance growth (σ·dt per step, a random walk).
    pub angular_velocity_stddev: f64,
    /// Initial attitude from gravity: average the accelerometer over this long, s.
    pub gravity_init_seconds: f64,
    /// Variance of roll and pitch from the gravity initialisation, rad².
    pub initial_tilt_variance: f64,
    /// Variance of the initial yaw, rad² (gravity says nothing about it).
    pub initial_yaw_variance: f64,
    /// Orientation variance added per second of gap, rad² (the attitude is held over a gap).
    pub gap_variance_per_second: f64,
    /// Gyro bias left after the correction, rad/s per axis, constant over a run: the
    /// orientation error it leaves grows as σ_b·t, which is what bounds an open-loop attitude
    /// (the white noise alone, σ·√(t·dt), claimed 0.2° after 100 s where 3° were measured).
    pub bias_stddev: f64,
    /// [`Self::bias_stddev`] when nothing corrects the gyro at its rate (no model, or an input
    /// rate off the model's): a MEMS gyro's own turn-on bias, rad/s (consumer parts: ±3–5 °/s,
    /// EuRoC's ADIS16448 4.4 °/s). At 1 mrad/s a consumer gyro's pass-through attitude claimed
    /// σ 5.8° where it was 14.8° off after 100 s; at 10 mrad/s EuRoC's tilt NEES was 6–24.
    pub uncorrected_bias_stddev: f64,
    /// Feed a model an input whose rate is off the model's in the model's periods
    /// ([`crate::resample`]); false runs it on the samples as they come (its window then spans
    /// another time, and the orientation's covariance allows for an uncorrected bias).
    pub resample_to_model_rate: bool,
    /// Measure the gyro's power-on bias at standstills ([`crate::standstill`]): subtracted
    /// where no model runs and before a model adapted after its support's bias was removed;
    /// measured and reported (not subtracted) before a model trained on this IMU.
    pub power_on_bias: bool,
    /// How a standstill is recognised.
    pub standstill: crate::standstill::StandstillConfig,
    /// Run a model on an IMU it was neither trained nor adapted on (measured worse than the
    /// rest calibration there: docs/poweron.md). Off: the power-on bias instead, said on
    /// /diagnostics.
    pub model_on_new_imu: bool,
    /// The published orientation: `open_loop` (the corrected gyro integrated) or
    /// `gravity_aided` (its tilt corrected by the accelerometer's gravity, [`super::gravity_aided`]).
    pub orientation: super::OrientationMode,
    /// The gravity-aided filter's settings.
    pub gravity_aided: super::GravityAidedConfig,
    /// Up to this many seconds of samples before the first standstill are kept and the
    /// gravity-aided attitude run again over them once that standstill has measured the
    /// power-on bias ([`super::hindsight`]); 0: off.
    pub attitude_hindsight_s: f64,
    /// What carries the IMU: `any`, or `car` (a wheeled vehicle moving along the IMU's x axis),
    /// whose settings [`Platform::preset`] fills in where the parameter file leaves them unset.
    pub platform: Platform,
}

/// What carries the IMU, for the two gravity filters' model of its own accelerations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Platform {
    /// Any platform: its accelerations are a block's noise.
    #[default]
    Any,
    /// A car or another wheeled vehicle: it moves along the IMU's x axis (REP-103: x forward),
    /// so a bend's acceleration is its speed × yaw rate and a braking is its speed's change
    /// (`gravity_aided.forward_speed_stddev`): the published attitude's tilt holds through them.
    Car,
    /// A multirotor: its accelerations average out within seconds, so the bias seen in motion is
    /// removed before its model check (`standstill.motion.apply_before_check`).
    Multirotor,
    /// A legged robot: the same as a multirotor.
    Legged,
    /// A hand-held device: the same as a multirotor.
    Handheld,
}

impl Platform {
    /// The settings a platform implies, as (key path below `pipeline`, YAML value): filled in
    /// where the parameter file does not set them.
    pub fn preset(self) -> &'static [(&'static [&'static str], &'static str)] {
        match self {
            Platform::Any => &[],
            // Measured in docs/node.md ("A car"): a speed of 0 ± 20 m/s, the rest of a block
            // 0.5 m/s² once bends and brakings are predicted. Not the bias seen in motion: there
            // the speed × yaw rate ties the bias about up to the accelerometer's lateral bias
            // (docs/log/2026-12-06-car-platform.md).
            // Its 1-s blocks: a bend's acceleration is predicted sample by sample, not averaged out.
            Platform::Car => &[
                (&["gravity_aided", "forward_speed_stddev"], "20.0"),
                (&["gravity_aided", "accel_stddev"], "0.5"),
                (&["gravity_aided", "block_s"], "1.0"),
            ],
            // Measured in docs/poweron.md ("Before the check"): on these the bias of a power-on
            // that starts moving is removed within seconds; a car's sustained braking and bends
            // would be taken for a bias until the check refuses them, hence not `Any`'s.
            Platform::Multirotor | Platform::Legged | Platform::Handheld => &[(&["standstill", "motion", "apply_before_check"], "true")],
        }
    }
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            nominal_rate_hz: 0.0,
            gap_periods: crate::resample::GAP_PERIODS,
            rate_tolerance: 0.2,
            angular_velocity_stddev: 0.005,
            gravity_init_seconds: 0.5,
            initial_tilt_variance: 1e-4,
            initial_yaw_variance: std::f64::consts::PI * std::f64::consts::PI,
            gap_variance_per_second: 0.25,
            bias_stddev: 1e-3,
            uncorrected_bias_stddev: 3e-2,
            resample_to_model_rate: true,
            power_on_bias: true,
            standstill: crate::standstill::StandstillConfig::default(),
            model_on_new_imu: false,
            orientation: super::OrientationMode::GravityAided,
            gravity_aided: super::GravityAidedConfig::default(),
            attitude_hindsight_s: 60.0,
            platform: Platform::Any,
        }
    }
}

impl PipelineConfig {
    /// Refuses settings the pipeline cannot run with, naming the key: a NaN or a negative
    /// variance would reach every published covariance, and a gap of at most one period would
    /// make every sample a gap.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for (key, value) in [
            ("nominal_rate_hz", self.nominal_rate_hz),
            ("angular_velocity_stddev", self.angular_velocity_stddev),
            ("gravity_init_seconds", self.gravity_init_seconds),
            ("initial_tilt_variance", self.initial_tilt_variance),
            ("initial_yaw_variance", self.initial_yaw_variance),
            ("gap_variance_per_second", self.gap_variance_per_second),
            ("bias_stddev", self.bias_stddev),
            ("uncorrected_bias_stddev", self.uncorrected_bias_stddev),
            ("attitude_hindsight_s", self.attitude_hindsight_s),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("pipeline.{key} must be finite and ≥ 0, not {value}").into());
            }
        }
        self.standstill.validate().map_err(|e| e.within("pipeline"))?;
        self.gravity_aided.validate().map_err(|e| e.within("pipeline"))?;
        if !(self.gap_periods.is_finite() && self.gap_periods > 1.0) {
            return Err(format!("pipeline.gap_periods must be finite and > 1 (nominal periods), not {}", self.gap_periods).into());
        }
        if !(self.rate_tolerance.is_finite() && self.rate_tolerance > 0.0) {
            return Err(format!("pipeline.rate_tolerance must be finite and > 0, not {}", self.rate_tolerance).into());
        }
        Ok(())
    }
}
