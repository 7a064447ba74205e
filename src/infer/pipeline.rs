//! The per-sample pipeline: input checks → gyro correction → orientation integration.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::attitude::Attitude;
use super::gravity_aided::GravityAided;
use super::hindsight::Hindsight;
use super::stamps::{BackwardsRun, StreamRate};
use super::{choose, Correction, Counters, Dropped, GyroCorrector, OrientationMode, PipelineConfig};
use crate::core::{ClipDetector, ImuSample};
use crate::resample::PeriodMeans;
use crate::so3::{exp, renormalize};
use crate::standstill::{BiasEstimate, PowerOnBias, StandstillCounters, WindowVerdict};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CorrectedImu {
    pub stamp_ns: i64,
    /// Corrected angular velocity ω̂, rad/s.
    pub gyro: Vector3<f64>,
    /// The estimated correction ω̂ − ω, rad/s.
    pub correction: Vector3<f64>,
    /// Specific force, passed through, m/s².
    pub accel: Vector3<f64>,
    /// Variance of each corrected gyro axis's white noise, (rad/s)².
    pub gyro_variance: f64,
    /// Variance of the bias left in each corrected gyro axis, (rad/s)²: the power-on bias
    /// estimate's where it is removed (before one, the uncorrected gyro's), the model's residual
    /// where it runs, 0 for the gyro as measured. Added to the published covariance.
    pub gyro_bias_variance: f64,
    /// No model ran on the gyro: the input's own covariance, where it gives one, stands for
    /// its noise.
    pub passed_through: bool,
    /// `world_from_body` and its covariance (rad², about world x, y, z), integrated or
    /// gravity aided (`PipelineConfig::orientation`); `None` until the initial attitude is known.
    pub orientation: Option<(UnitQuaternion<f64>, Matrix3<f64>)>,
    /// The corrector has seen fewer than N samples since the start or the last reset.
    pub warming_up: bool,
    /// This sample follows a gap (the window was reset, the attitude held).
    pub after_gap: bool,
}

/// The pipeline: feed raw samples in stamp order, get corrected samples out.
pub struct Pipeline {
    corrector: Box<dyn GyroCorrector>,
    cfg: PipelineConfig,
    rate: StreamRate,
    last: Option<(i64, Vector3<f64>)>,
    since_reset: u64,
    attitude: Attitude,
    counters: Counters,
    backwards_run: BackwardsRun,
    clipping: ClipDetector,
    /// The model's periods, when the corrector has a rate ([`crate::resample`]).
    periods: Option<PeriodMeans>,
    /// The stream is fed to the model in its periods: its rate is off the model's.
    resampling: bool,
    /// The correction of the last period completed, rad/s (while resampling).
    period_correction: Vector3<f64>,
    /// This power-on's gyro bias, measured at standstills.
    standstill: PowerOnBias,
    /// The attitude at the start of the standstill window in progress: held there if the window
    /// turns out still (the body did not turn).
    hold_from: Option<(i64, UnitQuaternion<f64>)>,
    /// The gravity-aided attitude (`orientation: gravity_aided`), from the first sample on.
    gravity_aided: Option<GravityAided>,
    /// The samples since the gravity-aided filter started, run again at the first standstill.
    hindsight: Hindsight,
    /// The power-on bias removed from the gyro the gravity-aided filter last saw, rad/s, and
    /// the still windows counted then ([`Self::keep_gravity_aided_bias_in_step`]).
    aided_removed: Vector3<f64>,
    aided_still_windows: u64,
}

/// What a sample's stamp did to the stream: a gap before it, or the body's turn since the
/// last sample (none across a gap or at the first).
struct Advance {
    after_gap: bool,
    turned: Option<Vector3<f64>>,
}

impl Pipeline {
    pub fn new(corrector: Box<dyn GyroCorrector>, mut cfg: PipelineConfig) -> Self {
        // A bias memory file (this robot's own record) wins over what the model's training
        // recordings predict.
        if cfg.standstill.remembered.is_none() {
            cfg.standstill.remembered = corrector.earlier_power_ons(cfg.standstill.min_power_on_spread);
        }
        let rate = if cfg.nominal_rate_hz > 0.0 { Some(cfg.nominal_rate_hz) } else { corrector.rate_hz() };
        let nominal_period_ns = rate.map(|r| 1e9 / r);
        // The model's periods, for a corrector with a rate that is not a pass-through.
        let standstill = PowerOnBias::new(cfg.standstill);
        let periods = corrector.rate_hz().filter(|r| *r > 0.0 && !corrector.passes_through()).map(PeriodMeans::new);
        let rate = StreamRate::new(nominal_period_ns, cfg.gap_periods, cfg.rate_tolerance);
        // Sized for the nominal rate, or 1 kHz where none is known (a faster stream outgrows it).
        let hindsight = Hindsight::new(cfg.attitude_hindsight_s, if cfg.nominal_rate_hz > 0.0 { cfg.nominal_rate_hz } else { 1000.0 });
        Pipeline {
            corrector,
            cfg,
            rate,
            last: None,
            since_reset: 0,
            attitude: Attitude::new(),
            counters: Counters::default(),
            backwards_run: BackwardsRun::default(),
            clipping: ClipDetector::default(),
            periods,
            resampling: false,
            period_correction: Vector3::zeros(),
            standstill,
            hold_from: None,
            gravity_aided: None,
            hindsight,
            aided_removed: Vector3::zeros(),
            aided_still_windows: 0,
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

    /// What earlier power-ons predicted for this one's bias ([`crate::bias_memory`]).
    pub fn remembered_bias(&self) -> Option<crate::standstill::BiasPrediction> {
        self.cfg.standstill.remembered
    }

    /// Nominal input period, s, once known.
    pub fn nominal_rate_hz(&self) -> Option<f64> {
        self.rate.nominal_period_ns.map(|p| 1e9 / p)
    }

    /// The input's smoothed rate, Hz, once measured.
    pub fn input_rate_hz(&self) -> Option<f64> {
        (self.rate.smoothed_period_ns > 0.0).then(|| 1e9 / self.rate.smoothed_period_ns)
    }

    /// The rate the corrector was made for, Hz, if it has one.
    pub fn corrector_rate_hz(&self) -> Option<f64> {
        self.corrector.rate_hz()
    }

    /// The gyro bias the attitude's covariance allows for: the residual after a model at its
    /// rate; after the power-on bias alone, that estimate's σ (at least `bias_stddev`); else the
    /// sensor's own.
    fn bias_stddev(&self) -> f64 {
        let uncorrected = self.cfg.uncorrected_bias_stddev.max(self.cfg.bias_stddev);
        let (correction, _) = self.correction();
        let at = self.last.map_or(0, |(t, _)| t);
        let measured = self.bias_in_force().filter(|_| correction.removes_power_on_bias());
        match correction {
            Correction::Raw => uncorrected,
            Correction::PowerOnBias => {
                // Never above the uncorrected gyro's: a direction not measured is left as it was.
                measured.map_or(uncorrected, |e| {
                    e.stddev_at(at, self.cfg.standstill.bias_random_walk).min(uncorrected).max(self.cfg.bias_stddev)
                })
            }
            Correction::PowerOnBiasThenModel if measured.is_none() => uncorrected,
            _ if self.rate.rate_off && self.corrector.rate_hz().is_some() && !self.resampling => uncorrected,
            _ => self.cfg.bias_stddev,
        }
    }

    /// The correction that runs, and why ([`super::choose`]).
    pub fn correction(&self) -> (Correction, &'static str) {
        choose(self.corrector.domain(), self.cfg.power_on_bias, self.cfg.model_on_new_imu)
    }

    /// The power-on bias measured so far, if a standstill was found.
    pub fn power_on_bias(&self) -> Option<&BiasEstimate> {
        self.standstill.estimate()
    }

    /// The bias subtracted where the correction removes it, and its variance: a standstill's,
    /// or before one, the bias seen in motion ([`crate::standstill::InMotion`]).
    pub fn bias_in_force(&self) -> Option<BiasEstimate> {
        self.standstill.in_force(self.last.map_or(0, |(t, _)| t))
    }

    /// Where [`Self::bias_in_force`] comes from: `standstill`, `motion` or nothing yet.
    pub fn bias_source(&self) -> &'static str {
        self.standstill.source()
    }

    pub fn standstill_counters(&self) -> &StandstillCounters {
        self.standstill.counters()
    }

    /// The gravity-aided attitude's blocks used and left out (`orientation: gravity_aided`).
    pub fn gravity_aided_blocks(&self) -> Option<(u64, u64)> {
        (self.cfg.orientation == OrientationMode::GravityAided).then(|| self.gravity_aided.as_ref().map_or((0, 0), GravityAided::blocks))
    }

    /// Seconds of samples the gravity-aided attitude was run again over at the first
    /// standstill ([`super::hindsight`]), once it has been.
    pub fn attitude_hindsight_s(&self) -> Option<f64> {
        self.hindsight.last_span_s
    }

    /// The gravity-aided filter's forward speed and its σ, m/s, where it carries one
    /// (`platform: car`).
    pub fn gravity_aided_forward_speed(&self) -> Option<(f64, f64)> {
        self.gravity_aided.as_ref().and_then(GravityAided::forward_speed)
    }

    /// A still body read at a steady rate above `standstill.max_bias`: said, not removed.
    pub fn rate_above_max_bias(&self) -> Option<crate::standstill::RateAboveMaxBias> {
        self.standstill.rate_above_max_bias()
    }

    /// True while the platform is standing still (the last window judged was still).
    pub fn standing(&self) -> bool {
        self.standstill.standing()
    }

    /// Forgets the power-on bias measured: the next standstill measures it afresh (after the
    /// IMU was power-cycled under a running node, or to re-take it on demand).
    pub fn retake_power_on_bias(&mut self) {
        self.standstill.retake();
        self.hold_from = None;
    }

    /// Turns the power-on bias on or off while running (`ros2 param set … pipeline.power_on_bias`):
    /// off, the gyro is corrected as without it and nothing is measured; on again, the
    /// estimate measured before is kept and measuring resumes.
    pub fn set_power_on_bias(&mut self, on: bool) {
        self.cfg.power_on_bias = on;
        self.hold_from = None;
    }

    /// Runs the model on an IMU it was neither trained nor adapted on, or not ([`super::choose`]).
    pub fn set_model_on_new_imu(&mut self, on: bool) {
        self.cfg.model_on_new_imu = on;
    }

    /// True while the smoothed input rate is off nominal by more than the tolerance.
    pub fn rate_off_nominal(&self) -> bool {
        self.rate.rate_off
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
        if !self.cfg.resample_to_model_rate || self.rate.smoothed_period_ns <= 0.0 {
            return;
        }
        let off = (1e9 / self.rate.smoothed_period_ns / model_rate - 1.0).abs();
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
        self.admit(s)?;
        let Advance { after_gap, turned } = self.advance_clock(s)?;
        if self.clipping.push(s) {
            self.counters.saturated_samples += 1;
        }
        let (correction, _) = self.correction();
        let raw = s;
        let debiased = self.measure_power_on_bias(s, correction);
        let s = &debiased;
        let (gyro, warming_up) = self.step_model(s, correction);
        if warming_up {
            self.counters.warmup_samples += 1;
        }
        self.last = Some((s.stamp_ns, gyro));
        self.counters.processed += 1;
        self.attitude.accumulate_gravity(s, turned, &self.cfg);
        // Set inside a standstill window: held from where it was set, should the window be still.
        if let (None, Some(q), Some(w)) = (self.hold_from, self.attitude.world_from_body, self.standstill.window_start_ns()) {
            self.hold_from = Some((w, q));
        }
        let orientation = self.orientation(s, &gyro, correction);
        Ok(CorrectedImu {
            stamp_ns: s.stamp_ns,
            gyro,
            correction: gyro - raw.gyro,
            accel: s.accel,
            gyro_variance: self.cfg.angular_velocity_stddev * self.cfg.angular_velocity_stddev,
            gyro_bias_variance: if correction == Correction::Raw { 0.0 } else { self.bias_stddev().powi(2) },
            passed_through: !correction.runs_model(),
            orientation,
            warming_up,
            after_gap,
        })
    }

    /// Refuses a sample that is not a number or not physical.
    fn admit(&mut self, s: &ImuSample) -> Result<(), Dropped> {
        if !s.is_finite() {
            self.counters.dropped_non_finite += 1;
            return Err(Dropped::NonFinite);
        }
        if !s.is_plausible() {
            self.counters.dropped_implausible += 1;
            return Err(Dropped::Implausible);
        }
        Ok(())
    }

    /// The sample's stamp against the last: refuses a duplicate or a stray stamp back, holds
    /// over a gap or a clock jump, else turns the open-loop attitude by the last rate.
    fn advance_clock(&mut self, s: &ImuSample) -> Result<Advance, Dropped> {
        let Some((t_last, w_last)) = self.last else { return Ok(Advance { after_gap: false, turned: None }) };
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
        let period_before_ns = self.rate.smoothed_period_ns;
        if !jumped_back {
            self.rate.learn_period(dt_ns, &mut self.counters);
        }
        let mut advance = Advance { after_gap: false, turned: None };
        if jumped_back || self.rate.gap_limit_ns().is_some_and(|l| dt_ns as f64 > l) {
            advance.after_gap = true;
            self.hold_over_gap(s.stamp_ns, dt_ns, jumped_back);
        } else {
            self.rate.count_missed(dt_ns, period_before_ns, &mut self.counters);
            let dt = dt_ns as f64 * 1e-9;
            advance.turned = Some(w_last * dt);
            if let Some(q) = self.attitude.world_from_body {
                self.attitude.world_from_body = Some(renormalize(q * exp(&(w_last * dt))));
                self.attitude.grow(dt, self.cfg.angular_velocity_stddev, self.bias_stddev());
            }
        }
        self.rate.last_dt_ns = dt_ns;
        Ok(advance)
    }

    /// A gap (or a clock that went back) ending at `stamp_ns`: the model and the periods start
    /// again, the attitude is held and its variance grown.
    fn hold_over_gap(&mut self, stamp_ns: i64, dt_ns: i64, jumped_back: bool) {
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
        if let Some(g) = self.gravity_aided.as_mut() {
            g.hold(stamp_ns, self.cfg.gap_variance_per_second * held_s);
        }
        self.hindsight.close();
    }

    /// Steps the model on the (debiased) sample, sample by sample or in its periods: the gyro
    /// to publish and whether the model is still warming up. The model is stepped whichever
    /// correction runs (it stays warm, and a model swapped in by ~/adapt finds its history);
    /// its output is used only where it is trusted.
    fn step_model(&mut self, s: &ImuSample, correction: Correction) -> (Vector3<f64>, bool) {
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
        if correction.runs_model() {
            (gyro, warming_up)
        } else {
            (s.gyro, false)
        }
    }

    /// The orientation to publish with its covariance, per `orientation`.
    fn orientation(&mut self, s: &ImuSample, gyro: &Vector3<f64>, correction: Correction) -> Option<(UnitQuaternion<f64>, Matrix3<f64>)> {
        match self.cfg.orientation {
            OrientationMode::OpenLoop => self.attitude.world_from_body.map(|q| (q, self.attitude.covariance)),
            // From the open loop's gravity start-up on (a mean over a rest, turns allowed for).
            OrientationMode::GravityAided => {
                self.keep_gravity_aided_bias_in_step(correction);
                match (self.gravity_aided.as_mut(), self.attitude.world_from_body) {
                    (Some(g), _) => {
                        g.push(s.stamp_ns, gyro, &s.accel);
                        self.hindsight.record(s.stamp_ns, gyro, &s.accel, self.aided_removed, correction.runs_model());
                        g.orientation()
                    }
                    (None, Some(q)) => {
                        let mut g = GravityAided::new(&self.cfg.gravity_aided, self.bias_stddev(), correction.runs_model());
                        g.start_at(q, self.attitude.covariance, s.stamp_ns, gyro);
                        let o = g.orientation();
                        self.hindsight.start(&g, self.aided_removed);
                        self.gravity_aided = Some(g);
                        o
                    }
                    (None, None) => None,
                }
            }
        }
    }

    /// The gravity-aided filter sees the gyro after the power-on bias: where that bias changes,
    /// its residual-bias state moves by as much (else a bias removed upstream would be taken
    /// off twice). While the first standstill lasts, each still window measured the bias
    /// itself: the residual is then 0 within its σ, at least `bias_stddev` (a rest's bias is not
    /// quite the one in motion: EuRoC's rotors-off rest is 1.8 mrad/s off its flight's,
    /// docs/training.md). A later standstill moves it by its change: what the filter learnt in
    /// motion is a rest-to-motion offset a rest does not see. Until 2026-12-07 only the first
    /// still window reset the residual; the rest of that standstill moved it, which kept the
    /// first window's error (V1_01 without a model: 1 mrad/s about up, its heading drifting
    /// twice as fast as the open loop's).
    fn keep_gravity_aided_bias_in_step(&mut self, correction: Correction) {
        if self.gravity_aided.as_ref().is_some_and(|g| !g.follows_upstream_bias()) {
            return;
        }
        let removed = if self.cfg.power_on_bias && correction.removes_power_on_bias() { self.standstill.bias() } else { Vector3::zeros() };
        let counters = self.standstill.counters();
        if counters.standstills > 0 {
            self.hindsight.close();
        }
        let still_windows = counters.still_windows;
        let from_standstill =
            counters.standstills == 0 && still_windows != self.aided_still_windows && self.bias_source().starts_with("standstill");
        self.aided_still_windows = still_windows;
        if removed == self.aided_removed {
            return;
        }
        let floor = self.cfg.bias_stddev.powi(2);
        let measured = from_standstill.then(|| self.bias_in_force()).flatten().map(|e| e.variance.map(|v| v.max(floor)));
        if let Some(rerun) = measured.and_then(|v| self.hindsight.rerun(removed, v)) {
            self.gravity_aided = Some(rerun);
            self.aided_removed = removed;
            return;
        }
        if let Some(g) = self.gravity_aided.as_mut() {
            g.rebase_bias(removed - self.aided_removed, measured);
        }
        self.aided_removed = removed;
    }

    /// Feeds the standstill detector the raw sample; holds the attitude over a window found
    /// still where the power-on bias is trusted (the body did not turn). Returns the sample to
    /// correct: the raw one minus the bias, where `correction` removes it.
    fn measure_power_on_bias(&mut self, s: &ImuSample, correction: Correction) -> ImuSample {
        if !self.cfg.power_on_bias {
            return *s;
        }
        let verdict = self.standstill.push(s);
        if let (Some(WindowVerdict::Still { start_ns, .. }), Some((from_ns, q))) = (verdict, self.hold_from) {
            if from_ns == start_ns && correction.removes_power_on_bias() && self.attitude.world_from_body.is_some() {
                self.attitude.world_from_body = Some(q);
            }
        }
        if self.standstill.window_start_ns() == Some(s.stamp_ns) {
            self.hold_from = self.attitude.world_from_body.map(|q| (s.stamp_ns, q));
        }
        if correction.removes_power_on_bias() {
            ImuSample { gyro: s.gyro - self.standstill.bias(), ..*s }
        } else {
            *s
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::Recording;
    use crate::infer::{BiasCorrector, ModelDomain, PassThrough, CLOCK_JUMP_SAMPLES, RATE_FROM_GAPS};
    use crate::so3::integrate_gyro;

    /// The pipeline's defaults with the open-loop orientation, whose integration these tests
    /// check against offline (the gravity-aided one is `gravity_aided::tests`').
    fn open_loop() -> PipelineConfig {
        PipelineConfig { orientation: OrientationMode::OpenLoop, ..Default::default() }
    }

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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias }), PipelineConfig { gravity_init_seconds: 0.0, ..open_loop() });
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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

    /// [`stream`]'s specific force does not turn with its rate (it is no body's motion): where
    /// a test runs the power-on bias on it, the bias seen in motion is off (it is tested on a
    /// body's motion in `the_bias_seen_in_motion_is_removed_without_a_rest`).
    fn no_motion_bias() -> crate::standstill::StandstillConfig {
        crate::standstill::StandstillConfig { in_motion: crate::standstill::InMotion::Off, ..Default::default() }
    }

    /// Without a model the attitude's σ allows for the gyro's own bias, not a model's residual:
    /// after 10 s at 30 mrad/s the tilt σ is about 0.3 rad (at 1 mrad/s, 0.01, both beside
    /// the initial 0.01 rad).
    #[test]
    fn an_uncorrected_gyro_states_its_own_bias() {
        let cfg = PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, standstill: no_motion_bias(), ..open_loop() };
        let tilt_sigma = |corrector: Box<dyn GyroCorrector>| {
            let mut p = Pipeline::new(corrector, cfg.clone());
            let last = stream(2001, 5_000_000).iter().map(|s| p.push(s).unwrap()).last().unwrap();
            last.orientation.unwrap().1[(0, 0)].sqrt()
        };
        let corrected = tilt_sigma(Box::new(BiasCorrector { bias: Vector3::zeros() }));
        let passed = tilt_sigma(Box::new(PassThrough));
        assert!((corrected - 0.0142).abs() < 0.001 && (passed - 0.3002).abs() < 0.006, "{corrected} {passed}");
    }

    /// A model whose correction is an error of its own (what the bundled model is on an IMU it
    /// never saw), for the guard.
    struct Wrong(ModelDomain);

    impl GyroCorrector for Wrong {
        fn step(&mut self, gyro: &Vector3<f64>, _accel: &Vector3<f64>) -> Vector3<f64> {
            gyro + Vector3::new(0.01, 0.0, 0.0)
        }
        fn reset(&mut self) {}
        fn window(&self) -> usize {
            1
        }
        fn rate_hz(&self) -> Option<f64> {
            None
        }
        fn name(&self) -> &str {
            "wrong"
        }
        fn domain(&self) -> ModelDomain {
            self.0
        }
    }

    /// 2 s at rest with a turn-on bias, then the motion of [`stream`].
    fn rest_then_motion(bias: Vector3<f64>) -> Vec<ImuSample> {
        let rest = (0..400).map(|k| ImuSample { stamp_ns: 1_000_000 + k * 5_000_000, gyro: bias, accel: Vector3::new(0.0, 0.0, 9.81) });
        let t0 = 1_000_000 + 400 * 5_000_000;
        rest.chain(stream(1600, 5_000_000).into_iter().map(|s| ImuSample {
            stamp_ns: s.stamp_ns - 1_000_000 + t0,
            gyro: s.gyro + bias,
            ..s
        }))
        .collect()
    }

    #[test]
    fn a_new_imu_runs_the_power_on_bias_not_the_model() {
        let bias = Vector3::new(0.04, -0.06, 0.02);
        let imu = rest_then_motion(bias);
        let cfg = PipelineConfig { gravity_init_seconds: 0.2, standstill: no_motion_bias(), ..open_loop() };
        let mut p = Pipeline::new(Box::new(Wrong(ModelDomain::NewImu)), cfg.clone());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert_eq!(p.correction().0, Correction::PowerOnBias);
        let e = p.power_on_bias().expect("the rest measured");
        assert!((e.bias - bias).amax() < 1e-12, "{}", e.bias);
        // After the rest: the raw gyro minus the bias, not the model's output.
        assert!((out[1000].gyro - (imu[1000].gyro - bias)).amax() < 1e-12);
        assert!(out[1000].passed_through);
        // Held over the rest: the attitude at its end is the one set from gravity.
        let set = out.iter().position(|o| o.orientation.is_some()).unwrap();
        let at_rest_end = out[399].orientation.unwrap().0;
        assert!(
            at_rest_end.angle_to(&out[set].orientation.unwrap().0) < 1e-9,
            "{}",
            at_rest_end.angle_to(&out[set].orientation.unwrap().0)
        );
        // Asked for, the model runs on the raw gyro; adapted after the bias, after it.
        let mut p = Pipeline::new(Box::new(Wrong(ModelDomain::NewImu)), PipelineConfig { model_on_new_imu: true, ..cfg.clone() });
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!((out[1000].gyro - imu[1000].gyro - Vector3::new(0.01, 0.0, 0.0)).amax() < 1e-12);
        let mut p = Pipeline::new(Box::new(Wrong(ModelDomain::AdaptedAfterPowerOnBias)), cfg.clone());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!((out[1000].gyro - (imu[1000].gyro - bias) - Vector3::new(0.01, 0.0, 0.0)).amax() < 1e-12);
        // Trained on this IMU: the model on the raw gyro, the rest reported only.
        let mut p = Pipeline::new(Box::new(Wrong(ModelDomain::Trained)), cfg);
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!((out[1000].gyro - imu[1000].gyro - Vector3::new(0.01, 0.0, 0.0)).amax() < 1e-12);
        assert!(p.power_on_bias().is_some());
    }

    /// [`Wrong`] trained on this IMU with its recordings' power-on biases removed, which it
    /// remembers (as a model's `trained_power_on_biases`).
    struct TrainedWithout(Vec<crate::model::export::TrainedPowerOn>);

    impl GyroCorrector for TrainedWithout {
        fn step(&mut self, gyro: &Vector3<f64>, accel: &Vector3<f64>) -> Vector3<f64> {
            Wrong(ModelDomain::TrainedAfterPowerOnBias).step(gyro, accel)
        }
        fn reset(&mut self) {}
        fn window(&self) -> usize {
            1
        }
        fn rate_hz(&self) -> Option<f64> {
            None
        }
        fn name(&self) -> &str {
            "trained without its power-on biases"
        }
        fn domain(&self) -> ModelDomain {
            ModelDomain::TrainedAfterPowerOnBias
        }
        fn earlier_power_ons(&self, floor_stddev: f64) -> Option<crate::standstill::BiasPrediction> {
            crate::infer::predict_from(&self.0, floor_stddev)
        }
    }

    #[test]
    fn a_model_trained_without_its_power_on_biases_starts_from_what_they_predict() {
        let power_on = |k: usize, bias: [f64; 3]| crate::model::export::TrainedPowerOn {
            recording: format!("p{k}"),
            bias_rad_s: bias,
            stddev_rad_s: [2e-4; 3],
            still_s: 3.0,
        };
        // z repeats, x changes sign between power-ons: only z is predicted.
        let trained = vec![power_on(1, [0.02, -0.031, 0.079]), power_on(2, [-0.02, -0.029, 0.081]), power_on(3, [0.01, -0.030, 0.080])];
        let cfg = PipelineConfig { gravity_init_seconds: 0.2, standstill: no_motion_bias(), ..open_loop() };
        // Moving from the first sample: nothing measured yet.
        let imu = stream(400, 5_000_000);
        let offset = Vector3::new(0.01, 0.0, 0.0);
        let mut p = Pipeline::new(Box::new(TrainedWithout(trained.clone())), cfg.clone());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert_eq!(p.correction().0, Correction::PowerOnBiasThenModel);
        let predicted = Vector3::new(0.0, -0.030, 0.080);
        assert!((out[300].gyro - (imu[300].gyro - predicted + offset)).amax() < 1e-12, "{}", out[300].gyro - imu[300].gyro);
        // This robot's own bias memory wins over the training recordings'.
        let own = crate::standstill::BiasPrediction {
            bias: Vector3::new(0.0, 0.0, 0.05),
            variance: Vector3::repeat(1e-6),
            applied: [false, false, true],
            power_ons: 4,
        };
        let with_memory =
            PipelineConfig { standstill: crate::standstill::StandstillConfig { remembered: Some(own), ..cfg.standstill }, ..cfg.clone() };
        let mut p = Pipeline::new(Box::new(TrainedWithout(trained)), with_memory);
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!((out[300].gyro - (imu[300].gyro - own.bias + offset)).amax() < 1e-12);
        // A model trained on the raw stream predicts nothing: the model on the raw gyro.
        let mut p = Pipeline::new(Box::new(Wrong(ModelDomain::Trained)), cfg);
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!((out[300].gyro - (imu[300].gyro + offset)).amax() < 1e-12);
    }

    #[test]
    fn a_measured_power_on_bias_states_its_own_sigma() {
        let imu = rest_then_motion(Vector3::new(0.03, 0.0, 0.0));
        let cfg = PipelineConfig { gravity_init_seconds: 0.2, standstill: no_motion_bias(), ..open_loop() };
        let sigma_after = |c: Box<dyn GyroCorrector>| {
            let mut p = Pipeline::new(c, cfg.clone());
            imu.iter().map(|s| p.push(s).unwrap()).last().unwrap().orientation.unwrap().1[(0, 0)].sqrt()
        };
        // The rest measured the bias exactly (no noise): the bias term is bias_stddev's, far
        // below the uncorrected gyro's.
        let measured = sigma_after(Box::new(PassThrough));
        let without = {
            let mut p = Pipeline::new(Box::new(PassThrough), PipelineConfig { power_on_bias: false, ..cfg.clone() });
            imu.iter().map(|s| p.push(s).unwrap()).last().unwrap().orientation.unwrap().1[(0, 0)].sqrt()
        };
        assert!(measured < without / 5.0, "{measured} {without}");
        // The rate's stated bias: the uncorrected gyro's before the rest ends, the estimate's
        // after; none for the gyro as measured (power_on_bias off).
        let mut p = Pipeline::new(Box::new(PassThrough), cfg.clone());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert_eq!(out[10].gyro_bias_variance, cfg.uncorrected_bias_stddev.powi(2));
        assert_eq!(out[1000].gyro_bias_variance, cfg.bias_stddev.powi(2));
        let mut p = Pipeline::new(Box::new(PassThrough), PipelineConfig { power_on_bias: false, ..cfg.clone() });
        assert_eq!(imu.iter().map(|s| p.push(s).unwrap()).last().unwrap().gyro_bias_variance, 0.0);
    }

    /// No rest at all, a consumer gyro's bias, a body that turns about every axis: the bias
    /// seen in motion is removed once known, its σ on the attitude below the uncorrected one.
    #[test]
    fn the_bias_seen_in_motion_is_removed_without_a_rest() {
        let bias = Vector3::new(0.05, -0.04, 0.03);
        let imu = crate::motion_bias::tumbling(bias, 120.0, 0.5);
        let cfg = PipelineConfig { gravity_init_seconds: 0.2, ..open_loop() };
        let mut p = Pipeline::new(Box::new(PassThrough), cfg.clone());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        assert!(p.power_on_bias().is_none(), "no standstill in a tumble");
        let e = p.bias_in_force().expect("the bias seen in motion");
        assert_eq!(p.bias_source(), "motion");
        let last = out.len() - 1;
        let removed = imu[last].gyro - out[last].gyro;
        assert!((removed - bias).amax() < 0.005, "removed {removed}, bias {bias}");
        assert!((e.bias - removed).amax() < 1e-12);
        // Its σ stands in the attitude's covariance: below what the uncorrected gyro allows.
        let mut off = Pipeline::new(Box::new(PassThrough), PipelineConfig { standstill: no_motion_bias(), ..cfg });
        let unaided = imu.iter().map(|s| off.push(s).unwrap()).last().unwrap();
        assert!(out[last].orientation.unwrap().1.trace() < unaided.orientation.unwrap().1.trace());
        assert!((imu[last].gyro - unaided.gyro).amax() < 1e-15, "off: nothing removed");
    }

    #[test]
    fn a_gap_resets_and_holds_the_attitude() {
        let mut imu = stream(400, 5_000_000);
        for s in &mut imu[200..] {
            s.stamp_ns += 1_000_000_000; // one second of nothing
        }
        let mut p = Pipeline::new(
            Box::new(BiasCorrector { bias: Vector3::zeros() }),
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..open_loop() },
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
        let cfg = PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..open_loop() };
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
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..open_loop() },
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
            PipelineConfig { nominal_rate_hz: 200.0, gravity_init_seconds: 0.0, ..open_loop() },
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
        let mut p =
            Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), PipelineConfig { gravity_init_seconds: 0.0, ..open_loop() });
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
        let out: Vec<CorrectedImu> = imu.iter().map(|s| p.push(s).unwrap()).collect();
        let k = out.iter().position(|o| o.orientation.is_some()).unwrap();
        assert!(k >= 600, "set at sample {k}, in the bend");
        let (q, cov) = out[k].orientation.unwrap();
        let (r, pch, _) = q.euler_angles();
        assert!(r.abs() < 1e-6 && pch.abs() < 1e-6 && cov[(0, 0)] < 1e-3, "{r} {pch} {cov}");
        // Turning for ever: set after 20 intervals, its stated tilt σ at least the 21.7° it is off.
        let mut imu = stream(3000, 5_000_000);
        imu.iter_mut().for_each(|s| bend(s, true));
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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
        let mut p = Pipeline::new(Box::new(BiasCorrector { bias: Vector3::zeros() }), open_loop());
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
        let cfg = PipelineConfig { gravity_init_seconds: 0.0, ..open_loop() };
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
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), open_loop());
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
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), open_loop());
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
        let mut p = Pipeline::new(Box::new(WindowMean(Default::default())), open_loop());
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
