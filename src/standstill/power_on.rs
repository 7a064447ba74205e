//! The streaming standstill detector and the per-power-on bias it measures: its state, the
//! bias in force (a standstill's, earlier power-ons', or the one seen in motion) and where it
//! comes from, a re-take and a break. Its window is judged in `window.rs`, its standstill in
//! progress kept in `run.rs`.

use nalgebra::Vector3;

use super::run::Run;
use super::steady_rate::{RateAboveMaxBias, SteadyRate};
use super::window::Sums;
use super::{BiasEstimate, InMotion, StandstillConfig, StandstillCounters, MAX_BLOCKS};
use crate::motion_bias::MotionBias;

/// The streaming standstill detector and the per-power-on bias it measures.
#[derive(Debug, Clone)]
pub struct PowerOnBias {
    pub(super) cfg: StandstillConfig,
    pub(super) block_ns: i64,
    pub(super) last: Option<(i64, Vector3<f64>)>,
    pub(super) block: Sums,
    pub(super) block_start_ns: i64,
    /// The window's completed blocks' means.
    pub(super) gyro_means: [Vector3<f64>; MAX_BLOCKS],
    pub(super) accel_means: [Vector3<f64>; MAX_BLOCKS],
    pub(super) blocks_done: usize,
    pub(super) window: Sums,
    /// The accelerometer's variance inside each completed block, summed over the window.
    pub(super) accel_within_var: Vector3<f64>,
    pub(super) window_start_ns: Option<i64>,
    /// ∫ω dt over the window so far, and its duration, s.
    pub(super) window_turn: Vector3<f64>,
    pub(super) window_s: f64,
    pub(super) run: Option<Run>,
    /// The estimate before the current run (what the run is fused with).
    pub(super) prior: Option<BiasEstimate>,
    pub(super) estimate: Option<BiasEstimate>,
    pub(super) counters: StandstillCounters,
    /// Windows refused only as turning, at one rate: the run in progress and the last said.
    pub(super) steady: Option<SteadyRate>,
    pub(super) above_max_bias: Option<RateAboveMaxBias>,
    /// A hole of `new_power_on_gap_s` (or a clock that went back) since the last still window.
    pub(super) after_hole: bool,
    /// The bias seen in motion (unless `in_motion: off`).
    pub(super) motion: Option<MotionBias>,
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
            accel_within_var: Vector3::zeros(),
            window_start_ns: None,
            window_turn: Vector3::zeros(),
            window_s: 0.0,
            run: None,
            prior: None,
            estimate: None,
            counters: StandstillCounters::default(),
            steady: None,
            above_max_bias: None,
            after_hole: false,
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
    /// `in_motion` uses it (stamped `now_ns`, its variance the filter's own). After a hole in
    /// the input, until a standstill agrees with it or replaces it, its variance is at least a
    /// new turn-on bias's (`motion.prior_stddev`²): the IMU may have been power-cycled.
    pub fn in_force(&self, now_ns: i64) -> Option<BiasEstimate> {
        let mut e = self.measured_in_force(now_ns)?;
        if self.after_hole {
            e.variance = e.variance.sup(&Vector3::repeat(self.cfg.motion.prior_stddev.powi(2)));
        }
        Some(e)
    }

    fn measured_in_force(&self, now_ns: i64) -> Option<BiasEstimate> {
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

    /// A still body read at a steady rate above `max_bias` (the run in progress, else the last
    /// one of at least 2 s): said, not removed ([`RateAboveMaxBias`]).
    pub fn rate_above_max_bias(&self) -> Option<RateAboveMaxBias> {
        self.steady.and_then(|s| s.said(self.cfg.max_bias, self.cfg.max_tilt_change)).or(self.above_max_bias)
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
        self.forget();
    }

    /// The window being judged, after a hole in the input, contradicts the estimate: the IMU
    /// was power-cycled under the node. What was measured is forgotten and the window judged
    /// as a power-on's first (a re-take the detector makes itself).
    pub(super) fn new_power_on(&mut self) {
        self.end_run();
        self.forget();
        self.counters.new_power_ons += 1;
        tracing::warn!("a standstill after a hole in the input contradicts the power-on bias measured before it: taken as a new power-on's (the IMU was power-cycled)");
    }

    fn forget(&mut self) {
        self.prior = None;
        self.estimate = None;
        self.above_max_bias = None;
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
        self.end_steady();
        self.clear_window();
        self.last = None;
    }
}
