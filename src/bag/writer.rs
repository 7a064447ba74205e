//! Writing a bag: [`BagWriter`] (written aside and renamed when finished) and
//! [`write_recording`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::core::{ImuSample, Recording};
use crate::msg::{Imu, PoseStamped, RosMessage, Temperature};

use super::{io_err, BagError, BagMessage, GROUND_TRUTH_TOPIC, IMU_FRAME, IMU_TOPIC, TEMPERATURE_TOPIC, WORLD_FRAME};

/// Writes a ROS 2 MCAP bag. The bag is written as `<path>.<pid>.partial` and renamed to `path`
/// by [`BagWriter::finish`], so a run that fails or is killed half-way never replaces an
/// earlier bag of that name, nor leaves a truncated one where a finished one is expected, and
/// two runs writing one path never write one file (the last to finish wins, whole). A writer
/// dropped unfinished (an error) closes its `.partial` as a readable bag of what it holds.
pub struct BagWriter {
    path: PathBuf,
    partial: PathBuf,
    /// `None` once finished.
    writer: Option<mcap::Writer<BufWriter<File>>>,
    schemas: BTreeMap<&'static str, u16>,
    sequence: u32,
    scratch: Vec<u8>,
}

/// A channel opened on a [`BagWriter`] for one message type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channel {
    id: u16,
}

impl BagWriter {
    pub fn create(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let mut path = path.as_ref().to_path_buf();
        if path.is_dir() || path.file_name().is_none() {
            return Err(BagError::NotMcap { path, what: "is a folder: name the bag file to write".into() });
        }
        // A link is followed: the bag replaces what it points to, as writing through it did.
        if path.is_symlink() {
            if let Ok(target) = std::fs::canonicalize(&path) {
                path = target;
            }
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            crate::core::create_dir_all(dir).map_err(io_err(&path))?;
        }
        let partial = partial_path(&path, std::process::id());
        // Never truncated in place: a leftover of this pid (a writer of this process that
        // failed, or a dead process long ago) is unlinked first, so a reader of it keeps its data.
        let file = match File::create_new(&partial) {
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                std::fs::remove_file(&partial).map_err(io_err(&partial))?;
                File::create_new(&partial)
            }
            other => other,
        }
        .map_err(io_err(&partial))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("imu-fsda ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(1 << 20))
            .create(BufWriter::with_capacity(1 << 16, file))
            .map_err(|source| BagError::McapWrite { path: partial.clone(), messages: 0, source })?;
        Ok(BagWriter { path, partial, writer: Some(writer), schemas: BTreeMap::new(), sequence: 0, scratch: Vec::with_capacity(512) })
    }

    fn mcap(&mut self) -> &mut mcap::Writer<BufWriter<File>> {
        self.writer.as_mut().expect("a BagWriter is consumed by finish")
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn mcap_err(&self, source: mcap::McapError) -> BagError {
        BagError::McapWrite { path: self.partial.clone(), messages: self.sequence as u64, source }
    }

    /// Open (or reuse) a channel for messages of type `M` on `topic`.
    pub fn channel<M: RosMessage>(&mut self, topic: &str) -> Result<Channel, BagError> {
        let schema_id = match self.schemas.get(M::TYPE_NAME) {
            Some(id) => *id,
            None => {
                let id = self.mcap().add_schema(M::TYPE_NAME, "ros2msg", M::DEFINITION.as_bytes()).map_err(|e| self.mcap_err(e))?;
                self.schemas.insert(M::TYPE_NAME, id);
                id
            }
        };
        let id = self.mcap().add_channel(schema_id, topic, "cdr", &BTreeMap::new()).map_err(|e| self.mcap_err(e))?;
        Ok(Channel { id })
    }

    /// A channel on `topic` like the one `m` was read from: its schema, message encoding and
    /// metadata (rosbag2's QoS profiles), for messages copied through unchanged.
    pub fn channel_of(&mut self, topic: &str, m: &BagMessage) -> Result<Channel, BagError> {
        let schema_id = match m.schema.as_deref() {
            None => 0,
            Some(s) => self.mcap().add_schema(&s.name, &s.encoding, &s.data).map_err(|e| self.mcap_err(e))?,
        };
        let encoding = if m.channel.message_encoding.is_empty() { "cdr" } else { m.channel.message_encoding.as_str() };
        let id = self.mcap().add_channel(schema_id, topic, encoding, &m.channel.metadata).map_err(|e| self.mcap_err(e))?;
        Ok(Channel { id })
    }

    /// Write one message with its log time (ns); publish time is the same.
    pub fn write<M: RosMessage>(&mut self, channel: Channel, log_time_ns: i64, msg: &M) -> Result<(), BagError> {
        let mut buf = std::mem::take(&mut self.scratch);
        msg.encode_into(&mut buf).map_err(|source| BagError::Decode {
            path: self.path.clone(),
            topic: format!("channel {}", channel.id),
            index: self.sequence as u64,
            log_time_ns: log_time_ns.max(0) as u64,
            source,
        })?;
        let res = self.write_raw(channel, log_time_ns, &buf);
        self.scratch = buf;
        res
    }

    /// Write already-encoded CDR bytes.
    pub fn write_raw(&mut self, channel: Channel, log_time_ns: i64, cdr: &[u8]) -> Result<(), BagError> {
        let t = log_time_ns.max(0) as u64;
        let header = mcap::records::MessageHeader { channel_id: channel.id, sequence: self.sequence, log_time: t, publish_time: t };
        self.sequence = self.sequence.wrapping_add(1);
        self.mcap().write_to_known_channel(&header, cdr).map_err(|e| self.mcap_err(e))
    }

    /// Write the summary (schemas, channels, Statistics, indexes) and close the file.
    pub fn finish(mut self) -> Result<(), BagError> {
        let mut writer = self.writer.take().expect("a BagWriter is consumed by finish");
        writer.finish().map_err(|e| self.mcap_err(e))?;
        writer.into_inner().into_inner().map_err(|e| BagError::Io { path: self.partial.clone(), source: e.into_error() })?;
        std::fs::rename(&self.partial, &self.path).map_err(io_err(&self.path))
    }
}

impl Drop for BagWriter {
    fn drop(&mut self) {
        if let Some(mut w) = self.writer.take() {
            let closed = w.finish().is_ok();
            drop(w);
            tracing::warn!(
                "{} was not finished; what was written of it before the failure is in {}{}",
                self.path.display(),
                self.partial.display(),
                if closed { "" } else { " (without its summary: read up to its last whole chunk)" }
            );
        }
    }
}

/// Where process `pid` writes a bag until it is finished: `<path>.<pid>.partial`, beside it.
pub fn partial_path(path: &Path, pid: u32) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(format!(".{pid}.partial"));
    PathBuf::from(p)
}

/// What a recording's bag states beside its samples ([`write_recording_with`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RecordingBagOptions {
    /// Each `/imu/data` message's covariance diagonals (gyro, accelerometer), the per-sample
    /// white-noise variance where known (the simulator's); `None`: zeros (unknown, REP-145).
    pub imu_variance: Option<(f64, f64)>,
    /// Each `/imu/temperature` message's variance, °C².
    pub temperature_variance: f64,
}

/// Write a recording as a bag: `/imu/data`, `/ground_truth/pose` and `/imu/temperature` where
/// it has them, in stamp order (log time = header stamp; at equal stamps the IMU sample, then
/// the pose, then the temperature). Same recording → same bytes.
pub fn write_recording(path: impl AsRef<Path>, rec: &Recording) -> Result<(), BagError> {
    write_recording_with(path, rec, &RecordingBagOptions::default(), |_, _| {})
}

/// [`write_recording`] with what the bag states beside the samples, calling `progress(done,
/// total)` every 10 000 messages and at the end.
pub fn write_recording_with(
    path: impl AsRef<Path>,
    rec: &Recording,
    options: &RecordingBagOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<(), BagError> {
    let mut w = BagWriter::create(path)?;
    let imu_ch = w.channel::<Imu>(IMU_TOPIC)?;
    let gt_ch = if rec.ground_truth.is_empty() { None } else { Some(w.channel::<PoseStamped>(GROUND_TRUTH_TOPIC)?) };
    let temp_ch = if rec.temperature.is_empty() { None } else { Some(w.channel::<Temperature>(TEMPERATURE_TOPIC)?) };
    let mut imu_msg = Imu::from_sample(
        &rec.imu.first().copied().unwrap_or(ImuSample { stamp_ns: 0, gyro: Default::default(), accel: Default::default() }),
        IMU_FRAME,
    );
    if let Some((gyro, accel)) = options.imu_variance {
        for i in [0, 4, 8] {
            imu_msg.angular_velocity_covariance.0[i] = gyro;
            imu_msg.linear_acceleration_covariance.0[i] = accel;
        }
    }
    let total = rec.imu.len() + rec.ground_truth.len() + rec.temperature.len();
    let (mut i, mut g, mut t) = (0, 0, 0);
    for done in 1..=total {
        let ti = rec.imu.get(i).map_or(i64::MAX, |s| s.stamp_ns);
        let tg = rec.ground_truth.get(g).map_or(i64::MAX, |s| s.stamp_ns);
        let tt = rec.temperature.get(t).map_or(i64::MAX, |s| s.stamp_ns);
        if ti <= tg && ti <= tt {
            let s = &rec.imu[i];
            imu_msg.header.stamp = crate::msg::Time::from_ns(s.stamp_ns);
            imu_msg.angular_velocity = s.gyro.into();
            imu_msg.linear_acceleration = s.accel.into();
            w.write(imu_ch, ti, &imu_msg)?;
            i += 1;
        } else if tg <= tt {
            if let Some(ch) = gt_ch {
                w.write(ch, tg, &PoseStamped::from_sample(&rec.ground_truth[g], WORLD_FRAME))?;
            }
            g += 1;
        } else {
            if let Some(ch) = temp_ch {
                let s = &rec.temperature[t];
                let msg = Temperature {
                    header: crate::msg::Header { stamp: crate::msg::Time::from_ns(s.stamp_ns), frame_id: IMU_FRAME.into() },
                    temperature: s.celsius,
                    variance: options.temperature_variance,
                };
                w.write(ch, tt, &msg)?;
            }
            t += 1;
        }
        if done % 10_000 == 0 {
            progress(done, total);
        }
    }
    progress(total, total);
    w.finish()
}
