//! How a standstill is recognised and how far its bias is trusted: the settings, their
//! defaults and their checks; where the bias seen in motion is used.

use crate::motion_bias::MotionBiasConfig;
use crate::setting::InvalidSetting;

use super::BiasPrediction;

/// Where the bias observed in motion ([`crate::motion_bias`]) is used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InMotion {
    /// Never: only standstills measure the bias.
    Off,
    /// Until the first standstill (a recording that starts moving); a standstill's estimate
    /// then rules.
    UntilStandstill,
    /// Always: standstills seed the filter, motion refines it between them.
    Always,
}

/// Most blocks a window is judged on.
pub const MAX_BLOCKS: usize = 16;

/// How a standstill is recognised and how far its bias is trusted.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StandstillConfig {
    /// Window judged at once, s.
    pub window_s: f64,
    /// Blocks per window whose means are compared (at most [`MAX_BLOCKS`]).
    pub blocks: usize,
    /// Still while the block means of every gyro axis span less than this, rad/s …
    pub max_gyro_spread: f64,
    /// … those of every accelerometer axis less than this, m/s² …
    pub max_accel_spread: f64,
    /// … or, where more, this many σ of an accelerometer block mean, σ from the scatter inside
    /// the blocks: a standing robot's or an idling car's vibration (0: the fixed limit alone) …
    pub vibration_sigmas: f64,
    /// … and ‖mean specific force‖ is within this of standard gravity, m/s².
    pub max_gravity_error: f64,
    /// A window whose mean rate exceeds this on any axis is turning, not biased, rad/s.
    pub max_bias: f64,
    /// Gravity may turn in the body by at most this since the standstill began, rad.
    pub max_tilt_change: f64,
    /// A later standstill may differ from the estimate by at most this (plus 5 σ), rad/s.
    pub max_bias_change: f64,
    /// How fast the bias wanders between standstills, rad/s/√s: the estimate's variance grows by
    /// its square per second.
    pub bias_random_walk: f64,
    /// An interval longer than this (or a stamp not after the last) breaks a window, s.
    pub max_sample_gap_s: f64,
    /// A hole in the input at least this long, or a clock that went back, may be the IMU
    /// power-cycled under the node: the next standstill that contradicts the estimate is then
    /// taken as a new power-on's, not refused (0: never), s.
    pub new_power_on_gap_s: f64,
    /// Where the bias seen in motion through gravity is used.
    pub in_motion: InMotion,
    /// That filter's noise model.
    pub motion: MotionBiasConfig,
    /// The least spread assumed between power-ons' biases when earlier ones predict this one
    /// ([`crate::bias_memory`]), rad/s: two that agree closer by chance are not taken as closer.
    pub min_power_on_spread: f64,
    /// What earlier power-ons of this IMU predict for this one's bias (not a parameter: set
    /// from the bias memory file, `power_on_bias_memory`); used before the first standstill.
    #[serde(skip)]
    pub remembered: Option<BiasPrediction>,
}

impl Default for StandstillConfig {
    fn default() -> Self {
        // The spreads are `eval`'s static-bias rule (0.1-s block means of a vibrating robot at
        // rest scatter by ~0.005 rad/s; walking or driving moves them by far more than 0.02).
        // max_bias: a consumer gyro's turn-on bias reaches ~5 °/s (0.09 rad/s).
        // max_gravity_error: a consumer accelerometer's turn-on bias reaches 60 mg (0.6 m/s²):
        // a simulated MPU-9250 at rest read |f| = 9.26 m/s² and, at 0.5, never stood still.
        StandstillConfig {
            window_s: 0.5,
            blocks: 5,
            max_gyro_spread: 0.02,
            max_accel_spread: 0.2,
            vibration_sigmas: 4.5,
            max_gravity_error: 1.0,
            max_bias: 0.15,
            max_tilt_change: 0.02,
            max_bias_change: 0.01,
            bias_random_walk: 1e-5,
            max_sample_gap_s: 0.1,
            // A USB IMU re-enumerated and its driver restarted: seconds; a DDS hiccup: less.
            new_power_on_gap_s: 2.0,
            in_motion: InMotion::UntilStandstill,
            motion: MotionBiasConfig::default(),
            // Of the order of an industrial MEMS part's turn-on repeatability (EuRoC's
            // ADIS16448: 1.5–2.6 mrad/s across its recordings).
            min_power_on_spread: 0.002,
            remembered: None,
        }
    }
}

impl StandstillConfig {
    /// Refuses settings the detector cannot run with, naming the key.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        for (key, value) in [
            ("window_s", self.window_s),
            ("max_gyro_spread", self.max_gyro_spread),
            ("max_accel_spread", self.max_accel_spread),
            ("max_gravity_error", self.max_gravity_error),
            ("max_bias", self.max_bias),
            ("max_tilt_change", self.max_tilt_change),
            ("max_bias_change", self.max_bias_change),
            ("max_sample_gap_s", self.max_sample_gap_s),
            ("min_power_on_spread", self.min_power_on_spread),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(format!("standstill.{key} must be finite and > 0, not {value}").into());
            }
        }
        for (key, value) in [
            ("new_power_on_gap_s", self.new_power_on_gap_s),
            ("vibration_sigmas", self.vibration_sigmas),
            ("bias_random_walk", self.bias_random_walk),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("standstill.{key} must be finite and ≥ 0, not {value}").into());
            }
        }
        if !(2..=MAX_BLOCKS).contains(&self.blocks) {
            return Err(format!("standstill.blocks must be 2 … {MAX_BLOCKS}, not {}", self.blocks).into());
        }
        self.motion.validate().map_err(|e| e.within("motion").within("standstill"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_settings_are_refused_with_the_key() {
        let e = StandstillConfig { blocks: 1, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("standstill.blocks"), "{e}");
        let e = StandstillConfig { max_bias: f64::NAN, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("standstill.max_bias"), "{e}");
    }

    /// The motion filter's settings sit under `standstill: motion:` in the parameter file.
    #[test]
    fn a_bad_motion_setting_names_its_key_as_the_file_has_it() {
        let motion = MotionBiasConfig { accel_stddev: -1.0, ..Default::default() };
        let e = StandstillConfig { motion, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().starts_with("standstill.motion.accel_stddev must be"), "{e}");
    }
}
