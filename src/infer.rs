//! The per-sample denoising pipeline, free of ROS and async: input checks → gyro correction
//! (any [`GyroCorrector`], e.g. the model's streaming form) → orientation integration.
//! The node, `replay` and the tests all drive this same [`Pipeline::push`], so what the node
//! publishes on a bag is what `replay` writes. No allocation and no I/O per sample.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::core::{ClipDetector, ImuSample, STANDARD_GRAVITY};
use crate::resample::PeriodMeans;
use crate::so3::{exp, renormalize};

/// Something that corrects a gyro stream sample by sample (causal, stateful).
pub trait GyroCorrector: Send {
    /// Corrected angular velocity (rad/s) of the newest sample.
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64>;
    /// Forget the history: the next sample starts a new stream (warm-up again).
    fn reset(&mut self);
    /// Samples of history the correction depends on (N); 1 for memoryless methods.
    fn window(&self) -> usize;
    /// The IMU rate the corrector was made for, Hz, if it has one.
    fn rate_hz(&self) -> Option<f64>;
    /// Short name for diagnostics.
    fn name(&self) -> &str;
    /// True when the output is the input unchanged: its noise is the sensor's own.
    fn passes_through(&self) -> bool {
        false
    }
}

/// The identity: the raw gyro minus a constant bias. The baseline and the model-free mode.
#[derive(Debug, Clone)]
pub struct BiasCorrector {
    pub bias: Vector3<f64>,
}

impl GyroCorrector for BiasCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
        gyro - self.bias
    }
    fn reset(&mut self) {}
    fn window(&self) -> usize {
        1
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        "bias"
    }
}

/// The gyro as measured: what the node runs with no model configured.
pub struct PassThrough;

impl GyroCorrector for PassThrough {
    fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
        *gyro
    }
    fn reset(&mut self) {}
    fn window(&self) -> usize {
        1
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        "pass-through (no model)"
    }
    fn passes_through(&self) -> bool {
        true
    }
}

/// A trained model in its streaming form (pure Rust, f64, constant cost per sample).
pub struct ModelCorrector {
    pub denoiser: crate::model::StreamingDenoiser,
    pub name: String,
    pub rate_hz: f64,
}

impl ModelCorrector {
    /// Load `<model>.json` + `<model>.ot` (the `.pt` beside them is the TorchScript form),
    /// with IMU `imu`'s Ĉ_ω (`None`: the model's own).
    pub fn load(model: &std::path::Path, imu: Option<&str>) -> Result<Self, crate::model::ModelError> {
        Ok(Self::load_with_metadata(model, imu)?.0)
    }

    /// [`ModelCorrector::load`], also returning the model's metadata.
    pub fn load_with_metadata(
        model: &std::path::Path,
        imu: Option<&str>,
    ) -> Result<(Self, crate::model::ModelMetadata), crate::model::ModelError> {
        let (denoiser, meta) = crate::model::export::load_streaming(&crate::model::predict::metadata_path(model), imu)?;
        Ok((ModelCorrector { denoiser, name: meta.name.clone(), rate_hz: meta.rate_hz }, meta))
    }
}

impl GyroCorrector for ModelCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        self.denoiser.step(gyro, accel)
    }
    fn reset(&mut self) {
        self.denoiser.reset();
    }
    fn window(&self) -> usize {
        self.denoiser.receptive_field()
    }
    fn rate_hz(&self) -> Option<f64> {
        (self.rate_hz > 0.0).then_some(self.rate_hz)
    }
    fn name(&self) -> &str {
        &self.name
    }
}

/// The naive approach, for benchmarks: keep the last N samples and run the whole window
/// through the network (tch) for every new sample, keeping only the last output. Same
/// outputs as the streaming form (up to f32), cost proportional to N.
pub struct FullWindowCorrector {
    net: crate::model::InferenceNet,
    window: Vec<ImuSample>,
    n: usize,
    name: String,
    correction_gain: f64,
}

impl FullWindowCorrector {
    pub fn new(net: crate::model::InferenceNet, name: &str) -> Self {
        let n = net.receptive_field() as usize;
        FullWindowCorrector { net, window: Vec::with_capacity(n), n, name: format!("{name} (naive full window)"), correction_gain: 1.0 }
    }

    /// Applies the share `gain` of the model's correction (as [`crate::model::StreamingDenoiser::set_correction_gain`]).
    pub fn with_correction_gain(mut self, gain: f64) -> Self {
        self.correction_gain = gain;
        self
    }
}

impl GyroCorrector for FullWindowCorrector {
    fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
        let s = ImuSample { stamp_ns: 0, gyro: *gyro, accel: *accel };
        if self.window.is_empty() {
            // The model's causal padding: the first sample replicated to the left.
            self.window.resize(self.n, s);
        }
        self.window.rotate_left(1);
        if let Some(last) = self.window.last_mut() {
            *last = s;
        }
        let input = crate::model::predict::imu_tensor(&self.window, tch::Kind::Float);
        let out = tch::no_grad(|| self.net.forward(&input));
        let last = out.select(1, self.n as i64 - 1).reshape([3]).to_kind(tch::Kind::Double);
        match Vec::<f64>::try_from(last) {
            Ok(v) => crate::model::streaming::apply_correction_gain(gyro, &Vector3::new(v[0], v[1], v[2]), self.correction_gain),
            Err(_) => *gyro,
        }
    }
    fn reset(&mut self) {
        self.window.clear();
    }
    fn window(&self) -> usize {
        self.n
    }
    fn rate_hz(&self) -> Option<f64> {
        None
    }
    fn name(&self) -> &str {
        &self.name
    }
}

/// Pipeline settings (the node reads them from its ROS parameters).
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
    /// rate off the model's): a MEMS gyro's own turn-on bias, rad/s. At 1 mrad/s a consumer
    /// gyro's pass-through attitude claimed σ 5.8° where it was 14.8° off after 100 s.
    pub uncorrected_bias_stddev: f64,
    /// Feed a model an input whose rate is off the model's in the model's periods
    /// ([`crate::resample`]); false runs it on the samples as they come (its window then spans
    /// another time, and the orientation's covariance allows for an uncorrected bias).
    pub resample_to_model_rate: bool,
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
            uncorrected_bias_stddev: 1e-2,
            resample_to_model_rate: true,
        }
    }
}

impl PipelineConfig {
    /// Refuses settings the pipeline cannot run with, naming the key: a NaN or a negative
    /// variance would reach every published covariance, and a gap of at most one period would
    /// make every sample a gap.
    pub fn validate(&self) -> Result<(), String> {
        for (key, value) in [
            ("nominal_rate_hz", self.nominal_rate_hz),
            ("angular_velocity_stddev", self.angular_velocity_stddev),
            ("gravity_init_seconds", self.gravity_init_seconds),
            ("initial_tilt_variance", self.initial_tilt_variance),
            ("initial_yaw_variance", self.initial_yaw_variance),
            ("gap_variance_per_second", self.gap_variance_per_second),
            ("bias_stddev", self.bias_stddev),
            ("uncorrected_bias_stddev", self.uncorrected_bias_stddev),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("pipeline.{key} must be finite and ≥ 0, not {value}"));
            }
        }
        if !(self.gap_periods.is_finite() && self.gap_periods > 1.0) {
            return Err(format!("pipeline.gap_periods must be finite and > 1 (nominal periods), not {}", self.gap_periods));
        }
        if !(self.rate_tolerance.is_finite() && self.rate_tolerance > 0.0) {
            return Err(format!("pipeline.rate_tolerance must be finite and > 0, not {}", self.rate_tolerance));
        }
        Ok(())
    }
}

/// Why an input sample was not used. Every drop is counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dropped {
    NonFinite,
    /// Beyond what an IMU measures ([`ImuSample::is_plausible`]): a corrupt value, which would
    /// poison the model's window and jump the integrated attitude.
    Implausible,
    DuplicateStamp,
    BackwardsStamp,
}

/// Counters of everything the pipeline saw and did, by reason (published on /diagnostics).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct Counters {
    pub received: u64,
    pub processed: u64,
    pub dropped_non_finite: u64,
    pub dropped_implausible: u64,
    pub dropped_duplicate_stamp: u64,
    pub dropped_backwards_stamp: u64,
    pub gaps: u64,
    /// Times the source's clock went back and was followed ([`CLOCK_JUMP_SAMPLES`]).
    pub clock_jumps: u64,
    pub rate_changes: u64,
    pub resets: u64,
    pub warmup_samples: u64,
    /// Samples missing from holes shorter than a gap, estimated from the stamps of a regular
    /// stream (best-effort DDS dropping a burst, a driver's buffer overrun): bridged, not reset.
    pub missed_samples: u64,
    /// Samples with an axis held at the sensor's range ([`ClipDetector`]): used as recorded,
    /// their true values were larger.
    pub saturated_samples: u64,
    /// Times the model started or stopped being fed the input's periods ([`crate::resample`]).
    pub resampling_switches: u64,
}

impl Counters {
    /// Every input dropped, whatever the reason.
    pub fn dropped(&self) -> u64 {
        self.dropped_non_finite + self.dropped_implausible + self.dropped_duplicate_stamp + self.dropped_backwards_stamp
    }
}

/// One corrected sample: what `/imu/denoised` and `/imu/gyro_correction` carry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectedImu {
    pub stamp_ns: i64,
    /// Corrected angular velocity ω̂, rad/s.
    pub gyro: Vector3<f64>,
    /// The estimated correction ω̂ − ω, rad/s.
    pub correction: Vector3<f64>,
    /// Specific force, passed through, m/s².
    pub accel: Vector3<f64>,
    /// Variance of each corrected gyro axis, (rad/s)².
    pub gyro_variance: f64,
    /// The gyro is the input's unchanged (no model): the input's own covariance, where it
    /// gives one, is the output's.
    pub passed_through: bool,
    /// Integrated `world_from_body` and its covariance (rad², about world x, y, z); `None`
    /// until the initial attitude is known.
    pub orientation: Option<(UnitQuaternion<f64>, Matrix3<f64>)>,
    /// The corrector has seen fewer than N samples since the start or the last reset.
    pub warming_up: bool,
    /// This sample follows a gap (the window was reset, the attitude held).
    pub after_gap: bool,
}

/// Open-loop attitude from the corrected gyro, with the same convention as evaluation:
/// R(t_{n+1}) = R(t_n)·Exp(ω̂_n (t_{n+1} − t_n)).
#[derive(Debug, Clone)]
struct Attitude {
    world_from_body: Option<UnitQuaternion<f64>>,
    covariance: Matrix3<f64>,
    /// Seconds integrated since the attitude was set (the bias term's t).
    since_set_s: f64,
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
    fn new() -> Self {
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
    fn grow(&mut self, dt: f64, noise_stddev: f64, bias_stddev: f64) {
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
}

/// Mean rate over the initial-attitude interval above which the platform is turning, rad/s:
/// above a consumer gyro's bias (EuRoC's uncalibrated ADIS16448: 0.08 rad/s), below a car's
/// bend.
pub const INIT_TURN_RATE: f64 = 0.15;
/// Intervals the initial attitude waits for a turn to end; then it is taken anyway, its tilt
/// variance covering the horizontal acceleration.
pub const TURNING_INTERVALS: u32 = 20;

/// The pipeline: feed raw samples in stamp order, get corrected samples out.
pub struct Pipeline {
    corrector: Box<dyn GyroCorrector>,
    cfg: PipelineConfig,
    nominal_period_ns: Option<f64>,
    smoothed_period_ns: f64,
    rate_off: bool,
    last: Option<(i64, Vector3<f64>)>,
    since_reset: u64,
    attitude: Attitude,
    counters: Counters,
    first_dts: [i64; 8],
    n_first_dts: usize,
    backwards_run: BackwardsRun,
    clipping: ClipDetector,
    /// Consecutive intervals longer than a gap: a few in a row are a rate, not a hole.
    consecutive_gaps: u32,
    /// Whether the nominal period came from the first intervals (not the model or config).
    period_learned: bool,
    /// The period gaps are measured in while a stream runs slower than a fixed nominal (the
    /// model's): else every sample of a 20-Hz stream into a 200-Hz model was a gap, the model
    /// never warmed up and the attitude was never integrated.
    slow_period_ns: Option<f64>,
    /// The interval before the last, ns: a hole is counted only in a regular stream.
    last_dt_ns: i64,
    /// The model's periods, when the corrector has a rate ([`crate::resample`]).
    periods: Option<PeriodMeans>,
    /// The stream is fed to the model in its periods: its rate is off the model's.
    resampling: bool,
    /// The correction of the last period completed, rad/s (while resampling).
    period_correction: Vector3<f64>,
}

/// Consecutive samples, advancing among themselves but behind the last accepted stamp, after
/// which the source's clock is taken as having gone back (a driver restarted, or one stamp
/// was far in the future) and followed, as after a gap. Before, one stamp three hours ahead
/// stopped the output for good: every later sample was "backwards".
pub const CLOCK_JUMP_SAMPLES: u32 = 20;

/// Consecutive stamps refused as not after the last accepted one, counted while they advance
/// among themselves: [`CLOCK_JUMP_SAMPLES`] of them say the source's clock went back.
#[derive(Debug, Default, Clone, Copy)]
pub struct BackwardsRun(Option<(i64, u32)>);

impl BackwardsRun {
    /// For a stamp not after the last accepted: true when it completes a run (follow the
    /// source's new clock), false when it is to be refused.
    pub fn follows(&mut self, stamp_ns: i64) -> bool {
        let n = match self.0 {
            Some((t, n)) if stamp_ns > t => n + 1,
            _ => 1,
        };
        self.0 = (n < CLOCK_JUMP_SAMPLES).then_some((stamp_ns, n));
        self.0.is_none()
    }

    /// A stamp was accepted: the run, if any, is over.
    pub fn end(&mut self) {
        self.0 = None;
    }
}

/// Intervals longer than a gap in a row after which the input's rate is taken as changed.
pub const RATE_FROM_GAPS: u32 = 8;

impl Pipeline {
    pub fn new(corrector: Box<dyn GyroCorrector>, cfg: PipelineConfig) -> Self {
        let rate = if cfg.nominal_rate_hz > 0.0 { Some(cfg.nominal_rate_hz) } else { corrector.rate_hz() };
        let nominal_period_ns = rate.map(|r| 1e9 / r);
        // The model's periods, for a corrector with a rate that is not a pass-through.
        let periods = corrector.rate_hz().filter(|r| *r > 0.0 && !corrector.passes_through()).map(PeriodMeans::new);
        Pipeline {
            corrector,
            cfg,
            nominal_period_ns,
            smoothed_period_ns: nominal_period_ns.unwrap_or(0.0),
            rate_off: false,
            last: None,
            since_reset: 0,
            attitude: Attitude::new(),
            counters: Counters::default(),
            first_dts: [0; 8],
            n_first_dts: 0,
            backwards_run: BackwardsRun::default(),
            clipping: ClipDetector::default(),
            consecutive_gaps: 0,
            period_learned: false,
            slow_period_ns: None,
            last_dt_ns: 0,
            periods,
            resampling: false,
            period_correction: Vector3::zeros(),
        }
    }

    /// Set the initial attitude from an external source (an initial-pose topic).
    pub fn set_attitude(&mut self, world_from_body: UnitQuaternion<f64>, covariance: Matrix3<f64>) {
        self.attitude.world_from_body = Some(world_from_body);
        self.attitude.covariance = covariance;
        self.attitude.since_set_s = 0.0;
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    pub fn corrector_name(&self) -> &str {
        self.corrector.name()
    }

    pub fn window(&self) -> usize {
        self.corrector.window()
    }

    /// Nominal input period, s, once known.
    pub fn nominal_rate_hz(&self) -> Option<f64> {
        self.nominal_period_ns.map(|p| 1e9 / p)
    }

    /// The input's smoothed rate, Hz, once measured.
    pub fn input_rate_hz(&self) -> Option<f64> {
        (self.smoothed_period_ns > 0.0).then(|| 1e9 / self.smoothed_period_ns)
    }

    /// The rate the corrector was made for, Hz, if it has one.
    pub fn corrector_rate_hz(&self) -> Option<f64> {
        self.corrector.rate_hz()
    }

    /// The gyro bias the attitude's covariance allows for: the residual after a model at its
    /// rate, else the sensor's own.
    fn bias_stddev(&self) -> f64 {
        if self.corrector.passes_through() || (self.rate_off && self.corrector.rate_hz().is_some() && !self.resampling) {
            self.cfg.uncorrected_bias_stddev.max(self.cfg.bias_stddev)
        } else {
            self.cfg.bias_stddev
        }
    }

    /// True while the smoothed input rate is off nominal by more than the tolerance.
    pub fn rate_off_nominal(&self) -> bool {
        self.rate_off
    }

    /// True while the input is fed to the model in the model's periods, its rate being off the
    /// model's ([`crate::resample`]).
    pub fn resampling(&self) -> bool {
        self.resampling
    }

    /// Decides whether to feed the model in its periods: when the smoothed input rate is off the
    /// model's by more than [`crate::model::RATE_TOLERANCE`], back at half that (a rate at the
    /// edge would reset the model at every wobble). A switch restarts the model's warm-up.
    fn update_resampling(&mut self) {
        let Some(model_rate) = self.corrector.rate_hz().filter(|_| self.periods.is_some()) else {
            return;
        };
        if !self.cfg.resample_to_model_rate || self.smoothed_period_ns <= 0.0 {
            return;
        }
        let off = (1e9 / self.smoothed_period_ns / model_rate - 1.0).abs();
        let tolerance = if self.resampling { 0.5 } else { 1.0 } * crate::model::RATE_TOLERANCE;
        if (off > tolerance) != self.resampling {
            self.resampling = !self.resampling;
            self.period_correction = Vector3::zeros();
            self.corrector.reset();
            self.since_reset = 0;
            self.counters.resets += 1;
            self.counters.resampling_switches += 1;
        }
    }

    /// Process one raw sample.
    pub fn push(&mut self, s: &ImuSample) -> Result<CorrectedImu, Dropped> {
        self.counters.received += 1;
        if !s.is_finite() {
            self.counters.dropped_non_finite += 1;
            return Err(Dropped::NonFinite);
        }
        if !s.is_plausible() {
            self.counters.dropped_implausible += 1;
            return Err(Dropped::Implausible);
        }
        let mut after_gap = false;
        // The body's turn since the previous sample (none across a gap or at the first).
        let mut turned = None;
        if let Some((t_last, w_last)) = self.last {
            let dt_ns = s.stamp_ns - t_last;
            if dt_ns == 0 {
                self.counters.dropped_duplicate_stamp += 1;
                return Err(Dropped::DuplicateStamp);
            }
            if dt_ns < 0 && !self.backwards_run.follows(s.stamp_ns) {
                self.counters.dropped_backwards_stamp += 1;
                return Err(Dropped::BackwardsStamp);
            }
            self.backwards_run.end();
            let jumped_back = dt_ns < 0;
            let period_before_ns = self.smoothed_period_ns;
            if !jumped_back {
                self.learn_period(dt_ns);
            }
            if jumped_back || self.gap_limit_ns().is_some_and(|l| dt_ns as f64 > l) {
                after_gap = true;
                if jumped_back {
                    self.counters.clock_jumps += 1;
                } else {
                    self.counters.gaps += 1;
                }
                self.counters.resets += 1;
                self.corrector.reset();
                self.since_reset = 0;
                if let Some(p) = self.periods.as_mut() {
                    p.reset();
                }
                self.period_correction = Vector3::zeros();
                // Hold the attitude over the hole: integrating a stale rate would invent motion.
                // A clock that went back says nothing of how long: a second's worth of gap.
                let held_s = if jumped_back { 1.0 } else { dt_ns as f64 * 1e-9 };
                self.attitude.covariance += Matrix3::identity() * (self.cfg.gap_variance_per_second * held_s);
                if !jumped_back && self.attitude.world_from_body.is_some() {
                    self.attitude.grow(held_s, 0.0, self.bias_stddev());
                }
            } else {
                self.count_missed(dt_ns, period_before_ns);
                let dt = dt_ns as f64 * 1e-9;
                turned = Some(w_last * dt);
                if let Some(q) = self.attitude.world_from_body {
                    self.attitude.world_from_body = Some(renormalize(q * exp(&(w_last * dt))));
                    self.attitude.grow(dt, self.cfg.angular_velocity_stddev, self.bias_stddev());
                }
            }
            self.last_dt_ns = dt_ns;
        }
        if self.clipping.push(s) {
            self.counters.saturated_samples += 1;
        }
        self.update_resampling();
        let window = self.corrector.window() as u64;
        // The periods run from the stream's start (or its last gap) whether the model is fed
        // them or not: a switch to them keeps their grid, as `eval` lays it over a recording.
        if let Some(periods) = self.periods.as_mut() {
            let (resampling, corrector, correction, steps) =
                (self.resampling, &mut self.corrector, &mut self.period_correction, &mut self.since_reset);
            periods.push(s, |_, gyro, accel| {
                if resampling {
                    *correction = corrector.step(&gyro, &accel) - gyro;
                    *steps += 1;
                }
            });
        }
        let (gyro, warming_up) = if self.resampling {
            // Warm until the model has seen a window of its periods.
            (s.gyro + self.period_correction, self.since_reset < window)
        } else {
            let warming_up = self.since_reset < window;
            self.since_reset += 1;
            (self.corrector.step(&s.gyro, &s.accel), warming_up)
        };
        if warming_up {
            self.counters.warmup_samples += 1;
        }
        self.last = Some((s.stamp_ns, gyro));
        self.counters.processed += 1;
        self.init_attitude(s, turned);
        let orientation = self.attitude.world_from_body.map(|q| (q, self.attitude.covariance));
        Ok(CorrectedImu {
            stamp_ns: s.stamp_ns,
            gyro,
            correction: gyro - s.gyro,
            accel: s.accel,
            gyro_variance: self.cfg.angular_velocity_stddev * self.cfg.angular_velocity_stddev,
            passed_through: self.corrector.passes_through(),
            orientation,
            warming_up,
            after_gap,
        })
    }

    /// `turned`: the body's rotation vector since the previous sample, from the corrected gyro.
    fn init_attitude(&mut self, s: &ImuSample, turned: Option<Vector3<f64>>) {
        let att = &mut self.attitude;
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
        if (s.stamp_ns - t0) as f64 * 1e-9 >= self.cfg.gravity_init_seconds {
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
                let tilt = self.cfg.initial_tilt_variance + spread + off.max(horizontal);
                att.world_from_body = Some(Attitude::from_gravity(&f));
                att.covariance = Matrix3::from_diagonal(&Vector3::new(tilt, tilt, self.cfg.initial_yaw_variance));
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

    /// A hole shorter than a gap: an interval of k of the stream's periods `p` (as it was before
    /// this interval) after a regular one
    /// stands for k − 1 samples that never arrived. Stamps taken on arrival (bursts of nearly
    /// equal stamps, then a pause) are not regular, and count nothing.
    fn count_missed(&mut self, dt_ns: i64, p: f64) {
        let regular = (self.last_dt_ns as f64 - p).abs() <= 0.25 * p;
        if self.gap_limit_ns().is_some() && p > 0.0 && regular && dt_ns as f64 >= 1.5 * p {
            self.counters.missed_samples += ((dt_ns as f64 / p).round() as u64).saturating_sub(1);
        }
    }

    /// An interval longer than this is a gap, ns.
    fn gap_limit_ns(&self) -> Option<f64> {
        self.slow_period_ns.or(self.nominal_period_ns).map(|p| self.cfg.gap_periods * p)
    }

    /// Collects one of the first intervals; the median of them once there are 8.
    fn first_intervals_median(&mut self, dt_ns: i64) -> Option<f64> {
        self.first_dts[self.n_first_dts] = dt_ns;
        self.n_first_dts += 1;
        (self.n_first_dts == self.first_dts.len()).then(|| {
            let mut d = self.first_dts;
            d.sort_unstable();
            (d[3] + d[4]) as f64 / 2.0
        })
    }

    /// Learn the nominal period from the first intervals (median of 8) if not given, then
    /// track the smoothed period to report rate changes.
    fn learn_period(&mut self, dt_ns: i64) {
        match self.nominal_period_ns {
            None => {
                if let Some(p) = self.first_intervals_median(dt_ns) {
                    self.nominal_period_ns = Some(p);
                    self.smoothed_period_ns = p;
                    self.period_learned = true;
                }
            }
            Some(p) => {
                // Under a nominal given (the model's), the smoothed rate starts from the median of
                // the first intervals: from the nominal, a 212-Hz stream took 90 samples to pass
                // 5 % off a 200-Hz model, and restarted a model already warming up.
                if !self.period_learned && self.n_first_dts < self.first_dts.len() {
                    if let Some(median) = self.first_intervals_median(dt_ns) {
                        if median > p * (1.0 + self.cfg.rate_tolerance) {
                            // Slower than the nominal: gaps are measured in its own period from
                            // here (40 Hz with 1 ms of jitter under a 200-Hz model had every other
                            // interval over 5 model periods, each a reset: it never warmed up).
                            self.slow_period_ns = Some(median);
                            self.smoothed_period_ns = median;
                        } else if self.gap_limit_ns().is_some_and(|l| median < l) {
                            self.smoothed_period_ns = median;
                        }
                    }
                }
                // A gap is not a rate change, but gaps in a row are: a stream slower than the
                // nominal (20 Hz into a 200-Hz model) made every sample a gap, unreported.
                if self.gap_limit_ns().is_some_and(|l| (dt_ns as f64) < l) {
                    self.smoothed_period_ns += 0.02 * (dt_ns as f64 - self.smoothed_period_ns);
                    self.consecutive_gaps = 0;
                } else {
                    self.consecutive_gaps += 1;
                }
                if self.consecutive_gaps >= RATE_FROM_GAPS {
                    self.consecutive_gaps = 0;
                    if self.period_learned {
                        // Learnt from a start-up burst: learn it again from what follows.
                        self.nominal_period_ns = None;
                        self.n_first_dts = 0;
                        self.counters.rate_changes += 1;
                        return;
                    }
                    // The nominal is the model's: keep it (and say the rate is off), but measure
                    // gaps in the stream's own period.
                    self.slow_period_ns = Some(dt_ns as f64);
                    self.smoothed_period_ns = dt_ns as f64;
                }
                let off = (self.smoothed_period_ns / p - 1.0).abs() > self.cfg.rate_tolerance || self.slow_period_ns.is_some();
                if off && !self.rate_off {
                    self.counters.rate_changes += 1;
                }
                self.rate_off = off;
                // Back at the nominal rate: gaps are the nominal's again.
                if self.slow_period_ns.is_some() && (self.smoothed_period_ns / p - 1.0).abs() <= self.cfg.rate_tolerance {
                    self.slow_period_ns = None;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::Recording;
    use crate::so3::integrate_gyro;

    fn stream(n: usize, dt_ns: i64) -> Vec<ImuSample> {
        (0..n)
            .map(|k| {
                let t = k as f64 * dt_ns as f64 * 1e-9;
                ImuSample {
                    stamp_ns: 1_000_000 + k as i64 * dt_ns,
                    gyro: Vector3::new(0.3 * (t * 2.0).sin(), 0.1, -0.2 * t.cos()) + Vector3::new(0.01, 0.02, 0.03),
                    accel: Vector3::new(0.0, 0.0, 9.81),
                }
            })
            .collect()
    }

    #[test]
    fn orientation_equals_offline_integration() {
        let imu = stream(2000, 5_000_000);
        let bias = Vector3::new(0.01, 0.02, 0.03);
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias }), PipelineConfig { gravity_init_seconds: 0.0, ..Default::default() });
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let q0 = out[0].orientation.unwrap().0;
        let offline = integrate_gyro(&imu, q0, |n| imu[n].gyro - bias);
        let worst = out.iter().zip(&offline).map(|(o, q)| o.orientation.unwrap().0.angle_to(q)).fold(0.0, f64::max);
        assert!(worst < 1e-12, "{worst}");
        assert!((out[5].correction + bias).norm() < 1e-15);
        let _ = Recording::default();
    }

    #[test]
    fn bad_samples_are_dropped_and_counted() {
        let mut imu = stream(100, 5_000_000);
        imu[10].gyro.y = f64::NAN;
        imu[20].stamp_ns = imu[19].stamp_ns;
        imu[30].stamp_ns = imu[29].stamp_ns - 1;
        imu[40].gyro.z = 1e30;
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let results: Vec<_> = imu.iter().map(|s| p.push(s)).collect();
        assert_eq!(results[10], Err(Dropped::NonFinite));
        assert_eq!(results[40], Err(Dropped::Implausible));
        assert_eq!(results[20], Err(Dropped::DuplicateStamp));
        assert_eq!(results[30], Err(Dropped::BackwardsStamp));
        let c = p.counters();
        assert_eq!(
            (c.received, c.processed, c.dropped_non_finite, c.dropped_implausible, c.dropped_duplicate_stamp, c.dropped_backwards_stamp),
            (100, 96, 1, 1, 1, 1)
        );
        assert_eq!(c.dropped(), 4);
    }

    /// Without a model the attitude's σ allows for the gyro's own bias, not a model's residual:
    /// after 10 s at 10 mrad/s the tilt σ is about 0.1 rad (at 1 mrad/s, 0.01, both beside
    /// the initial 0.01 rad).
    #[test]
    fn an_uncorrected_gyro_states_its_own_bias() {
        let cfg = PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..Default::default() };
        let tilt_sigma = |corrector: Box<dyn GyroCorrector>| {
            let mut p = Pipeline::new(corrector, cfg.clone());
            let last = stream(2001, 5_000_000).iter().map(|s| p.push(s).unwrap()).last().unwrap();
            last.orientation.unwrap().1[(0, 0)].sqrt()
        };
        let corrected = tilt_sigma(Box::new(BiasCorrector { bias: Vector3::zeros() }));
        let passed = tilt_sigma(Box::new(PassThrough));
        assert!((corrected - 0.0142).abs() < 0.001 && (passed - 0.1005).abs() < 0.002, "{corrected} {passed}");
    }

    #[test]
    fn a_gap_resets_and_holds_the_attitude() {
        let mut imu = stream(400, 5_000_000);
        for s in &mut imu[200..] {
            s.stamp_ns += 1_000_000_000; // one second of nothing
        }
        let mut p = Pipeline::new(
            Box::new(BiasCorrector { bias: Vector3::zeros() }),
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..Default::default() },
        );
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(out[200].after_gap && !out[199].after_gap && !out[201].after_gap);
        assert_eq!(p.counters().gaps, 1);
        let (q199, p199) = out[199].orientation.unwrap();
        let (q200, p200) = out[200].orientation.unwrap();
        assert!(q199.angle_to(&q200) < 1e-15, "held across the gap");
        assert!(p200[(0, 0)] > p199[(0, 0)] + 0.2, "flagged by a larger covariance");
        assert_eq!(p.counters().rate_changes, 0);
    }

    /// Holes shorter than a gap are bridged and their missing samples counted, at the model's
    /// rate and at a stream's own; stamps taken on arrival in bursts count nothing.
    #[test]
    fn holes_shorter_than_a_gap_are_counted() {
        let cfg = PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..Default::default() };
        let bias = || Box::new(BiasCorrector { bias: Vector3::zeros() });
        // 200 Hz, samples 100 and 101 lost (a 15-ms interval): 2 missed, no gap.
        let mut p = Pipeline::new(bias(), cfg.clone());
        for (i, s) in stream(300, 5_000_000).iter().enumerate() {
            if i != 100 && i != 101 {
                p.push(s).unwrap();
            }
        }
        assert_eq!((p.counters().missed_samples, p.counters().gaps, p.counters().resets), (2, 0, 0));
        // 1 kHz into the 200-Hz model: holes of 3 and 11 samples.
        let mut p = Pipeline::new(bias(), cfg.clone());
        for (i, s) in stream(3000, 1_000_000).iter().enumerate() {
            if !(1000..1003).contains(&i) && !(2000..2011).contains(&i) {
                p.push(s).unwrap();
            }
        }
        assert_eq!((p.counters().missed_samples, p.counters().gaps), (14, 0));
        // Arrival-stamped bursts: 20 samples 50 µs apart every 20 ms lose nothing.
        let mut p = Pipeline::new(bias(), PipelineConfig { nominal_rate_hz: 0.0, ..cfg });
        let mut imu = stream(2000, 1_000_000);
        imu.iter_mut().enumerate().for_each(|(i, s)| s.stamp_ns = (i / 20) as i64 * 20_000_000 + (i % 20) as i64 * 50_000);
        imu.iter().for_each(|s| {
            let _ = p.push(s);
        });
        assert_eq!(p.counters().missed_samples, 0);
    }

    /// One stamp three hours ahead (or a source whose clock restarts) is followed after
    /// [`CLOCK_JUMP_SAMPLES`] samples, as after a gap; a single backwards stamp is only dropped.
    #[test]
    fn a_clock_that_jumps_back_is_followed() {
        let mut imu = stream(400, 5_000_000);
        imu[100].stamp_ns += 3 * 3600 * 1_000_000_000;
        imu[300].stamp_ns -= 1_000_000_000;
        let mut p = Pipeline::new(
            Box::new(BiasCorrector { bias: Vector3::zeros() }),
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..Default::default() },
        );
        let out: Vec<Result<CorrectedImu, Dropped>> = imu.iter().map(|s| p.push(s)).collect();
        assert!(out[100].as_ref().unwrap().after_gap, "the jump ahead is a gap");
        let back = 100 + CLOCK_JUMP_SAMPLES as usize;
        assert!(out[101..back].iter().all(|o| matches!(o, Err(Dropped::BackwardsStamp))));
        assert!(out[back].as_ref().unwrap().after_gap, "followed at sample {back}");
        assert!(out[back + 1..300].iter().all(|o| o.as_ref().is_ok_and(|c| !c.after_gap)));
        assert!(matches!(out[300], Err(Dropped::BackwardsStamp)));
        assert!(out[301..].iter().all(Result::is_ok), "one glitch is not a jump");
        let c = p.counters();
        assert_eq!((c.clock_jumps, c.gaps, c.dropped_backwards_stamp), (1, 1, CLOCK_JUMP_SAMPLES as u64));
    }

    /// A stream slower than the model's rate (every interval a gap) is reported as a rate
    /// change; a period learnt from a start-up burst is learnt again from what follows.
    #[test]
    fn gaps_in_a_row_are_a_rate() {
        let slow = stream(100, 50_000_000);
        let mut p = Pipeline::new(
            Box::new(BiasCorrector { bias: Vector3::zeros() }),
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..Default::default() },
        );
        let out: Vec<CorrectedImu> = slow.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(p.rate_off_nominal() && p.counters().rate_changes == 1, "{:?}", p.counters());
        // Gaps are then measured in the stream's own period: corrected and integrated again.
        assert!(out[20..].iter().all(|c| !c.after_gap && c.orientation.is_some()), "{:?}", p.counters());
        assert_eq!(p.counters().gaps, RATE_FROM_GAPS as u64 - 1, "the last interval of the run sets the rate");
        // Back at the model's rate, a hole is a gap again.
        let mut back = stream(400, 5_000_000);
        let t0 = slow.last().unwrap().stamp_ns + 50_000_000;
        back.iter_mut().for_each(|s| s.stamp_ns += t0);
        back[399].stamp_ns += 100_000_000;
        let out: Vec<CorrectedImu> = back.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(!p.rate_off_nominal() && out[399].after_gap, "{:?}", p.counters());
        let mut burst = stream(20, 500_000);
        let t0 = burst.last().unwrap().stamp_ns;
        burst.extend(stream(400, 5_000_000).into_iter().map(|mut s| {
            s.stamp_ns += t0;
            s
        }));
        let mut p = Pipeline::new(
            Box::new(BiasCorrector { bias: Vector3::zeros() }),
            PipelineConfig { gravity_init_seconds: 0.0, ..Default::default() },
        );
        let out: Vec<CorrectedImu> = burst.iter().map(|s| p.push(s).unwrap()).collect();
        assert_eq!(p.nominal_rate_hz().map(f64::round), Some(200.0));
        assert!(out[100..].iter().all(|c| !c.after_gap), "the orientation is integrated again");
    }

    #[test]
    fn gravity_initialises_roll_and_pitch() {
        let mut imu = stream(300, 5_000_000);
        let tilt = UnitQuaternion::from_euler_angles(0.2, -0.3, 0.0);
        for s in &mut imu {
            // At rest: a constant specific force is a platform that does not turn.
            s.gyro = Vector3::zeros();
            s.accel = tilt.inverse() * Vector3::new(0.0, 0.0, 9.81);
        }
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(out[50].orientation.is_none(), "no orientation before 0.5 s of gravity");
        let k = out.iter().position(|o| o.orientation.is_some()).unwrap();
        assert_eq!(k, 100);
        let (q, cov) = out[k].orientation.unwrap();
        let (r, pch, _) = q.euler_angles();
        assert!((r - 0.2).abs() < 1e-9 && (pch + 0.3).abs() < 1e-9);
        assert!(cov[(2, 2)] > 1.0, "yaw unknown");
        // At rest the tilt variance is the configured one; then it grows by the white noise and
        // the residual bias: σ_b·t dominates, about (1 mrad/s · 1 s)² after 200 samples.
        assert!((cov[(0, 0)] - 1e-4).abs() < 1e-12, "{}", cov[(0, 0)]);
        let (_, last) = out[299].orientation.unwrap();
        let t = 199.0 * 5e-3;
        let expected = 1e-4 + 199.0 * (0.005f64 * 5e-3).powi(2) + (1e-3f64 * t).powi(2);
        assert!((last[(0, 0)] - expected).abs() < 1e-12, "{} vs {expected}", last[(0, 0)]);
        // Moving while the gravity is averaged (a swinging accelerometer), the tilt is wider.
        for (k, s) in imu.iter_mut().enumerate() {
            s.accel += Vector3::new(3.0 * (k as f64 * 0.3).sin(), 0.0, 0.0);
        }
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let (_, moving) = imu.iter().filter_map(|s| p.push(s).unwrap().orientation).next().unwrap();
        assert!(moving[(0, 0)] > 0.03, "{}", moving[(0, 0)]);
    }

    /// A car starting in a bend: the centripetal acceleration is not gravity. The attitude
    /// waits for the bend to end; a platform that never stops turning gets it after ten
    /// seconds, with a tilt variance that covers the horizontal acceleration.
    #[test]
    fn the_initial_attitude_waits_for_a_turn_to_end() {
        let bend = |s: &mut ImuSample, turning: bool| {
            s.gyro = if turning { Vector3::new(0.0, 0.0, 0.4) } else { Vector3::zeros() };
            s.accel = Vector3::new(0.0, if turning { 3.9 } else { 0.0 }, 9.81);
        };
        let mut imu = stream(1200, 5_000_000);
        imu.iter_mut().enumerate().for_each(|(k, s)| bend(s, k < 600));
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let k = out.iter().position(|o| o.orientation.is_some()).unwrap();
        assert!(k >= 600, "set at sample {k}, in the bend");
        let (q, cov) = out[k].orientation.unwrap();
        let (r, pch, _) = q.euler_angles();
        assert!(r.abs() < 1e-6 && pch.abs() < 1e-6 && cov[(0, 0)] < 1e-3, "{r} {pch} {cov}");
        // Turning for ever: set after 20 intervals, its stated tilt σ at least the 21.7° it is off.
        let mut imu = stream(3000, 5_000_000);
        imu.iter_mut().for_each(|s| bend(s, true));
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let k = out.iter().position(|o| o.orientation.is_some()).unwrap();
        assert!((2000..2200).contains(&k), "{k}");
        let (q, cov) = out[k].orientation.unwrap();
        let off = q.euler_angles().0.abs();
        assert!(
            off.to_degrees() > 20.0 && cov[(0, 0)].sqrt() >= 0.99 * off,
            "{} vs σ {}",
            off.to_degrees(),
            cov[(0, 0)].sqrt().to_degrees()
        );
    }

    /// A platform turning while the gravity is averaged: the samples' gravity is turned with
    /// the body, so the attitude set is the one at the interval's end, not the mean of the
    /// turn (which was 7.0° off here).
    #[test]
    fn a_turn_while_gravity_is_averaged_does_not_tilt_the_start() {
        let (w, dt) = (Vector3::new(0.5, 0.0, 0.2), 0.005);
        let start = UnitQuaternion::from_euler_angles(0.1, -0.05, 0.3);
        let truth = |k: usize| start * exp(&(w * (k as f64 * dt)));
        let imu: Vec<ImuSample> = (0..2400)
            .map(|k| ImuSample {
                stamp_ns: 1_000_000 + k as i64 * 5_000_000,
                gyro: w,
                accel: truth(k).inverse() * Vector3::new(0.0, 0.0, 9.81),
            })
            .collect();
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let k = out.iter().position(|o| o.orientation.is_some()).unwrap();
        let (q, _) = out[k].orientation.unwrap();
        // Gravity gives roll and pitch: compare the body's up vector.
        let up = |q: &UnitQuaternion<f64>| q.inverse() * Vector3::z();
        let tilt_error = up(&q).angle(&up(&truth(k)));
        assert!(tilt_error < 1e-6, "{}° off at sample {k}", tilt_error.to_degrees());
    }

    #[test]
    fn rate_change_is_reported_once() {
        let mut imu = stream(600, 5_000_000);
        for (k, s) in imu.iter_mut().enumerate().skip(300) {
            s.stamp_ns = imu_stamp(k);
        }
        fn imu_stamp(k: usize) -> i64 {
            1_000_000 + 300 * 5_000_000 + (k as i64 - 300) * 2_500_000
        }
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig::default());
        for s in &imu {
            p.push(s).unwrap();
        }
        assert_eq!(p.nominal_rate_hz().map(|r| r.round()), Some(200.0));
        assert_eq!(p.counters().rate_changes, 1);
        assert!(p.rate_off_nominal());
    }

    /// A corrector made for 200 Hz whose correction depends on how many samples its window
    /// holds: minus half the mean of its last 8 inputs.
    struct WindowMean(std::collections::VecDeque<Vector3<f64>>);

    impl GyroCorrector for WindowMean {
        fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
            self.0.push_back(*gyro);
            if self.0.len() > 8 {
                self.0.pop_front();
            }
            gyro - self.0.iter().sum::<Vector3<f64>>() / (2.0 * self.0.len() as f64)
        }
        fn reset(&mut self) {
            self.0.clear();
        }
        fn window(&self) -> usize {
            8
        }
        fn rate_hz(&self) -> Option<f64> {
            Some(200.0)
        }
        fn name(&self) -> &str {
            "window mean"
        }
    }

    /// Each sample of `slow` held five times over the interval to the next, at 1 kHz.
    fn held_five_times(slow: &[ImuSample]) -> Vec<ImuSample> {
        let dt = (slow[1].stamp_ns - slow[0].stamp_ns) / 5;
        slow.iter().flat_map(|s| (0..5).map(move |j| ImuSample { stamp_ns: s.stamp_ns + j * dt, ..*s })).collect()
    }

    /// A 1-kHz stream into a 200-Hz model is fed to it in its 5-ms periods: the five samples
    /// of a period get the correction the model gives the period before on the 200-Hz stream,
    /// and the warm-up lasts the model's window in periods.
    #[test]
    fn a_faster_stream_runs_the_model_in_its_periods() {
        let slow = stream(400, 5_000_000);
        let cfg = PipelineConfig { gravity_init_seconds: 0.0, ..Default::default() };
        let mut at_rate = Pipeline::new(Box::new(WindowMean(Default::default())), cfg.clone());
        let reference: Vec<CorrectedImu> = slow.iter().map(|s| at_rate.push(s).unwrap()).collect();
        assert!(!at_rate.resampling());
        let fast = held_five_times(&slow);
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), cfg.clone());
        let out: Vec<CorrectedImu> = fast.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(p.resampling() && p.rate_off_nominal(), "{:?}", p.counters());
        // The switch came within the first samples; from 8 periods after it the windows agree.
        for n in 40..slow.len() {
            let (first, last) = (&out[5 * n], &out[5 * n + 4]);
            assert_eq!(first.stamp_ns, slow[n].stamp_ns);
            let want = reference[n - 1].correction;
            assert!((first.correction - want).norm() < 1e-12, "period {n}: {} against {want}", first.correction);
            assert!((last.correction - want).norm() < 1e-12 && (first.gyro - slow[n].gyro - want).norm() < 1e-12, "period {n}");
        }
        let warm = out.iter().rposition(|o| o.warming_up).unwrap();
        assert!((35..60).contains(&warm), "warm until sample {warm}: 8 periods are 40 samples");
        // The covariance allows for what a model corrects, as at its rate.
        let sigma = |o: &CorrectedImu| o.orientation.unwrap().1[(0, 0)].sqrt();
        assert!(sigma(out.last().unwrap()) < 1.1 * sigma(reference.last().unwrap()));
        // Without resampling the model counts samples: another output, and the larger bias.
        let mut direct = Pipeline::new(Box::new(WindowMean(Default::default())), PipelineConfig { resample_to_model_rate: false, ..cfg });
        let raw: Vec<CorrectedImu> = fast.iter().map(|s| direct.push(s).unwrap()).collect();
        assert!(!direct.resampling() && direct.rate_off_nominal());
        assert!((raw[5 * 300].gyro - reference[300].gyro).norm() > 1e-3);
        assert!(sigma(raw.last().unwrap()) > 2.0 * sigma(reference.last().unwrap()));
    }

    /// A stream 6 % off the model's rate is known from its first intervals: the model is fed
    /// its periods from the tenth sample, one switch (it took 90 samples from the nominal).
    #[test]
    fn a_rate_just_off_is_resampled_from_the_start() {
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), PipelineConfig::default());
        for (k, s) in stream(2000, 4_716_981).iter().enumerate() {
            p.push(s).unwrap();
            assert_eq!(p.resampling(), k >= 8, "sample {k}");
        }
        assert_eq!(p.counters().resampling_switches, 1);
    }

    /// A 40-Hz stream with ±1 ms of jitter under a 200-Hz model: its gaps are measured in its
    /// own period from the eighth interval, so it warms up and is integrated (before, every
    /// other interval was over 5 model periods, a reset each, and it never left the warm-up).
    #[test]
    fn a_slow_jittered_stream_warms_up() {
        let mut imu = stream(2400, 25_000_000);
        for (k, s) in imu.iter_mut().enumerate() {
            s.stamp_ns += [1_000_000, -1_000_000, 400_000, -600_000][k % 4];
        }
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), PipelineConfig::default());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(p.counters().gaps <= 7, "{:?}", p.counters());
        assert!(!out.last().unwrap().warming_up && p.resampling() && p.rate_off_nominal(), "{:?}", p.counters());
        assert!(out.last().unwrap().orientation.is_some());
    }

    /// A gap restarts the periods and the model's warm-up; a stream back at the model's rate
    /// is fed to it sample by sample again.
    #[test]
    fn resampling_restarts_after_a_gap_and_ends_at_the_models_rate() {
        let mut fast = held_five_times(&stream(200, 5_000_000));
        let t_end = fast.last().unwrap().stamp_ns;
        fast.extend(stream(200, 1_000_000).into_iter().map(|s| ImuSample { stamp_ns: s.stamp_ns + t_end + 1_000_000_000, ..s }));
        let t_end = fast.last().unwrap().stamp_ns;
        let slow = stream(600, 5_000_000);
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), PipelineConfig::default());
        let mut out = Vec::new();
        for s in &fast {
            out.push(p.push(s).unwrap());
        }
        let gap = out.iter().position(|o| o.after_gap).unwrap();
        assert!(p.resampling() && out[gap].warming_up && out[gap + 30].warming_up && !out[gap + 60].warming_up);
        for s in &slow {
            p.push(&ImuSample { stamp_ns: s.stamp_ns + t_end, ..*s }).unwrap();
        }
        assert!(!p.resampling(), "{:?}", p.counters());
    }
}
