//! The input's clock: its nominal period (given, or the median of its first intervals), its
//! smoothed rate, what counts as a gap or a hole, and a source clock that went back.

use super::Counters;

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

/// The input stream's rate as the pipeline measures it, and what is a gap in it.
#[derive(Debug, Clone)]
pub(super) struct StreamRate {
    pub(super) nominal_period_ns: Option<f64>,
    pub(super) smoothed_period_ns: f64,
    pub(super) rate_off: bool,
    first_dts: [i64; 8],
    n_first_dts: usize,
    /// Consecutive intervals longer than a gap: a few in a row are a rate, not a hole.
    consecutive_gaps: u32,
    /// Whether the nominal period came from the first intervals (not the model or config).
    period_learned: bool,
    /// The period gaps are measured in while a stream runs slower than a fixed nominal (the
    /// model's): else every sample of a 20-Hz stream into a 200-Hz model was a gap, the model
    /// never warmed up and the attitude was never integrated.
    pub(super) slow_period_ns: Option<f64>,
    /// The interval before the last, ns: a hole is counted only in a regular stream.
    pub(super) last_dt_ns: i64,
    gap_periods: f64,
    rate_tolerance: f64,
}

impl StreamRate {
    pub(super) fn new(nominal_period_ns: Option<f64>, gap_periods: f64, rate_tolerance: f64) -> Self {
        StreamRate {
            nominal_period_ns,
            smoothed_period_ns: nominal_period_ns.unwrap_or(0.0),
            rate_off: false,
            first_dts: [0; 8],
            n_first_dts: 0,
            consecutive_gaps: 0,
            period_learned: false,
            slow_period_ns: None,
            last_dt_ns: 0,
            gap_periods,
            rate_tolerance,
        }
    }

    /// this interval) after a regular one
    /// stands for k − 1 samples that never arrived. Stamps taken on arrival (bursts of nearly
    /// equal stamps, then a pause) are not regular, and count nothing.
    pub(super) fn count_missed(&mut self, dt_ns: i64, p: f64, counters: &mut Counters) {
        let regular = (self.last_dt_ns as f64 - p).abs() <= 0.25 * p;
        if self.gap_limit_ns().is_some() && p > 0.0 && regular && dt_ns as f64 >= 1.5 * p {
            counters.missed_samples += ((dt_ns as f64 / p).round() as u64).saturating_sub(1);
        }
    }

    /// An interval longer than this is a gap, ns.
    pub(super) fn gap_limit_ns(&self) -> Option<f64> {
        self.slow_period_ns.or(self.nominal_period_ns).map(|p| self.gap_periods * p)
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
    pub(super) fn learn_period(&mut self, dt_ns: i64, counters: &mut Counters) {
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
                        if median > p * (1.0 + self.rate_tolerance) {
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
                        counters.rate_changes += 1;
                        return;
                    }
                    // The nominal is the model's: keep it (and say the rate is off), but measure
                    // gaps in the stream's own period.
                    self.slow_period_ns = Some(dt_ns as f64);
                    self.smoothed_period_ns = dt_ns as f64;
                }
                let off = (self.smoothed_period_ns / p - 1.0).abs() > self.rate_tolerance || self.slow_period_ns.is_some();
                if off && !self.rate_off {
                    counters.rate_changes += 1;
                }
                self.rate_off = off;
                // Back at the nominal rate: gaps are the nominal's again.
                if self.slow_period_ns.is_some() && (self.smoothed_period_ns / p - 1.0).abs() <= self.rate_tolerance {
                    self.slow_period_ns = None;
                }
            }
        }
    }
}
