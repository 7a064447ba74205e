//! The IMU simulator: a seeded trajectory ([`trajectory`]) sampled at the IMU rate gives the
//! true signals; the grade's noise model ([`grade`]) and any extra [`Term`]s from `physics`
//! turn them into a measured stream; the result is a [`Recording`] with ground truth, and
//! the truth of every random draw.
//!
//! ```no_run
//! use imu_fsda::sim::{simulate, write_bag, SimConfig};
//! let cfg: SimConfig = serde_yaml::from_str("
//! profile: handheld
//! grade: bmi160
//! rate_hz: 200
//! seconds: 30
//! seed: 7
//! terms:
//!   - {term: gyro_scale, scale: [0.001, 0, 0]}
//! ").unwrap();
//! let out = simulate(&cfg).unwrap();
//! write_bag("handheld.mcap", &out).unwrap();
//! println!("realised gyro bias walk at the end: {:?}", out.history.gyro_bias_walk.last());
//! ```
//!
//! Seeds: one per concern, derived from `seed` ([`crate::physics::derive_seed`]): the
//! trajectory, the turn-on bias, each noise stream and the temperature sensor noise draw
//! from their own streams, so adding a term does not change the trajectory or the noise.

pub mod grade;
pub mod trajectory;

use std::path::Path;

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::bag::{write_recording_with, BagError, RecordingBagOptions};
use crate::core::{PoseSample, Recording, TemperatureSample};
use crate::physics::{apply_terms, derive_seed, ImuSignals, PhysicsError, Term, TermContext, TruthHistory, NOMINAL_GRAVITY};

pub use crate::physics::NoiseModel;
pub use grade::{Grade, GradeSpec};
pub use trajectory::{KinematicState, Profile, Trajectory};

/// Ground truth is written at this rate, or at the IMU rate when that is lower, Hz.
pub const GROUND_TRUTH_RATE_HZ: f64 = 100.0;
/// Upper bound on the IMU samples of one simulation (≈ 3.5 h at 400 Hz).
pub const MAX_SAMPLES: usize = 5_000_000;
/// Default first stamp: 2023-11-14T22:13:20Z, ns (a realistic ROS time, not 0).
pub const DEFAULT_START_TIME_NS: i64 = 1_700_000_000_000_000_000;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("rate_hz must be a positive finite number of Hz, got {0}")]
    BadRate(f64),
    #[error("seconds must be a positive finite duration, got {0}")]
    BadSeconds(f64),
    #[error("{samples} IMU samples requested (rate × seconds); at least 2 and at most {max} are supported")]
    BadLength { samples: f64, max: usize },
    #[error("temperature model: {0}")]
    BadTemperature(String),
    #[error("rest_s must be finite, ≥ 0 and shorter than the {seconds} s simulated, got {rest_s}")]
    BadRest { rest_s: f64, seconds: f64 },
    #[error(
        "start_time_ns {start} with {seconds} s of samples does not fit a ROS 2 stamp (0 to {} s, a signed 32-bit count of seconds)",
        i32::MAX
    )]
    BadStart { start: i64, seconds: f64 },
    #[error(
        "the terms make IMU sample {index} {what} (|ω| ≤ {:e} rad/s and |a| ≤ {:e} m/s² are what an IMU measures): a term's parameters are out of any physical range",
        crate::core::IMPLAUSIBLE_RATE_RAD_S,
        crate::core::IMPLAUSIBLE_ACCEL_M_S2
    )]
    Implausible { index: usize, what: String },
    #[error(transparent)]
    Physics(#[from] PhysicsError),
    // The I/O error is in the message, not a `source`, so a chain printer does not repeat it.
    #[error("reading {path}: {error}")]
    Read { path: std::path::PathBuf, error: std::io::Error },
    #[error("{path}: not a simulation config: {msg}")]
    Parse { path: std::path::PathBuf, msg: String },
}

fn default_start() -> i64 {
    DEFAULT_START_TIME_NS
}

/// A die-temperature history: a warm-up from `initial_c` towards `final_c` with time
/// constant `time_constant_s`, T(t) = T_f + (T_0 − T_f) e^{−t/τ}; the published reading adds
/// white noise of `noise_c`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureModel {
    /// Temperature at the first sample, °C.
    pub initial_c: f64,
    /// Temperature approached, °C.
    pub final_c: f64,
    /// Warm-up time constant, s.
    pub time_constant_s: f64,
    /// Standard deviation of the temperature sensor's reading noise, °C.
    #[serde(default)]
    pub noise_c: f64,
}

impl Default for TemperatureModel {
    /// A board warming up after power-on: 20 → 45 °C, τ = 120 s, 0.05 °C reading noise.
    fn default() -> Self {
        TemperatureModel { initial_c: 20.0, final_c: 45.0, time_constant_s: 120.0, noise_c: 0.05 }
    }
}

impl TemperatureModel {
    /// True die temperature at `t` s after the first sample, °C.
    pub fn at(&self, t: f64) -> f64 {
        self.final_c + (self.initial_c - self.final_c) * (-t / self.time_constant_s).exp()
    }

    fn validate(&self) -> Result<(), SimError> {
        let finite = [self.initial_c, self.final_c, self.time_constant_s, self.noise_c].iter().all(|v| v.is_finite());
        if !finite || self.time_constant_s <= 0.0 || self.noise_c < 0.0 {
            return Err(SimError::BadTemperature(format!("{self:?}: values must be finite, time_constant_s > 0, noise_c ≥ 0")));
        }
        Ok(())
    }
}

/// A simulation, as a YAML file gives it (`params/sim/*.yaml`); a field left out takes
/// [`SimConfig::default`]'s value (the CLI flags override either).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Motion: aerial (or mav), handheld, car, quadruped.
    pub profile: Profile,
    /// IMU grade: certus-evo, mti-600, mpu-9250, adis16448, bmi160.
    pub grade: Grade,
    /// IMU rate, Hz.
    pub rate_hz: f64,
    /// Duration, s.
    pub seconds: f64,
    /// Master seed; every random concern derives its own stream from it.
    pub seed: u64,
    /// First IMU stamp, ns.
    #[serde(default = "default_start")]
    pub start_time_ns: i64,
    /// The simulator's noise model; default: the grade's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulator_noise: Option<NoiseModel>,
    /// Also apply the grade's datasheet errors: a turn-on bias drawn in the datasheet's range,
    /// quantisation at its LSB and saturation at its range.
    #[serde(default)]
    pub datasheet_errors: bool,
    /// Die temperature; default: none (25 °C constant, no temperature topic) unless a
    /// temperature-dependent term is configured, which then gets [`TemperatureModel::default`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature: Option<TemperatureModel>,
    /// Extra error terms (the `physics` vocabulary), applied in physical order with the noise.
    #[serde(default)]
    pub terms: Vec<Term>,
    /// Which power-on of this IMU: the same lasting terms (`terms`, the grade), a new turn-on
    /// bias, noise and motion drawn for each; 0 is the configuration's own draw.
    #[serde(default, skip_serializing_if = "is_zero_u64")]
    pub power_on: u64,
    /// Seconds at rest before the motion starts (the attitude of its first instant, no rate,
    /// no acceleration), as a robot stands after power-on.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub rest_s: f64,
}

fn is_zero_u64(v: &u64) -> bool {
    *v == 0
}

fn is_zero_f64(v: &f64) -> bool {
    *v == 0.0
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            profile: Profile::Aerial,
            grade: Grade::Mpu9250,
            rate_hz: 200.0,
            seconds: 30.0,
            seed: 0,
            start_time_ns: DEFAULT_START_TIME_NS,
            simulator_noise: None,
            datasheet_errors: false,
            temperature: None,
            terms: Vec::new(),
            power_on: 0,
            rest_s: 0.0,
        }
    }
}

impl SimConfig {
    /// Reads a simulation config file (YAML, `params/sim/`); the values are checked by
    /// [`SimConfig::validate`] when it is simulated.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|error| SimError::Read { path: path.into(), error })?;
        serde_yaml::from_str(&text).map_err(|e| SimError::Parse { path: path.into(), msg: e.to_string() })
    }

    /// The noise model in use: the explicit one, else the grade's.
    pub fn noise(&self) -> NoiseModel {
        self.simulator_noise.unwrap_or_else(|| self.grade.spec().noise())
    }

    /// The temperature model in use, if any.
    pub fn temperature_model(&self) -> Option<TemperatureModel> {
        let needs = self.terms.iter().any(|t| matches!(t, Term::GyroBiasTemperature(_)));
        self.temperature.or(needs.then(TemperatureModel::default))
    }

    /// Number of IMU samples: round(rate × seconds).
    pub fn samples(&self) -> Result<usize, SimError> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(SimError::BadRate(self.rate_hz));
        }
        if !(self.seconds.is_finite() && self.seconds > 0.0) {
            return Err(SimError::BadSeconds(self.seconds));
        }
        let n = (self.rate_hz * self.seconds).round();
        if n < 2.0 || n > MAX_SAMPLES as f64 {
            return Err(SimError::BadLength { samples: n, max: MAX_SAMPLES });
        }
        Ok(n as usize)
    }

    /// Check everything that can be checked before simulating.
    pub fn validate(&self) -> Result<(), SimError> {
        self.samples()?;
        if !(self.rest_s.is_finite() && self.rest_s >= 0.0 && self.rest_s < self.seconds) {
            return Err(SimError::BadRest { rest_s: self.rest_s, seconds: self.seconds });
        }
        // The last stamp too must be a ROS 2 time (builtin_interfaces/Time: i32 seconds).
        let last_ns = self.start_time_ns as f64 + self.seconds * 1e9;
        if self.start_time_ns < 0 || last_ns >= i32::MAX as f64 * 1e9 {
            return Err(SimError::BadStart { start: self.start_time_ns, seconds: self.seconds });
        }
        if let Some(t) = self.temperature_model() {
            t.validate()?;
        }
        for t in self.noise().terms().iter().chain(&self.terms) {
            t.validate()?;
        }
        Ok(())
    }
}

/// A simulation's result: the recording and everything needed to check it.
#[derive(Debug, Clone)]
pub struct SimOutput {
    pub config: SimConfig,
    pub trajectory: Trajectory,
    /// The clean signals at the IMU stamps (true ω, specific force, attitude, temperature).
    pub ideal: ImuSignals,
    /// The measured signals.
    pub measured: ImuSignals,
    /// Every term applied, in application order: the noise model, the drawn datasheet errors
    /// and the configured terms.
    pub applied: Vec<Term>,
    /// The realised random errors (white noise, bias walks).
    pub history: TruthHistory,
    /// The noise model, as the covariance fields state it.
    pub noise: NoiseModel,
    /// Per-sample white-noise variances (gyro (rad/s)², accel (m/s²)²).
    pub imu_variance: (f64, f64),
    /// Variance of the published temperature, °C² (when there is a temperature topic).
    pub temperature_variance: f64,
    /// IMU stream, ground truth (body pose) and published temperature.
    pub recording: Recording,
}

/// What a simulation was, for a sidecar file next to its bag.
#[derive(Debug, Clone, Serialize)]
pub struct SimTruth<'a> {
    pub config: &'a SimConfig,
    pub simulator_noise: NoiseModel,
    pub applied: &'a [Term],
}

impl SimOutput {
    pub fn truth(&self) -> SimTruth<'_> {
        SimTruth { config: &self.config, simulator_noise: self.noise, applied: &self.applied }
    }
}

/// IMU stamps: start + round(k · 10⁹ / rate) ns, k = 0..n.
pub fn stamps(start_ns: i64, rate_hz: f64, n: usize) -> Vec<i64> {
    (0..n).map(|k| start_ns + (k as f64 * 1e9 / rate_hz).round() as i64).collect()
}

/// The clean signals of `trajectory` at `stamps` (t = 0 at the first), nominal gravity.
pub fn ideal_signals(trajectory: &Trajectory, stamps_ns: &[i64], temperature: impl Fn(f64) -> f64) -> ImuSignals {
    ideal_signals_after_rest(trajectory, stamps_ns, 0.0, temperature)
}

/// The body at rest for `rest_s` in the trajectory's first attitude, then the trajectory from
/// its start (the motion starts at once, as a robot that sets off).
pub fn state_after_rest(trajectory: &Trajectory, t: f64, rest_s: f64) -> KinematicState {
    if t < rest_s {
        let first = trajectory.state(0.0);
        KinematicState { world_from_body: first.world_from_body, ..KinematicState::at_rest() }
    } else {
        trajectory.state(t - rest_s)
    }
}

/// [`ideal_signals`] after `rest_s` s at rest ([`state_after_rest`]).
pub fn ideal_signals_after_rest(trajectory: &Trajectory, stamps_ns: &[i64], rest_s: f64, temperature: impl Fn(f64) -> f64) -> ImuSignals {
    let t0 = stamps_ns.first().copied().unwrap_or(0);
    let times: Vec<f64> = stamps_ns.iter().map(|s| (s - t0) as f64 * 1e-9).collect();
    let states: Vec<KinematicState> = times.iter().map(|&t| state_after_rest(trajectory, t, rest_s)).collect();
    ImuSignals {
        stamps_ns: stamps_ns.to_vec(),
        world_from_imu: states.iter().map(|s| s.world_from_body).collect(),
        alpha_in_imu: states.iter().map(|s| s.alpha_in_body).collect(),
        temperature_c: times.iter().map(|&t| temperature(t)).collect(),
        gyro: states.iter().map(|s| s.omega_in_body).collect(),
        accel: states.iter().map(|s| s.specific_force_in_body(NOMINAL_GRAVITY)).collect(),
    }
}

/// Run a simulation.
pub fn simulate(cfg: &SimConfig) -> Result<SimOutput, SimError> {
    cfg.validate()?;
    let n = cfg.samples()?;
    // Power-on k > 0: its own motion, turn-on bias and noise; 0 keeps the configuration's draw.
    let draw = |concern: &str| if cfg.power_on == 0 { cfg.seed } else { derive_seed(cfg.seed, concern, cfg.power_on) };
    let trajectory = Trajectory::new(cfg.profile, draw("power_on_motion"));
    let imu_stamps = stamps(cfg.start_time_ns, cfg.rate_hz, n);
    let temperature = cfg.temperature_model();
    let ideal = ideal_signals_after_rest(&trajectory, &imu_stamps, cfg.rest_s, |t| temperature.map_or(25.0, |m| m.at(t)));

    let noise = cfg.noise();
    let spec = cfg.grade.spec();
    let mut applied: Vec<Term> = noise.terms().to_vec();
    if cfg.datasheet_errors {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(derive_seed(draw("power_on_bias"), "turn_on_bias", 0));
        applied.extend(spec.turn_on_bias(&mut rng));
        applied.extend(spec.range_and_resolution());
    }
    applied.extend(cfg.terms.iter().cloned());
    let applied: Vec<Term> = crate::physics::in_application_order(&applied).into_iter().cloned().collect();

    let mut measured = ideal.clone();
    let mut ctx = TermContext::new(draw("power_on_noise"));
    apply_terms(&applied, &mut measured, &mut ctx)?;
    // Parameters no sensor has (a rotation of 1e300 rad) give NaN or absurd readings: refused
    // rather than written into a bag.
    let samples = measured.to_samples();
    if let Some((index, s)) = samples.iter().enumerate().find(|(_, s)| !s.is_plausible()) {
        let what = if s.gyro.iter().chain(s.accel.iter()).all(|v| v.is_finite()) {
            format!("|ω| = {:.3e} rad/s, |a| = {:.3e} m/s²", s.gyro.norm(), s.accel.norm())
        } else {
            "non-finite".to_string()
        };
        return Err(SimError::Implausible { index, what });
    }

    // Ground truth: the body pose at 100 Hz (or the IMU rate when lower).
    let pose_stamps = if cfg.rate_hz <= GROUND_TRUTH_RATE_HZ {
        imu_stamps.clone()
    } else {
        let m = ((cfg.seconds * GROUND_TRUTH_RATE_HZ).round() as usize).max(2);
        stamps(cfg.start_time_ns, GROUND_TRUTH_RATE_HZ, m)
    };
    let pose_times: Vec<f64> = pose_stamps.iter().map(|s| (s - cfg.start_time_ns) as f64 * 1e-9).collect();
    let moving_times: Vec<f64> = pose_times.iter().map(|t| (t - cfg.rest_s).max(0.0)).collect();
    let positions = trajectory.positions(&moving_times);
    let ground_truth = pose_stamps
        .iter()
        .zip(&pose_times)
        .zip(positions)
        .map(|((&stamp_ns, &t), position_in_world)| PoseSample {
            stamp_ns,
            position_in_world,
            world_from_body: state_after_rest(&trajectory, t, cfg.rest_s).world_from_body,
        })
        .collect();

    // Published temperature: the die temperature plus reading noise, at the IMU stamps.
    let (temperature, temperature_variance) = match temperature {
        None => (Vec::new(), 0.0),
        Some(model) => {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(derive_seed(cfg.seed, "temperature", 0));
            let readings = imu_stamps
                .iter()
                .zip(&ideal.temperature_c)
                .map(|(&stamp_ns, &c)| {
                    let w: f64 = StandardNormal.sample(&mut rng);
                    TemperatureSample { stamp_ns, celsius: c + model.noise_c * w }
                })
                .collect();
            (readings, model.noise_c * model.noise_c)
        }
    };

    let imu_variance = noise.per_sample_variance(ideal.nominal_dt());
    let recording = Recording {
        name: format!("sim {} {} {} Hz {} s seed {}", cfg.profile, cfg.grade, cfg.rate_hz, cfg.seconds, cfg.seed),
        imu: samples,
        ground_truth,
        temperature,
    };
    Ok(SimOutput {
        config: cfg.clone(),
        trajectory,
        ideal,
        measured,
        applied,
        history: ctx.history,
        noise,
        imu_variance,
        temperature_variance,
        recording,
    })
}

/// Write a simulation as a ROS 2 bag ([`crate::bag::write_recording_with`]): `/imu/data`
/// (covariance diagonals = per-sample white-noise variance), `/ground_truth/pose`, and
/// `/imu/temperature` when simulated; messages in stamp order, IMU first at equal stamps.
/// Same output → same bytes.
pub fn write_bag(path: impl AsRef<Path>, out: &SimOutput) -> Result<(), BagError> {
    write_bag_with_progress(path, out, |_, _| {})
}

/// [`write_bag`], calling `progress(done, total)` every 10 000 messages.
pub fn write_bag_with_progress(path: impl AsRef<Path>, out: &SimOutput, progress: impl FnMut(usize, usize)) -> Result<(), BagError> {
    let options = RecordingBagOptions { imu_variance: Some(out.imu_variance), temperature_variance: out.temperature_variance };
    write_recording_with(path, &out.recording, &options, progress)
}

/// Mean of a channel, for summaries.
pub fn mean(x: &[Vector3<f64>]) -> Vector3<f64> {
    if x.is_empty() {
        return Vector3::zeros();
    }
    x.iter().sum::<Vector3<f64>>() / x.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bag::{read_recording, RecordingTopics, IMU_TOPIC};
    use crate::msg::Imu;
    use crate::physics::{GyroBiasTemperature, MountRotation};

    fn cfg(profile: Profile) -> SimConfig {
        SimConfig { profile, grade: Grade::Mpu9250, rate_hz: 200.0, seconds: 5.0, seed: 3, ..Default::default() }
    }

    #[test]
    fn ideal_signals_are_the_truth_and_noise_is_recorded() {
        let out = simulate(&cfg(Profile::Car)).unwrap();
        assert_eq!(out.recording.imu.len(), 1000);
        assert_eq!(out.recording.ground_truth.len(), 500);
        assert!(out.recording.temperature.is_empty());
        // measured − ideal = white noise + bias walk, exactly.
        for k in [0, 10, 999] {
            let e = out.measured.gyro[k] - out.ideal.gyro[k] - out.history.gyro_white[k] - out.history.gyro_bias_walk[k];
            assert!(e.norm() < 1e-12, "{k}: {e:?}");
        }
        // At rest-ish a car's accelerometer reads about +g on z.
        assert!((mean(&out.ideal.accel).z - 9.81).abs() < 0.5);
        let (vg, _) = out.imu_variance;
        assert!((vg - (0.01f64.to_radians()).powi(2) * 200.0).abs() < 1e-12);
    }

    #[test]
    fn same_seed_same_output_other_seed_other_output() {
        let a = simulate(&cfg(Profile::Quadruped)).unwrap();
        let b = simulate(&cfg(Profile::Quadruped)).unwrap();
        assert_eq!(a.recording.imu, b.recording.imu);
        let c = simulate(&SimConfig { seed: 4, ..cfg(Profile::Quadruped) }).unwrap();
        assert_ne!(a.recording.imu, c.recording.imu);
        // Adding a term changes neither the trajectory nor the noise draws.
        let d =
            simulate(&SimConfig { terms: vec![Term::MountRotation(MountRotation { rotvec: [0.0, 0.0, 0.0] })], ..cfg(Profile::Quadruped) })
                .unwrap();
        assert_eq!(a.recording.imu, d.recording.imu);
    }

    #[test]
    fn temperature_topic_only_when_needed() {
        let t = Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: [1e-4, 0.0, 0.0], reference_c: 25.0 });
        let out = simulate(&SimConfig { terms: vec![t], ..cfg(Profile::Aerial) }).unwrap();
        assert_eq!(out.recording.temperature.len(), out.recording.imu.len());
        let k = 999;
        let want = 1e-4 * (out.ideal.temperature_c[k] - 25.0);
        let got = out.measured.gyro[k].x - out.ideal.gyro[k].x - out.history.gyro_white[k].x - out.history.gyro_bias_walk[k].x;
        assert!((got - want).abs() < 1e-12);
    }

    #[test]
    fn datasheet_errors_add_bias_range_and_resolution() {
        let out = simulate(&SimConfig { datasheet_errors: true, ..cfg(Profile::Handheld) }).unwrap();
        let names: Vec<_> = out.applied.iter().map(|t| t.name()).collect();
        assert_eq!(names, ["gyro_bias", "accel_bias", "white_noise", "bias_random_walk", "quantization", "saturation"]);
        let lsb = Grade::Mpu9250.spec().gyro_lsb.unwrap();
        assert!(out.measured.gyro.iter().all(|g| g.iter().all(|x| ((x / lsb) - (x / lsb).round()).abs() < 1e-6)));
    }

    #[test]
    fn example_configs_parse_and_run() {
        for (name, text) in [
            ("aerial_adis16448", include_str!("../../params/sim/aerial_adis16448.yaml")),
            ("handheld_bmi160", include_str!("../../params/sim/handheld_bmi160.yaml")),
            ("car_mti600", include_str!("../../params/sim/car_mti600.yaml")),
            ("quadruped_mpu9250", include_str!("../../params/sim/quadruped_mpu9250.yaml")),
            ("all_terms", include_str!("../../params/sim/all_terms.yaml")),
        ] {
            let c: SimConfig = serde_yaml::from_str(text).unwrap_or_else(|e| panic!("{name}: {e}"));
            let out = simulate(&SimConfig { seconds: 2.0, ..c.clone() }).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(out.measured.gyro.iter().chain(&out.measured.accel).all(|v| v.iter().all(|x| x.is_finite())), "{name}");
            assert_eq!(out.applied.len(), 2 + c.terms.len() + if c.datasheet_errors { 4 } else { 0 }, "{name}");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        for (c, what) in [
            (SimConfig { rate_hz: 0.0, ..cfg(Profile::Car) }, "rate_hz"),
            (SimConfig { rate_hz: f64::NAN, ..cfg(Profile::Car) }, "rate_hz"),
            (SimConfig { seconds: -1.0, ..cfg(Profile::Car) }, "seconds"),
            (SimConfig { seconds: 0.001, ..cfg(Profile::Car) }, "at least 2"),
            (
                SimConfig { temperature: Some(TemperatureModel { time_constant_s: 0.0, ..Default::default() }), ..cfg(Profile::Car) },
                "temperature",
            ),
            (
                SimConfig {
                    simulator_noise: Some(NoiseModel {
                        gyro_noise_density: f64::NAN,
                        accel_noise_density: 0.0,
                        gyro_bias_random_walk: 0.0,
                        accel_bias_random_walk: 0.0,
                    }),
                    ..cfg(Profile::Car)
                },
                "gyro_noise_density",
            ),
        ] {
            let e = simulate(&c).unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
        let e =
            serde_yaml::from_str::<SimConfig>("{profile: boat, grade: bmi160, rate_hz: 1, seconds: 1, seed: 1}").unwrap_err().to_string();
        assert!(e.contains("boat") && e.contains("aerial"), "{e}");
        let e =
            serde_yaml::from_str::<SimConfig>("{profile: car, grade: bmi161, rate_hz: 1, seconds: 1, seed: 1}").unwrap_err().to_string();
        assert!(e.contains("bmi161") && e.contains("bmi160"), "{e}");
        let e = serde_yaml::from_str::<SimConfig>("{profile: car, grade: bmi160, rate_hz: 1, seconds: 1, seed: 1, colour: red}")
            .unwrap_err()
            .to_string();
        assert!(e.contains("colour"), "{e}");
        let c: SimConfig = serde_yaml::from_str("{profile: mav, grade: adis16448, rate_hz: 200, seconds: 1, seed: 1}").unwrap();
        assert_eq!(c.profile, Profile::Aerial);
    }

    #[test]
    fn bag_round_trip_is_byte_identical_and_readable() {
        let dir = tempfile::tempdir().unwrap();
        let t = Term::GyroBiasTemperature(GyroBiasTemperature { coefficient: [1e-4, 0.0, 0.0], reference_c: 25.0 });
        let out = simulate(&SimConfig { terms: vec![t], rate_hz: 400.0, ..cfg(Profile::Quadruped) }).unwrap();
        let (a, b) = (dir.path().join("a.mcap"), dir.path().join("b.mcap"));
        write_bag(&a, &out).unwrap();
        write_bag(&b, &simulate(&out.config).unwrap()).unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        let (rec, report) = read_recording(&a, &RecordingTopics::default()).unwrap();
        assert_eq!(report.skipped(), 0);
        assert_eq!(rec.imu, out.recording.imu);
        assert_eq!(rec.temperature, out.recording.temperature);
        assert_eq!(rec.ground_truth.len(), 500);
        let msg = crate::bag::BagReader::open(&a).unwrap().map(|m| m.unwrap()).find(|m| &*m.topic == IMU_TOPIC).unwrap();
        let imu = <Imu as crate::msg::RosMessage>::decode(&msg.data).unwrap();
        assert_eq!(imu.angular_velocity_covariance.0[4], out.imu_variance.0);
        assert_eq!(imu.linear_acceleration_covariance.0[8], out.imu_variance.1);
        assert_eq!(imu.orientation_covariance.0[0], -1.0);
    }
}
