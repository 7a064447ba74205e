//! A window of short blocks and its judgement: still, or why not (moving, turning, tilting,
//! inconsistent with the estimate), and the counts of each.

use nalgebra::Vector3;

use super::steady_rate::SteadyRate;
use super::{InMotion, PowerOnBias};
use crate::core::{ImuSample, STANDARD_GRAVITY};

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
    /// Standstills after a hole of `new_power_on_gap_s` (or a clock that went back) that
    /// contradicted the estimate, taken as a new power-on's (the IMU power-cycled).
    pub new_power_ons: u64,
}

/// Sums over one block or window.
#[derive(Debug, Clone, Copy)]
pub(super) struct Sums {
    pub(super) gyro: Vector3<f64>,
    pub(super) accel: Vector3<f64>,
    /// The accelerometer's sum of squares per axis: the scatter inside a block.
    pub(super) accel_sq: Vector3<f64>,
    pub(super) n: u32,
}

impl Sums {
    pub(super) const ZERO: Sums =
        Sums { gyro: Vector3::new(0.0, 0.0, 0.0), accel: Vector3::new(0.0, 0.0, 0.0), accel_sq: Vector3::new(0.0, 0.0, 0.0), n: 0 };
}

impl PowerOnBias {
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
                let hole = self.cfg.new_power_on_gap_s;
                if dt < 0 || (hole > 0.0 && dt as f64 * 1e-9 >= hole) {
                    self.after_hole = true;
                }
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
        self.block.accel_sq += s.accel.component_mul(&s.accel);
        self.block.n += 1;
        self.last = Some((s.stamp_ns, s.gyro));
        verdict
    }

    pub(super) fn clear_window(&mut self) {
        self.block = Sums::ZERO;
        self.window = Sums::ZERO;
        self.accel_within_var = Vector3::zeros();
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
        // The scatter about the block's own mean: a vibration shows in it, a trend barely does.
        let mean_sq = self.accel_means[k].component_mul(&self.accel_means[k]);
        self.accel_within_var += (self.block.accel_sq / n - mean_sq).map(|v| v.max(0.0));
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
        let judged = match self.judge() {
            Err(NotStill::Inconsistent) if self.after_hole => {
                self.new_power_on();
                self.judge()
            }
            judged => judged,
        };
        if judged.is_ok() {
            self.after_hole = false;
        }
        if judged == Err(NotStill::Turning) {
            self.note_steady_rate(start_ns, hold_rate);
        } else {
            self.end_steady();
        }
        let verdict = match judged {
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
            || span(&self.accel_means[..k]) >= self.allowed_accel_spread()
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

    /// A window refused only as turning: extends the run at its rate, or starts one.
    fn note_steady_rate(&mut self, start_ns: i64, rate: Vector3<f64>) {
        let gravity = self.window.accel / self.window.n.max(1) as f64;
        let extended = self.steady.as_mut().is_some_and(|s| s.extend(self.window_s, rate, gravity, self.cfg.max_gyro_spread));
        if !extended {
            self.end_steady();
            self.steady = Some(SteadyRate::start(start_ns, self.window_s, rate, gravity));
        }
    }

    /// Ends the run of windows at a steady rate above `max_bias`, keeping it if long enough.
    pub(super) fn end_steady(&mut self) {
        if let Some(said) = self.steady.take().and_then(|s| s.said(self.cfg.max_bias, self.cfg.max_tilt_change)) {
            self.above_max_bias = Some(said);
        }
    }

    /// How far the window's accelerometer block means may spread: the fixed limit, or
    /// `vibration_sigmas` σ of a block mean where the scatter inside the blocks is larger (a
    /// vibration leaves a residue in each block's mean that grows with its amplitude).
    fn allowed_accel_spread(&self) -> f64 {
        let k = self.blocks_done.max(1) as f64;
        let per_block = self.window.n.max(1) as f64 / k;
        let block_mean_sigma = (self.accel_within_var.max() / k / per_block).sqrt();
        self.cfg.max_accel_spread.max(self.cfg.vibration_sigmas * block_mean_sigma)
    }
}
