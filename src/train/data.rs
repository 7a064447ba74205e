//! Training data: recordings (ASL sequence folders or MCAP bags) turned into tasks.
//!
//! Each recording is checked before any training starts (ground truth present, overlapping
//! the IMU in time, every sample finite, long enough for the window / support set), cropped
//! to the span its ground truth covers, and kept as tensors:
//! - `imu [T, 6]` f32 raw (rad/s, m/s²);
//! - `dt [T]` f64 from the real stamps, `dt_k = t_{k+1} − t_k` (the last entry repeats the
//!   previous one; the loss never uses it);
//! - `gt [T, 4]` f64 (w, x, y, z) `world_from_body` slerped at the IMU stamps (never across a
//!   gap longer than `max_interpolation_gap_ms`), NaN where there is none;
//! - `valid [T]`: ground truth present and the nearest pose ≤ `max_nearest_gt_ms` away (DIGDL's
//!   TUM-VI rule, 10 ms); the loss drops every increment spanning an invalid sample.
//!
//! A task's support set is its first `support_seconds`, the query set the rest (paper §III-B).

use std::path::{Path, PathBuf};

use rand::Rng;
use tch::Tensor;

use super::config::{file_stem, DatasetConfig, SourceConfig, SIM_DOMAIN};
use crate::bag::{read_recording, LoadReport, RecordingTopics, GROUND_TRUTH_TOPIC, IMU_TOPIC};
use crate::core::Recording;
use crate::dataset::load_sequence;
use crate::sim::{simulate, SimConfig};
use crate::so3::slerp_at;

/// Why a recording cannot be used; every one is reported before training starts.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{source_name}: {msg}")]
    Load { source_name: String, msg: String },
    #[error("{name}: its power-on bias could not be removed (dataset.power_on_bias: remove): {why}")]
    PowerOnBias { name: String, why: String },
    #[error("{0}: no ground truth (a bag needs a ground-truth topic such as {GROUND_TRUTH_TOPIC}; training and evaluation need it)")]
    NoGroundTruth(String),
    #[error("{name}: ground truth ({gt_start:.3}–{gt_end:.3} s) does not overlap the IMU ({imu_start:.3}–{imu_end:.3} s) in time")]
    NoOverlap { name: String, imu_start: f64, imu_end: f64, gt_start: f64, gt_end: f64 },
    #[error(
        "{name}: the ground truth's {poses} pose(s) ({gt_start:.3}–{gt_end:.3} s) lie within the IMU's time but cover no \
         IMU sample: interpolation needs two poses at most {max_gap_ms} ms apart around a sample (slower ground truth: raise \
         `eval --max-gap-ms`, dataset.max_interpolation_gap_ms in a train config, max_interpolation_gap_ms in an adapt one)"
    )]
    NotCovered { name: String, poses: usize, gt_start: f64, gt_end: f64, max_gap_ms: f64 },
    #[error("{name}: {count} {what} in the data; fix or drop them before training")]
    NonFinite { name: String, what: &'static str, count: u64 },
    #[error("{name}: {samples} IMU samples ({seconds:.1} s) with ground truth, shorter than {needed}")]
    TooShort { name: String, samples: usize, seconds: f64, needed: String },
    #[error(
        "{name}: no {increment}-sample increment of the loss can be scored: the longest run of IMU samples within \
         dataset.max_nearest_gt_ms ({nearest_ms} ms) of a ground-truth pose is {longest} samples ({share:.1} % of the samples \
         are), and an increment needs {needed}; poses this sparse need a larger max_nearest_gt_ms (and a \
         max_interpolation_gap_ms above their interval), if they are to be trusted"
    )]
    NoScoredIncrement { name: String, increment: i64, longest: usize, needed: usize, share: f64, nearest_ms: f64 },
    #[error(
        "{name}: the ground truth turns {ratio:.3}× as far as the gyro over 0.25 s (median over {increments} increments of \
         clear motion; 1 is expected): the gyro is not in rad/s, the poses are not this IMU's, or their clocks differ by more \
         than the 30 s searched"
    )]
    RotationScale { name: String, ratio: f64, increments: usize },
    #[error(
        "{name}: the ground truth is in another frame: a constant rotation of {angle_deg:.1}° takes the gyro's increments \
         onto it (residual {residual_deg:.1}° with it, {identity_deg:.1}° without); express the ground truth in the IMU frame"
    )]
    OtherFrame { name: String, angle_deg: f64, residual_deg: f64, identity_deg: f64 },
    #[error(
        "{name}: the gyro's axes are a mirror image of the ground truth's ({axes}; residual {mirror_deg:.1}° as a mirror image, \
         {rotation_deg:.1}° after the best rotation): an axis sign flipped in the IMU driver, or a left-handed frame; \
         no rotation of the ground truth fixes that: correct the driver's axes (ROS frames are right-handed, REP 103)"
    )]
    MirroredAxes { name: String, axes: String, mirror_deg: f64, rotation_deg: f64 },
    #[error(
        "{name}: the ground truth's rotation axes do not follow the gyro's (RMS {residual_deg:.1}° apart over {increments} \
         0.25-s increments, even after the best constant rotation): inverted quaternions (body-from-world), another body's poses, \
         or clocks more than the 30 s searched apart?"
    )]
    NotFollowing { name: String, residual_deg: f64, increments: usize },
    #[error(
        "{name}: the ground truth's quaternions are inverted (world in body, not body in world): read inverted they follow \
         the gyro's rotation, as stored they do not; conjugate them (x, y, z → −x, −y, −z)"
    )]
    InvertedQuaternions { name: String },
    #[error("{name}: crop start_s {start} s is past the end of the ground-truth-covered data ({seconds:.1} s)")]
    EmptyCrop { name: String, start: f64, seconds: f64 },
    #[error(
        "{name}: the ground truth lags the IMU by {:.1} ms (where the gyro's and the ground truth's rotation rates \
         correlate best, r = {correlation:.2}); beyond {:.0} ms it would be learnt as gyro error: correct the stamps first",
        lag_s * 1e3, crate::eval::GROUND_TRUTH_LAG_TOLERANCE_S * 1e3
    )]
    Misaligned { name: String, lag_s: f64, correlation: f64 },
    #[error(
        "{name}: {count} IMU samples beyond what any IMU measures (|ω| > {:e} rad/s or |a| > \
         {:e} m/s²; largest |ω| {largest_rate:.3e} rad/s, |a| {largest_accel:.3e} m/s²): corrupt values; \
         fix or drop them first",
        crate::core::IMPLAUSIBLE_RATE_RAD_S,
        crate::core::IMPLAUSIBLE_ACCEL_M_S2
    )]
    Implausible { name: String, count: usize, largest_rate: f64, largest_accel: f64 },
    #[error(
        "{name}: the accelerometer's median |a| is {median:.3} (gravity alone is 9.81 m/s²): {}",
        if (0.5..=2.0).contains(median) { "in g, not m/s²? (multiply by 9.80665)" } else { "not the specific force in m/s² (gravity removed by the driver, or other units?)" }
    )]
    AccelUnits { name: String, median: f64 },
}

/// One recording ready for training or evaluation.
#[derive(Debug)]
pub struct Task {
    pub name: String,
    /// Where it came from (config spelling).
    pub source: String,
    /// The cropped recording (IMU over the ground-truth span, all ground truth kept), for
    /// [`crate::eval::evaluate`].
    pub rec: Recording,
    pub imu: Tensor,
    pub dt: Tensor,
    pub gt: Tensor,
    pub valid: Tensor,
    /// First index of the query set (= the support set's length).
    pub support_end: usize,
    /// Fraction of samples with valid ground truth.
    pub valid_fraction: f64,
    /// The longest run of consecutive samples with valid ground truth: an increment of j
    /// samples is scored only where j + 1 are.
    pub longest_valid_run: usize,
    /// The IMU that recorded it ([`SourceConfig::imu_name`]).
    pub imu_name: String,
    /// Its row of the model's Ĉ_ω ([`crate::model::Net::calibration_row`]; set by the
    /// trainer). `None`: the model's selected Ĉ_ω ([`crate::model::Net::gyro_calibration`]).
    pub calibration_row: Option<i64>,
    /// The power-on constant taken out of it (`dataset.power_on_bias: remove`).
    pub power_on_constant: Option<super::power_on::RemovedConstant>,
}

impl Task {
    pub fn len(&self) -> usize {
        self.rec.imu.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rec.imu.is_empty()
    }

    pub fn seconds(&self) -> f64 {
        self.rec.imu_seconds()
    }

    /// A digest of the samples this task trains or scores on (FNV-1a over every IMU and
    /// ground-truth stamp and value, bit for bit): a resumed run refuses data that changed
    /// under the same path since its checkpoint.
    pub fn fingerprint(&self) -> String {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bits: u64| {
            for b in bits.to_le_bytes() {
                h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        for s in &self.rec.imu {
            eat(s.stamp_ns as u64);
            s.gyro.iter().chain(s.accel.iter()).for_each(|v| eat(v.to_bits()));
        }
        for p in &self.rec.ground_truth {
            eat(p.stamp_ns as u64);
            p.world_from_body.coords.iter().chain(p.position_in_world.iter()).for_each(|v| eat(v.to_bits()));
        }
        format!("{h:016x}")
    }

    /// Seconds with valid ground truth (gaps left out).
    pub fn covered_seconds(&self) -> f64 {
        self.seconds() * self.valid_fraction
    }
}

/// A batch of windows, `[B, W, …]`.
#[derive(Debug)]
pub struct Batch {
    pub imu: Tensor,
    pub dt: Tensor,
    pub gt: Tensor,
    pub valid: Tensor,
    /// `[B]` int64: each window's Ĉ_ω row ([`Task::calibration_row`]), when every task has one.
    pub calibration_rows: Option<Tensor>,
}

fn resolve(root: &Path, rel: &str) -> PathBuf {
    let p = Path::new(rel);
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        root.join(p)
    }
}

/// Reads one source as it is on disk (no cropping), with the input checks.
pub fn read_source(root: &Path, src: &SourceConfig) -> Result<Recording, DataError> {
    let described = src.describe();
    let load_err = |msg: String| DataError::Load { source_name: described.clone(), msg };
    let (mut rec, report) = if let Some(seq) = &src.sequence {
        let (_, rec, report) = load_sequence(&resolve(root, seq)).map_err(|e| load_err(e.to_string()))?;
        (rec, report)
    } else if let Some(sim) = &src.simulate {
        (simulated(Path::new(sim)).map_err(load_err)?, LoadReport::default())
    } else {
        let bag = src.bag.as_deref().expect("validated: exactly one of sequence, bag or simulate");
        let topics = RecordingTopics {
            imu: src.imu_topic.clone().unwrap_or_else(|| IMU_TOPIC.into()),
            ground_truth: Some(src.ground_truth_topic.clone().unwrap_or_else(|| GROUND_TRUTH_TOPIC.into())),
            temperature: None,
        };
        read_recording(resolve(root, bag), &topics).map_err(|e| load_err(e.to_string()))?
    };
    let name = src.name.clone().unwrap_or_else(|| {
        let stem = file_stem(&src.path());
        let stem = if src.simulate.is_some() { format!("{SIM_DOMAIN}_{stem}") } else { stem };
        let stem = stem.trim_start_matches("dataset-").trim_end_matches("_512_16").to_string();
        match (src.start_s, src.end_s) {
            (None, None) => stem,
            (a, b) => format!("{stem}@{}-{}s", a.unwrap_or(0.0), b.map_or("end".into(), |b| b.to_string())),
        }
    });
    rec.name = name.clone();
    // Stamps most of which repeat (a driver stamping bursts on arrival) would be trained on as
    // a quarter of the data at a quarter of the rate: refused, as `eval` refuses them.
    if let Some(problem) = report.stamp_problem_above(0.1).or_else(|| crate::core::burst_stamps(&rec.imu)) {
        return Err(DataError::Load { source_name: described, msg: problem });
    }
    // Clipped samples teach a correction for a gyro that reads too small: trained on all the
    // same (the rest of the recording is good), and said.
    if let Some(clipped) = crate::core::clipped_samples(&rec.imu) {
        tracing::warn!("{described}: {clipped}");
    }
    if report.imu_non_finite > 0 {
        return Err(DataError::NonFinite { name, what: "non-finite (NaN/inf) IMU samples", count: report.imu_non_finite });
    }
    if report.ground_truth_invalid > 0 {
        return Err(DataError::NonFinite {
            name,
            what: "invalid ground-truth poses (NaN/inf, or a quaternion of norm near 0)",
            count: report.ground_truth_invalid,
        });
    }
    if rec.ground_truth.is_empty() {
        if let Some(bag) = &src.bag {
            // Say which topic was searched and what the bag has, as `eval` does.
            let topic = src.ground_truth_topic.clone().unwrap_or_else(|| GROUND_TRUTH_TOPIC.into());
            let (topics, _) = crate::bag::bag_info(resolve(root, bag));
            let present: Vec<String> = topics.iter().map(|t| format!("{} [{}]", t.topic, t.type_name)).collect();
            return Err(DataError::Load {
                source_name: described,
                msg: format!(
                    "no ground truth on {topic} (the bag's topics: {}); set `ground_truth_topic:` on this source",
                    present.join(", ")
                ),
            });
        }
        return Err(DataError::NoGroundTruth(name));
    }
    check_clock(&rec)?;
    check_plausible(&rec)?;
    check_accel_units(&rec)?;
    check_ground_truth_follows_gyro(&rec, true)?;
    Ok(rec)
}

/// How the ground truth's rotation compares with the gyro's over 0.25-s increments: the median
/// ratio of their angles where either turns by over 0.1 rad (6°, beyond any gyro bias over
/// 0.25 s), the number of such increments, the frame check on them, and whether the quaternions
/// read inverted follow the gyro better ([`crate::ground_truth_frame::inverted_quaternions`]).
pub fn rotation_agreement(rec: &Recording) -> Option<(Option<f64>, usize, Option<crate::ground_truth_frame::FrameCheck>, bool)> {
    let rate = rec.nominal_imu_rate_hz();
    if rate <= 0.0 {
        return None;
    }
    let window = ((0.25 * rate).round() as usize).max(2);
    let gt = slerp_at(&rec.ground_truth, rec.imu.iter().map(|s| s.stamp_ns), crate::eval::EvalOptions::default().max_gap_ns);
    let pairs = crate::ground_truth_frame::increments(&rec.imu, &gt, window);
    let mut ratios: Vec<f64> =
        pairs.iter().map(|p| (p.gt.norm(), p.imu.norm())).filter(|(g, i)| g.max(*i) > 0.1).map(|(g, i)| g / i.max(1e-9)).collect();
    // A slow motion (a car turning at under 0.4 rad/s) has no such increment: no ratio, but the
    // frame checks still run on the smaller ones.
    let median = (!ratios.is_empty()).then(|| {
        let mid = ratios.len() / 2;
        *ratios.select_nth_unstable_by(mid, f64::total_cmp).1
    });
    // The frame on longer increments where the 0.25-s ones turn too little (a gently driven car).
    let pairs = crate::ground_truth_frame::turning_increments(&rec.imu, &gt, rate, 0.05, 10);
    let frame = crate::ground_truth_frame::check_frame_on(&pairs, 0.05);
    let inverted = frame.as_ref().is_some_and(|f| crate::ground_truth_frame::inverted_quaternions(&pairs, 0.05, f));
    Some((median, ratios.len(), frame, inverted))
}

/// Refuses ground truth that does not describe this IMU's rotation: a gyro in °/s, a pose that
/// never turns while the gyro does, inverted quaternions, another frame. Training on it
/// fits the network to nonsense without a word (the loss just stays high).
/// `other_frame`: whether ground truth in another constant frame is refused here (`adapt`
/// has its own policy for it: refuse or re-express).
pub fn check_ground_truth_follows_gyro(rec: &Recording, other_frame: bool) -> Result<(), DataError> {
    let Some((ratio, increments, frame, inverted)) = rotation_agreement(rec) else { return Ok(()) };
    if let Some(ratio) = ratio.filter(|r| increments >= 10 && !(0.5..=2.0).contains(r)) {
        return Err(DataError::RotationScale { name: rec.name.clone(), ratio, increments });
    }
    if let Some(f) = frame.filter(|f| f.increments >= 10) {
        if inverted {
            return Err(DataError::InvertedQuaternions { name: rec.name.clone() });
        }
        if f.mirrored {
            return Err(DataError::MirroredAxes {
                name: rec.name.clone(),
                axes: f.mirror_axes().unwrap_or_default(),
                mirror_deg: f.mirror_residual_deg.unwrap_or(f64::NAN),
                rotation_deg: f.residual_deg,
            });
        }
        if f.is_other_frame(5.0) {
            if !other_frame {
                return Ok(());
            }
            return Err(DataError::OtherFrame {
                name: rec.name.clone(),
                angle_deg: f.angle_deg,
                residual_deg: f.residual_deg,
                identity_deg: f.residual_identity_deg,
            });
        }
        if f.residual_deg > NOT_FOLLOWING_DEG {
            return Err(DataError::NotFollowing { name: rec.name.clone(), residual_deg: f.residual_deg, increments: f.increments });
        }
    }
    Ok(())
}

/// RMS angle between the ground truth's and the gyro's 0.25-s rotation axes (after the best
/// constant rotation) beyond which the ground truth is not this IMU's motion.
const NOT_FOLLOWING_DEG: f64 = 45.0;

/// Refuses a recording whose ground truth is measurably off the IMU's clock
/// ([`crate::eval::misaligned_ground_truth`]).
pub fn check_clock(rec: &Recording) -> Result<(), DataError> {
    match crate::eval::misaligned_ground_truth(rec, &crate::eval::EvalOptions::default()) {
        Some(l) => Err(DataError::Misaligned { name: rec.name.clone(), lag_s: l.lag_s, correlation: l.correlation }),
        None => Ok(()),
    }
}

/// Refuses a recording with IMU samples no IMU measures ([`crate::core::ImuSample::is_plausible`]):
/// they would swamp the normalisation or the loss.
pub fn check_plausible(rec: &Recording) -> Result<(), DataError> {
    let count = rec.imu.iter().filter(|s| !s.is_plausible()).count();
    if count == 0 {
        return Ok(());
    }
    let largest = |f: fn(&crate::core::ImuSample) -> f64| rec.imu.iter().map(f).fold(0.0, f64::max);
    Err(DataError::Implausible {
        name: rec.name.clone(),
        count,
        largest_rate: largest(|s| s.gyro.norm()),
        largest_accel: largest(|s| s.accel.norm()),
    })
}

/// Refuses an accelerometer whose median |a| is not near gravity ([`accel_units_suspect`]).
pub fn check_accel_units(rec: &Recording) -> Result<(), DataError> {
    match accel_units_suspect(rec) {
        Some(median) => Err(DataError::AccelUnits { name: rec.name.clone(), median }),
        None => Ok(()),
    }
}

/// The median |a| when it is outside [g/2, 2g]: an accelerometer on any robot on Earth reads
/// gravity plus motion whose median stays near g, so outside that it is in g (median ≈ 1),
/// has gravity removed (≈ 0) or is in other units. The model reads the specific force in m/s².
pub fn accel_units_suspect(rec: &Recording) -> Option<f64> {
    const G: f64 = 9.80665;
    let mut norms: Vec<f64> = rec.imu.iter().map(|s| s.accel.norm()).filter(|n| n.is_finite()).collect();
    if norms.len() < 100 {
        return None;
    }
    let mid = norms.len() / 2;
    let median = *norms.select_nth_unstable_by(mid, f64::total_cmp).1;
    (!(0.5 * G..=2.0 * G).contains(&median)).then_some(median)
}

/// A `simulate` source: the simulator's recording (IMU and ground-truth pose), never a bag.
fn simulated(config: &Path) -> Result<Recording, String> {
    let cfg = SimConfig::load(config).map_err(|e| e.to_string())?;
    Ok(simulate(&cfg).map_err(|e| format!("{}: {e}", config.display()))?.recording)
}

/// Ground truth at the IMU stamps and its validity (see the module doc).
pub fn ground_truth_at_imu(rec: &Recording, cfg: &DatasetConfig) -> (Vec<Option<nalgebra::UnitQuaternion<f64>>>, Vec<bool>) {
    let stamps: Vec<i64> = rec.imu.iter().map(|s| s.stamp_ns).collect();
    let gt = slerp_at(&rec.ground_truth, stamps.iter().copied(), (cfg.max_interpolation_gap_ms * 1e6) as i64);
    let nearest_max = (cfg.max_nearest_gt_ms * 1e6) as i64;
    let mut valid = Vec::with_capacity(stamps.len());
    let mut j = 0usize;
    let poses = &rec.ground_truth;
    for (t, g) in stamps.iter().zip(&gt) {
        while j + 1 < poses.len() && poses[j + 1].stamp_ns <= *t {
            j += 1;
        }
        let mut d = (poses[j].stamp_ns - t).abs();
        if j + 1 < poses.len() {
            d = d.min((poses[j + 1].stamp_ns - t).abs());
        }
        valid.push(g.is_some() && d <= nearest_max);
    }
    (gt, valid)
}

/// Loads, checks and crops one source into a task. `min_samples` (with its description)
/// is the shortest usable length.
/// With `dataset.power_on_bias: remove`, the recording's power-on bias is taken out first
/// (of the whole recording, before the crop) and said in the task.
pub fn load_task(root: &Path, src: &SourceConfig, cfg: &DatasetConfig, support_seconds: Option<f64>) -> Result<Task, DataError> {
    let mut rec = read_source(root, src)?;
    let removed = match cfg.power_on_bias {
        super::power_on::PowerOnBiasInTraining::Keep => None,
        super::power_on::PowerOnBiasInTraining::Remove => {
            let removed = super::power_on::remove_power_on_bias(&mut rec, &crate::standstill::StandstillConfig::default())
                .map_err(|e| DataError::PowerOnBias { name: rec.name.clone(), why: e.to_string() })?;
            tracing::info!("{}: {} removed", rec.name, removed.describe());
            Some(removed)
        }
    };
    let mut task = task_from_recording(rec, src, cfg, support_seconds)?;
    task.power_on_constant = removed;
    Ok(task)
}

/// Per-channel mean and std over every IMU sample of the tasks (f64).
pub fn normalization(tasks: &[Task]) -> ([f64; 6], [f64; 6]) {
    let mut sum = [0.0f64; 6];
    let mut sq = [0.0f64; 6];
    let mut n = 0.0f64;
    for t in tasks {
        for s in &t.rec.imu {
            let v = [s.gyro.x, s.gyro.y, s.gyro.z, s.accel.x, s.accel.y, s.accel.z];
            for c in 0..6 {
                sum[c] += v[c];
                sq[c] += v[c] * v[c];
            }
            n += 1.0;
        }
    }
    let mean = sum.map(|s| s / n.max(1.0));
    let mut std = [0.0; 6];
    for c in 0..6 {
        std[c] = ((sq[c] / n.max(1.0) - mean[c] * mean[c]).max(0.0)).sqrt().max(1e-9);
    }
    (mean, std)
}

/// `count` random windows of `len` samples from index range `range` of each task, stacked
/// into one batch (order: task-major).
pub fn sample_windows<R: Rng>(tasks: &[&Task], range: impl Fn(&Task) -> (usize, usize), count: usize, len: usize, rng: &mut R) -> Batch {
    let mut imu = Vec::new();
    let mut dt = Vec::new();
    let mut gt = Vec::new();
    let mut valid = Vec::new();
    let mut rows = Vec::new();
    for t in tasks {
        let (a, b) = range(t);
        assert!(b >= a + len, "{}: range {a}..{b} shorter than window {len} (checked at load)", t.name);
        for _ in 0..count {
            let start = rng.gen_range(a..=b - len) as i64;
            imu.push(t.imu.narrow(0, start, len as i64));
            dt.push(t.dt.narrow(0, start, len as i64));
            gt.push(t.gt.narrow(0, start, len as i64));
            valid.push(t.valid.narrow(0, start, len as i64));
            rows.push(t.calibration_row);
        }
    }
    Batch {
        imu: Tensor::stack(&imu, 0),
        dt: Tensor::stack(&dt, 0),
        gt: Tensor::stack(&gt, 0),
        valid: Tensor::stack(&valid, 0),
        calibration_rows: rows.iter().copied().collect::<Option<Vec<i64>>>().map(|r| Tensor::from_slice(&r)),
    }
}

/// Minimum length checks for a training task.
pub fn check_length(task: &Task, needed: usize, what: &str, available: usize) -> Result<(), DataError> {
    if available < needed {
        return Err(DataError::TooShort {
            name: task.name.clone(),
            samples: available,
            seconds: match task.rec.nominal_imu_rate_hz() {
                r if r > 0.0 => available as f64 / r,
                _ => 0.0,
            },
            needed: format!("{what} ({needed} samples)"),
        });
    }
    Ok(())
}

/// Why no IMU sample has ground truth: the poses cover the IMU's span but with holes longer
/// than the interpolation allows, or the two do not overlap at all.
fn not_covered(rec: &Recording, cfg: &DatasetConfig) -> DataError {
    let (i0, i1) = (rec.imu[0].stamp_ns, rec.imu[rec.imu.len() - 1].stamp_ns);
    let (g0, g1) = (rec.ground_truth[0].stamp_ns, rec.ground_truth[rec.ground_truth.len() - 1].stamp_ns);
    if g0 <= i1 && g1 >= i0 {
        return DataError::NotCovered {
            name: rec.name.clone(),
            poses: rec.ground_truth.len(),
            gt_start: g0 as f64 * 1e-9,
            gt_end: g1 as f64 * 1e-9,
            max_gap_ms: cfg.max_interpolation_gap_ms,
        };
    }
    DataError::NoOverlap {
        name: rec.name.clone(),
        imu_start: i0 as f64 * 1e-9,
        imu_end: i1 as f64 * 1e-9,
        gt_start: g0 as f64 * 1e-9,
        gt_end: g1 as f64 * 1e-9,
    }
}

/// A hole in the IMU stream (a dropout of more than the node's gap rule) is no interval to
/// integrate over: the samples either side are masked like a ground-truth gap, and said.
fn mask_imu_holes(name: &str, imu: &[crate::core::ImuSample], valid: &mut [bool]) {
    let n = imu.len();
    let period_ns = 1e9 / crate::core::nominal_rate_hz(imu).max(1e-9);
    let limit_ns = (crate::resample::GAP_PERIODS * period_ns) as i64;
    let holes: Vec<usize> = (1..n).filter(|&k| imu[k].stamp_ns - imu[k - 1].stamp_ns > limit_ns).collect();
    if let Some(longest) = holes.iter().map(|&k| imu[k].stamp_ns - imu[k - 1].stamp_ns).max() {
        tracing::warn!(
            "{}: {} gap(s) in the IMU stream (longest {:.3} s): the increments across them are left out of the loss",
            name,
            holes.len(),
            longest as f64 * 1e-9
        );
        for &k in &holes {
            valid[k - 1] = false;
            valid[k] = false;
        }
    }
}

/// [`load_task`] on a recording already in memory (the checks, ground truth at the IMU
/// stamps, the crop of `src.start_s` / `src.end_s` and the support split): the node's
/// buffered data and `imu-fsda adapt`'s split bag go through the trainer's own path.
pub fn task_from_recording(
    rec: Recording,
    src: &SourceConfig,
    cfg: &DatasetConfig,
    support_seconds: Option<f64>,
) -> Result<Task, DataError> {
    let (gt, valid) = ground_truth_at_imu(&rec, cfg);
    let first = gt.iter().position(Option::is_some);
    let last = gt.iter().rposition(Option::is_some);
    let (Some(first), Some(last)) = (first, last) else { return Err(not_covered(&rec, cfg)) };
    // Optional crop, in seconds from the first covered sample.
    let t0 = rec.imu[first].stamp_ns;
    let covered_s = (rec.imu[last].stamp_ns - t0) as f64 * 1e-9;
    let in_crop = |i: usize| {
        let s = (rec.imu[i].stamp_ns - t0) as f64 * 1e-9;
        src.start_s.is_none_or(|a| s >= a) && src.end_s.is_none_or(|b| s <= b)
    };
    let Some(a) = (first..=last).find(|&i| in_crop(i)) else {
        return Err(DataError::EmptyCrop { name: rec.name.clone(), start: src.start_s.unwrap_or(0.0), seconds: covered_s });
    };
    let b = (a..=last).rev().find(|&i| in_crop(i)).unwrap_or(a);
    if let Some(end) = src.end_s.filter(|e| *e > covered_s + 1.0) {
        // Said, not refused: the crop is the rest of the recording, perhaps not what was meant.
        tracing::warn!("{}: end_s {end} s is past its ground-truth-covered data ({covered_s:.1} s): cropped to the end", rec.name);
    }
    let imu = rec.imu[a..=b].to_vec();
    let gt = &gt[a..=b];
    let mut valid = valid[a..=b].to_vec();
    let n = imu.len();
    mask_imu_holes(&rec.name, &imu, &mut valid);
    let valid = &valid[..];
    let cropped = Recording { name: rec.name.clone(), imu, ground_truth: rec.ground_truth, temperature: Vec::new() };

    let flat: Vec<f32> =
        cropped.imu.iter().flat_map(|s| [s.gyro.x, s.gyro.y, s.gyro.z, s.accel.x, s.accel.y, s.accel.z]).map(|v| v as f32).collect();
    let mut dt: Vec<f64> = cropped.imu.windows(2).map(|w| (w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9).collect();
    dt.push(dt.last().copied().unwrap_or(0.005));
    let gt_flat: Vec<f64> = gt
        .iter()
        .flat_map(|q| match q {
            Some(q) => [q.w, q.i, q.j, q.k],
            None => [f64::NAN; 4],
        })
        .collect();
    let valid_count = valid.iter().filter(|v| **v).count();
    let longest_valid_run = valid.split(|v| !*v).map(<[bool]>::len).max().unwrap_or(0);
    let support_end = match support_seconds {
        Some(s) => {
            let t0 = cropped.imu[0].stamp_ns;
            cropped.imu.iter().position(|x| (x.stamp_ns - t0) as f64 * 1e-9 >= s).unwrap_or(n)
        }
        None => 0,
    };
    Ok(Task {
        name: cropped.name.clone(),
        source: src.describe(),
        imu: Tensor::from_slice(&flat).reshape([n as i64, 6]),
        dt: Tensor::from_slice(&dt),
        gt: Tensor::from_slice(&gt_flat).reshape([n as i64, 4]),
        valid: Tensor::from_slice(valid),
        support_end,
        valid_fraction: valid_count as f64 / n.max(1) as f64,
        longest_valid_run,
        imu_name: src.imu_name(),
        calibration_row: None,
        power_on_constant: None,
        rec: cropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::{ImuSample, PoseSample};
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn samples_no_imu_measures_are_refused() {
        let sample =
            |gyro: f64, accel: f64| ImuSample { stamp_ns: 0, gyro: Vector3::new(gyro, 0.0, 0.0), accel: Vector3::new(0.0, 0.0, accel) };
        let rec = |imu: Vec<ImuSample>| Recording { name: "r".into(), imu, ground_truth: vec![], temperature: vec![] };
        // A 35 rad/s spin and a 16 g impact are motion.
        assert!(check_plausible(&rec(vec![sample(35.0, 9.81), sample(0.1, 157.0)])).is_ok());
        let e = check_plausible(&rec(vec![sample(1e30, 9.81), sample(0.1, 9.81), sample(0.0, 2e4)])).unwrap_err();
        assert!(matches!(e, DataError::Implausible { count: 2, .. }), "{e}");
        assert!(e.to_string().contains("1.000e30 rad/s") && e.to_string().contains("2.000e4 m/s²"), "{e}");
    }

    fn dcfg() -> DatasetConfig {
        DatasetConfig {
            root: ".".into(),
            train: vec![],
            validation: vec![],
            test: vec![],
            monitor: vec![],
            support_seconds: 60.0,
            max_interpolation_gap_ms: 50.0,
            max_nearest_gt_ms: 10.0,
            power_on_bias: Default::default(),
        }
    }

    #[test]
    fn gt_gaps_are_masked_by_nearest_pose() {
        let imu: Vec<ImuSample> =
            (0..100).map(|i| ImuSample { stamp_ns: i * 5_000_000, gyro: Vector3::zeros(), accel: Vector3::zeros() }).collect();
        // Poses every 8 ms, with a 40 ms hole between 200 and 240 ms.
        let ground_truth: Vec<PoseSample> = (0..70)
            .map(|i| i * 8_000_000)
            .filter(|t| !(*t > 200_000_000 && *t < 240_000_000))
            .map(|t| PoseSample { stamp_ns: t, position_in_world: Vector3::zeros(), world_from_body: UnitQuaternion::identity() })
            .collect();
        let rec = Recording { name: "x".into(), imu, ground_truth, temperature: vec![] };
        let (gt, valid) = ground_truth_at_imu(&rec, &dcfg());
        assert!(gt[44].is_some()); // 220 ms: interpolated across the 40 ms hole …
        assert!(!valid[44]); // … but 20 ms from the nearest pose: masked
        assert!(valid[10] && valid[60]);
    }

    /// A `simulate` source is the recording `imu-fsda simulate` writes to a bag (the IMU
    /// exactly, the poses to 1e-12), loaded without one; its domain and IMU are `sim`, and bad
    /// configs are errors.
    #[test]
    fn simulate_source_equals_the_simulated_bag() {
        let dir = tempfile::tempdir().unwrap();
        let sim_yaml = dir.path().join("hover.yaml");
        std::fs::write(&sim_yaml, "profile: aerial\ngrade: adis16448\nrate_hz: 200\nseconds: 4\nseed: 5\ndatasheet_errors: true\n")
            .unwrap();
        let train_yaml = dir.path().join("t.yaml");
        std::fs::write(&train_yaml, "model: {}\ndataset: {train: [{simulate: hover.yaml}]}\ntrain: {epochs: 1}\n").unwrap();
        let cfg = crate::train::TrainConfig::load(&train_yaml).unwrap();
        let src = &cfg.dataset.train[0];
        assert_eq!((src.imu_name().as_str(), src.path().as_str()), ("sim", "sim/hover"));
        let rec = read_source(&cfg.dataset.root, src).unwrap();
        assert_eq!(rec.name, "sim_hover");

        let sim: SimConfig = serde_yaml::from_str(&std::fs::read_to_string(&sim_yaml).unwrap()).unwrap();
        let bag = dir.path().join("hover.mcap");
        crate::sim::write_bag(&bag, &simulate(&sim).unwrap()).unwrap();
        let (from_bag, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
        assert_eq!(rec.imu.len(), 800);
        assert_eq!(rec.imu, from_bag.imu);
        assert_eq!(rec.ground_truth.len(), from_bag.ground_truth.len());
        for (a, b) in rec.ground_truth.iter().zip(&from_bag.ground_truth) {
            let d = (a.position_in_world - b.position_in_world).norm() + a.world_from_body.angle_to(&b.world_from_body);
            assert!(a.stamp_ns == b.stamp_ns && d < 1e-12, "{a:?} {b:?}");
        }

        for (text, expected) in [
            ("profile: aerial\nspeed: 3\n", "not a simulation config"),
            ("profile: aerial\ngrade: bmi160\nrate_hz: -1\nseconds: 4\nseed: 0\n", "rate"),
        ] {
            std::fs::write(&sim_yaml, text).unwrap();
            let err = read_source(&cfg.dataset.root, src).unwrap_err().to_string();
            assert!(err.contains(expected) && err.contains("hover.yaml"), "{err}");
        }
        let missing = SourceConfig { simulate: Some(dir.path().join("none.yaml").to_string_lossy().into_owned()), ..Default::default() };
        assert!(read_source(&cfg.dataset.root, &missing).unwrap_err().to_string().contains("none.yaml"));
        let two = "model: {}\ndataset: {train: [{simulate: a.yaml, bag: b.mcap}]}\ntrain: {epochs: 1}\n";
        assert!(crate::train::TrainConfig::parse(two).unwrap().validate().unwrap_err().to_string().contains("exactly one"));
    }
}
