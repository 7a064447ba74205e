//! A bag read as a [`Recording`] (IMU, ground truth, temperature), every repair counted in a
//! [`LoadReport`].

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use crate::core::{ImuSample, PoseSample, Recording, TemperatureSample};
use crate::msg::{Imu, Odometry, PoseStamped, RosMessage, Temperature};

use super::{BagError, BagReader, GROUND_TRUTH_TOPIC, IMU_TOPIC, TEMPERATURE_TOPIC};

/// What [`read_recording`] skipped, by reason. Every skip is counted, never silent.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct LoadReport {
    pub imu_read: u64,
    pub imu_non_finite: u64,
    pub imu_duplicate_stamp: u64,
    pub imu_backwards_stamp: u64,
    /// Samples stamped 0 in a stream whose other stamps are clock times (a driver that
    /// publishes before its clock is set): left out, not integrated as a gap of decades.
    pub imu_unset_stamp: u64,
    pub ground_truth_read: u64,
    pub ground_truth_invalid: u64,
    pub ground_truth_out_of_order: u64,
    /// Poses of a frozen ground truth ([`crate::frozen_ground_truth::drop_frozen_ground_truth`]).
    pub ground_truth_frozen: u64,
    pub temperature_read: u64,
    /// Messages written after one with a later log time: read in log-time order, not skipped.
    pub out_of_log_time_order: u64,
    /// Where the first backwards IMU stamp came (ns into the stream) and how far back, ns.
    pub first_step_back: Option<(i64, i64)>,
    /// Samples stamped slightly before the one received ahead of them (jittered driver
    /// stamps, at most [`IMU_REORDER_LIMIT_NS`] back): put back in stamp order, not skipped.
    pub imu_reordered: u64,
    /// Samples of another sensor on the IMU topic: two frame_ids alternating (two drivers
    /// publishing on one topic). The frame_id with the most samples is read, these are left out.
    pub imu_other_sensor: u64,
    /// The frame_ids when the topic interleaves two sensors: (read, left out).
    pub interleaved_frames: Option<(String, String)>,
    /// The stamps stepped back past the reorder limit and have not yet passed the last kept
    /// one: what follows is the stepped clock's, dropped, not reordered.
    #[serde(skip)]
    pub(crate) stepped_back: bool,
}

impl LoadReport {
    /// When most IMU samples repeat or go back from an earlier header stamp, the stamps are
    /// not the samples' times (a driver that leaves `header.stamp` at zero): what to say.
    pub fn stamp_problem(&self) -> Option<String> {
        self.stamp_problem_above(0.5)
    }

    /// [`Self::stamp_problem`] from a share of `fraction` on: training and adaptation, which
    /// would learn from a stream thinned to what is left, refuse from 10 %.
    pub fn stamp_problem_above(&self, fraction: f64) -> Option<String> {
        let bad = self.imu_duplicate_stamp + self.imu_backwards_stamp;
        let problem = self.imu_read >= 2 && bad as f64 >= fraction * self.imu_read as f64 && bad > 0;
        // Mostly backwards after one step of a second or more: the clock stepped back (a driver
        // restarted), not stamps taken on arrival.
        if let Some((at, by)) =
            self.first_step_back.filter(|(_, by)| *by >= 1_000_000_000 && self.imu_backwards_stamp > 2 * self.imu_duplicate_stamp)
        {
            let (at, by) = (at as f64 * 1e-9, by as f64 * 1e-9);
            return problem.then(|| {
                format!(
                    "{bad} of {} IMU samples go back from an earlier header stamp: the IMU's clock steps back by {by:.3} s at \
                     {at:.3} s into the stream (a driver restart?), and every later sample until it passes the old time is \
                     dropped; split the bag at the restart",
                    self.imu_read
                )
            });
        }
        problem.then(|| {
            format!(
                "{bad} of {} IMU samples repeat or go back from an earlier header stamp ({} repeated, {} backwards): \
                 header.stamp is not set to the sample's time (a driver stamping bursts on arrival, or leaving it at zero?); \
                 the stamps are what every command here integrates with",
                self.imu_read, self.imu_duplicate_stamp, self.imu_backwards_stamp
            )
        })
    }

    pub fn skipped(&self) -> u64 {
        self.imu_skipped() + self.ground_truth_skipped() + self.ground_truth_frozen
    }

    /// IMU samples left out, whatever the reason.
    pub fn imu_skipped(&self) -> u64 {
        self.imu_non_finite + self.imu_unset_stamp + self.imu_duplicate_stamp + self.imu_backwards_stamp + self.imu_other_sensor
    }

    /// What the reader did that the user should know of beyond plain skips: another sensor's
    /// samples on the topic, and jittered stamps put back in order.
    pub fn imu_stream_note(&self) -> Option<String> {
        let mut parts = Vec::new();
        if let Some((read, other)) = &self.interleaved_frames {
            parts.push(format!(
                "the IMU topic interleaves two sensors (frame_id {read:?} and {other:?}): read {read:?} only, {} samples of \
                 {other:?} left out",
                self.imu_other_sensor
            ));
        }
        if self.imu_reordered > 0 {
            parts.push(format!(
                "{} IMU samples stamped up to {} ms before the sample received ahead of them (jittered stamps) were put back \
                 in stamp order",
                self.imu_reordered,
                IMU_REORDER_LIMIT_NS / 1_000_000
            ));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// Ground-truth poses left out as unreadable (invalid or out of order; frozen ones apart).
    pub fn ground_truth_skipped(&self) -> u64 {
        self.ground_truth_invalid + self.ground_truth_out_of_order
    }
}

impl std::fmt::Display for LoadReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "imu {} read, skipped {} non-finite, {} duplicate stamps, {} backwards stamps",
            self.imu_read, self.imu_non_finite, self.imu_duplicate_stamp, self.imu_backwards_stamp
        )?;
        if self.imu_unset_stamp > 0 {
            write!(f, ", {} unset (0) stamps", self.imu_unset_stamp)?;
        }
        if let Some((_, other)) = &self.interleaved_frames {
            write!(f, ", {} of another sensor (frame_id {other:?})", self.imu_other_sensor)?;
        }
        write!(
            f,
            "; ground truth {} read, skipped {} invalid, {} out of order",
            self.ground_truth_read, self.ground_truth_invalid, self.ground_truth_out_of_order
        )?;
        if self.ground_truth_frozen > 0 {
            write!(f, ", {} frozen (one pose repeated while the IMU moved: left out as a gap)", self.ground_truth_frozen)?;
        }
        Ok(())
    }
}

/// Which topics to read a recording from. Ground truth may be `geometry_msgs/PoseStamped`,
/// `nav_msgs/Odometry` or a reference `sensor_msgs/Imu` with orientation; the type is
/// taken from the bag's schema.
#[derive(Debug, Clone)]
pub struct RecordingTopics {
    pub imu: String,
    pub ground_truth: Option<String>,
    pub temperature: Option<String>,
}

impl Default for RecordingTopics {
    fn default() -> Self {
        RecordingTopics {
            imu: IMU_TOPIC.into(),
            ground_truth: Some(GROUND_TRUTH_TOPIC.into()),
            temperature: Some(TEMPERATURE_TOPIC.into()),
        }
    }
}

/// Read a recording from a bag, stamps from the message headers. Samples that are not
/// finite, repeat a stamp or go back in time are skipped and counted in the report.
/// An IMU topic with no messages is an error; a missing ground-truth topic is not (the
/// recording then has none, and callers that need it say so).
pub fn read_recording(path: impl AsRef<Path>, topics: &RecordingTopics) -> Result<(Recording, LoadReport), BagError> {
    let path = path.as_ref();
    let mut rec = Recording { name: path.display().to_string(), ..Default::default() };
    let mut report = LoadReport::default();
    let mut decoded = Decoded::read(path, topics)?;
    report.out_of_log_time_order = in_log_time_order(&mut decoded.imu, |s| Some(s.0.stamp_ns))
        + in_log_time_order(&mut decoded.poses, |p| p.as_ref().map(|p| p.stamp_ns))
        + in_log_time_order(&mut decoded.temperature, |t| Some(t.stamp_ns));
    take_imu(decoded.imu, &decoded.frames, &mut rec, &mut report);
    take_ground_truth(decoded.poses, &mut rec, &mut report);
    report.temperature_read = decoded.temperature.len() as u64;
    for (_, t) in decoded.temperature {
        if t.celsius.is_finite() && rec.temperature.last().is_none_or(|l| t.stamp_ns > l.stamp_ns) {
            rec.temperature.push(t);
        }
    }
    if report.out_of_log_time_order > 0 {
        tracing::info!(
            "{}: {} messages were written out of log-time order; read in log-time order",
            path.display(),
            report.out_of_log_time_order
        );
    }
    if rec.imu.is_empty() {
        let present = decoded.present.iter().map(|(t, ty)| format!("{t} [{ty}]")).collect::<Vec<_>>().join(", ");
        return Err(BagError::MissingTopic { path: path.to_path_buf(), topic: topics.imu.clone(), present });
    }
    if report.skipped() > 0 {
        tracing::warn!("{}: {}", path.display(), report);
    }
    if let Some(note) = report.imu_stream_note() {
        tracing::warn!("{}: {note}", path.display());
    }
    Ok((rec, report))
}

/// A recording's messages decoded with their log times, in file order: MCAP does not require
/// a file to be in log-time order (a recorder's threads interleave), and readers order it by
/// log time, as `ros2 bag play` does. In file order such a bag lost its late-written samples
/// as "backwards stamps".
struct Decoded {
    /// Every topic in the bag and its type, for the error that names what is there.
    present: BTreeMap<Arc<str>, Arc<str>>,
    /// Each IMU sample with the index of its frame_id in `frames`: two sensors on one topic
    /// show as alternating frame_ids.
    imu: Vec<(u64, (ImuSample, usize))>,
    frames: Vec<String>,
    /// Ground-truth poses; `None` for a message that carries none (an Imu without orientation).
    poses: Vec<(u64, Option<PoseSample>)>,
    temperature: Vec<(u64, TemperatureSample)>,
}

impl Decoded {
    fn read(path: &Path, topics: &RecordingTopics) -> Result<Self, BagError> {
        let mut d = Decoded { present: BTreeMap::new(), imu: Vec::new(), frames: Vec::new(), poses: Vec::new(), temperature: Vec::new() };
        for (index, m) in BagReader::open(path)?.enumerate() {
            let m = m?;
            let index = index as u64 + 1;
            if !d.present.contains_key(&m.topic) {
                d.present.insert(m.topic.clone(), m.type_name.clone());
            }
            let decode_err = |source| BagError::Decode {
                path: path.to_path_buf(),
                topic: m.topic.to_string(),
                index,
                log_time_ns: m.log_time_ns,
                source,
            };
            let wrong_type = |expected: &str| BagError::WrongType {
                path: path.to_path_buf(),
                topic: m.topic.to_string(),
                found: m.type_name.to_string(),
                expected: expected.into(),
            };
            if *m.topic == *topics.imu {
                if *m.type_name != *Imu::TYPE_NAME {
                    return Err(wrong_type(Imu::TYPE_NAME));
                }
                let msg = Imu::decode(&m.data).map_err(decode_err)?;
                let frame = match d.frames.iter().position(|f| *f == msg.header.frame_id) {
                    Some(k) => k,
                    None => {
                        d.frames.push(msg.header.frame_id.clone());
                        d.frames.len() - 1
                    }
                };
                d.imu.push((m.log_time_ns, (msg.sample(), frame)));
            } else if topics.ground_truth.as_deref() == Some(&*m.topic) {
                let pose = match &*m.type_name {
                    t if t == PoseStamped::TYPE_NAME => PoseStamped::decode(&m.data).map_err(decode_err)?.sample(),
                    t if t == Odometry::TYPE_NAME => Odometry::decode(&m.data).map_err(decode_err)?.sample(),
                    t if t == Imu::TYPE_NAME => {
                        let imu = Imu::decode(&m.data).map_err(decode_err)?;
                        imu.has_orientation().then(|| imu.orientation.to_unit()).flatten().map(|q| PoseSample {
                            stamp_ns: imu.header.stamp.to_ns(),
                            position_in_world: nalgebra::Vector3::zeros(),
                            world_from_body: q,
                        })
                    }
                    _ => return Err(wrong_type("geometry_msgs/msg/PoseStamped, nav_msgs/msg/Odometry or sensor_msgs/msg/Imu")),
                };
                d.poses.push((m.log_time_ns, pose));
            } else if topics.temperature.as_deref() == Some(&*m.topic) {
                if *m.type_name != *Temperature::TYPE_NAME {
                    return Err(wrong_type(Temperature::TYPE_NAME));
                }
                d.temperature.push((m.log_time_ns, Temperature::decode(&m.data).map_err(decode_err)?.sample()));
            }
        }
        Ok(d)
    }
}

/// The IMU samples in log-time order into `rec`: the other sensor's of two interleaved on one
/// topic, unset stamps, and what [`push_imu`] refuses are counted and skipped.
fn take_imu(imu: Vec<(u64, (ImuSample, usize))>, frames: &[String], rec: &mut Recording, report: &mut LoadReport) {
    // Stamped 0 and followed by a clock time (the next other stamp over an hour later): not
    // set, rather than the sample's time. A simulator's clock starting at 0 goes on in steps.
    let mut next_stamp = vec![0i64; imu.len()];
    let mut next = 0i64;
    for (k, (_, (s, _))) in imu.iter().enumerate().rev() {
        next_stamp[k] = next;
        if s.stamp_ns != 0 {
            next = s.stamp_ns;
        }
    }
    let sensor = interleaved_sensor(&imu);
    if let Some(read) = sensor {
        let other = imu.iter().map(|(_, (_, f))| *f).find(|f| *f != read).unwrap_or(read);
        report.interleaved_frames = Some((frames[read].clone(), frames[other].clone()));
    }
    for ((_, (s, frame)), next) in imu.into_iter().zip(next_stamp) {
        report.imu_read += 1;
        if sensor.is_some_and(|read| frame != read) {
            report.imu_other_sensor += 1;
            continue;
        }
        if s.stamp_ns == 0 && next > UNSET_STAMP_BESIDE_NS {
            report.imu_unset_stamp += 1;
            continue;
        }
        push_imu(&mut rec.imu, s, report);
    }
}

/// The ground-truth poses in log-time order into `rec`: invalid and out-of-order ones counted
/// and skipped, a frozen stretch dropped.
fn take_ground_truth(poses: Vec<(u64, Option<PoseSample>)>, rec: &mut Recording, report: &mut LoadReport) {
    for (_, pose) in poses {
        report.ground_truth_read += 1;
        match pose {
            None => report.ground_truth_invalid += 1,
            Some(p) => match rec.ground_truth.last() {
                Some(last) if p.stamp_ns <= last.stamp_ns => report.ground_truth_out_of_order += 1,
                _ => rec.ground_truth.push(p),
            },
        }
    }
    report.ground_truth_frozen = crate::frozen_ground_truth::drop_frozen_ground_truth(rec) as u64;
}

/// The frame_id changes this many times or more in a topic's messages: two sensors
/// interleaved, not a driver renamed once.
const INTERLEAVED_SWITCHES: usize = 10;

/// When the IMU messages alternate between frame_ids from two sensors (two drivers on one
/// topic), the frame to read: the one with the most samples. `None` for one sensor: a single
/// rename, rare glitched frame_ids (another frame under a tenth of the samples), or frame_ids
/// alternating on one continuous signal (consecutive samples of different frames no further
/// apart than samples two apart of one frame).
fn interleaved_sensor(imu: &[(u64, (ImuSample, usize))]) -> Option<usize> {
    let frame = |k: usize| imu[k].1 .1;
    let switches = imu.windows(2).filter(|w| w[0].1 .1 != w[1].1 .1).count();
    if switches < INTERLEAVED_SWITCHES {
        return None;
    }
    let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
    for (_, (_, f)) in imu {
        *counts.entry(*f).or_default() += 1;
    }
    // The most samples, the first seen on a tie (frame indices are in order of appearance).
    let (&read, _) = counts.iter().max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(a.0)))?;
    let others = imu.len() - counts[&read];
    if others * 10 < imu.len() {
        return None;
    }
    let gyro = |k: usize| imu[k].1 .0.gyro;
    let median = |mut v: Vec<f64>| {
        let mid = v.len() / 2;
        (!v.is_empty()).then(|| *v.select_nth_unstable_by(mid, f64::total_cmp).1)
    };
    let across = median((1..imu.len()).filter(|&k| frame(k) != frame(k - 1)).map(|k| (gyro(k) - gyro(k - 1)).norm()).collect());
    let within = median((2..imu.len()).filter(|&k| frame(k) == frame(k - 2)).map(|k| (gyro(k) - gyro(k - 2)).norm()).collect());
    match (across, within) {
        (Some(a), Some(w)) if a <= 2.0 * w + 1e-9 => None,
        _ => Some(read),
    }
}

/// An IMU stamp of 0 is taken as unset when the stream's next other stamp is past this (1 h):
/// a simulator's clock starts at 0 and its first sample may well be stamped 0.
pub(super) const UNSET_STAMP_BESIDE_NS: i64 = 3_600_000_000_000;

/// Orders one topic's messages by log time (a stable sort: equal log times keep the file's
/// order); returns how many came before an earlier-written one's log time. Where the header
/// stamps (`stamp`) are in order as written and log-time order would put more of them out of
/// order (a recorder that swapped two receive times), the file's order is kept: the stamps are
/// what is integrated, and a sample out of their order is dropped as a backwards stamp.
pub(super) fn in_log_time_order<T>(messages: &mut [(u64, T)], stamp: impl Fn(&T) -> Option<i64>) -> u64 {
    let mut latest = 0u64;
    let mut late = 0u64;
    for (t, _) in messages.iter() {
        if *t < latest {
            late += 1;
        }
        latest = latest.max(*t);
    }
    if late > 0 {
        // Stamps at or before the latest one read so far: what the reader drops.
        let backwards = |order: &mut dyn Iterator<Item = &(u64, T)>| {
            let mut latest = i64::MIN;
            let mut count = 0usize;
            for s in order.filter_map(|m| stamp(&m.1)) {
                count += usize::from(s <= latest);
                latest = latest.max(s);
            }
            count
        };
        let mut by_log: Vec<usize> = (0..messages.len()).collect();
        by_log.sort_by_key(|&i| messages[i].0);
        if backwards(&mut by_log.iter().map(|&i| &messages[i])) <= backwards(&mut messages.iter()) {
            messages.sort_by_key(|m| m.0);
        }
    }
    late
}

/// How far back a sample's stamp may be from the last one's and still be put back in order
/// (20 ms): driver stamps jittered by a few ms. Further back is a clock that stepped.
pub const IMU_REORDER_LIMIT_NS: i64 = 20_000_000;

/// Append an IMU sample unless it is non-finite or repeats a stamp. A sample stamped up to
/// [`IMU_REORDER_LIMIT_NS`] before the last one is inserted in stamp order (jittered stamps);
/// further back it is skipped as a backwards stamp.
pub fn push_imu(imu: &mut Vec<ImuSample>, s: ImuSample, report: &mut LoadReport) {
    if !s.is_finite() {
        report.imu_non_finite += 1;
        return;
    }
    if let Some(last) = imu.last() {
        if s.stamp_ns == last.stamp_ns {
            report.imu_duplicate_stamp += 1;
            return;
        }
        if s.stamp_ns < last.stamp_ns && last.stamp_ns - s.stamp_ns <= IMU_REORDER_LIMIT_NS && !report.stepped_back {
            // Binary search; the insert moves only the few samples within the limit.
            let at = imu.partition_point(|p| p.stamp_ns < s.stamp_ns);
            if imu[at].stamp_ns == s.stamp_ns {
                report.imu_duplicate_stamp += 1;
            } else {
                imu.insert(at, s);
                report.imu_reordered += 1;
            }
            return;
        }
        if s.stamp_ns < last.stamp_ns {
            report.stepped_back = true;
            report.imu_backwards_stamp += 1;
            if report.imu_backwards_stamp == 1 {
                let first = imu.first().map_or(last.stamp_ns, |f| f.stamp_ns);
                report.first_step_back = Some((last.stamp_ns - first, last.stamp_ns - s.stamp_ns));
            }
            return;
        }
    }
    report.stepped_back = false;
    imu.push(s);
}
