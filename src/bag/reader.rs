//! Reading a bag: [`BagReader`] streams its messages, [`bag_info`] its topics, and
//! [`messages_in_log_time_order`] the order a subscriber would have received them in.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{io_err, BagError};

/// One message read from a bag: its topic, type, log time and CDR payload.
#[derive(Debug, Clone)]
pub struct BagMessage {
    pub topic: Arc<str>,
    pub type_name: Arc<str>,
    /// The channel's schema (encoding and definition), to copy messages into another bag.
    pub schema: Option<Arc<mcap::Schema<'static>>>,
    /// The channel's message encoding and metadata, to copy it whole ([`BagWriter::channel_of`](super::BagWriter::channel_of)).
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
