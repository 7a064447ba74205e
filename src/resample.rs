//! An IMU stream at another rate than a model's, brought to the model's rate.
//!
//! The network counts samples: on a 1-kHz IMU a 200-Hz model's window would span a fifth of
//! the time it was trained on. So the stream is cut into the model's periods from its first
//! stamp, each period's sample is the mean of what the IMU measured over it (each sample held
//! until the next one, as the attitude integration and the training losses hold it, and split
//! where a period ends), and the model runs once a period. The mean is the rotation increment
//! over the period divided by its length. A period is complete when a stamp at or after its end
//! arrives; each input sample gets the correction `ω̂ − ω̄` of the last period completed at its
//! arrival: causal, one period late, and with Ĉ_ω applied to the period's mean rather than to
//! the sample (the two differ by (Ĉ_ω − I)(ω − ω̄), where Ĉ_ω stays within 1 % of I).

use nalgebra::Vector3;

use crate::core::ImuSample;

/// Accumulates a stream into a model's periods (allocation-free, one call a sample).
#[derive(Debug, Clone)]
pub struct PeriodMeans {
    period_ns: f64,
    /// The last sample, held until the next one comes.
    last: Option<ImuSample>,
    /// The first stamp: period k is [origin + k·T, origin + (k+1)·T), rounded to the ns. Kept
    /// in integer ns: as f64, a stamp since 1970 resolves only 256 ns.
    origin_ns: i64,
    /// The period being filled.
    period: u64,
    gyro_sum: Vector3<f64>,
    accel_sum: Vector3<f64>,
}

impl PeriodMeans {
    /// Periods of `rate_hz` (a model's rate, > 0).
    pub fn new(rate_hz: f64) -> Self {
        PeriodMeans {
            period_ns: 1e9 / rate_hz,
            last: None,
            origin_ns: 0,
            period: 0,
            gyro_sum: Vector3::zeros(),
            accel_sum: Vector3::zeros(),
        }
    }

    /// Start again: the next sample starts the periods (it covers no time itself).
    pub fn reset(&mut self) {
        self.last = None;
        self.period = 0;
        self.gyro_sum = Vector3::zeros();
        self.accel_sum = Vector3::zeros();
    }

    /// Add `s`: the sample before it is held until `s`'s stamp. Calls `period` with each
    /// period that completes: the period's start stamp (ns) and its mean gyro and
    /// accelerometer. Stamps must increase (the pipeline refuses the others before this).
    pub fn push(&mut self, s: &ImuSample, mut period: impl FnMut(i64, Vector3<f64>, Vector3<f64>)) {
        let Some(last) = self.last.filter(|l| s.stamp_ns > l.stamp_ns) else {
            if self.last.is_none() {
                self.last = Some(*s);
                self.origin_ns = s.stamp_ns;
                self.period = 0;
            }
            return;
        };
        let mut from = last.stamp_ns;
        loop {
            let end = self.boundary_ns(self.period + 1);
            if s.stamp_ns < end {
                break;
            }
            let start = self.boundary_ns(self.period);
            let part = (end - from) as f64;
            let length = (end - start) as f64;
            period(start, (self.gyro_sum + last.gyro * part) / length, (self.accel_sum + last.accel * part) / length);
            self.gyro_sum = Vector3::zeros();
            self.accel_sum = Vector3::zeros();
            from = end;
            self.period += 1;
        }
        let part = (s.stamp_ns - from) as f64;
        self.gyro_sum += last.gyro * part;
        self.accel_sum += last.accel * part;
        self.last = Some(*s);
    }

    /// Start of period `k`, ns.
    fn boundary_ns(&self, k: u64) -> i64 {
        self.origin_ns.saturating_add((k as f64 * self.period_ns).round() as i64)
    }
}

/// An interval longer than this many model periods is a hole: the periods start again after
/// it, and nothing is held across it (the node's pipeline default `gap_periods`, after which
/// it resets the model and restarts the periods).
pub const GAP_PERIODS: f64 = 5.0;

/// A recording's IMU at a model's rate: one sample a period of `rate_hz`, stamped at the
/// period's start (see the module doc), and for each input sample the index of the last period
/// completed at its arrival (since the last hole: none before the first after it).
pub fn to_model_rate(imu: &[ImuSample], rate_hz: f64) -> (Vec<ImuSample>, Vec<Option<usize>>) {
    let mut means = PeriodMeans::new(rate_hz);
    let gap_ns = GAP_PERIODS * 1e9 / rate_hz;
    let span_s = match (imu.first(), imu.last()) {
        (Some(a), Some(b)) => (b.stamp_ns - a.stamp_ns).max(0) as f64 * 1e-9,
        _ => 0.0,
    };
    let mut periods = Vec::with_capacity((span_s * rate_hz) as usize + 1);
    let mut current = None;
    let mut last_stamp = None;
    let last_period = imu
        .iter()
        .map(|s| {
            if last_stamp.is_some_and(|t: i64| (s.stamp_ns - t) as f64 > gap_ns) {
                means.reset();
                current = None;
            }
            last_stamp = Some(last_stamp.map_or(s.stamp_ns, |t: i64| t.max(s.stamp_ns)));
            means.push(s, |stamp_ns, gyro, accel| {
                periods.push(ImuSample { stamp_ns, gyro, accel });
                current = Some(periods.len() - 1);
            });
            current
        })
        .collect();
    (periods, last_period)
}

/// Each input sample's gyro plus the correction of the last period completed at its arrival
/// (`corrected[k] − periods[k].gyro`); the gyro as measured before the first.
pub fn corrections_to_input(
    imu: &[ImuSample],
    periods: &[ImuSample],
    corrected: &[Vector3<f64>],
    last_period: &[Option<usize>],
) -> Vec<Vector3<f64>> {
    imu.iter()
        .zip(last_period)
        .map(|(s, k)| match k {
            Some(k) => s.gyro + (corrected[*k] - periods[*k].gyro),
            None => s.gyro,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn sample(stamp_ns: i64, g: f64) -> ImuSample {
        ImuSample { stamp_ns, gyro: Vector3::new(g, -2.0 * g, 0.5), accel: Vector3::new(0.0, g, 9.81) }
    }

    /// A 200-Hz stream held five times at 1 kHz gives back the 200-Hz samples, stamped at
    /// their own stamps.
    #[test]
    fn a_held_stream_gives_back_its_samples() {
        let slow: Vec<ImuSample> = (0..50).map(|n| sample(1_000_000_000 + n * 5_000_000, (n as f64 * 0.37).sin())).collect();
        let fast: Vec<ImuSample> =
            slow.iter().flat_map(|s| (0..5).map(move |j| ImuSample { stamp_ns: s.stamp_ns + j * 1_000_000, ..*s })).collect();
        let (periods, last) = to_model_rate(&fast, 200.0);
        assert_eq!(periods.len(), slow.len() - 1, "the last period is not complete");
        for (p, s) in periods.iter().zip(&slow) {
            assert_eq!(p.stamp_ns, s.stamp_ns);
            assert!((p.gyro - s.gyro).norm() < 1e-12 && (p.accel - s.accel).norm() < 1e-12, "{p:?} {s:?}");
        }
        // A period completes when the next one's first sample comes: that sample and the rest of
        // its period get it.
        assert_eq!(&last[..5], &[None; 5]);
        assert_eq!(&last[5..11], &[Some(0), Some(0), Some(0), Some(0), Some(0), Some(1)]);
    }

    /// The corrections go back to each sample causally: a constant correction comes back as it
    /// was, after the first period.
    #[test]
    fn corrections_reach_every_sample_after_the_first_period() {
        let imu: Vec<ImuSample> = (0..40).map(|k| sample(k * 2_000_000, k as f64 * 0.01)).collect();
        let (periods, last) = to_model_rate(&imu, 200.0);
        let offset = Vector3::new(0.01, -0.02, 0.03);
        let corrected: Vec<Vector3<f64>> = periods.iter().map(|p| p.gyro + offset).collect();
        let out = corrections_to_input(&imu, &periods, &corrected, &last);
        for (k, (o, s)) in out.iter().zip(&imu).enumerate() {
            let want = if k < 3 { s.gyro } else { s.gyro + offset };
            assert_eq!(last[k].is_some(), k >= 3, "sample {k} at {} ms", s.stamp_ns / 1_000_000);
            assert!((o - want).norm() < 1e-12, "sample {k}: {o} against {want}");
        }
    }

    /// A hole longer than the gap limit starts the periods again: no period spans it, and the
    /// samples after it are not corrected until a period after it completes (as in the node).
    #[test]
    fn a_hole_starts_the_periods_again() {
        let mut imu: Vec<ImuSample> = (0..20).map(|k| sample(k * 1_000_000, 0.1)).collect();
        imu.extend((0..20).map(|k| sample(3_600_000_000_000 + k * 1_000_000, 0.2)));
        let (periods, last) = to_model_rate(&imu, 200.0);
        assert_eq!(periods.len(), 3 + 3, "{periods:?}");
        assert_eq!(periods[3].stamp_ns, 3_600_000_000_000);
        assert!(periods.iter().all(|p| p.gyro.x == 0.1 || p.gyro.x == 0.2));
        assert_eq!(&last[19..26], &[Some(2), None, None, None, None, None, Some(3)]);
    }

    proptest! {
        /// Whatever the stamps, the periods keep the rotation the samples held: the integral of
        /// the rate over the completed periods is the input's over the same span.
        #[test]
        fn periods_keep_the_integral(dts in proptest::collection::vec(0.01f64..4.99, 2..300), rate in 50.0f64..1500.0) {
            // Stamps since 1970, where an f64 resolves only 256 ns; intervals of 0.01 to 4.99
            // model periods (beyond, a hole).
            let mut t = 1_403_715_273_262_142_976;
            let imu: Vec<ImuSample> = dts
                .iter()
                .enumerate()
                .map(|(k, dt)| { t += (dt * 1e9 / rate) as i64; sample(t, (k as f64 * 0.7).cos()) })
                .collect();
            let (periods, _) = to_model_rate(&imu, rate);
            // Period k spans [t₀ + k·T, t₀ + (k+1)·T), each end rounded to the ns.
            let boundary = |k: usize| imu[0].stamp_ns + (k as f64 * 1e9 / rate).round() as i64;
            let from_periods: f64 = periods.iter().enumerate().map(|(k, p)| p.gyro.x * (boundary(k + 1) - boundary(k)) as f64 * 1e-9).sum();
            let end = boundary(periods.len());
            // The input held over [t_k, t_{k+1}), up to the last period's end.
            let mut from_input = 0.0;
            for w in imu.windows(2) {
                let (a, b) = (w[0].stamp_ns, w[1].stamp_ns.min(end));
                if b > a {
                    from_input += w[0].gyro.x * (b - a) as f64 * 1e-9;
                }
            }
            prop_assert!((from_periods - from_input).abs() < 1e-9 * (1.0 + from_input.abs()), "{from_periods} against {from_input}");
            prop_assert!(periods.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
        }
    }
}
