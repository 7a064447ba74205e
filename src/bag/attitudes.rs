//! The attitudes a node published on a `sensor_msgs/Imu` topic.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use crate::core::PublishedAttitude;
use crate::msg::{Imu, RosMessage};

use super::{in_log_time_order, BagError, BagReader};

/// What a node published on one `sensor_msgs/Imu` topic (`/imu/denoised`): its attitudes.
#[derive(Debug, Clone, Default)]
pub struct PublishedAttitudes {
    /// Messages on the topic, with or without an orientation.
    pub messages: u64,
    /// Header stamp of the topic's first message in log-time order: the node's first output.
    pub first_stamp_ns: Option<i64>,
    /// The messages that carry an orientation (REP 145: covariance\[0\] ≠ −1), in stamp order.
    pub attitudes: Vec<PublishedAttitude>,
    /// Orientations left out: a quaternion or covariance not finite, a zero quaternion, a
    /// stamp at or before the previous one.
    pub skipped: u64,
}

/// The attitudes published on `topic` (see [`PublishedAttitudes`]), in log-time order as
/// [`read_recording`](super::read_recording) reads a bag.
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
