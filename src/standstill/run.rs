//! One standstill in progress (consecutive still windows): its sums, its level part kept
//! should it end in a slow turn, the turn rate its tilt shows as σ, and its measurement fused
//! into the estimate.

use nalgebra::Vector3;

use super::estimate::fuse;
use super::{BiasEstimate, PowerOnBias};
use crate::core::STANDARD_GRAVITY;

/// A standstill's gravity may turn by this fraction of `max_tilt_change` and still count as
/// level: where a standstill ends tilting, its windows up to the one before the last level one
/// are kept.
const LEVEL_FRACTION: f64 = 0.25;

/// One standstill in progress: consecutive still windows.
#[derive(Debug, Clone, Copy)]
pub(super) struct Run {
    sums: RunSums,
    /// Its first window's gravity direction, and that window's middle.
    pub(super) gravity: Vector3<f64>,
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

impl PowerOnBias {
    /// Adds a still window to the standstill in progress and updates the estimate.
    pub(super) fn accept_window(&mut self, start_ns: i64, end_ns: i64) {
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
    pub(super) fn keep_the_level_part(&mut self) {
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

    pub(super) fn end_run(&mut self) {
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
