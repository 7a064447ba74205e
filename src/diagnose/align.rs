//! Load a sim bag and a real bag and put them on one time grid.
//!
//! The sim bag's stamps are the grid. When the real stamps are the same, nothing is done;
//! otherwise a coarse lag (whole sim samples, from the cross-correlation of the gyro norms)
//! is removed first and the real channels are resampled onto the sim stamps by cubic
//! Hermite interpolation. Both steps are written down in [`Aligned::notes`]: a sub-sample
//! delay is left in the residual on purpose, for the `time_offset` term to explain.

use std::path::Path;

use nalgebra::UnitQuaternion;

use super::DiagnoseError;
use crate::bag::{read_recording, BagReader, RecordingTopics};
use crate::core::{ImuSample, Recording};
use crate::msg::{Imu, RosMessage};

/// Sim and real IMU streams on the sim stamps, with what the diagnosis needs beside them.
#[derive(Debug, Clone)]
pub struct Aligned {
    /// Common stamps (the sim bag's, inside the overlap), ns.
    pub stamps_ns: Vec<i64>,
    /// Sim channels: gyro x y z (rad/s), accel x y z (m/s²).
    pub sim: [Vec<f64>; 6],
    /// Real channels on the same stamps.
    pub real: [Vec<f64>; 6],
    /// The sim's per-sample white-noise variance (gyro (rad/s)², accel (m/s²)²), from the
    /// sim bag's covariance fields (or estimated, see the notes).
    pub sim_variance: (f64, f64),
    /// The real stream's per-sample white-noise variance before any left-out term: the sim's
    /// when the rates agree (the simulator claims to model the real sensor).
    pub real_variance: (f64, f64),
    /// Attitude of the IMU frame at each stamp (ground truth, slerped), if the bags carry it.
    pub world_from_imu: Option<Vec<UnitQuaternion<f64>>>,
    /// Die temperature at each stamp, °C, if either bag carries it.
    pub temperature_c: Option<Vec<f64>>,
    /// What was done to align, and what is missing.
    pub notes: Vec<String>,
    /// Stamp artefacts of the real stream (its driver's or recording's, not the sensor's
    /// physics), one sentence each, measured before any fit.
    pub artefacts: Vec<String>,
    /// Per common stamp: true inside a gap of the real stream (no real sample there, only an
    /// interpolation across the gap), which the fit leaves out. Empty: no gap.
    pub in_real_gap: Vec<bool>,
    /// Per common stamp: true where the reference the sim was made from has a dropout (a
    /// ground truth that lost tracking: the sim there is made up across the hole), which the
    /// fit leaves out too. Empty: none.
    pub in_reference_gap: Vec<bool>,
    /// The sim recording as read (for writing the corrected bag).
    pub sim_recording: Recording,
    /// Samples of the recordings each common point is the mean of: 1 at full rate, more when
    /// compared at a measured reference's bandwidth ([`Aligned::block_means`]).
    pub samples_per_point: usize,
}

impl Aligned {
    /// Per common stamp: left out of the fit (a gap of the real stream or of the reference).
    pub fn left_out(&self) -> Vec<bool> {
        let flag = |v: &[bool], i: usize| v.get(i).copied().unwrap_or(false);
        (0..self.len()).map(|i| flag(&self.in_real_gap, i) || flag(&self.in_reference_gap, i)).collect()
    }

    /// Number of common samples.
    pub fn len(&self) -> usize {
        self.stamps_ns.len()
    }

    pub fn is_empty(&self) -> bool {
        self.stamps_ns.is_empty()
    }

    /// Mean sample interval, s.
    pub fn dt(&self) -> f64 {
        let n = self.len();
        if n < 2 {
            return 0.0;
        }
        (self.stamps_ns[n - 1] - self.stamps_ns[0]) as f64 * 1e-9 / (n - 1) as f64
    }
}

/// The per-sample white-noise variances stated by the first IMU message's covariance
/// diagonals (mean of the three), `None` when they are absent (zero, negative or unknown).
pub fn covariance_variances(path: &Path, imu_topic: &str) -> Result<Option<(f64, f64)>, DiagnoseError> {
    for m in BagReader::open(path)? {
        let m = m?;
        if *m.topic == *imu_topic && *m.type_name == *Imu::TYPE_NAME {
            let imu = Imu::decode(&m.data).map_err(|e| DiagnoseError::Input(format!("{}: first IMU message: {e}", path.display())))?;
            let g =
                (imu.angular_velocity_covariance.0[0] + imu.angular_velocity_covariance.0[4] + imu.angular_velocity_covariance.0[8]) / 3.0;
            let a = (imu.linear_acceleration_covariance.0[0]
                + imu.linear_acceleration_covariance.0[4]
                + imu.linear_acceleration_covariance.0[8])
                / 3.0;
            return Ok((g > 0.0 && a > 0.0 && g.is_finite() && a.is_finite()).then_some((g, a)));
        }
    }
    Ok(None)
}

/// Channels of IMU samples, gyro then accel.
pub fn channels(imu: &[ImuSample]) -> [Vec<f64>; 6] {
    std::array::from_fn(|c| imu.iter().map(|s| if c < 3 { s.gyro[c] } else { s.accel[c - 3] }).collect())
}

/// A white-noise variance estimated from the data: the variance of the third difference
/// divided by 20 (for white noise Var(Δ³x) = 20 σ²; smooth motion contributes little).
pub fn white_variance_from_data(x: &[f64]) -> f64 {
    if x.len() < 8 {
        return 0.0;
    }
    let d: Vec<f64> = x.windows(4).map(|w| w[3] - 3.0 * w[2] + 3.0 * w[1] - w[0]).collect();
    // Median of squares / 0.455 (χ²₁ median) is robust to motion spikes.
    let mut sq: Vec<f64> = d.iter().map(|v| v * v).collect();
    let mid = sq.len() / 2;
    sq.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    sq[mid] / 0.454_936 / 20.0
}

impl Aligned {
    /// Replace the real stream's white-noise variance (the simulator's claim) by an estimate
    /// from the residual r = real − sim: its white part is σ_real² + σ_sim², read off third
    /// differences ([`white_variance_from_data`], pooled over each sensor's axes). For a real
    /// sensor whose in-use noise is not the stated one (e.g. rotor vibration above the
    /// motion band on a MAV); the estimate is written to the notes.
    pub fn estimate_real_white_noise(&mut self) {
        let left_out = self.left_out();
        let est = |s: usize, sim_var: f64| {
            let v = (3 * s..3 * s + 3)
                .map(|c| {
                    let mut r: Vec<f64> = self.real[c].iter().zip(&self.sim[c]).map(|(a, b)| a - b).collect();
                    if self.samples_per_point > 1 {
                        // Window means are not smooth at their own rate: a scale's 1 % of the
                        // motion would read as noise in the third differences. The residual's
                        // best affine map of the sensor's sim channels is taken out first.
                        r = without_affine_fit(&r, &self.sim[3 * s..3 * s + 3], &left_out);
                    }
                    white_variance_from_data(&r)
                })
                .sum::<f64>()
                / 3.0;
            (v - sim_var).max(0.0)
        };
        let (g, a) = (est(0, self.sim_variance.0), est(1, self.sim_variance.1));
        self.notes.push(format!(
            "real white-noise variance estimated from the residual's third differences: gyro {g:.3e} (rad/s)², accel {a:.3e} (m/s²)² per sample ({:.2}× and {:.2}× the simulator's σ); gyro_noise_density is not judged",
            (g / self.real_variance.0).sqrt(),
            (a / self.real_variance.1).sqrt()
        ));
        self.real_variance = (g, a);
    }
}

/// `y` less its least-squares fit by 1 and the three channels `x`, fitted on the samples not
/// `left_out` (unchanged when the normal equations are singular).
fn without_affine_fit(y: &[f64], x: &[Vec<f64>], left_out: &[bool]) -> Vec<f64> {
    let row = |i: usize| nalgebra::Vector4::new(1.0, x[0][i], x[1][i], x[2][i]);
    let (mut g, mut b) = (nalgebra::Matrix4::<f64>::zeros(), nalgebra::Vector4::<f64>::zeros());
    for (i, v) in y.iter().enumerate().filter(|(i, _)| !left_out[*i]) {
        let r = row(i);
        g += r * r.transpose();
        b += r * *v;
    }
    match g.cholesky() {
        Some(ch) => {
            let beta = ch.solve(&b);
            y.iter().enumerate().map(|(i, v)| v - row(i).dot(&beta)).collect()
        }
        None => y.to_vec(),
    }
}

/// Cubic Hermite (Catmull–Rom) interpolation of (t, x) at the query times; outside the
/// source range the end value is held. `t` and `q` increasing.
pub fn interpolate(t: &[f64], x: &[f64], q: &[f64]) -> Vec<f64> {
    let n = t.len();
    let tangent = |k: usize| {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        if b == a {
            0.0
        } else {
            (x[b] - x[a]) / (t[b] - t[a])
        }
    };
    let mut k = 0usize;
    q.iter()
        .map(|&tq| {
            if n == 1 || tq <= t[0] {
                return x[0];
            }
            if tq >= t[n - 1] {
                return x[n - 1];
            }
            while t[k + 1] <= tq {
                k += 1;
            }
            while t[k] > tq {
                k -= 1;
            }
            let h = t[k + 1] - t[k];
            let u = (tq - t[k]) / h;
            let (u2, u3) = (u * u, u * u * u);
            x[k] * (2.0 * u3 - 3.0 * u2 + 1.0)
                + tangent(k) * h * (u3 - 2.0 * u2 + u)
                + x[k + 1] * (3.0 * u2 - 2.0 * u3)
                + tangent(k + 1) * h * (u3 - u2)
        })
        .collect()
}

/// An interval of the real stream longer than 1.5 nominal ones.
#[derive(Debug, Clone, PartialEq)]
pub struct Gap {
    /// Stamps of the samples either side, s (on the caller's time axis).
    pub from: f64,
    pub to: f64,
    /// Samples missing at the nominal interval.
    pub missing: usize,
    /// The gap is a whole number of intervals (within a tenth): samples dropped from a
    /// stream whose clock ran on, rather than a restart of its clock.
    pub on_grid: bool,
}

/// Stamp artefacts of a stream: nominal interval, the spread of the intervals around it, gaps.
#[derive(Debug, Clone, PartialEq)]
pub struct StampArtefacts {
    pub nominal_interval_s: f64,
    /// Robust spread (1.4826 × median absolute deviation) of the intervals within half a
    /// nominal interval of it, s: jitter of the stamps; 0 for a regular clock.
    pub interval_spread_s: f64,
    pub gaps: Vec<Gap>,
}

/// Interval spread (share of the nominal interval) above which stamps are called jittered: a
/// sample clock's stamps are regular to its ppm-level drift and ns rounding, far below 1 %.
pub const JITTER_SHARE: f64 = 0.01;

/// Measure the stamp artefacts of stamps `t` (s, increasing) with the stream's nominal rate.
pub fn stamp_artefacts(t: &[f64], nominal_rate_hz: f64) -> StampArtefacts {
    let m = 1.0 / nominal_rate_hz;
    let d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let mut dev: Vec<f64> = d.iter().filter(|x| (**x - m).abs() <= 0.5 * m).map(|x| (x - m).abs()).collect();
    let spread = if dev.is_empty() {
        0.0
    } else {
        let mid = dev.len() / 2;
        1.4826 * *dev.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
    };
    let gaps = d
        .iter()
        .enumerate()
        .filter(|(_, x)| **x > 1.5 * m)
        .map(|(i, x)| {
            let k = x / m;
            Gap { from: t[i], to: t[i + 1], missing: (k.round() as usize).saturating_sub(1), on_grid: (k - k.round()).abs() < 0.1 }
        })
        .collect();
    StampArtefacts { nominal_interval_s: m, interval_spread_s: spread, gaps }
}

impl StampArtefacts {
    /// The artefacts as sentences for the report (none for a regular stream without gaps).
    pub fn sentences(&self) -> Vec<String> {
        let mut out = Vec::new();
        let m = self.nominal_interval_s;
        if self.interval_spread_s > JITTER_SHARE * m {
            out.push(format!(
                "real stamps jitter: interval {:.3} ms ± {:.3} ms (robust σ, {:.0} % of the interval) — host-side stamping, not the sensor's sample clock",
                m * 1e3,
                self.interval_spread_s * 1e3,
                100.0 * self.interval_spread_s / m
            ));
        }
        if !self.gaps.is_empty() {
            let missing: usize = self.gaps.iter().map(|g| g.missing).sum();
            let on_grid = self.gaps.iter().filter(|g| g.on_grid).count();
            let list: Vec<String> = self
                .gaps
                .iter()
                .take(5)
                .map(|g| {
                    format!("{:.3}–{:.3} s ({} missing{})", g.from, g.to, g.missing, if g.on_grid { "" } else { ", off the sample grid" })
                })
                .collect();
            out.push(format!(
                "real stream has {} gap(s), {missing} samples missing ({on_grid} on the sample grid: dropped samples, the clock ran on){}: {}{} — a driver or recording artefact; the sim samples inside them are left out of the fit, not interpolated across",
                self.gaps.len(),
                if on_grid < self.gaps.len() { "; the others are not whole intervals: a clock restart or a stamp jump" } else { "" },
                list.join(", "),
                if self.gaps.len() > 5 { ", …" } else { "" }
            ));
        }
        out
    }
}

/// Stamps on the least-squares line t = a + b·k through `t` against the sample index k (a gap
/// of g intervals advancing k by g).
pub fn regular_grid(t: &[f64], interval: f64) -> Vec<f64> {
    let mut k = vec![0.0; t.len()];
    for i in 1..t.len() {
        k[i] = k[i - 1] + ((t[i] - t[i - 1]) / interval).round().max(1.0);
    }
    let n = t.len() as f64;
    let (mk, mt) = (k.iter().sum::<f64>() / n, t.iter().sum::<f64>() / n);
    let (sxy, sxx) = k.iter().zip(t).fold((0.0, 0.0), |(sxy, sxx), (x, y)| (sxy + (x - mk) * (y - mt), sxx + (x - mk) * (x - mk)));
    let b = if sxx > 0.0 { sxy / sxx } else { interval };
    k.iter().map(|x| mt + b * (x - mk)).collect()
}

/// The lag (in sim samples, real = sim shifted later by the lag) that best lines up the gyro
/// norms, searched within ±`max_lag` samples.
pub(crate) fn coarse_lag(sim_t: &[f64], sim_norm: &[f64], real_t: &[f64], real_norm: &[f64], dt: f64, max_lag: i64) -> i64 {
    // Real norm on the sim grid extended by the lag range.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let (ms, mr) = (mean(sim_norm), mean(real_norm));
    let step = (sim_t.len() / 20_000).max(1);
    let mut best = (f64::NEG_INFINITY, 0i64);
    for lag in -max_lag..=max_lag {
        let q: Vec<f64> = sim_t.iter().step_by(step).map(|t| t + lag as f64 * dt).collect();
        let r = interpolate(real_t, real_norm, &q);
        let (mut num, mut cnt) = (0.0, 0usize);
        for (i, (&tq, rv)) in q.iter().zip(&r).enumerate() {
            if tq >= real_t[0] && tq <= *real_t.last().unwrap_or(&0.0) {
                num += (sim_norm[i * step] - ms) * (rv - mr);
                cnt += 1;
            }
        }
        if cnt > 100 {
            let c = num / cnt as f64;
            if c > best.0 {
                best = (c, lag);
            }
        }
    }
    best.1
}

/// Load both bags (on the default topics) and align the real stream to the sim stamps.
pub fn load(sim_path: &Path, real_path: &Path) -> Result<Aligned, DiagnoseError> {
    load_on(sim_path, real_path, &RecordingTopics::default())
}

/// [`load`] with the topics both bags are read on.
pub fn load_on(sim_path: &Path, real_path: &Path, topics: &RecordingTopics) -> Result<Aligned, DiagnoseError> {
    load_each_on(sim_path, topics, real_path, topics)
}

/// [`load_on`] with each bag's own topics: a simulator and a robot seldom name them alike.
pub fn load_each_on(
    sim_path: &Path,
    sim_topics: &RecordingTopics,
    real_path: &Path,
    real_topics: &RecordingTopics,
) -> Result<Aligned, DiagnoseError> {
    let (sim, sim_report) = read_recording(sim_path, sim_topics)?;
    let (real, real_report) = read_recording(real_path, real_topics)?;
    let mut notes = Vec::new();
    for (name, path, rec, topics) in [("sim", sim_path, &sim, sim_topics), ("real", real_path, &real, real_topics)] {
        if let Some(topic) = topics.ground_truth.as_deref().filter(|_| rec.ground_truth.is_empty()) {
            // Said, not refused: the diagnosis runs on the IMU streams without it.
            tracing::warn!("{name} bag {}: no ground truth on {topic}", path.display());
            notes.push(format!("{name} bag: no ground truth on {topic}"));
        }
    }
    for (name, r) in [("sim", &sim_report), ("real", &real_report)] {
        if r.skipped() > 0 {
            notes.push(format!("{name} bag: {r}"));
        }
    }
    align(sim, real, covariance_variances(sim_path, &sim_topics.imu)?, notes)
}

/// Align two recordings (see the module docs).
pub fn align(sim: Recording, real: Recording, stated: Option<(f64, f64)>, mut notes: Vec<String>) -> Result<Aligned, DiagnoseError> {
    if sim.imu.len() < 64 || real.imu.len() < 64 {
        return Err(DiagnoseError::Input(format!(
            "too few IMU samples to diagnose (sim {}, real {}; need 64 each)",
            sim.imu.len(),
            real.imu.len()
        )));
    }
    let t0 = sim.imu[0].stamp_ns;
    let sim_t: Vec<f64> = sim.imu.iter().map(|s| (s.stamp_ns - t0) as f64 * 1e-9).collect();
    let mut real_t: Vec<f64> = real.imu.iter().map(|s| (s.stamp_ns - t0) as f64 * 1e-9).collect();
    let sim_ch = channels(&sim.imu);
    let real_ch = channels(&real.imu);
    // Nominal rates (median-based): a gap or dropped samples must not read as another rate.
    let (sim_rate, real_rate) = (sim.nominal_imu_rate_hz(), real.nominal_imu_rate_hz());
    let stamps = stamp_artefacts(&real_t, real_rate);
    let mut artefacts = stamps.sentences();
    if stamps.interval_spread_s > JITTER_SHARE * stamps.nominal_interval_s {
        // Jittered stamps of an evenly sampling sensor: interpolating at them would read the
        // jitter as noise (ω̇·δt). The samples are put on the straight line through their
        // stamps against their sample index (a clock drift stays in its slope).
        real_t = regular_grid(&real_t, stamps.nominal_interval_s);
        artefacts.push(
            "the real samples are taken as evenly sampled and re-stamped on the least-squares line through their stamps (sample index counted across gaps); a sensor that really samples unevenly would be misread by this".into(),
        );
    }
    let dt = sim.imu_seconds() / (sim.imu.len() - 1) as f64;

    let same_stamps = sim.imu.len() == real.imu.len() && sim.imu.iter().zip(&real.imu).all(|(a, b)| a.stamp_ns == b.stamp_ns);
    let (stamps_ns, real_on_grid, in_real_gap) = if same_stamps {
        (sim.imu.iter().map(|s| s.stamp_ns).collect(), real_ch, Vec::new())
    } else {
        notes.push(format!(
            "the real stamps differ from the sim stamps (sim {} samples at {sim_rate:.3} Hz from {} ns, real {} at {real_rate:.3} Hz from {} ns): real resampled onto the sim stamps",
            sim.imu.len(),
            sim.imu[0].stamp_ns,
            real.imu.len(),
            real.imu[0].stamp_ns
        ));
        real_on_sim_stamps(&sim, (&sim_t, &sim_ch), (&mut real_t, &real_ch), real_rate, dt, &mut notes)?
    };
    let first = sim.imu.iter().position(|s| s.stamp_ns == stamps_ns[0]).unwrap_or(0);
    let n = stamps_ns.len();
    let sim_on: [Vec<f64>; 6] = std::array::from_fn(|c| sim_ch[c][first..first + n].to_vec());

    let sim_variance = match stated {
        Some(v) => v,
        None => {
            let g = (0..3).map(|c| white_variance_from_data(&sim_on[c])).sum::<f64>() / 3.0;
            let a = (3..6).map(|c| white_variance_from_data(&sim_on[c])).sum::<f64>() / 3.0;
            notes.push(format!("the sim bag states no white-noise variance in its covariance fields: estimated from the data (gyro {g:.3e}, accel {a:.3e})"));
            (g, a)
        }
    };
    let real_variance = if same_stamps || (real_rate / sim_rate - 1.0).abs() < 1e-3 {
        sim_variance
    } else {
        let g = (0..3).map(|c| white_variance_from_data(&real_on_grid[c])).sum::<f64>() / 3.0;
        let a = (3..6).map(|c| white_variance_from_data(&real_on_grid[c])).sum::<f64>() / 3.0;
        notes.push(format!(
            "real rate {real_rate:.3} Hz differs from the sim rate {sim_rate:.3} Hz: the real white noise after resampling is estimated from the data (gyro {g:.3e}, accel {a:.3e}); gyro_noise_density is not judged"
        ));
        (g, a)
    };

    // Ground truth (the sim's, else the real's) → attitude at the stamps.
    let gt = if !sim.ground_truth.is_empty() { &sim.ground_truth } else { &real.ground_truth };
    let world_from_imu = attitude_at(gt, &stamps_ns);
    if world_from_imu.is_none() {
        notes.push("no ground truth in either bag: gravity_magnitude and earth_rotation cannot be judged".into());
    }
    let temps = if !sim.temperature.is_empty() { &sim.temperature } else { &real.temperature };
    let temperature_c = temperature_at(temps, &stamps_ns, t0);
    if temperature_c.is_none() {
        notes.push("no temperature topic: gyro_bias_temperature cannot be judged".into());
    }
    Ok(Aligned {
        stamps_ns,
        sim: sim_on,
        real: real_on_grid,
        sim_variance,
        real_variance,
        world_from_imu,
        temperature_c,
        notes,
        artefacts,
        in_real_gap,
        in_reference_gap: vec![],
        sim_recording: sim,
        samples_per_point: 1,
    })
}

/// The sim stamps of the overlap, the real channels there, and per stamp: inside a real gap.
type RealOnSimStamps = (Vec<i64>, [Vec<f64>; 6], Vec<bool>);

/// The real channels interpolated at the sim's stamps after a coarse lag on the gyro norms.
fn real_on_sim_stamps(
    sim: &Recording,
    (sim_t, sim_ch): (&[f64], &[Vec<f64>; 6]),
    (real_t, real_ch): (&mut [f64], &[Vec<f64>; 6]),
    real_rate: f64,
    dt: f64,
    notes: &mut Vec<String>,
) -> Result<RealOnSimStamps, DiagnoseError> {
    let norm = |ch: &[Vec<f64>; 6]| -> Vec<f64> {
        (0..ch[0].len()).map(|i| (ch[0][i].powi(2) + ch[1][i].powi(2) + ch[2][i].powi(2)).sqrt()).collect()
    };
    let max_lag = ((5.0 / dt).round() as i64).max(4);
    let lag = coarse_lag(sim_t, &norm(sim_ch), real_t, &norm(real_ch), dt, max_lag);
    if lag != 0 {
        let shift = lag as f64 * dt;
        real_t.iter_mut().for_each(|t| *t -= shift);
        notes.push(format!(
            "real stamps shifted by {:.6} s ({lag} sim samples) to line up the gyro norms; a finer offset is left to time_offset",
            -shift
        ));
    }
    let (lo, hi) = (real_t[0], *real_t.last().unwrap_or(&0.0));
    let keep: Vec<usize> = (0..sim_t.len()).filter(|&i| sim_t[i] >= lo && sim_t[i] <= hi).collect();
    if keep.len() < 64 {
        return Err(DiagnoseError::Input("the sim and real recordings do not overlap in time".into()));
    }
    if keep.len() < sim_t.len() {
        notes.push(format!("only the overlap is used: {} of {} sim samples", keep.len(), sim_t.len()));
    }
    let q: Vec<f64> = keep.iter().map(|&i| sim_t[i]).collect();
    let real_on: [Vec<f64>; 6] = std::array::from_fn(|c| interpolate(real_t, &real_ch[c], &q));
    // Inside a real gap the interpolant is made up: those stamps leave the fit.
    let m = 1.0 / real_rate;
    let gaps: Vec<(f64, f64)> = real_t.windows(2).filter(|w| w[1] - w[0] > 1.5 * m).map(|w| (w[0], w[1])).collect();
    let in_real_gap = if gaps.is_empty() {
        Vec::new()
    } else {
        q.iter().map(|&t| gaps.iter().any(|&(a, b)| t > a + 0.5 * m && t < b - 0.5 * m)).collect()
    };
    Ok((keep.iter().map(|&i| sim.imu[i].stamp_ns).collect(), real_on, in_real_gap))
}

/// The ground truth's attitude at each stamp (slerp; before the first pose, the first), or
/// `None` without two poses.
fn attitude_at(gt: &[crate::core::PoseSample], stamps_ns: &[i64]) -> Option<Vec<UnitQuaternion<f64>>> {
    if gt.len() < 2 {
        return None;
    }
    let q = crate::so3::slerp_at(gt, stamps_ns.iter().copied(), 1_000_000_000);
    let mut last = q.iter().flatten().next().copied().unwrap_or_else(UnitQuaternion::identity);
    Some(
        q.into_iter()
            .map(|o| {
                if let Some(v) = o {
                    last = v;
                }
                last
            })
            .collect(),
    )
}

/// The temperature interpolated at each stamp, or `None` without two readings.
fn temperature_at(temps: &[crate::core::TemperatureSample], stamps_ns: &[i64], t0: i64) -> Option<Vec<f64>> {
    if temps.len() < 2 {
        return None;
    }
    let tt: Vec<f64> = temps.iter().map(|s| (s.stamp_ns - t0) as f64 * 1e-9).collect();
    let tv: Vec<f64> = temps.iter().map(|s| s.celsius).collect();
    let q: Vec<f64> = stamps_ns.iter().map(|s| (s - t0) as f64 * 1e-9).collect();
    Some(interpolate(&tt, &tv, &q))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A 200 Hz recording of a 1 Hz rotation (ω̇ up to 6 rad/s², so a 1 ms stamp error is
    /// 6e-3 rad/s) with white noise of σ 1e-3 rad/s, 0.01 m/s², stamped at `stamp(k)`.
    fn recording(seed: u64, n: usize, stamp: impl Fn(usize) -> i64, keep: impl Fn(usize) -> bool) -> Recording {
        let mut u = crate::diagnose::residual::tests::uniform(seed);
        let mut g = move || (0..12).map(|_| u()).sum::<f64>() - 6.0;
        let imu = (0..n)
            .filter(|&k| keep(k))
            .map(|k| {
                let t = k as f64 * 0.005;
                let w = (std::f64::consts::TAU * t).sin();
                ImuSample {
                    stamp_ns: stamp(k),
                    gyro: Vector3::new(w + 1e-3 * g(), 0.5 * w + 1e-3 * g(), 1e-3 * g()),
                    accel: Vector3::new(0.01 * g(), 0.01 * g(), 9.81 + 0.01 * g()),
                }
            })
            .collect();
        Recording { name: "t".into(), imu, ground_truth: vec![], temperature: vec![] }
    }

    const VAR: (f64, f64) = (1e-6, 1e-4);

    /// 50 samples dropped mid-stream: named as a gap on the sample grid, the rate still read
    /// as the sim's (no "differs" note), and only the sim stamps inside the gap are masked.
    #[test]
    fn dropped_samples_are_a_gap_not_a_rate_and_are_not_fitted() {
        let n = 4000;
        let sim = recording(1, n, |k| k as i64 * 5_000_000, |_| true);
        let real = recording(2, n, |k| k as i64 * 5_000_000, |k| !(2000..2050).contains(&k));
        let a = align(sim, real, Some(VAR), vec![]).unwrap();
        assert!(a.notes.iter().all(|n| !n.contains("differs from the sim rate")), "{:?}", a.notes);
        assert_eq!(a.real_variance, VAR);
        assert_eq!(a.artefacts.len(), 1, "{:?}", a.artefacts);
        assert!(a.artefacts[0].contains("1 gap(s), 50 samples missing (1 on the sample grid"), "{}", a.artefacts[0]);
        let masked: Vec<usize> = (0..a.len()).filter(|&i| a.in_real_gap[i]).collect();
        assert_eq!(masked, (2000..2050).collect::<Vec<_>>());
    }

    /// ±1 ms uniform stamp jitter on an evenly sampled stream: named as jitter, and after the
    /// re-stamping the residual's white noise is the two draws' (2σ²), where interpolating at
    /// the jittered stamps would add (ω̇ δ)² ≈ 20σ².
    #[test]
    fn jittered_stamps_are_named_and_not_read_as_noise() {
        let n = 4000;
        let mut u = crate::diagnose::residual::tests::uniform(9);
        let jitter: Vec<i64> = (0..n).map(|_| ((u() - 0.5) * 2e6) as i64).collect();
        let sim = recording(1, n, |k| k as i64 * 5_000_000, |_| true);
        let real = recording(2, n, |k| k as i64 * 5_000_000 + jitter[k], |_| true);
        let a = align(sim, real, Some(VAR), vec![]).unwrap();
        assert!(a.artefacts.iter().any(|s| s.contains("real stamps jitter")), "{:?}", a.artefacts);
        assert!(a.in_real_gap.is_empty());
        let r: Vec<f64> = a.real[0].iter().zip(&a.sim[0]).map(|(x, y)| x - y).collect();
        let white = white_variance_from_data(&r[10..r.len() - 10]);
        assert!(white < 1.5 * 2.0 * VAR.0, "residual white variance {white:.3e} against 2σ² = {:.3e}", 2.0 * VAR.0);
        // A regular stream has no artefact.
        let regular = stamp_artefacts(&(0..n).map(|k| k as f64 * 0.005).collect::<Vec<_>>(), 200.0);
        assert!(regular.sentences().is_empty(), "{:?}", regular.sentences());
    }
}
