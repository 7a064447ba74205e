//! MCAP bags as rosbag2 writes them: profile `ros2`, `ros2msg` schemas with full
//! definitions, `cdr` messages, Zstd chunks, a summary with Statistics.
//!
//! Reading streams record by record (memory does not grow with the bag); writing keeps only
//! the open chunk in memory. [`read_recording`] turns a bag into a [`Recording`] with the
//! repairs it made counted in a [`LoadReport`].

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::core::{ImuSample, PoseSample, PublishedAttitude, Recording, TemperatureSample};
use crate::msg::{Imu, MsgError, Odometry, PoseStamped, RosMessage, Temperature};

/// Default topic names written by `import` and `simulate` and read by `eval`.
pub const IMU_TOPIC: &str = "/imu/data";
pub const GROUND_TRUTH_TOPIC: &str = "/ground_truth/pose";
pub const TEMPERATURE_TOPIC: &str = "/imu/temperature";
pub const IMU_FRAME: &str = "imu_link";
pub const WORLD_FRAME: &str = "world";

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a readable MCAP bag (after {messages} messages): {source}")]
    Mcap {
        path: PathBuf,
        messages: u64,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: writing the bag failed (after {messages} messages): {source}")]
    McapWrite {
        path: PathBuf,
        messages: u64,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: message {index} on {topic} (log time {log_time_ns} ns): {source}")]
    Decode {
        path: PathBuf,
        topic: String,
        index: u64,
        log_time_ns: u64,
        #[source]
        source: MsgError,
    },
    #[error("{path}: topic {topic} has type {found}, expected {expected}")]
    WrongType { path: PathBuf, topic: String, found: String, expected: String },
    #[error("{path}: no messages on topic {topic} (topics present: {present})")]
    MissingTopic { path: PathBuf, topic: String, present: String },
    #[error("{path}: {what}")]
    NotMcap { path: PathBuf, what: String },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io { path: path.to_path_buf(), source }
}

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

/// One message read from a bag: its topic, type, log time and CDR payload.
#[derive(Debug, Clone)]
pub struct BagMessage {
    pub topic: Arc<str>,
    pub type_name: Arc<str>,
    /// The channel's schema (encoding and definition), to copy messages into another bag.
    pub schema: Option<Arc<mcap::Schema<'static>>>,
    /// The channel's message encoding and metadata, to copy it whole ([`BagWriter::channel_of`]).
    pub channel: Arc<ChannelExtras>,
    pub log_time_ns: u64,
    pub data: Vec<u8>,
}

/// Streams the messages of a bag in file order; memory stays bounded by one chunk.
pub struct BagReader {
    path: PathBuf,
    inner: mcap::io::MessageReader<BufReader<File>>,
    topics: BTreeMap<u16, ChannelInfo>,
    count: u64,
}

type ChannelInfo = (Arc<str>, Arc<str>, Option<Arc<mcap::Schema<'static>>>, Arc<ChannelExtras>);

/// What a channel carries beside its topic and schema, copied with its messages: rosbag2's
/// `offered_qos_profiles` (a /tf_static replayed without its transient-local durability is
/// never heard by tf2's static listener) and the message encoding.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ChannelExtras {
    pub message_encoding: String,
    pub metadata: BTreeMap<String, String>,
}

impl BagReader {
    pub fn open(path: impl AsRef<Path>) -> Result<Self, BagError> {
        let path = path.as_ref().to_path_buf();
        if let Some(what) = not_mcap(&path) {
            return Err(BagError::NotMcap { path, what });
        }
        let file = File::open(&path).map_err(io_err(&path))?;
        // A corrupt length field must not make the reader allocate it (no record can be
        // longer than the file), and a damaged chunk must be an error, not altered data.
        let file_len = file.metadata().map(|m| m.len()).unwrap_or(0) as usize;
        let options =
            mcap::sans_io::LinearReaderOptions::default().with_record_length_limit(file_len.max(1 << 26)).with_validate_chunk_crcs(true);
        let inner = mcap::io::MessageReader::new_with_options(BufReader::with_capacity(1 << 16, file), options);
        Ok(BagReader { path, inner, topics: BTreeMap::new(), count: 0 })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Iterator for BagReader {
    type Item = Result<BagMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        let msg = match self.inner.next()? {
            Ok(m) => m,
            Err(source) => return Some(Err(BagError::Mcap { path: self.path.clone(), messages: self.count, source })),
        };
        self.count += 1;
        let (topic, type_name, schema, channel) = self
            .topics
            .entry(msg.channel.id)
            .or_insert_with(|| {
                let type_name = msg.channel.schema.as_ref().map(|s| s.name.as_str()).unwrap_or("");
                let extras =
                    ChannelExtras { message_encoding: msg.channel.message_encoding.clone(), metadata: msg.channel.metadata.clone() };
                (Arc::from(msg.channel.topic.as_str()), Arc::from(type_name), msg.channel.schema.clone(), Arc::new(extras))
            })
            .clone();
        Some(Ok(BagMessage { topic, type_name, schema, channel, log_time_ns: msg.log_time, data: msg.data.into_owned() }))
    }
}

/// What `ros2 bag record` leaves that is not an MCAP file, said plainly (the MCAP reader's own
/// errors for them are "Bad magic number" or a compression-stream error): a rosbag2 folder, an
/// SQLite3 `.db3` bag, a bag compressed whole (`--compression-mode file`).
fn not_mcap(path: &Path) -> Option<String> {
    const CONVERT: &str =
        "only MCAP is read; convert it with `ros2 bag convert` to storage_id mcap, or record with `ros2 bag record -s mcap`";
    if path.is_dir() {
        let mut inside: Vec<PathBuf> = std::fs::read_dir(path).ok()?.filter_map(|e| e.ok().map(|e| e.path())).collect();
        // The listing's order is the file system's: a split recording's first part first.
        inside.sort();
        let with = |ext: &str| inside.iter().filter(|p| p.to_string_lossy().ends_with(ext)).cloned().collect::<Vec<_>>();
        let (mcaps, db3s) = (with(".mcap"), with(".db3"));
        return Some(match (mcaps.first(), db3s.first()) {
            (Some(m), _) => format!(
                "a folder (a rosbag2 recording?): pass its MCAP file{}, e.g. {}",
                if mcaps.len() > 1 { "s one at a time" } else { "" },
                m.display()
            ),
            (None, Some(_)) => format!("a rosbag2 folder in SQLite3 (.db3) storage: {CONVERT}"),
            _ => "a folder, not an MCAP bag".into(),
        });
    }
    let mut head = [0u8; 16];
    let n = std::io::Read::read(&mut File::open(path).ok()?, &mut head).ok()?;
    let head = &head[..n];
    if head.starts_with(b"SQLite format 3\0") {
        Some(format!("an SQLite3 (.db3) rosbag2 file: {CONVERT}"))
    } else if head.starts_with(&[0x28, 0xb5, 0x2f, 0xfd]) {
        Some("a zstd-compressed file (rosbag2 --compression-mode file): decompress it first (`zstd -d`), then read the .mcap".into())
    } else {
        None
    }
}

/// Per-topic figures of a bag, as `bag info` prints them.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct TopicInfo {
    pub topic: String,
    pub type_name: String,
    pub count: u64,
    pub first_ns: u64,
    pub last_ns: u64,
    /// Messages of this topic written after one (of any topic) with a later log time.
    pub out_of_log_time_order: u64,
}

impl TopicInfo {
    pub fn rate_hz(&self) -> f64 {
        if self.count > 1 && self.last_ns > self.first_ns {
            (self.count - 1) as f64 / ((self.last_ns - self.first_ns) as f64 * 1e-9)
        } else {
            0.0
        }
    }
}

/// Scan a bag once and count its topics. Reports what was read before an error too.
pub fn bag_info(path: impl AsRef<Path>) -> (Vec<TopicInfo>, Option<BagError>) {
    let mut topics: BTreeMap<Arc<str>, TopicInfo> = BTreeMap::new();
    let reader = match BagReader::open(path) {
        Ok(r) => r,
        Err(e) => return (Vec::new(), Some(e)),
    };
    let mut latest = 0u64;
    for m in reader {
        match m {
            Ok(m) => {
                let e = topics.entry(m.topic.clone()).or_insert_with(|| TopicInfo {
                    topic: m.topic.to_string(),
                    type_name: m.type_name.to_string(),
                    first_ns: m.log_time_ns,
                    last_ns: m.log_time_ns,
                    ..Default::default()
                });
                e.count += 1;
                e.first_ns = e.first_ns.min(m.log_time_ns);
                e.last_ns = e.last_ns.max(m.log_time_ns);
                e.out_of_log_time_order += u64::from(m.log_time_ns < latest);
                latest = latest.max(m.log_time_ns);
            }
            Err(e) => return (topics.into_values().collect(), Some(e)),
        }
    }
    (topics.into_values().collect(), None)
}

/// The messages of a bag in log-time order (the order a subscriber would have received them),
/// given its [`bag_info`]: streamed when the file is in that order already, read whole and
/// sorted when a recorder wrote it otherwise (MCAP allows it). An error ends the iteration
/// after the messages read before it.
pub fn messages_in_log_time_order(
    path: &Path,
    topics: &[TopicInfo],
) -> Result<Box<dyn Iterator<Item = Result<BagMessage, BagError>>>, BagError> {
    if topics.iter().all(|t| t.out_of_log_time_order == 0) {
        return Ok(Box::new(BagReader::open(path)?));
    }
    tracing::warn!("{}: written out of log-time order; read whole and taken in log-time order", path.display());
    let mut all = Vec::new();
    let mut error = None;
    for m in BagReader::open(path)? {
        match m {
            Ok(m) => all.push(m),
            Err(e) => {
                error = Some(e);
                break;
            }
        }
    }
    // Stable: messages with one log time keep their file order.
    all.sort_by_key(|m| m.log_time_ns);
    Ok(Box::new(all.into_iter().map(Ok).chain(error.map(Err))))
}

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
    /// Poses of a frozen ground truth ([`Recording::drop_frozen_ground_truth`]).
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
    let mut present: BTreeMap<Arc<str>, Arc<str>> = BTreeMap::new();
    // Decoded with their log times first: MCAP does not require a file to be in log-time order
    // (a recorder's threads interleave), and readers order it by log time, as `ros2 bag play`
    // does. In file order such a bag lost its late-written samples as "backwards stamps".
    let mut imu: Vec<(u64, (ImuSample, usize))> = Vec::new();
    // Each IMU message's frame_id, as an index into `frames`: two sensors on one topic show as
    // alternating frame_ids.
    let mut frames: Vec<String> = Vec::new();
    let mut poses: Vec<(u64, Option<PoseSample>)> = Vec::new();
    let mut temperature: Vec<(u64, TemperatureSample)> = Vec::new();
    for (index, m) in BagReader::open(path)?.enumerate() {
        let m = m?;
        let index = index as u64 + 1;
        if !present.contains_key(&m.topic) {
            present.insert(m.topic.clone(), m.type_name.clone());
        }
        let decode_err =
            |source| BagError::Decode { path: path.to_path_buf(), topic: m.topic.to_string(), index, log_time_ns: m.log_time_ns, source };
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
            let frame = match frames.iter().position(|f| *f == msg.header.frame_id) {
                Some(k) => k,
                None => {
                    frames.push(msg.header.frame_id.clone());
                    frames.len() - 1
                }
            };
            imu.push((m.log_time_ns, (msg.sample(), frame)));
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
            poses.push((m.log_time_ns, pose));
        } else if topics.temperature.as_deref() == Some(&*m.topic) {
            if *m.type_name != *Temperature::TYPE_NAME {
                return Err(wrong_type(Temperature::TYPE_NAME));
            }
            temperature.push((m.log_time_ns, Temperature::decode(&m.data).map_err(decode_err)?.sample()));
        }
    }
    report.out_of_log_time_order = in_log_time_order(&mut imu, |s| Some(s.0.stamp_ns))
        + in_log_time_order(&mut poses, |p| p.as_ref().map(|p| p.stamp_ns))
        + in_log_time_order(&mut temperature, |t| Some(t.stamp_ns));
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
        push_imu(&mut rec.imu, s, &mut report);
    }
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
    report.ground_truth_frozen = rec.drop_frozen_ground_truth() as u64;
    report.temperature_read = temperature.len() as u64;
    for (_, t) in temperature {
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
        let present = present.iter().map(|(t, ty)| format!("{t} [{ty}]")).collect::<Vec<_>>().join(", ");
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

/// What a node published on one `sensor_msgs/Imu` topic (`/imu/denoised`): its attitudes.
#[derive(Debug, Clone, Default)]
pub struct PublishedAttitudes {
    /// Messages on the topic, with or without an orientation.
    pub messages: u64,
    /// Header stamp of the topic's first message in log-time order: the node's first output.
    pub first_stamp_ns: Option<i64>,
    /// The messages that carry an orientation (REP 145: covariance[0] ≠ −1), in stamp order.
    pub attitudes: Vec<PublishedAttitude>,
    /// Orientations left out: a quaternion or covariance not finite, a zero quaternion, a
    /// stamp at or before the previous one.
    pub skipped: u64,
}

/// The attitudes published on `topic` (see [`PublishedAttitudes`]), in log-time order as
/// [`read_recording`] reads a bag.
pub fn read_published_attitudes(path: impl AsRef<Path>, topic: &str) -> Result<PublishedAttitudes, BagError> {
    let path = path.as_ref();
    let mut present: BTreeMap<Arc<str>, Arc<str>> = BTreeMap::new();
    /// One message's orientation: none (REP 145: covariance[0] = −1), one that cannot be used,
    /// or an attitude.
    enum Orientation {
        Absent,
        Unusable,
        Usable(PublishedAttitude),
    }
    let mut read: Vec<(u64, (i64, Orientation))> = Vec::new();
    for (index, m) in BagReader::open(path)?.enumerate() {
        let m = m?;
        present.entry(m.topic.clone()).or_insert_with(|| m.type_name.clone());
        if *m.topic != *topic {
            continue;
        }
        if *m.type_name != *Imu::TYPE_NAME {
            return Err(BagError::WrongType {
                path: path.to_path_buf(),
                topic: topic.into(),
                found: m.type_name.to_string(),
                expected: Imu::TYPE_NAME.into(),
            });
        }
        let msg = Imu::decode(&m.data).map_err(|source| BagError::Decode {
            path: path.to_path_buf(),
            topic: topic.into(),
            index: index as u64 + 1,
            log_time_ns: m.log_time_ns,
            source,
        })?;
        let stamp_ns = msg.header.stamp.to_ns();
        let covariance = nalgebra::Matrix3::from_row_slice(&msg.orientation_covariance.0);
        let attitude = match msg.orientation.to_unit().filter(|_| covariance.iter().all(|v| v.is_finite())) {
            _ if !msg.has_orientation() => Orientation::Absent,
            None => Orientation::Unusable,
            Some(world_from_body) => Orientation::Usable(PublishedAttitude { stamp_ns, world_from_body, covariance }),
        };
        read.push((m.log_time_ns, (stamp_ns, attitude)));
    }
    if read.is_empty() {
        let present = present.iter().map(|(t, ty)| format!("{t} [{ty}]")).collect::<Vec<_>>().join(", ");
        return Err(BagError::MissingTopic { path: path.to_path_buf(), topic: topic.into(), present });
    }
    in_log_time_order(&mut read, |(stamp, _)| Some(*stamp));
    let mut out = PublishedAttitudes { messages: read.len() as u64, first_stamp_ns: Some(read[0].1 .0), ..Default::default() };
    for (_, (_, attitude)) in read {
        match attitude {
            Orientation::Absent => {}
            Orientation::Unusable => out.skipped += 1,
            Orientation::Usable(a) if out.attitudes.last().is_some_and(|l| a.stamp_ns <= l.stamp_ns) => out.skipped += 1,
            Orientation::Usable(a) => out.attitudes.push(a),
        }
    }
    Ok(out)
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
const UNSET_STAMP_BESIDE_NS: i64 = 3_600_000_000_000;

/// Orders one topic's messages by log time (a stable sort: equal log times keep the file's
/// order); returns how many came before an earlier-written one's log time. Where the header
/// stamps (`stamp`) are in order as written and log-time order would put more of them out of
/// order (a recorder that swapped two receive times), the file's order is kept: the stamps are
/// what is integrated, and a sample out of their order is dropped as a backwards stamp.
fn in_log_time_order<T>(messages: &mut [(u64, T)], stamp: impl Fn(&T) -> Option<i64>) -> u64 {
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

/// Write a recording as a bag: `/imu/data`, `/ground_truth/pose` and, when present,
/// `/imu/temperature`, interleaved in stamp order (log time = header stamp).
pub fn write_recording(path: impl AsRef<Path>, rec: &Recording) -> Result<(), BagError> {
    let mut w = BagWriter::create(path)?;
    let imu_ch = w.channel::<Imu>(IMU_TOPIC)?;
    let gt_ch = if rec.ground_truth.is_empty() { None } else { Some(w.channel::<PoseStamped>(GROUND_TRUTH_TOPIC)?) };
    let temp_ch = if rec.temperature.is_empty() { None } else { Some(w.channel::<Temperature>(TEMPERATURE_TOPIC)?) };
    let (mut i, mut g, mut t) = (0, 0, 0);
    let mut imu_msg = Imu::from_sample(
        &rec.imu.first().copied().unwrap_or(ImuSample { stamp_ns: 0, gyro: Default::default(), accel: Default::default() }),
        IMU_FRAME,
    );
    loop {
        let ti = rec.imu.get(i).map(|s| s.stamp_ns).unwrap_or(i64::MAX);
        let tg = rec.ground_truth.get(g).map(|s| s.stamp_ns).unwrap_or(i64::MAX);
        let tt = rec.temperature.get(t).map(|s| s.stamp_ns).unwrap_or(i64::MAX);
        let next = ti.min(tg).min(tt);
        if next == i64::MAX {
            break;
        }
        if tg == next {
            if let Some(ch) = gt_ch {
                w.write(ch, tg, &PoseStamped::from_sample(&rec.ground_truth[g], WORLD_FRAME))?;
            }
            g += 1;
        } else if ti == next {
            let s = &rec.imu[i];
            imu_msg.header.stamp = crate::msg::Time::from_ns(s.stamp_ns);
            imu_msg.angular_velocity = s.gyro.into();
            imu_msg.linear_acceleration = s.accel.into();
            w.write(imu_ch, ti, &imu_msg)?;
            i += 1;
        } else {
            if let Some(ch) = temp_ch {
                let s = &rec.temperature[t];
                let msg = Temperature {
                    header: crate::msg::Header { stamp: crate::msg::Time::from_ns(s.stamp_ns), frame_id: IMU_FRAME.into() },
                    temperature: s.celsius,
                    variance: 0.0,
                };
                w.write(ch, tt, &msg)?;
            }
            t += 1;
        }
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    /// What `ros2 bag record` leaves that is not an MCAP file is named, with what to do.
    #[test]
    fn rosbag2_folders_sqlite_and_compressed_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let says = |p: &Path| match BagReader::open(p) {
            Err(e @ BagError::NotMcap { .. }) => e.to_string(),
            Err(e) => panic!("{}: {e}", p.display()),
            Ok(_) => panic!("{}: opened", p.display()),
        };
        let rosbag2 = dir.path().join("rec");
        std::fs::create_dir_all(&rosbag2).unwrap();
        std::fs::write(rosbag2.join("metadata.yaml"), "rosbag2_bagfile_information: {}\n").unwrap();
        std::fs::write(rosbag2.join("rec_0.mcap"), b"").unwrap();
        assert!(says(&rosbag2).contains("rec_0.mcap"), "{}", says(&rosbag2));
        std::fs::remove_file(rosbag2.join("rec_0.mcap")).unwrap();
        std::fs::write(rosbag2.join("rec_0.db3"), b"SQLite format 3\0").unwrap();
        assert!(says(&rosbag2).contains("ros2 bag convert"));
        assert!(says(&rosbag2.join("rec_0.db3")).contains("SQLite3"));
        let zst = dir.path().join("rec_0.mcap.zstd");
        std::fs::write(&zst, [0x28, 0xb5, 0x2f, 0xfd, 0, 0, 0, 0]).unwrap();
        assert!(says(&zst).contains("zstd -d"));
    }

    /// The attitudes a node published: messages without an orientation pass, unusable ones
    /// (a NaN covariance, a zero quaternion) and repeated stamps are counted as skipped.
    #[test]
    fn published_attitudes_are_read_in_stamp_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.mcap");
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>("/imu/denoised").unwrap();
        let sample = |k: i64| ImuSample { stamp_ns: 1_000_000_000 + k * 5_000_000, gyro: Vector3::zeros(), accel: Vector3::zeros() };
        let with = |k: i64, q: crate::msg::Quaternion, cov0: f64| {
            let mut m = Imu::from_sample(&sample(k), "imu_link");
            m.orientation = q;
            m.orientation_covariance.0 = [cov0, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1.0];
            m
        };
        let turned: crate::msg::Quaternion = UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0).into();
        let zero = crate::msg::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 0.0 };
        let msgs = [
            Imu::from_sample(&sample(0), "imu_link"),
            with(1, turned, 1e-4),
            with(2, turned, f64::NAN),
            with(3, zero, 1e-4),
            with(1, turned, 1e-4),
            with(4, turned, 2e-4),
        ];
        for (i, m) in msgs.iter().enumerate() {
            w.write(ch, 1_000 + i as i64, m).unwrap();
        }
        w.finish().unwrap();
        let p = read_published_attitudes(&path, "/imu/denoised").unwrap();
        assert_eq!((p.messages, p.attitudes.len(), p.skipped), (6, 2, 3));
        assert_eq!(p.first_stamp_ns, Some(sample(0).stamp_ns));
        assert_eq!(p.attitudes[1].stamp_ns, sample(4).stamp_ns);
        assert!((p.attitudes[1].covariance[(0, 0)] - 2e-4).abs() < 1e-18 && (p.attitudes[0].world_from_body.angle() - 0.1).abs() < 1e-12);
        assert!(matches!(read_published_attitudes(&path, "/imu/none"), Err(BagError::MissingTopic { .. })));
    }

    fn recording() -> Recording {
        let imu = (0..500)
            .map(|k| ImuSample {
                stamp_ns: 1_000_000_000 + k * 5_000_000,
                gyro: Vector3::new(0.01 * k as f64, -0.2, 0.3),
                accel: Vector3::new(0.0, 0.1, 9.81),
            })
            .collect();
        let ground_truth = (0..250)
            .map(|k| PoseSample {
                stamp_ns: 1_000_000_000 + k * 10_000_000,
                position_in_world: Vector3::new(k as f64, 0.0, 1.0),
                world_from_body: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001 * k as f64),
            })
            .collect();
        let temperature =
            (0..25).map(|k| TemperatureSample { stamp_ns: 1_000_000_000 + k * 100_000_000, celsius: 25.0 + k as f64 * 0.01 }).collect();
        Recording { name: "t".into(), imu, ground_truth, temperature }
    }

    #[test]
    fn recording_round_trips_through_a_bag() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let rec = recording();
        write_recording(&path, &rec).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!(report.skipped(), 0);
        assert_eq!(back.imu, rec.imu);
        assert_eq!(back.temperature, rec.temperature);
        assert_eq!(back.ground_truth.len(), rec.ground_truth.len());
        for (a, b) in back.ground_truth.iter().zip(&rec.ground_truth) {
            assert_eq!(a.stamp_ns, b.stamp_ns);
            assert!(a.world_from_body.angle_to(&b.world_from_body) < 1e-12);
        }
        let (info, err) = bag_info(&path);
        assert!(err.is_none());
        let imu = info.iter().find(|t| t.topic == IMU_TOPIC).unwrap();
        assert_eq!(imu.count, 500);
        assert!((imu.rate_hz() - 200.0).abs() < 1e-6);
    }

    /// A first sample stamped 0 before the driver's clock was set is left out and counted, not
    /// integrated as a gap of decades; a simulator's clock, which starts at 0, keeps it.
    #[test]
    fn an_unset_stamp_beside_clock_times_is_left_out() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let mut rec = recording();
        rec.imu.iter_mut().for_each(|s| s.stamp_ns += 1_700_000_000_000_000_000);
        rec.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 1_700_000_000_000_000_000);
        rec.temperature.clear();
        rec.imu[0].stamp_ns = 0;
        write_recording(&path, &rec).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.imu_unset_stamp, report.skipped(), back.imu.len()), (1, 1, 499));
        assert_eq!(back.imu[..], rec.imu[1..]);
        assert!(report.to_string().contains("1 unset (0) stamps"), "{report}");
        let mut sim = recording();
        sim.imu.iter_mut().for_each(|s| s.stamp_ns -= 1_000_000_000);
        write_recording(&path, &sim).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.skipped(), back.imu.len(), back.imu[0].stamp_ns), (0, 500, 0));
        // … however long it runs (here past an hour).
        sim.imu.last_mut().unwrap().stamp_ns = 2 * UNSET_STAMP_BESIDE_NS;
        write_recording(&path, &sim).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.skipped(), back.imu.len(), back.imu[0].stamp_ns), (0, 500, 0));
    }

    /// A bag is written beside its path and renamed when finished: an unfinished writer leaves
    /// the earlier bag as it was and its own readable `.partial`, which a later writer of this
    /// process replaces without touching the file another reader may hold.
    #[test]
    fn a_bag_appears_whole_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.mcap");
        write_recording(&path, &recording()).unwrap();
        let earlier = std::fs::read(&path).unwrap();
        {
            let mut w = BagWriter::create(&path).unwrap();
            let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
            w.write(ch, 1, &Imu::from_sample(&recording().imu[0], IMU_FRAME)).unwrap();
        }
        assert!(std::fs::read(&path).unwrap() == earlier);
        let partial = partial_path(&path, std::process::id());
        let held = File::open(&partial).unwrap();
        assert_eq!(BagReader::open(&partial).unwrap().count(), 1);
        let rec = Recording { imu: recording().imu[..10].to_vec(), ..Default::default() };
        write_recording(&path, &rec).unwrap();
        assert!(!partial.exists());
        assert_eq!(read_recording(&path, &RecordingTopics::default()).unwrap().0.imu.len(), 10);
        assert!(held.metadata().unwrap().len() > 0, "the old .partial was unlinked, not truncated");
        assert!(matches!(BagWriter::create(dir.path()), Err(BagError::NotMcap { .. })));
    }

    /// Messages written out of log-time order (allowed by MCAP) are read in log-time order,
    /// not dropped as backwards stamps.
    #[test]
    fn a_bag_out_of_log_time_order_is_read_in_log_time_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shuffled.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        let mut order: Vec<usize> = (0..rec.imu.len()).collect();
        for pair in order.chunks_mut(7) {
            pair.reverse();
        }
        for k in order {
            let s = &rec.imu[k];
            w.write(ch, s.stamp_ns, &Imu::from_sample(s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) =
            read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        assert_eq!(back.imu, rec.imu);
        assert_eq!(report.skipped(), 0);
        assert!(report.out_of_log_time_order > 400, "{}", report.out_of_log_time_order);
        // What replay and play publish: every message, in log-time order.
        let (topics, damage) = bag_info(&path);
        assert!(damage.is_none() && topics[0].out_of_log_time_order > 400);
        let times: Vec<u64> = messages_in_log_time_order(&path, &topics).unwrap().map(|m| m.unwrap().log_time_ns).collect();
        assert_eq!(times.len(), rec.imu.len());
        assert!(times.windows(2).all(|w| w[0] <= w[1]), "not in log-time order");
    }

    /// Two messages whose receive (log) times a recorder swapped, their header stamps in order
    /// as written: kept in the file's order, not one dropped as a backwards stamp.
    #[test]
    fn swapped_log_times_with_ordered_stamps_lose_no_sample() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("swapped.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let log = match k {
                100 => rec.imu[101].stamp_ns,
                101 => rec.imu[100].stamp_ns,
                _ => s.stamp_ns,
            };
            w.write(ch, log, &Imu::from_sample(s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) =
            read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        assert_eq!((report.skipped(), report.out_of_log_time_order), (0, 1), "{report}");
        assert_eq!(back.imu, rec.imu);
    }

    /// A driver restart steps the IMU's clock back: said as such, not as stamps taken on
    /// arrival or left at zero.
    #[test]
    fn a_clock_stepping_back_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("restart.mcap");
        let rec = recording();
        let n = rec.imu.len();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            s.stamp_ns += 100_000_000_000;
            if k >= n / 4 {
                s.stamp_ns -= 30_000_000_000;
            }
            // Received in order: the recorder's clock did not step.
            w.write(ch, 1_000_000_000 + k as i64 * 5_000_000, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (_, report) = read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        let why = report.stamp_problem_above(0.1).unwrap();
        assert!(why.contains("the IMU's clock steps back by 29.995 s at 0.620 s") && why.contains("a driver restart?"), "{why}");
    }

    #[test]
    fn bad_samples_are_skipped_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.mcap");
        let mut rec = recording();
        rec.imu[10].gyro.x = f64::NAN;
        rec.imu[20].stamp_ns = rec.imu[19].stamp_ns; // duplicate
        rec.imu[30].accel.z = f64::INFINITY;
        // The writer interleaves by stamp, so write the raw stream by hand to keep a backwards
        // header stamp (received in order: its log time is in order).
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            let received = s.stamp_ns;
            if k == 40 {
                s.stamp_ns -= 1_000_000_000;
            }
            w.write(ch, received, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!(report.imu_non_finite, 2);
        assert_eq!(report.imu_duplicate_stamp, 1);
        assert_eq!(report.imu_backwards_stamp, 1);
        assert_eq!(back.imu.len(), 496);
        assert!(back.imu.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
    }

    #[test]
    fn jittered_stamps_are_put_back_in_order_and_a_clock_step_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jitter.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            let received = s.stamp_ns;
            // Stamped 7 ms late, so the next one (5 ms on) is 2 ms before it; sample 300
            // repeats sample 298's stamp; sample 400 is stamped 30 ms back (past the limit).
            match k {
                k if k % 50 == 7 => s.stamp_ns += 7_000_000,
                300 => s.stamp_ns -= 10_000_000,
                400 => s.stamp_ns -= 30_000_000,
                // A clock stepped back 32.5 ms: the 6 samples until it passes the last kept
                // stamp are dropped, none put among the older ones.
                k if k >= 460 => s.stamp_ns -= 32_500_000,
                _ => {}
            }
            w.write(ch, received, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.imu_reordered, report.imu_duplicate_stamp, report.imu_backwards_stamp), (10, 1, 7), "{report}");
        assert_eq!(back.imu.len(), 492);
        assert!(back.imu.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
        // The late-stamped sample sits after the one received behind it, with its own rates.
        let late = back.imu.iter().position(|s| s.stamp_ns == rec.imu[7].stamp_ns + 7_000_000).unwrap();
        assert_eq!((back.imu[late - 1].stamp_ns, back.imu[late].gyro), (rec.imu[8].stamp_ns, rec.imu[7].gyro));
        let note = report.imu_stream_note().unwrap();
        assert!(note.contains("10 IMU samples stamped up to 20 ms before") && note.contains("put back in stamp order"), "{note}");
    }

    #[test]
    fn a_second_sensor_on_the_imu_topic_is_left_out_and_said() {
        let dir = tempfile::tempdir().unwrap();
        let rec = recording();
        let write = |name: &str, frame_of: &dyn Fn(usize) -> &'static str| {
            let path = dir.path().join(name);
            let mut w = BagWriter::create(&path).unwrap();
            let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
            for (k, s) in rec.imu.iter().enumerate() {
                let mut s = *s;
                if frame_of(k) == "imu2_link" {
                    // The other sensor: its own axes and a clock 1 ms behind.
                    s.gyro = -s.gyro;
                    s.stamp_ns -= 1_000_000;
                }
                w.write(ch, s.stamp_ns, &Imu::from_sample(&s, frame_of(k))).unwrap();
            }
            w.finish().unwrap();
            read_recording(&path, &RecordingTopics::default()).unwrap()
        };
        let (back, report) = write("two.mcap", &|k| if k % 2 == 1 { "imu2_link" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.imu_reordered), (250, 250, 0), "{report}");
        assert!(back.imu.iter().all(|s| s.gyro.y == -0.2));
        assert_eq!(report.interleaved_frames, Some((IMU_FRAME.to_string(), "imu2_link".to_string())));
        assert!(report.imu_stream_note().unwrap().contains("interleaves two sensors"));
        assert!(report.to_string().contains("250 of another sensor (frame_id \"imu2_link\")"), "{report}");
        // One rename mid-recording is one sensor: every sample is read.
        let (back, report) = write("renamed.mcap", &|k| if k >= 250 { "imu2_link" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
        // One driver alternating two frame_ids on one continuous signal: all read.
        let (back, report) = write("alternate.mcap", &|k| if k % 2 == 1 { "" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
        // Glitched frame_ids on one sensor, the first message among them: all read.
        let (back, report) = write("glitch.mcap", &|k| if k % 40 == 0 { "imu_glitch" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
    }

    #[test]
    fn truncated_bag_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        write_recording(&path, &recording()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.path().join("cut.mcap");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let err = read_recording(&cut, &RecordingTopics::default()).unwrap_err();
        assert!(err.to_string().contains("cut.mcap"), "{err}");
        let (_, err) = bag_info(&cut);
        assert!(err.is_some());
        let garbage = dir.path().join("garbage.mcap");
        std::fs::write(&garbage, b"not an mcap file at all").unwrap();
        assert!(read_recording(&garbage, &RecordingTopics::default()).is_err());
    }

    #[test]
    fn missing_topic_names_what_is_there() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        write_recording(&path, &recording()).unwrap();
        let topics = RecordingTopics { imu: "/imu/data_raw".into(), ..Default::default() };
        let err = read_recording(&path, &topics).unwrap_err().to_string();
        assert!(err.contains("/imu/data_raw") && err.contains("/imu/data [sensor_msgs/msg/Imu]"), "{err}");
    }
}
