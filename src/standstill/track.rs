//! The detector over a whole recording, as the pipeline runs it sample by sample: the bias in
//! force at each sample and the still windows, for eval, adapt and the bias memory.

use nalgebra::Vector3;

use super::{BiasEstimate, BiasPrediction, PowerOnBias, StandstillConfig, StandstillCounters, WindowVerdict};
use crate::core::ImuSample;

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
    /// A still body read at a steady rate above `max_bias` (said in the note).
    pub rate_above_max_bias: Option<super::RateAboveMaxBias>,
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
        track.rate_above_max_bias = p.rate_above_max_bias();
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
        let note = match &self.rate_above_max_bias {
            Some(r) => format!("{note}; {}", r.says()),
            None => note,
        };
        let note = match self.counters.new_power_ons {
            0 => note,
            n => format!("{note}; {n} standstill(s) after a hole in the input contradicted the bias before it: taken as a new power-on (the IMU power-cycled)"),
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
