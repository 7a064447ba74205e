//! Peers on the node's topics that cannot work with it: another message type under one of its
//! topic names, or a QoS its endpoint cannot serve (a transient-local reader of the volatile
//! `/imu/denoised`). RustDDS matches endpoints by topic name alone and leaves an incompatible
//! QoS unmatched without a word; so the node reads what discovery holds on each diagnostics
//! tick, logs each such peer once and names it on /diagnostics (`incompatible_peers`).

use std::collections::HashSet;

use ros2_client::dds::rustdds::discovery::{DiscoveredReaderData, DiscoveredWriterData};
use ros2_client::dds::rustdds::qos::QosPolicyId;
use ros2_client::dds::rustdds::{QosPolicies, GUID};
use ros2_client::{MessageTypeName, Name, NodeName, QosProfile};

/// The most peers kept by description: a graph full of them is said by its count.
const KEPT: usize = 8;

/// One of the node's own endpoints, as discovery names it.
#[derive(Debug, Clone)]
pub struct OwnEndpoint {
    /// The DDS topic name (`rt/imu/data_raw`).
    pub topic: String,
    /// The DDS type name (`sensor_msgs::msg::dds_::Imu_`).
    pub type_name: String,
    pub qos: QosPolicies,
    /// A writer (else a reader).
    pub writes: bool,
}

impl OwnEndpoint {
    /// The endpoint the node makes on `topic` (a ROS name, resolved in `node`'s namespace).
    pub fn new(topic: &Name, node: &NodeName, type_name: &MessageTypeName, qos: &QosProfile, writes: bool) -> Self {
        OwnEndpoint { topic: topic.to_dds_name("rt", node, ""), type_name: type_name.dds_msg_type(), qos: qos.clone().into(), writes }
    }
}

/// A remote endpoint, as discovery describes it.
#[derive(Debug, Clone)]
pub struct RemoteEndpoint {
    pub guid: GUID,
    pub topic: String,
    pub type_name: String,
    pub qos: QosPolicies,
    pub writes: bool,
}

impl RemoteEndpoint {
    pub fn writer(d: &DiscoveredWriterData) -> Self {
        let p = &d.publication_topic_data;
        RemoteEndpoint {
            guid: d.writer_proxy.remote_writer_guid,
            topic: p.topic_name.clone(),
            type_name: p.type_name.clone(),
            qos: p.qos(),
            writes: true,
        }
    }

    pub fn reader(d: &DiscoveredReaderData) -> Self {
        let s = &d.subscription_topic_data;
        RemoteEndpoint {
            guid: d.reader_proxy.remote_reader_guid,
            topic: s.topic_name().clone(),
            type_name: s.type_name().clone(),
            qos: s.qos(),
            writes: false,
        }
    }
}

/// Why `remote` cannot work with `own`, if it cannot: `None` for a peer on another topic, on
/// the same side, or one that matches.
pub fn mismatch(own: &OwnEndpoint, remote: &RemoteEndpoint) -> Option<String> {
    if own.topic != remote.topic || own.writes == remote.writes {
        return None;
    }
    let role = if remote.writes { "writer" } else { "reader" };
    let topic = ros_topic(&remote.topic);
    if remote.type_name != own.type_name {
        return Some(format!("a {role} on {topic} of type {}, not the node's {}", remote.type_name, own.type_name));
    }
    let (offered, requested) = if own.writes { (&own.qos, &remote.qos) } else { (&remote.qos, &own.qos) };
    let policy = offered.compliance_failure_wrt(requested)?;
    let side = if own.writes { "the node offers" } else { "the node requests" };
    Some(format!(
        "a {role} on {topic} whose {} QoS cannot match what {side}{}",
        policy_name(policy),
        policy_values(policy, &own.qos, &remote.qos)
    ))
}

/// The peers found so far, each said once, and those discovery still holds.
#[derive(Debug, Default)]
pub struct PeerCheck {
    own: Vec<OwnEndpoint>,
    said: HashSet<(GUID, String)>,
    /// The last scan's, described with their GUIDs; at most [`KEPT`].
    present: Vec<String>,
    present_count: usize,
    count: u64,
}

impl PeerCheck {
    pub fn new(own: Vec<OwnEndpoint>) -> Self {
        PeerCheck { own, ..Default::default() }
    }

    /// Checks what discovery holds now (`remotes`) against the node's endpoints; returns the
    /// peers not said before.
    pub fn scan(&mut self, remotes: impl IntoIterator<Item = RemoteEndpoint>) -> Vec<String> {
        let mut new = Vec::new();
        self.present.clear();
        self.present_count = 0;
        for remote in remotes {
            for own in &self.own {
                let Some(why) = mismatch(own, &remote) else { continue };
                let said = format!("{why} (GUID {})", hex(&remote.guid));
                self.present_count += 1;
                if self.present.len() < KEPT {
                    self.present.push(said.clone());
                }
                if self.said.insert((remote.guid, why)) {
                    self.count += 1;
                    new.push(said);
                }
            }
        }
        new
    }

    /// How many were found in all, present or gone.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// How many the last scan found, and the first [`KEPT`] of them described.
    pub fn present(&self) -> (usize, &[String]) {
        (self.present_count, &self.present)
    }
}

/// A GUID as 32 hex digits, as DDS tools print it.
fn hex(guid: &GUID) -> String {
    guid.to_bytes().iter().map(|b| format!("{b:02x}")).collect()
}

/// Writers followed by [`InputWriters`]; beyond them (a misconfigured graph) the oldest is
/// forgotten, and looked up in discovery again at its next sample.
const MAX_WRITERS: usize = 16;

/// The input's writers judged by the type discovery gives them. RustDDS matches a writer of
/// another type all the same (by topic name), and its samples would be read as the node's type
/// (garbage into the power-on bias and the model where the layouts agree): they are dropped.
#[derive(Debug)]
pub struct InputWriters {
    input: OwnEndpoint,
    /// Each writer seen, and why its samples are dropped (`None`: they are the node's type).
    known: Vec<(GUID, Option<String>)>,
}

impl InputWriters {
    pub fn new(input: OwnEndpoint) -> Self {
        InputWriters { input, known: Vec::new() }
    }

    /// Why `writer`'s samples are not the node's, if they are not; discovery (`writers`) is
    /// read once per writer, at its first sample. A writer discovery does not hold is taken as
    /// what its samples decoded as.
    pub fn refuses(&mut self, writer: GUID, writers: impl FnOnce() -> Vec<RemoteEndpoint>) -> Option<&str> {
        if let Some(i) = self.known.iter().position(|(w, _)| *w == writer) {
            return self.known[i].1.as_deref();
        }
        let why = writers()
            .into_iter()
            .find(|r| r.guid == writer && r.writes && r.type_name != self.input.type_name)
            .and_then(|r| mismatch(&self.input, &r));
        if self.known.len() >= MAX_WRITERS {
            self.known.remove(0);
        }
        self.known.push((writer, why));
        self.known.last().and_then(|(_, why)| why.as_deref())
    }
}

/// `rt/imu/data_raw` → `/imu/data_raw`: the name a ROS user knows.
fn ros_topic(dds: &str) -> String {
    dds.strip_prefix("rt").filter(|r| r.starts_with('/')).map_or_else(|| dds.to_string(), str::to_string)
}

fn policy_name(p: QosPolicyId) -> &'static str {
    match p {
        QosPolicyId::Durability => "durability",
        QosPolicyId::Reliability => "reliability",
        QosPolicyId::Deadline => "deadline",
        QosPolicyId::Liveliness => "liveliness",
        QosPolicyId::Ownership => "ownership",
        QosPolicyId::Presentation => "presentation",
        QosPolicyId::LatencyBudget => "latency budget",
        QosPolicyId::DestinationOrder => "destination order",
        QosPolicyId::Representation => "data representation",
        _ => "a",
    }
}

/// The two sides' values where the policy is one a ROS user sets (durability, reliability).
fn policy_values(p: QosPolicyId, own: &QosPolicies, remote: &QosPolicies) -> String {
    let durability = |q: &QosPolicies| if q.is_volatile() { "volatile" } else { "transient local or more" };
    let reliability = |q: &QosPolicies| if q.is_reliable() { "reliable" } else { "best effort" };
    match p {
        QosPolicyId::Durability => format!(" ({}; the peer: {})", durability(own), durability(remote)),
        QosPolicyId::Reliability => format!(" ({}; the peer: {})", reliability(own), reliability(remote)),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ros2_client::dds::rustdds::policy::{Durability, Reliability};
    use ros2_client::dds::rustdds::QosPolicyBuilder;

    const IMU: &str = "sensor_msgs::msg::dds_::Imu_";

    fn qos(reliable: bool, transient: bool) -> QosPolicies {
        let r = if reliable {
            Reliability::Reliable { max_blocking_time: ros2_client::dds::rustdds::Duration::ZERO }
        } else {
            Reliability::BestEffort
        };
        QosPolicyBuilder::new().reliability(r).durability(if transient { Durability::TransientLocal } else { Durability::Volatile }).build()
    }

    fn own(topic: &str, writes: bool, reliable: bool) -> OwnEndpoint {
        OwnEndpoint { topic: topic.into(), type_name: IMU.into(), qos: qos(reliable, false), writes }
    }

    fn remote(topic: &str, type_name: &str, writes: bool, q: QosPolicies) -> RemoteEndpoint {
        RemoteEndpoint { guid: GUID::from_bytes([7; 16]), topic: topic.into(), type_name: type_name.into(), qos: q, writes }
    }

    #[test]
    fn a_writer_of_another_type_on_the_input_is_named() {
        let why = mismatch(
            &own("rt/imu/data_raw", false, false),
            &remote("rt/imu/data_raw", "sensor_msgs::msg::dds_::Temperature_", true, qos(false, false)),
        );
        let why = why.expect("a type mismatch");
        assert!(why.contains("writer on /imu/data_raw of type sensor_msgs::msg::dds_::Temperature_"), "{why}");
    }

    #[test]
    fn a_transient_local_reader_of_a_volatile_output_is_named() {
        let why =
            mismatch(&own("rt/imu/denoised", true, true), &remote("rt/imu/denoised", IMU, false, qos(true, true))).expect("a QoS mismatch");
        assert!(why.contains("durability QoS") && why.contains("(volatile; the peer: transient local or more)"), "{why}");
    }

    #[test]
    fn a_reliable_reader_of_a_best_effort_writer_is_named() {
        let why = mismatch(&own("rt/imu/denoised", true, false), &remote("rt/imu/denoised", IMU, false, qos(true, false)))
            .expect("a QoS mismatch");
        assert!(why.contains("reliability QoS") && why.contains("(best effort; the peer: reliable)"), "{why}");
    }

    #[test]
    fn peers_that_match_or_sit_elsewhere_are_not_named() {
        let input = own("rt/imu/data_raw", false, false);
        // A best-effort reader takes a reliable writer's samples; the same side, another topic: nothing.
        assert_eq!(mismatch(&input, &remote("rt/imu/data_raw", IMU, true, qos(true, true))), None);
        assert_eq!(mismatch(&input, &remote("rt/imu/data_raw", "x::Y_", false, qos(false, false))), None);
        assert_eq!(mismatch(&input, &remote("rt/other", "x::Y_", true, qos(false, false))), None);
    }

    #[test]
    fn an_input_writer_of_another_type_is_refused_and_discovery_read_once_per_writer() {
        let mut writers = InputWriters::new(own("rt/imu/data_raw", false, false));
        let (good, bad) = (GUID::from_bytes([1; 16]), GUID::from_bytes([2; 16]));
        let discovered =
            |guid: GUID, type_name: &str| RemoteEndpoint { guid, ..remote("rt/imu/data_raw", type_name, true, qos(false, false)) };
        let lookups = std::cell::Cell::new(0);
        let graph = || {
            lookups.set(lookups.get() + 1);
            vec![discovered(good, IMU), discovered(bad, "my_msgs::msg::dds_::Imu_")]
        };
        assert_eq!(writers.refuses(good, graph), None);
        let why = writers.refuses(bad, graph).expect("refused").to_string();
        assert!(why.contains("of type my_msgs::msg::dds_::Imu_"), "{why}");
        for _ in 0..10 {
            assert_eq!(writers.refuses(good, graph), None);
            assert!(writers.refuses(bad, graph).is_some());
        }
        assert_eq!(lookups.get(), 2);
        // Unknown to discovery: taken as what it decoded as.
        assert_eq!(writers.refuses(GUID::from_bytes([3; 16]), Vec::new), None);
    }

    #[test]
    fn each_peer_is_said_once_and_the_list_is_bounded() {
        let mut check = PeerCheck::new(vec![own("rt/imu/data_raw", false, false)]);
        let bad = remote("rt/imu/data_raw", "x::Y_", true, qos(false, false));
        assert_eq!(check.scan([bad.clone()]).len(), 1);
        assert!(check.scan([bad.clone()]).is_empty());
        assert_eq!(check.present().0, 1);
        let many: Vec<_> = (0..20u8)
            .map(|i| {
                let mut r = bad.clone();
                r.guid = GUID::from_bytes([i + 8; 16]);
                r
            })
            .collect();
        assert_eq!(check.scan(many).len(), 20);
        assert_eq!(check.count(), 21);
        assert_eq!((check.present().0, check.present().1.len()), (20, KEPT));
        // Gone from discovery: no longer present, still counted.
        assert!(check.scan([]).is_empty());
        assert_eq!((check.present().0, check.count()), (0, 21));
    }
}
