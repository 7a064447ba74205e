//! The samples everything else passes around: IMU readings, ground-truth poses and
//! temperatures, each stamped in integer nanoseconds (ROS time), SI units throughout.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// Standard gravity, m/s².
pub const STANDARD_GRAVITY: f64 = 9.81;

/// One IMU reading in the sensor frame (`imu_link`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Sample time, ns.
    pub stamp_ns: i64,
    /// Angular velocity of the sensor frame, rad/s.
    pub gyro: Vector3<f64>,
    /// Specific force (accelerometer reading), m/s².
    pub accel: Vector3<f64>,
}

/// Rates and specific forces no IMU measures (MEMS gyros top out near 70 rad/s, accelerometers
/// short of shock sensors near 16 g): a sample beyond them is a corrupt value, not motion.
pub const IMPLAUSIBLE_RATE_RAD_S: f64 = 1e3;
pub const IMPLAUSIBLE_ACCEL_M_S2: f64 = 1e4;

impl ImuSample {
    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.gyro.iter().chain(self.accel.iter()).all(|v| v.is_finite())
    }

    /// True when the sample is within what an IMU measures ([`IMPLAUSIBLE_RATE_RAD_S`],
    /// [`IMPLAUSIBLE_ACCEL_M_S2`]); false for non-finite samples too.
    pub fn is_plausible(&self) -> bool {
        self.gyro.norm() <= IMPLAUSIBLE_RATE_RAD_S && self.accel.norm() <= IMPLAUSIBLE_ACCEL_M_S2
    }
}

/// One ground-truth pose: the body (IMU) frame in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    /// Sample time, ns.
    pub stamp_ns: i64,
    /// Position of the body origin in the world frame, m.
    pub position_in_world: Vector3<f64>,
    /// Rotation taking body-frame vectors to the world frame.
    pub world_from_body: UnitQuaternion<f64>,
}

/// An attitude a node published (`sensor_msgs/Imu` orientation, as `/imu/denoised` carries it)
/// with its covariance about world x, y, z (REP 145), rad².
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PublishedAttitude {
    /// Header stamp, ns.
    pub stamp_ns: i64,
    pub world_from_body: UnitQuaternion<f64>,
    pub covariance: Matrix3<f64>,
}

/// One temperature reading of the IMU die, °C.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TemperatureSample {
    pub stamp_ns: i64,
    pub celsius: f64,
}

/// A recording: the IMU stream with its ground truth, as read from a bag or dataset.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    /// Where it came from (bag path or sequence name), for messages.
    pub name: String,
    pub imu: Vec<ImuSample>,
    pub ground_truth: Vec<PoseSample>,
    pub temperature: Vec<TemperatureSample>,
}

impl Recording {
    /// Duration of the IMU stream, s.
    pub fn imu_seconds(&self) -> f64 {
        match (self.imu.first(), self.imu.last()) {
            (Some(a), Some(b)) => (b.stamp_ns - a.stamp_ns) as f64 * 1e-9,
            _ => 0.0,
        }
    }

    /// The IMU's rate from its sample intervals near the median ([`nominal_rate_hz`]).
    pub fn nominal_imu_rate_hz(&self) -> f64 {
        nominal_rate_hz(&self.imu)
    }

    /// Mean IMU rate from the stamps, Hz (0 when fewer than two samples).
    pub fn imu_rate_hz(&self) -> f64 {
        let s = self.imu_seconds();
        if s > 0.0 {
            (self.imu.len() - 1) as f64 / s
        } else {
            0.0
        }
    }

    /// The IMU samples between `start_s` and `end_s` seconds after the first IMU sample at or
    /// after the first ground-truth pose (the trainer's and `adapt`'s clock: "the first 60 s"
    /// means the same span everywhere), with all the ground truth and temperature kept. `None`
    /// when there is no ground truth, no IMU sample after it, or fewer than 2 samples in the span.
    pub fn crop_after_ground_truth_start(&self, start_s: Option<f64>, end_s: Option<f64>) -> Option<Recording> {
        let g0 = self.ground_truth.first()?.stamp_ns;
        let t0 = self.imu.iter().find(|s| s.stamp_ns >= g0)?.stamp_ns;
        let imu: Vec<ImuSample> = self
            .imu
            .iter()
            .filter(|s| {
                let t = ns_to_s(s.stamp_ns - t0);
                t >= 0.0 && start_s.is_none_or(|a| t >= a) && end_s.is_none_or(|b| t <= b)
            })
            .copied()
            .collect();
        // One sample is no path to integrate.
        (imu.len() >= 2).then(|| Recording {
            name: self.name.clone(),
            imu,
            ground_truth: self.ground_truth.clone(),
            temperature: self.temperature.clone(),
        })
    }
}

/// Nanoseconds to seconds.
pub fn ns_to_s(ns: i64) -> f64 {
    ns as f64 * 1e-9
}

/// A stream's rate, Hz (0 with fewer than two samples): from the mean of the sample intervals
/// within half a median interval of the median, so a gap or a burst does not move it (unlike
/// samples over span), and stamps rounded coarser than the period (a 400-Hz IMU stamped in
/// whole ms: 2, 3, 2, 3 ms) still give the rate (the median alone said 500 Hz).
pub fn nominal_rate_hz(imu: &[ImuSample]) -> f64 {
    let dt: Vec<i64> = imu.windows(2).map(|w| w[1].stamp_ns - w[0].stamp_ns).collect();
    if dt.is_empty() {
        return 0.0;
    }
    let mut sorted = dt.clone();
    let mid = sorted.len() / 2;
    let median = *sorted.select_nth_unstable(mid).1;
    if median <= 0 {
        return 0.0;
    }
    let (lo, hi) = (median / 2, median + median / 2);
    let (sum, count) = dt.iter().filter(|d| (lo..=hi).contains(*d)).fold((0i128, 0i128), |(s, c), d| (s + *d as i128, c + 1));
    let span: i128 = dt.iter().map(|d| *d as i128).sum();
    // Intervals near the median spanning under half the stream, with a tenth or more of the
    // intervals far above it, are a batch's, not the stream's (a driver stamping 5 samples
    // 10 µs apart on arrival read as 100 kHz): the mean over the span is the rate then. A
    // stream with long gaps has few long intervals.
    let long = dt.iter().filter(|d| **d > 2 * median).count();
    if 2 * sum < span && long * 10 >= dt.len() {
        return 1e9 * dt.len() as f64 / span as f64;
    }
    1e9 * count as f64 / sum as f64
}

/// Header stamps taken on a batch's arrival, not at each sample: most intervals far below
/// the stream's mean period (samples microseconds apart, then a pause). The stamps are what
/// every command integrates with, so training and adaptation refuse them; what to say.
pub fn burst_stamps(imu: &[ImuSample]) -> Option<String> {
    if imu.len() < 20 {
        return None;
    }
    let span = (imu[imu.len() - 1].stamp_ns - imu[0].stamp_ns) as f64;
    let mean = span / (imu.len() - 1) as f64;
    let short = imu.windows(2).filter(|w| ((w[1].stamp_ns - w[0].stamp_ns) as f64) < 0.1 * mean).count();
    // Two samples a batch already make half the intervals short.
    (short * 5 >= (imu.len() - 1) * 2).then(|| {
        format!(
            "{short} of {} IMU stamp intervals are under a tenth of the stream's mean period ({:.3} ms, {:.1} Hz): header.stamp is the arrival time of a batch, not each sample's time; restamp the samples at the IMU's rate",
            imu.len() - 1,
            mean * 1e-6,
            1e9 / mean
        )
    })
}

/// Separate runs of samples held at an axis's largest value that make it a clipped axis: a
/// signal's own peak reaches its maximum once; a sensor at the end of its range holds the same
/// value again at every impact or fast turn.
const CLIP_RUNS: u32 = 3;
/// Below these an axis is not taken as clipped: no IMU's range is narrower (125 °/s and 2 g are
/// the smallest in use), and a quantised signal at rest repeats its values.
const CLIP_MIN_RATE_RAD_S: f64 = 2.0;
const CLIP_MIN_ACCEL_M_S2: f64 = 15.0;
/// The band just under the limit (a share of it): a clipped signal crosses it on its way to
/// the range and stays at the limit, so more samples sit at the limit than in the band; a
/// signal that merely peaks there (a rate table at a constant speed, its noise under an LSB)
/// has most of its samples in the band.
const CLIP_BAND: f64 = 0.01;

/// Full-scale ranges IMUs are sold with (°/s for gyros, g for accelerometers): a held value
/// within [`FULL_SCALE_TOLERANCE`] of one can be a range; a rate table held at 286 °/s with
/// noise under an LSB repeats its top value like a clipped signal, and is not one.
const GYRO_RANGES_DEG_S: [f64; 9] = [125.0, 250.0, 300.0, 400.0, 450.0, 500.0, 1000.0, 2000.0, 4000.0];
const ACCEL_RANGES_G: [f64; 16] = [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 16.0, 18.0, 24.0, 32.0, 40.0, 50.0, 100.0, 200.0];
/// A driver's scale and bias move the held value off the nominal range by a little.
const FULL_SCALE_TOLERANCE: f64 = 0.03;

/// True when `limit` (rad/s for the gyro, m/s² for the accelerometer) is near a full-scale range.
fn near_full_scale(limit: f64, gyro: bool) -> bool {
    let (ranges, unit): (&[f64], f64) =
        if gyro { (&GYRO_RANGES_DEG_S, std::f64::consts::PI / 180.0) } else { (&ACCEL_RANGES_G, STANDARD_GRAVITY) };
    ranges.iter().any(|r| (limit / (r * unit) - 1.0).abs() <= FULL_SCALE_TOLERANCE)
}

/// Samples held at the sensor's range (saturation), found per axis and sign from the stream
/// itself: the largest value held in [`CLIP_RUNS`] or more separate runs, with more samples at
/// it than just under it. Online, one sample at a time with no allocation; a clipped sample is
/// integrated all the same (its true value was larger), so what it gets is a count and a
/// warning.
#[derive(Debug, Clone, Copy, Default)]
pub struct ClipDetector {
    /// Per axis and sign (gyro x, y, z, accel x, y, z; + then −).
    slots: [ClipSlot; 12],
}

#[derive(Debug, Clone, Copy, Default)]
struct ClipSlot {
    /// The largest value seen (for the − sign, of −v).
    limit: f64,
    /// The limit is one a sensor can clip at: at least the smallest range, near a full scale
    /// (set when the limit moves, not per sample).
    a_range: bool,
    /// Separate runs at the limit, samples at it, samples in the band under it.
    runs: u32,
    at: u64,
    band: u64,
    in_run: bool,
}

impl ClipSlot {
    fn push(&mut self, v: f64, gyro: bool) {
        if v > self.limit {
            // The band's earlier samples are not known any more: counted from here.
            let min = if gyro { CLIP_MIN_RATE_RAD_S } else { CLIP_MIN_ACCEL_M_S2 };
            let a_range = v >= min && near_full_scale(v, gyro);
            *self = ClipSlot { limit: v, a_range, runs: 1, at: 1, band: 0, in_run: true };
        } else if v == self.limit {
            self.runs += u32::from(!self.in_run);
            self.at += 1;
            self.in_run = true;
        } else {
            self.band += u64::from(v >= (1.0 - CLIP_BAND) * self.limit);
            self.in_run = false;
        }
    }

    fn clipped(&self) -> bool {
        self.a_range && self.runs >= CLIP_RUNS && self.at > self.band
    }
}

/// Slot `k` of a sample (axis k / 2, + for even k): its signed value, and whether it is a gyro's.
fn clip_value(s: &ImuSample, k: usize) -> (f64, bool) {
    let axis = k / 2;
    let sign = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
    if axis < 3 {
        (sign * s.gyro[axis], true)
    } else {
        (sign * s.accel[axis - 3], false)
    }
}

impl ClipDetector {
    /// Feed one sample; true when one of its axes sits at a range the stream has shown clipped.
    pub fn push(&mut self, s: &ImuSample) -> bool {
        for k in 0..12 {
            let (v, gyro) = clip_value(s, k);
            self.slots[k].push(v, gyro);
        }
        self.at_range(s, 0..6)
    }

    /// True when one of `axes` (0–2 gyro, 3–5 accel) of `s` sits at a clipped range.
    pub fn at_range(&self, s: &ImuSample, axes: std::ops::Range<usize>) -> bool {
        (2 * axes.start..2 * axes.end).any(|k| self.slots[k].clipped() && clip_value(s, k).0 == self.slots[k].limit)
    }

    /// The largest clipped range of the gyro (rad/s) and of the accelerometer (m/s²).
    pub fn ranges(&self) -> (Option<f64>, Option<f64>) {
        let range = |ks: std::ops::Range<usize>| ks.filter(|&k| self.slots[k].clipped()).map(|k| self.slots[k].limit).reduce(f64::max);
        (range(0..6), range(6..12))
    }
}

/// Samples of a recording held at the sensor's range (the whole stream's ranges, so its first
/// clipped samples count too); what to say, `None` when nothing is clipped.
pub fn clipped_samples(imu: &[ImuSample]) -> Option<String> {
    let mut scan = ClipDetector::default();
    for s in imu {
        scan.push(s);
    }
    let (gyro, accel) = scan.ranges();
    if gyro.is_none() && accel.is_none() {
        return None;
    }
    // One pass: samples with a clipped gyro axis, accelerometer axis, either.
    let (mut n_gyro, mut n_accel, mut n_any) = (0usize, 0usize, 0usize);
    for s in imu {
        let (g, a) = (scan.at_range(s, 0..3), scan.at_range(s, 3..6));
        n_gyro += usize::from(g);
        n_accel += usize::from(a);
        n_any += usize::from(g || a);
    }
    let mut parts = Vec::new();
    if let Some(r) = gyro {
        parts.push(format!("{n_gyro} gyro samples at ±{r:.3} rad/s"));
    }
    if let Some(r) = accel {
        parts.push(format!("{n_accel} accelerometer samples at ±{r:.2} m/s²"));
    }
    Some(format!(
        "{n_any} of {} IMU samples clipped at the sensor's range ({}): their true values were larger, and they are used as recorded",
        imu.len(),
        parts.join(", ")
    ))
}

/// `std::fs::create_dir_all`, but when a file stands where a folder of the path must be, the
/// error names that file ("File exists" alone sent users looking for the folder).
pub fn create_dir_all(dir: &std::path::Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| match dir.ancestors().find(|a| !a.as_os_str().is_empty() && a.exists() && !a.is_dir()) {
        Some(file) => std::io::Error::new(e.kind(), format!("{} is a file, not a folder", file.display())),
        None => e,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A gyro turning past its range and impacts past the accelerometer's are counted; a
    /// signal's own peaks, even quantised, and a quantised rest are not.
    #[test]
    fn clipping_is_a_value_held_at_the_range_again_and_again() {
        let quantised = |x: f64, lsb: f64| (x / lsb).round() * lsb;
        let stream = |gyro: &dyn Fn(f64) -> f64, accel: &dyn Fn(f64) -> f64| -> Vec<ImuSample> {
            (0..10_000)
                .map(|k| {
                    let t = k as f64 * 1e-3;
                    ImuSample { stamp_ns: k * 1_000_000, gyro: Vector3::new(gyro(t), 0.01, -0.02), accel: Vector3::new(0.1, 0.2, accel(t)) }
                })
                .collect()
        };
        // 12 rad/s swings clipped at 8.727 (500 °/s), 1 kHz, 16-bit; 8 g impacts every 0.5 s
        // clipped at 4 g. The sensors' noise (uniform, ±0.01 rad/s and ±0.05 m/s²); impacts of 60–80 m/s².
        let noise = |t: f64, size: f64| ((((t * 1e3).round() as u64 * 2_654_435_761) % 1000) as f64 / 1000.0 - 0.5) * 2.0 * size;
        let lsb = 8.727 / 32768.0;
        let swing = |t: f64| 12.0 * (2.0 * t).sin() + noise(t, 0.01);
        let gyro = |t: f64| quantised(swing(t).clamp(-8.727, 8.727), lsb);
        let impact = |t: f64| -> f64 { 9.81 + noise(t, 0.05) + if (t % 0.5) < 0.004 { 70.0 + noise(t + 0.3, 10.0) } else { 0.0 } };
        let clipped = stream(&gyro, &|t| quantised(impact(t).min(39.24), 0.0048));
        let note = clipped_samples(&clipped).unwrap();
        assert!(note.contains("gyro samples at ±8.727 rad/s") && note.contains("accelerometer samples at ±39.24 m/s²"), "{note}");
        // Samples at the limit: |12 sin(2t)| beyond 8.727 48 % of the time, in runs of 0.76 s;
        // 20 impacts of 4 samples.
        let mut online = ClipDetector::default();
        let flagged = clipped.iter().filter(|s| online.push(s)).count();
        let total: usize = note.split(" of ").next().unwrap().parse().unwrap();
        assert!((4700..4950).contains(&total), "{note}");
        // Online, the first two runs of each axis and sign are not yet known as clipping.
        assert!(flagged < total && flagged + 4 * 800 + 8 > total, "{flagged} of {total}");
        // Unclipped: the same swings and impacts whole, quantised; a quantised rest.
        assert_eq!(clipped_samples(&stream(&|t| quantised(swing(t), 2.0 * lsb), &|t| quantised(impact(t), 0.0096))), None);
        let rest = stream(&|t| quantised(0.001 * (t * 9.0).sin(), lsb), &|t| quantised(9.81 + 0.004 * (t * 31.0).sin(), 0.0048));
        assert_eq!(clipped_samples(&rest), None);
        // A rate table at 5 rad/s (286 °/s), a ±2000 °/s 16-bit gyro whose noise is under an
        // LSB: its top value recurs like a clipped one's, but 286 °/s is no gyro's range.
        let lsb2000 = 34.9 / 32768.0;
        let table = stream(&|t| quantised(5.0 + noise(t, 0.4 * lsb2000), lsb2000), &|_| 9.81);
        assert_eq!(clipped_samples(&table), None);
        // A range off centre (a driver that subtracts a bias): both signs found, each at its own
        // limit (+8.707 and −8.747 rad/s, 499 and 501 °/s).
        let shifted = stream(&|t| quantised(swing(t).clamp(-8.727, 8.727) - 0.02, lsb), &|_| 9.81);
        let note = clipped_samples(&shifted).unwrap();
        let total: usize = note.split(" of ").next().unwrap().parse().unwrap();
        assert!((4700..4950).contains(&total), "{note}");
    }

    /// Bursts stamped on arrival: 5 samples 10 µs apart every 25 ms are a 200-Hz stream
    /// (it read as 100 kHz), and said; a regular stream with a gap or rounded stamps is not.
    #[test]
    fn bursts_stamped_on_arrival_are_the_mean_rate() {
        let at = |stamps: &mut dyn Iterator<Item = i64>| -> Vec<ImuSample> {
            stamps.map(|t| ImuSample { stamp_ns: t, gyro: Vector3::zeros(), accel: Vector3::new(0.0, 0.0, 9.81) }).collect()
        };
        let bursts = at(&mut (0..2000).map(|k| (k / 5) * 25_000_000 + (k % 5) * 10_000));
        assert!((nominal_rate_hz(&bursts) - 200.0).abs() < 0.5, "{}", nominal_rate_hz(&bursts));
        assert!(burst_stamps(&bursts).unwrap().contains("1600 of 1999 IMU stamp intervals"), "{:?}", burst_stamps(&bursts));
        let gap = at(&mut (0..2000).map(|k| k * 5_000_000 + if k > 1000 { 2_000_000_000 } else { 0 }));
        assert!((nominal_rate_hz(&gap) - 200.0).abs() < 1e-6 && burst_stamps(&gap).is_none());
        let rounded = at(&mut (0..2000).map(|k| (k * 2_500_000 / 1_000_000) * 1_000_000));
        assert!((nominal_rate_hz(&rounded) - 400.0).abs() < 1.0 && burst_stamps(&rounded).is_none());
    }

    fn rec() -> Recording {
        // IMU at 100 Hz from t = 0 s, ground truth from t = 1.005 s.
        let imu = (0..1000)
            .map(|i| ImuSample { stamp_ns: i * 10_000_000, gyro: Vector3::zeros(), accel: Vector3::new(0.0, 0.0, 9.81) })
            .collect();
        let ground_truth = (0..100)
            .map(|i| PoseSample {
                stamp_ns: 1_005_000_000 + i * 50_000_000,
                position_in_world: Vector3::zeros(),
                world_from_body: UnitQuaternion::identity(),
            })
            .collect();
        Recording { name: "r".into(), imu, ground_truth, temperature: vec![] }
    }

    /// The rate holds through gaps and bursts, and for stamps rounded to whole ms at 400 Hz.
    #[test]
    fn nominal_rate_from_intervals_near_the_median() {
        let at = |stamps: Vec<i64>| -> Vec<ImuSample> {
            stamps.into_iter().map(|t| ImuSample { stamp_ns: t, gyro: Vector3::zeros(), accel: Vector3::zeros() }).collect()
        };
        let ms_rounded: Vec<i64> = (0..4000).map(|k| (k as f64 * 2.5).round() as i64 * 1_000_000).collect();
        assert!((nominal_rate_hz(&at(ms_rounded)) - 400.0).abs() < 0.5);
        let mut gappy: Vec<i64> = (0..1000).map(|k| k * 5_000_000).collect();
        gappy.extend((0..1000).map(|k| 10_000_000_000 + k * 5_000_000));
        gappy.extend((0..100).map(|k| 20_000_000_000 + k * 100_000));
        assert!((nominal_rate_hz(&at(gappy)) - 200.0).abs() < 1e-9);
        assert_eq!(nominal_rate_hz(&at(vec![7, 7, 7])), 0.0);
        assert_eq!(nominal_rate_hz(&at(vec![7])), 0.0);
    }

    #[test]
    fn crop_counts_from_the_first_imu_sample_covered_by_ground_truth() {
        let r = rec();
        let all = r.crop_after_ground_truth_start(None, None).unwrap();
        assert_eq!(all.imu[0].stamp_ns, 1_010_000_000);
        let c = r.crop_after_ground_truth_start(Some(2.0), Some(3.0)).unwrap();
        assert_eq!(c.imu[0].stamp_ns, 3_010_000_000);
        assert_eq!(c.imu.last().unwrap().stamp_ns, 4_010_000_000);
        assert_eq!(c.ground_truth.len(), 100);
        assert!(r.crop_after_ground_truth_start(Some(50.0), None).is_none());
        assert!(r.crop_after_ground_truth_start(None, Some(0.0)).is_none(), "one sample");
        assert!(Recording { ground_truth: vec![], ..r }.crop_after_ground_truth_start(None, None).is_none());
    }
}
