//! Standstill detection and the gyro bias measured there: this power-on's turn-on constant.
//!
//! A MEMS gyro's bias is drawn anew at every power-on (a consumer part: up to a few °/s), far
//! more than a learned model can tell from motion; at rest the gyro reads that bias alone. The
//! stream is cut into windows of short blocks; a window is still when
//! - the block means of every gyro axis span less than `max_gyro_spread` and those of every
//!   accelerometer axis less than `max_accel_spread` (block means, not samples: a standing
//!   robot's motors or engine vibrate, their block means stay put);
//! - its mean specific force is gravity (within `max_gravity_error`);
//! - its mean rate is a plausible bias (≤ `max_bias`): faster is a turn;
//! - gravity has not turned in the body since the standstill began (≤ `max_tilt_change`): a
//!   slow turn about a horizontal axis tilts it, and a standstill that tilts is dropped whole,
//!   unless it was level for at least two windows first (a rest that ended in a slow turn:
//!   that rest is kept, its variance widened by the turn rate its tilt allows);
//! - after an earlier standstill, its mean is within `max_bias_change` (plus 5 σ) of the
//!   estimate: a steady turn about gravity reads like a bias to one IMU, and it is at least not
//!   mixed into a bias already measured.
//!
//! Consecutive still windows are one standstill; its mean is fused with what earlier
//! standstills measured (their variance grown by the bias's random walk since). A steady turn
//! about gravity slower than `max_bias` at the *first* standstill cannot be told from a bias by
//! an IMU alone: that is the stated limit (docs/poweron.md). Per sample: no allocation.

use crate::setting::InvalidSetting;
use nalgebra::Vector3;

use crate::core::{ImuSample, STANDARD_GRAVITY};
use crate::motion_bias::{MotionBias, MotionBiasConfig};

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
            max_gravity_error: 1.0,
            max_bias: 0.15,
            max_tilt_change: 0.02,
            max_bias_change: 0.01,
            bias_random_walk: 1e-5,
            max_sample_gap_s: 0.1,
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
        if !(self.bias_random_walk.is_finite() && self.bias_random_walk >= 0.0) {
            return Err(format!("standstill.bias_random_walk must be finite and ≥ 0, not {}", self.bias_random_walk).into());
        }
        if !(2..=MAX_BLOCKS).contains(&self.blocks) {
            return Err(format!("standstill.blocks must be 2 … {MAX_BLOCKS}, not {}", self.blocks).into());
        }
        self.motion.validate().map_err(|e| e.within("motion").within("standstill"))
    }
}

/// The turn-on bias as measured at standstills, with its variance.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BiasEstimate {
    /// rad/s, IMU axes.
    pub bias: Vector3<f64>,
    /// Per-axis variance at [`Self::at_ns`], (rad/s)².
    pub variance: Vector3<f64>,
    /// The end of the last still window measured, ns.
    pub at_ns: i64,
    /// Seconds of standstill it rests on.
    pub still_s: f64,
}

impl BiasEstimate {
    /// Per-axis variance at `t_ns`, grown by the random walk since it was measured.
    pub fn variance_at(&self, t_ns: i64, random_walk: f64) -> Vector3<f64> {
        let dt = ((t_ns - self.at_ns) as f64 * 1e-9).max(0.0);
        self.variance.add_scalar(random_walk * random_walk * dt)
    }

    /// The largest per-axis standard deviation at `t_ns`, rad/s.
    pub fn stddev_at(&self, t_ns: i64, random_walk: f64) -> f64 {
        self.variance_at(t_ns, random_walk).max().sqrt()
    }
}

/// What earlier power-ons of the IMU predict for this one's bias, per axis
/// ([`crate::bias_memory`] makes it).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BiasPrediction {
    /// The remembered mean on the axes it is removed from, 0 elsewhere, rad/s.
    pub bias: Vector3<f64>,
    /// The variance of this power-on's bias about [`Self::bias`], (rad/s)²: the prediction
    /// interval's on an axis removed, the mean's square plus it elsewhere.
    pub variance: Vector3<f64>,
    /// The axes whose remembered mean is removed.
    pub applied: [bool; 3],
    /// Earlier power-ons it rests on.
    pub power_ons: usize,
}

impl BiasPrediction {
    pub fn applies_any(&self) -> bool {
        self.applied.iter().any(|&a| a)
    }

    /// What it predicts, in words (the log, /diagnostics `power_on_bias_memory`).
    pub fn describe(&self) -> String {
        if !self.applies_any() {
            return format!(
                "{} earlier power-ons do not predict this one's bias (it changes more between them than it is large)",
                self.power_ons
            );
        }
        let axes: Vec<String> =
            (0..3).filter(|&k| self.applied[k]).map(|k| format!("{} {:.5}", ["x", "y", "z"][k], self.bias[k])).collect();
        format!(
            "{} earlier power-ons predict {} rad/s (σ {:.1e}): removed until the first standstill",
            self.power_ons,
            axes.join(", "),
            (0..3).filter(|&k| self.applied[k]).map(|k| self.variance[k]).fold(0.0, f64::max).sqrt()
        )
    }

    /// Where this power-on's standstills measured a bias outside the prediction (beyond 3 σ of
    /// the two together on an axis it was removed from): another IMU under the same memory, or
    /// one whose bias no longer repeats. Said, for the log and /diagnostics.
    pub fn contradicted_by(&self, measured: &BiasEstimate) -> Option<String> {
        let outside: Vec<String> = (0..3)
            .filter(|&k| self.applied[k])
            .filter(|&k| (measured.bias[k] - self.bias[k]).abs() > 3.0 * (self.variance[k] + measured.variance[k]).sqrt())
            .map(|k| format!("{} {:.5} against {:.5} ± {:.5}", ["x", "y", "z"][k], measured.bias[k], self.bias[k], self.variance[k].sqrt()))
            .collect();
        (!outside.is_empty()).then(|| {
            format!(
                "the standstills measured a bias outside what the earlier power-ons predicted ({} rad/s): another IMU, or one whose bias no longer repeats",
                outside.join(", ")
            )
        })
    }

    /// As a bias estimate in force at `now_ns` (no standstill of this power-on behind it).
    pub fn as_estimate(&self, now_ns: i64) -> BiasEstimate {
        BiasEstimate { bias: self.bias, variance: self.variance, at_ns: now_ns, still_s: 0.0 }
    }
}

/// Why a window was not still (counted).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotStill {
    /// Its block means moved, or its specific force is not gravity.
    Moving,
    /// Its mean rate is above `max_bias`: a turn.
    Turning,
    /// Gravity turned in the body since the standstill began.
    Tilting,
    /// Its mean is off the estimate by more than `max_bias_change`: a slow turn about gravity,
    /// or a bias that jumped (re-take the estimate to accept it).
    Inconsistent,
}

/// A window judged, reported by [`PowerOnBias::push`] on the sample after its last.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WindowVerdict {
    /// Still from `start_ns` to `end_ns` (the stamp of the sample after it): the body did not
    /// turn, and its time-weighted mean rate `hold_rate` is what the gyro read there.
    Still {
        start_ns: i64,
        end_ns: i64,
        hold_rate: Vector3<f64>,
    },
    NotStill(NotStill),
}

/// Counts of what the detector judged (published on /diagnostics).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct StandstillCounters {
    pub still_windows: u64,
    /// Standstills measured (runs of still windows).
    pub standstills: u64,
    pub moving_windows: u64,
    pub turning_windows: u64,
    pub tilting_windows: u64,
    pub inconsistent_windows: u64,
    /// Windows broken by a gap or a stamp that went back.
    pub interrupted_windows: u64,
}

/// Sums over one block or window.
#[derive(Debug, Clone, Copy)]
struct Sums {
    gyro: Vector3<f64>,
    accel: Vector3<f64>,
    n: u32,
}

impl Sums {
    const ZERO: Sums = Sums { gyro: Vector3::new(0.0, 0.0, 0.0), accel: Vector3::new(0.0, 0.0, 0.0), n: 0 };
}

/// A standstill's gravity may turn by this fraction of `max_tilt_change` and still count as
/// level: where a standstill ends tilting, its windows up to the one before the last level one
/// are kept.
const LEVEL_FRACTION: f64 = 0.25;

/// One standstill in progress: consecutive still windows.
#[derive(Debug, Clone, Copy)]
struct Run {
    sums: RunSums,
    /// Its first window's gravity direction, and that window's middle.
    gravity: Vector3<f64>,
    first_mid_ns: i64,
    /// Its sums up to the window before the last one whose gravity was within
    /// `LEVEL_FRACTION × max_tilt_change` of the first's: what was a rest, should it end in a
    /// slow turn.
    level: Option<RunSums>,
}

/// The sums over a run's windows.
#[derive(Debug, Clone, Copy)]
struct RunSums {
    start_ns: i64,
    end_ns: i64,
    gyro_sum: Vector3<f64>,
    n: u64,
    /// Sum and sum of squares of its block means, per axis: the mean's variance.
    block_sum: Vector3<f64>,
    block_sq: Vector3<f64>,
    blocks: u32,
}

impl RunSums {
    fn mean(&self) -> Vector3<f64> {
        self.gyro_sum / self.n.max(1) as f64
    }

    /// The mean's per-axis variance from the scatter of its block means.
    fn variance(&self) -> Vector3<f64> {
        let k = self.blocks.max(2) as f64;
        let m = self.block_sum / k;
        (self.block_sq / k - m.component_mul(&m)).map(|v| v.max(0.0) * k / (k - 1.0) / k)
    }

    fn seconds(&self) -> f64 {
        (self.end_ns - self.start_ns) as f64 * 1e-9
    }

    /// What these windows measured, with `extra_variance` per axis added.
    fn estimate(&self, extra_variance: f64) -> BiasEstimate {
        let variance = self.variance().add_scalar(extra_variance);
        BiasEstimate { bias: self.mean(), variance, at_ns: self.end_ns, still_s: self.seconds() }
    }
}

/// The streaming standstill detector and the per-power-on bias it measures.
#[derive(Debug, Clone)]
pub struct PowerOnBias {
    cfg: StandstillConfig,
    block_ns: i64,
    last: Option<(i64, Vector3<f64>)>,
    block: Sums,
    block_start_ns: i64,
    /// The window's completed blocks' means.
    gyro_means: [Vector3<f64>; MAX_BLOCKS],
    accel_means: [Vector3<f64>; MAX_BLOCKS],
    blocks_done: usize,
    window: Sums,
    window_start_ns: Option<i64>,
    /// ∫ω dt over the window so far, and its duration, s.
    window_turn: Vector3<f64>,
    window_s: f64,
    run: Option<Run>,
    /// The estimate before the current run (what the run is fused with).
    prior: Option<BiasEstimate>,
    estimate: Option<BiasEstimate>,
    counters: StandstillCounters,
    /// The bias seen in motion (unless `in_motion: off`).
    motion: Option<MotionBias>,
}

impl PowerOnBias {
    pub fn new(cfg: StandstillConfig) -> Self {
        let block_ns = (cfg.window_s / cfg.blocks.clamp(2, MAX_BLOCKS) as f64 * 1e9) as i64;
        PowerOnBias {
            cfg,
            block_ns: block_ns.max(1),
            last: None,
            block: Sums::ZERO,
            block_start_ns: 0,
            gyro_means: [Vector3::zeros(); MAX_BLOCKS],
            accel_means: [Vector3::zeros(); MAX_BLOCKS],
            blocks_done: 0,
            window: Sums::ZERO,
            window_start_ns: None,
            window_turn: Vector3::zeros(),
            window_s: 0.0,
            run: None,
            prior: None,
            estimate: None,
            counters: StandstillCounters::default(),
            motion: (cfg.in_motion != InMotion::Off).then(|| MotionBias::new(cfg.motion)),
        }
    }

    pub fn config(&self) -> &StandstillConfig {
        &self.cfg
    }

    /// The bias in force, if any standstill was measured.
    pub fn estimate(&self) -> Option<&BiasEstimate> {
        self.estimate.as_ref()
    }

    /// The bias to subtract now: the standstills' (and, per `in_motion`, the one seen in
    /// motion); zero before any.
    pub fn bias(&self) -> Vector3<f64> {
        self.in_force(0).map_or(Vector3::zeros(), |e| e.bias)
    }

    /// The bias in force and its variance: a standstill's, or the one seen in motion where
    /// `in_motion` uses it (stamped `now_ns`, its variance the filter's own).
    pub fn in_force(&self, now_ns: i64) -> Option<BiasEstimate> {
        let from_motion = |m: &MotionBias| BiasEstimate {
            bias: m.applied().0,
            variance: m.applied().1,
            at_ns: now_ns,
            still_s: self.estimate.map_or(0.0, |e| e.still_s),
        };
        // Before the first standstill, what earlier power-ons predict comes first: it covers
        // the axis about gravity, which motion reveals only as the body turns.
        if let Some(r) = self.cfg.remembered.filter(|r| self.estimate.is_none() && r.applies_any()) {
            return Some(r.as_estimate(now_ns));
        }
        match (self.cfg.in_motion, self.motion.as_ref()) {
            (InMotion::Always | InMotion::UntilStandstill, Some(m)) if self.estimate.is_none() => m.applies_any().then(|| from_motion(m)),
            (InMotion::Always, Some(m)) if !m.misfit() => Some(from_motion(m)),
            _ => self.estimate,
        }
    }

    /// Where [`Self::in_force`] comes from: `standstill`, `memory` (earlier power-ons),
    /// `motion`, `motion, across up` (not about the up of a body that stayed near level), or ""
    /// (nothing yet).
    pub fn source(&self) -> &'static str {
        if self.estimate.is_none() && self.cfg.remembered.is_some_and(|r| r.applies_any()) {
            return "memory";
        }
        let applies = self.motion.as_ref().is_some_and(MotionBias::applies_any);
        let fits = self.motion.as_ref().is_some_and(|m| !m.misfit());
        match (self.cfg.in_motion, applies, self.estimate.is_some()) {
            (InMotion::Always, _, true) if fits => "standstill, then motion",
            (_, _, true) => "standstill",
            (InMotion::Always | InMotion::UntilStandstill, true, false) => {
                if self.motion.as_ref().is_some_and(MotionBias::withholds_about_up) {
                    "motion, across up"
                } else {
                    "motion"
                }
            }
            _ => "",
        }
    }

    /// The filter of the bias seen in motion, if it runs.
    pub fn motion(&self) -> Option<&MotionBias> {
        self.motion.as_ref()
    }

    pub fn counters(&self) -> &StandstillCounters {
        &self.counters
    }

    /// True while the last window judged was still (the platform is standing).
    pub fn standing(&self) -> bool {
        self.run.is_some()
    }

    /// The start of the window in progress, ns (the sample that opened it).
    pub fn window_start_ns(&self) -> Option<i64> {
        self.window_start_ns
    }

    /// Forgets every standstill measured: the next one measures the bias afresh (a re-take on
    /// demand, or a new power-on).
    pub fn retake(&mut self) {
        self.interrupt();
        self.prior = None;
        self.estimate = None;
        if let Some(m) = self.motion.as_mut() {
            m.restart();
        }
    }

    /// Breaks the window and the standstill in progress (a gap, a clock that went back); what
    /// was measured stays.
    pub fn interrupt(&mut self) {
        if self.window_start_ns.is_some() {
            self.counters.interrupted_windows += 1;
        }
        self.end_run();
        self.clear_window();
        self.last = None;
    }

    /// One sample, in stamp order. Returns the verdict on a window this sample closed.
    pub fn push(&mut self, s: &ImuSample) -> Option<WindowVerdict> {
        // Until a standstill rules (`until_standstill`), or always: a filter whose output is not
        // used is not stepped (a retake, or a dropped standstill, restarts its attitude).
        let in_use = self.cfg.in_motion == InMotion::Always || self.estimate.is_none();
        if let (Some(m), true) = (self.motion.as_mut(), in_use) {
            m.push(s);
        }
        if let Some((t, _)) = self.last {
            let dt = s.stamp_ns - t;
            if dt <= 0 || dt as f64 * 1e-9 > self.cfg.max_sample_gap_s {
                self.interrupt();
            }
        }
        let mut verdict = None;
        if let Some((t, w)) = self.last {
            let dt = (s.stamp_ns - t) as f64 * 1e-9;
            self.window_turn += w * dt;
            self.window_s += dt;
            if s.stamp_ns - self.block_start_ns >= self.block_ns {
                verdict = self.close_block(s.stamp_ns);
            }
        }
        if self.window_start_ns.is_none() {
            self.window_start_ns = Some(s.stamp_ns);
        }
        if self.block.n == 0 {
            self.block_start_ns = s.stamp_ns;
        }
        self.block.gyro += s.gyro;
        self.block.accel += s.accel;
        self.block.n += 1;
        self.last = Some((s.stamp_ns, s.gyro));
        verdict
    }

    fn clear_window(&mut self) {
        self.block = Sums::ZERO;
        self.window = Sums::ZERO;
        self.blocks_done = 0;
        self.window_start_ns = None;
        self.window_turn = Vector3::zeros();
        self.window_s = 0.0;
    }

    /// Closes the block at `now_ns` (the next sample's stamp); judges the window when full.
    fn close_block(&mut self, now_ns: i64) -> Option<WindowVerdict> {
        let n = self.block.n.max(1) as f64;
        let k = self.blocks_done;
        self.gyro_means[k] = self.block.gyro / n;
        self.accel_means[k] = self.block.accel / n;
        self.window.gyro += self.block.gyro;
        self.window.accel += self.block.accel;
        self.window.n += self.block.n;
        self.blocks_done += 1;
        self.block = Sums::ZERO;
        if self.blocks_done < self.cfg.blocks {
            return None;
        }
        let start_ns = self.window_start_ns.unwrap_or(now_ns);
        let hold_rate = self.window_turn / self.window_s.max(1e-12);
        let verdict = match self.judge() {
            Ok(()) => {
                self.accept_window(start_ns, now_ns);
                WindowVerdict::Still { start_ns, end_ns: now_ns, hold_rate }
            }
            Err(why) => {
                if why == NotStill::Tilting {
                    self.keep_the_level_part();
                }
                self.end_run();
                let c = &mut self.counters;
                match why {
                    NotStill::Moving => c.moving_windows += 1,
                    NotStill::Turning => c.turning_windows += 1,
                    NotStill::Tilting => c.tilting_windows += 1,
                    NotStill::Inconsistent => c.inconsistent_windows += 1,
                }
                WindowVerdict::NotStill(why)
            }
        };
        self.clear_window();
        // The sample that closed the window opens the next one (set by `push`).
        Some(verdict)
    }

    /// The window's tests, in the order of the module's list.
    fn judge(&self) -> Result<(), NotStill> {
        let k = self.blocks_done;
        let span = |m: &[Vector3<f64>]| {
            let (lo, hi) =
                m.iter().fold((Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY)), |(lo, hi), v| (lo.inf(v), hi.sup(v)));
            (hi - lo).max()
        };
        let n = self.window.n.max(1) as f64;
        let gyro = self.window.gyro / n;
        let accel = self.window.accel / n;
        if span(&self.gyro_means[..k]) >= self.cfg.max_gyro_spread
            || span(&self.accel_means[..k]) >= self.cfg.max_accel_spread
            || (accel.norm() - STANDARD_GRAVITY).abs() >= self.cfg.max_gravity_error
        {
            return Err(NotStill::Moving);
        }
        if gyro.amax() > self.cfg.max_bias {
            return Err(NotStill::Turning);
        }
        if let Some(run) = &self.run {
            if run.gravity.angle(&accel) > self.cfg.max_tilt_change {
                return Err(NotStill::Tilting);
            }
        }
        // Against what earlier standstills measured (not the run in progress: it is this one).
        if let Some(prior) = &self.prior {
            let sigma = prior.variance_at(self.window_start_ns.unwrap_or(prior.at_ns), self.cfg.bias_random_walk).map(f64::sqrt);
            let off = (gyro - prior.bias).abs() - sigma * 5.0;
            if off.max() > self.cfg.max_bias_change {
                return Err(NotStill::Inconsistent);
            }
        }
        Ok(())
    }

    /// Adds a still window to the standstill in progress and updates the estimate.
    fn accept_window(&mut self, start_ns: i64, end_ns: i64) {
        self.counters.still_windows += 1;
        let k = self.blocks_done;
        let n = self.window.n.max(1) as f64;
        let gravity = self.window.accel / n;
        let mid_ns = start_ns + (end_ns - start_ns) / 2;
        let run = self.run.get_or_insert(Run {
            sums: RunSums {
                start_ns,
                end_ns,
                gyro_sum: Vector3::zeros(),
                n: 0,
                block_sum: Vector3::zeros(),
                block_sq: Vector3::zeros(),
                blocks: 0,
            },
            gravity,
            first_mid_ns: mid_ns,
            level: None,
        });
        let tilt = run.gravity.angle(&gravity);
        if run.sums.n > 0 && tilt <= LEVEL_FRACTION * self.cfg.max_tilt_change {
            run.level = Some(run.sums);
        }
        let span_s = (mid_ns - run.first_mid_ns) as f64 * 1e-9;
        let turn_allowed = turn_rate_shown(tilt, span_s, &self.accel_means[..k]);
        let sums = &mut run.sums;
        sums.end_ns = end_ns;
        sums.gyro_sum += self.window.gyro;
        sums.n += self.window.n as u64;
        for m in &self.gyro_means[..k] {
            sums.block_sum += m;
            sums.block_sq += m.component_mul(m);
        }
        sums.blocks += k as u32;
        let measured = sums.estimate(turn_allowed * turn_allowed);
        self.set_measured(measured);
    }

    /// This standstill's measurement, fused with what earlier ones measured.
    fn set_measured(&mut self, measured: BiasEstimate) {
        self.estimate = Some(match &self.prior {
            None => measured,
            Some(p) => fuse(p, &measured, self.cfg.bias_random_walk),
        });
        self.seed_motion();
    }

    /// A standstill that tilts was a slow turn about a horizontal axis (a turn at 0.03 rad/s
    /// passes as runs of a few still windows). From its start, none of it was a bias: it is
    /// dropped. After a rest (at least two windows level before the turn), the rest is kept,
    /// its variance at least the square of the turn rate its own tilt allows (the tilt allowed
    /// over its span): a 10-s rest before a robot leans is not lost.
    fn keep_the_level_part(&mut self) {
        let rest = self.run.as_mut().and_then(|r| r.level.take()).filter(|l| l.blocks >= 2 * self.cfg.blocks as u32);
        match rest {
            Some(level) => {
                // The run ends here (`end_run`): its estimate becomes the prior.
                let bound = LEVEL_FRACTION * self.cfg.max_tilt_change / level.seconds().max(1e-3);
                self.set_measured(level.estimate(bound * bound));
            }
            None => {
                self.estimate = self.prior;
                self.run = None;
                self.seed_motion();
            }
        }
    }

    /// The filter in motion starts from what the standstills measured (or from its prior, when
    /// a standstill was dropped and none is left).
    fn seed_motion(&mut self) {
        let Some(m) = self.motion.as_mut() else { return };
        match &self.estimate {
            Some(e) => m.seed(e.bias, e.variance),
            None => m.seed(Vector3::zeros(), Vector3::repeat(self.cfg.motion.prior_stddev.powi(2))),
        }
    }

    fn end_run(&mut self) {
        if self.run.take().is_some() {
            self.counters.standstills += 1;
            self.prior = self.estimate;
        }
    }
}

/// Gravity turned by `tilt` (rad) between a standstill's first window and one `span_s` later:
/// a turn about a horizontal axis at tilt / span reads as bias. What of the tilt stands out of
/// the windows' own noise (twice the σ that `accel_means`, a window's block means, give the
/// difference of two window means) is that turn, rad/s.
fn turn_rate_shown(tilt: f64, span_s: f64, accel_means: &[Vector3<f64>]) -> f64 {
    if span_s <= 0.0 {
        return 0.0;
    }
    let noise_sq = 2.0 * block_scatter(accel_means) / accel_means.len().max(1) as f64 / (STANDARD_GRAVITY * STANDARD_GRAVITY);
    (tilt * tilt - 4.0 * noise_sq).max(0.0).sqrt() / span_s
}

/// The block means' variance about their mean, summed over the axes.
fn block_scatter(means: &[Vector3<f64>]) -> f64 {
    let k = means.len();
    if k < 2 {
        return 0.0;
    }
    let mean = means.iter().sum::<Vector3<f64>>() / k as f64;
    means.iter().map(|m| (m - mean).norm_squared()).sum::<f64>() / (k - 1) as f64
}

/// Inverse-variance fusion of an earlier estimate (grown by the random walk up to the new one)
/// and a new standstill, per axis.
fn fuse(prior: &BiasEstimate, new: &BiasEstimate, random_walk: f64) -> BiasEstimate {
    let vp = prior.variance_at(new.at_ns, random_walk);
    let vn = new.variance;
    let mut bias = Vector3::zeros();
    let mut variance = Vector3::zeros();
    for i in 0..3 {
        let (a, b) = (vp[i].max(1e-18), vn[i].max(1e-18));
        bias[i] = (prior.bias[i] * b + new.bias[i] * a) / (a + b);
        variance[i] = a * b / (a + b);
    }
    BiasEstimate { bias, variance, at_ns: new.at_ns, still_s: prior.still_s + new.still_s }
}

/// [`PowerOnBias`] over a whole recording, as the pipeline runs it sample by sample.
#[derive(Debug, Clone, Default)]
pub struct BiasTrack {
    /// The bias in force after each sample (zero before the first standstill), rad/s.
    pub bias: Vec<Vector3<f64>>,
    /// Still windows as sample indices [start, end): the body did not turn there.
    pub still: Vec<(usize, usize)>,
    /// The estimate at the end, if any standstill was found.
    pub last: Option<BiasEstimate>,
    /// The bias in force at the end (a standstill's, or the one seen in motion) and where it
    /// comes from.
    pub in_force_at_end: Option<BiasEstimate>,
    pub source: &'static str,
    pub counters: StandstillCounters,
    /// A standstill was in progress at the end.
    pub standing_at_end: bool,
    /// What earlier power-ons predicted (removed before the first standstill where it applies).
    pub remembered: Option<BiasPrediction>,
}

impl BiasTrack {
    /// Runs the detector over `imu` (stamp order, as `read_recording` gives it).
    pub fn over(imu: &[ImuSample], cfg: &StandstillConfig) -> Self {
        let mut p = PowerOnBias::new(*cfg);
        let mut track = BiasTrack { bias: Vec::with_capacity(imu.len()), ..Default::default() };
        let mut window_start = 0;
        for (i, s) in imu.iter().enumerate() {
            if let Some(WindowVerdict::Still { .. }) = p.push(s) {
                track.still.push((window_start, i));
            }
            if p.window_start_ns() == Some(s.stamp_ns) {
                window_start = i;
            }
            track.bias.push(p.bias());
        }
        track.last = p.estimate().copied();
        track.in_force_at_end = p.in_force(imu.last().map_or(0, |s| s.stamp_ns));
        track.source = p.source();
        track.counters = *p.counters();
        track.standing_at_end = p.standing();
        track.remembered = cfg.remembered;
        track
    }

    /// `gyro` (one per IMU sample) minus the bias in force at each sample.
    pub fn remove_from(&self, gyro: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        gyro.iter().zip(&self.bias).map(|(g, b)| g - b).collect()
    }

    /// The samples with the bias in force at each removed: what the pipeline feeds a model
    /// adapted after its support's power-on bias was removed.
    pub fn debiased(&self, imu: &[ImuSample]) -> Vec<ImuSample> {
        imu.iter().zip(&self.bias).map(|(s, b)| ImuSample { gyro: s.gyro - b, ..*s }).collect()
    }

    /// The gyro the pipeline's power-on-bias correction gives `imu` (each sample minus the bias
    /// in force, the attitude held over still windows).
    pub fn corrected_gyro(&self, imu: &[ImuSample]) -> Vec<Vector3<f64>> {
        let mut gyro = self.remove_from(&imu.iter().map(|s| s.gyro).collect::<Vec<_>>());
        self.hold_still_windows(imu, &mut gyro);
        gyro
    }

    /// The attitude held over each still window, as the pipeline holds it, written as a rate:
    /// `gyro` minus its own time-weighted mean there, so its integral over the window is zero.
    pub fn hold_still_windows(&self, imu: &[ImuSample], gyro: &mut [Vector3<f64>]) {
        for &(a, b) in &self.still {
            let (mut turn, mut secs) = (Vector3::zeros(), 0.0);
            for k in a..b.min(imu.len() - 1) {
                let dt = (imu[k + 1].stamp_ns - imu[k].stamp_ns) as f64 * 1e-9;
                turn += gyro[k] * dt;
                secs += dt;
            }
            if secs > 0.0 {
                let mean = turn / secs;
                for g in &mut gyro[a..b] {
                    *g -= mean;
                }
            }
        }
    }

    /// What it measured, for a note: the bias, its σ and the seconds of standstill, or why none.
    pub fn note(&self) -> String {
        let standstills = match &self.last {
            Some(e) => {
                format!("{:.1} s of standstill in {} standstills", e.still_s, self.counters.standstills + u64::from(self.standing_at_end))
            }
            None => format!(
                "no standstill (windows moving {}, turning {}, tilting {})",
                self.counters.moving_windows, self.counters.turning_windows, self.counters.tilting_windows
            ),
        };
        let note = match &self.in_force_at_end {
            Some(e) => format!(
                "power-on bias [{:.5}, {:.5}, {:.5}] rad/s at the end, σ {:.1e} (from {}), {standstills}",
                e.bias.x,
                e.bias.y,
                e.bias.z,
                e.variance.max().sqrt(),
                self.source
            ),
            None => format!("{standstills}: the turn-on bias is uncorrected"),
        };
        match self.remembered {
            Some(r) if r.applies_any() => format!(
                "{note}; before the first standstill [{:.5}, {:.5}, {:.5}] rad/s from {} earlier power-ons{}",
                r.bias.x,
                r.bias.y,
                r.bias.z,
                r.power_ons,
                self.last.and_then(|e| r.contradicted_by(&e)).map_or(String::new(), |c| format!(" ({c})"))
            ),
            Some(r) => format!("{note}; {} earlier power-ons do not predict this one's bias", r.power_ons),
            None => note,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A 200-Hz stream: `rate(t)` the true body rate, a bias, white noise σ (a seeded LCG), the
    /// specific force `accel(t)`.
    fn stream(
        seconds: f64,
        bias: Vector3<f64>,
        sigma: f64,
        rate: impl Fn(f64) -> Vector3<f64>,
        accel: impl Fn(f64) -> Vector3<f64>,
    ) -> Vec<ImuSample> {
        let mut state: u64 = 12345;
        let mut noise = move || {
            // Sum of 4 uniforms: roughly normal, unit variance.
            (0..4)
                .map(|_| {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .sum::<f64>()
                * 3f64.sqrt()
        };
        (0..(seconds * 200.0) as usize)
            .map(|k| {
                let t = k as f64 * 0.005;
                let n = Vector3::new(noise(), noise(), noise()) * sigma;
                ImuSample { stamp_ns: 1_000_000_000 + k as i64 * 5_000_000, gyro: rate(t) + bias + n, accel: accel(t) }
            })
            .collect()
    }

    fn level(_: f64) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, STANDARD_GRAVITY)
    }

    /// An accelerometer's white noise of `sigma` per axis, a function of the stamp alone.
    fn accel_noise(t: f64, sigma: f64) -> Vector3<f64> {
        let u = |k: f64| ((t * 7919.0 + k) * 12.9898).sin() * 43758.5453 % 1.0;
        Vector3::new(u(1.0), u(2.0), u(3.0)) * (sigma * 3f64.sqrt())
    }

    fn run(imu: &[ImuSample]) -> PowerOnBias {
        let mut p = PowerOnBias::new(StandstillConfig::default());
        for s in imu {
            p.push(s);
        }
        p
    }

    #[test]
    fn a_rest_measures_the_bias_and_its_variance_covers_the_error() {
        let bias = Vector3::new(0.03, -0.05, 0.08);
        let imu = stream(5.0, bias, 0.005, |_| Vector3::zeros(), level);
        let p = run(&imu);
        let e = p.estimate().expect("a rest");
        let err = e.bias - bias;
        assert!(err.amax() < 1e-3, "{err}");
        for i in 0..3 {
            assert!(err[i].abs() < 4.0 * e.variance[i].sqrt(), "axis {i}: error {} σ {}", err[i], e.variance[i].sqrt());
        }
        assert!(e.still_s > 4.0, "{}", e.still_s);
    }

    #[test]
    fn a_standing_robots_vibration_is_a_rest() {
        // 30 Hz shaking of ±0.05 rad/s and ±2 m/s²: block means stay put.
        let bias = Vector3::new(0.01, 0.0, -0.02);
        let shake = |t: f64| (2.0 * std::f64::consts::PI * 30.0 * t).sin();
        let imu =
            stream(4.0, bias, 0.01, |t| Vector3::new(0.05, 0.0, 0.0) * shake(t), |t| level(t) + Vector3::new(2.0, 0.0, 0.0) * shake(t));
        let e = *run(&imu).estimate().expect("a vibrating rest is a rest");
        assert!((e.bias - bias).amax() < 2e-3, "{}", e.bias);
    }

    #[test]
    fn a_slow_turn_about_a_horizontal_axis_is_not_a_rest() {
        // 0.03 rad/s about x: gravity turns in the body, 0.15 rad in 5 s.
        let w = 0.03;
        let imu = stream(
            5.0,
            Vector3::zeros(),
            0.001,
            |_| Vector3::new(w, 0.0, 0.0),
            |t| Vector3::new(0.0, (w * t).sin(), (w * t).cos()) * STANDARD_GRAVITY,
        );
        let p = run(&imu);
        assert!(p.counters().tilting_windows > 0, "{:?}", p.counters());
        // At most the first windows, before gravity had turned by max_tilt_change.
        let e = p.estimate().map_or(0.0, |e| e.still_s);
        assert!(e <= 1.0, "{e}");
        // Slower turns pass as level for longer: what is kept of them states the turn as σ
        // (an accelerometer with a consumer part's noise: the turn must stand out of it).
        for w in [0.01, 0.005, 0.002] {
            let imu = stream(
                20.0,
                Vector3::zeros(),
                0.001,
                |_| Vector3::new(w, 0.0, 0.0),
                |t| Vector3::new(0.0, (w * t).sin(), (w * t).cos()) * STANDARD_GRAVITY + accel_noise(t, 0.03),
            );
            if let Some(e) = run(&imu).estimate() {
                assert!(e.bias[0].abs() < 3.0 * e.variance[0].sqrt(), "{w} rad/s read as a bias {} ± {}", e.bias[0], e.variance[0].sqrt());
            }
        }
    }

    /// A rest of 10 s, then a turn at 0.03 rad/s about x from rest (a robot that starts to lean,
    /// a device lifted slowly): the turn's first windows pass the spreads and tilt the
    /// standstill, but what came before them was a rest and is kept, its bias unbiased by the
    /// turn.
    #[test]
    fn a_rest_that_ends_in_a_slow_turn_keeps_its_rest() {
        let (bias, w, t_turn) = (Vector3::new(0.01, -0.02, 0.03), 0.03, 10.0);
        let tilt = |t: f64| w * (t - t_turn).max(0.0);
        let imu = stream(
            16.0,
            bias,
            0.002,
            |t| if t < t_turn { Vector3::zeros() } else { Vector3::new(w, 0.0, 0.0) },
            |t| Vector3::new(0.0, tilt(t).sin(), tilt(t).cos()) * STANDARD_GRAVITY + accel_noise(t, 0.03),
        );
        let p = run(&imu);
        assert!(p.counters().tilting_windows > 0, "{:?}", p.counters());
        let e = p.estimate().expect("the rest before the turn");
        assert!(e.still_s >= 8.0, "{}", e.still_s);
        let err = e.bias - bias;
        assert!(err.amax() < 1e-3, "{err}");
        for i in 0..3 {
            assert!(err[i].abs() < 4.0 * e.variance[i].sqrt(), "axis {i}: error {} σ {}", err[i], e.variance[i].sqrt());
        }
    }

    #[test]
    fn a_turn_faster_than_any_bias_is_not_a_rest() {
        let imu = stream(3.0, Vector3::zeros(), 0.001, |_| Vector3::new(0.0, 0.0, 0.3), level);
        let p = run(&imu);
        assert!(p.estimate().is_none());
        assert!(p.counters().turning_windows >= 4, "{:?}", p.counters());
    }

    #[test]
    fn a_slow_turn_about_gravity_after_a_rest_is_not_mixed_in() {
        let bias = Vector3::new(0.0, 0.0, 0.02);
        let mut imu = stream(3.0, bias, 0.002, |_| Vector3::zeros(), level);
        // Then it moves, then stands turning at 0.06 rad/s about z (reads as a bias of 0.08).
        let moving = stream(3.0, bias, 0.002, |t| Vector3::new(0.5 * (3.0 * t).sin(), 0.0, 0.0), level);
        let turning = stream(5.0, bias, 0.002, |_| Vector3::new(0.0, 0.0, 0.06), level);
        let t_end = imu.last().unwrap().stamp_ns;
        for (k, s) in moving.iter().chain(&turning).enumerate() {
            imu.push(ImuSample { stamp_ns: t_end + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let p = run(&imu);
        let e = p.estimate().unwrap();
        assert!((e.bias - bias).amax() < 1e-3, "{}", e.bias);
        assert!(p.counters().inconsistent_windows >= 8, "{:?}", p.counters());
    }

    #[test]
    fn a_later_rest_refines_the_estimate() {
        let bias = Vector3::new(0.02, 0.01, -0.01);
        let first = stream(1.0, bias, 0.01, |_| Vector3::zeros(), level);
        let moving = stream(5.0, bias, 0.01, |t| Vector3::new(0.0, 0.8 * (2.0 * t).sin(), 0.0), level);
        let later = stream(10.0, bias, 0.01, |_| Vector3::zeros(), level);
        let mut imu = first.clone();
        for (k, s) in moving.iter().chain(&later).enumerate() {
            imu.push(ImuSample { stamp_ns: first.last().unwrap().stamp_ns + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let after_first = run(&first).estimate().copied().unwrap();
        let p = run(&imu);
        let e = p.estimate().unwrap();
        assert_eq!(p.counters().standstills, 1, "the first ended; the later one is in progress");
        assert!(e.variance.max() < after_first.variance.max() / 3.0, "{} vs {}", e.variance, after_first.variance);
        assert!((e.bias - bias).amax() < 1e-3);
    }

    #[test]
    fn a_bump_or_a_clock_jump_breaks_the_rest_and_keeps_what_was_measured() {
        let bias = Vector3::new(0.0, 0.04, 0.0);
        let mut imu = stream(6.0, bias, 0.002, |_| Vector3::zeros(), level);
        // A bump at 2 s: 0.05 s of a 1-rad/s knock and 5 m/s².
        for s in imu.iter_mut().skip(400).take(10) {
            s.gyro.x += 1.0;
            s.accel.x += 5.0;
        }
        // A clock that goes back 1 s at 4 s.
        for s in imu.iter_mut().skip(800) {
            s.stamp_ns -= 1_000_000_000;
        }
        let p = run(&imu);
        let c = p.counters();
        assert!(c.moving_windows >= 1 && c.interrupted_windows >= 1, "{c:?}");
        let e = p.estimate().unwrap();
        assert!((e.bias - bias).amax() < 1e-3, "{}", e.bias);
    }

    #[test]
    fn a_rest_hold_rate_integrates_the_window_to_zero() {
        let imu = stream(1.2, Vector3::new(0.01, 0.02, 0.03), 0.003, |_| Vector3::zeros(), level);
        let mut p = PowerOnBias::new(StandstillConfig::default());
        let mut found = None;
        for s in &imu {
            if let Some(WindowVerdict::Still { start_ns, end_ns, hold_rate }) = p.push(s) {
                found = Some((start_ns, end_ns, hold_rate));
                break;
            }
        }
        let (a, b, m) = found.expect("a still window");
        let turn: Vector3<f64> = imu
            .windows(2)
            .filter(|w| w[0].stamp_ns >= a && w[1].stamp_ns <= b)
            .map(|w| (w[0].gyro - m) * ((w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9))
            .sum();
        assert!(turn.amax() < 1e-12, "{turn}");
    }

    #[test]
    fn the_offline_track_holds_a_rest_and_removes_the_bias_after_it() {
        let bias = Vector3::new(0.02, -0.01, 0.05);
        let mut imu = stream(2.0, bias, 0.002, |_| Vector3::zeros(), level);
        let t_end = imu.last().unwrap().stamp_ns;
        for (k, s) in stream(2.0, bias, 0.002, |t| Vector3::new(0.0, 0.0, 0.4 * t.sin()), level).iter().enumerate() {
            imu.push(ImuSample { stamp_ns: t_end + (k as i64 + 1) * 5_000_000, ..*s });
        }
        let track = BiasTrack::over(&imu, &StandstillConfig::default());
        assert_eq!(track.still.len(), 4, "{:?}", track.still);
        assert!(track.bias[0].norm() == 0.0 && (track.bias[imu.len() - 1] - bias).amax() < 1e-3);
        let g = track.corrected_gyro(&imu);
        let q = crate::so3::integrate_gyro(&imu, nalgebra::UnitQuaternion::identity(), |n| g[n]);
        // Held over the rest (the body did not turn), then integrated with the bias removed.
        let at_rest_end = track.still.last().unwrap().1;
        assert!(q[at_rest_end].angle() < 1e-7, "{}", q[at_rest_end].angle());
        assert!(track.note().contains("power-on bias"));
    }

    #[test]
    fn retake_forgets_the_estimate() {
        let mut p = run(&stream(2.0, Vector3::new(0.05, 0.0, 0.0), 0.001, |_| Vector3::zeros(), level));
        assert!(p.estimate().is_some());
        p.retake();
        assert!(p.estimate().is_none());
        assert_eq!(p.bias(), Vector3::zeros());
    }

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

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Whatever the bias (within the limit) and noise, a rest's stated σ covers its error.
        #[test]
        fn the_stated_variance_covers_the_error(
            bx in -0.1f64..0.1, by in -0.1f64..0.1, bz in -0.1f64..0.1,
            sigma in 0.0005f64..0.02, seconds in 1.0f64..8.0,
        ) {
            let bias = Vector3::new(bx, by, bz);
            let p = run(&stream(seconds, bias, sigma, |_| Vector3::zeros(), level));
            let e = p.estimate().expect("a rest");
            let z = (e.bias - bias).component_div(&e.variance.map(f64::sqrt));
            prop_assert!(z.amax() < 5.0, "z {z}, σ {}", e.variance.map(f64::sqrt));
        }
    }

    #[test]
    fn earlier_power_ons_hold_until_the_first_standstill() {
        let bias = Vector3::new(0.002, -0.03, 0.08);
        let remembered = BiasPrediction {
            bias: Vector3::new(0.0, -0.031, 0.079),
            variance: Vector3::new(0.08f64.powi(2), 4e-6, 4e-6),
            applied: [false, true, true],
            power_ons: 5,
        };
        let cfg = StandstillConfig { remembered: Some(remembered), ..StandstillConfig::default() };
        // Moving for 5 s (a turn about x faster than any bias), then standing.
        let turning = stream(5.0, bias, 0.002, |t| Vector3::new(0.6 * (t * 2.0).sin(), 0.0, 0.0), level);
        let mut p = PowerOnBias::new(cfg);
        for s in &turning {
            p.push(s);
        }
        assert_eq!(p.source(), "memory");
        let e = p.in_force(turning.last().unwrap().stamp_ns).unwrap();
        assert_eq!(e.bias, remembered.bias);
        assert_eq!(e.variance, remembered.variance, "the prediction's own variance, x's the unremoved mean's");
        let still = stream(3.0, bias, 0.002, |_| Vector3::zeros(), level);
        let last = turning.last().unwrap().stamp_ns;
        for s in &still {
            p.push(&ImuSample { stamp_ns: last + s.stamp_ns, ..*s });
        }
        assert_eq!(p.source(), "standstill");
        assert!((p.bias() - bias).amax() < 2e-3, "{:?}", p.bias());
        // What the standstill measured is within the prediction; another IMU's is not.
        assert_eq!(remembered.contradicted_by(p.estimate().unwrap()), None);
        let other = BiasEstimate { bias: Vector3::new(0.0, -0.031, 0.02), variance: Vector3::repeat(1e-8), at_ns: 0, still_s: 1.0 };
        let said = remembered.contradicted_by(&other).unwrap();
        assert!(said.contains("z 0.02000 against 0.07900"), "{said}");
        // A prediction that applies to no axis is not in force.
        let none = BiasPrediction { applied: [false; 3], bias: Vector3::zeros(), ..remembered };
        let p = run_with(&turning, StandstillConfig { remembered: Some(none), ..StandstillConfig::default() });
        assert_eq!(p.source(), "");
        assert!(p.in_force(0).is_none());
    }

    fn run_with(imu: &[ImuSample], cfg: StandstillConfig) -> PowerOnBias {
        let mut p = PowerOnBias::new(cfg);
        for s in imu {
            p.push(s);
        }
        p
    }
}
