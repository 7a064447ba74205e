//! `imu-fsda play IN.mcap`: publish a bag onto DDS at its recorded rate (or ×k), like
//! `ros2 bag play`, so the live node can be driven end to end.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use imu_fsda::msg::{DiagnosticArray, Imu, Odometry, PoseStamped, RosMessage, Temperature, Time, Vector3Stamped};
use imu_fsda::node::{ros_type_name, LatencyHistogram, RosEnvironment};
use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions, Publisher, QosProfile};

#[derive(Debug, clap::Args)]
pub struct PlayArgs {
    /// The bag to publish.
    pub input: PathBuf,
    /// Playback speed factor (2 = twice as fast). 0 = as fast as possible.
    #[arg(long, default_value_t = 1.0, value_parser = playback_rate)]
    pub rate: f64,
    /// Only these topics (repeatable; default: all known message types).
    #[arg(long = "topic")]
    pub topics: Vec<String>,
    /// Topic remapping `from:=to` (repeatable), e.g. /imu/data:=/imu/data_raw.
    #[arg(short = 'r', long = "remap")]
    pub remaps: Vec<String>,
    /// Also publish /clock (rosgraph_msgs/Clock) from the bag's log times, for use_sim_time.
    #[arg(long)]
    pub clock: bool,
    /// Before starting, wait up to this many seconds for a subscriber on every played topic.
    #[arg(long, default_value = "0", value_parser = super::seconds)]
    pub wait_for_subscribers_s: Duration,
    /// DDS history depth of the publishers (reliable).
    #[arg(long, default_value_t = 1000, value_parser = queue_depth)]
    pub queue_depth: usize,
    /// Measure end-to-end latency: subscribe to this sensor_msgs/Imu topic (e.g. the node's
    /// /imu/denoised) and time each output from the moment its input was published,
    /// matched by header stamp. Prints p50/p99 at the end.
    #[arg(long)]
    pub latency_topic: Option<String>,
    /// The SROS2 enclave whose security files the player uses when `ROS_SECURITY_ENABLE=true`
    /// (rcl's `--ros-args --enclave`; `ROS_SECURITY_ENCLAVE_OVERRIDE` wins; default `/`).
    #[arg(long)]
    pub enclave: Option<String>,
}

/// 0 (as fast as possible) or a finite factor of at least 1e-3: slower than that, the
/// recorded stamps would be due after longer than a clock can count.
fn playback_rate(s: &str) -> Result<f64, String> {
    let x = super::non_negative(s)?;
    if x == 0.0 || x >= 1e-3 {
        Ok(x)
    } else {
        Err(format!("{s} is neither 0 (as fast as possible) nor at least 0.001"))
    }
}

fn queue_depth(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(0) => Err("a history of 0 messages holds nothing: at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("{s:?}: {e}")),
    }
}

enum AnyPublisher {
    Imu(Publisher<Imu>),
    Pose(Publisher<PoseStamped>),
    Odom(Publisher<Odometry>),
    Temp(Publisher<Temperature>),
    Vec3(Publisher<Vector3Stamped>),
    Diag(Publisher<DiagnosticArray>),
}

/// rosgraph_msgs/msg/Clock.
#[derive(serde::Serialize, serde::Deserialize)]
struct Clock {
    clock: Time,
}
impl ros2_client::Message for Clock {}

impl AnyPublisher {
    async fn publish(&self, data: &[u8]) -> anyhow::Result<()> {
        macro_rules! go {
            ($p:expr, $t:ty) => {
                $p.async_publish(<$t>::decode(data)?).await.map_err(|e| anyhow::anyhow!("publish: {e:?}"))
            };
        }
        match self {
            AnyPublisher::Imu(p) => go!(p, Imu),
            AnyPublisher::Pose(p) => go!(p, PoseStamped),
            AnyPublisher::Odom(p) => go!(p, Odometry),
            AnyPublisher::Temp(p) => go!(p, Temperature),
            AnyPublisher::Vec3(p) => go!(p, Vector3Stamped),
            AnyPublisher::Diag(p) => go!(p, DiagnosticArray),
        }
    }
}

pub fn run(args: PlayArgs) -> anyhow::Result<()> {
    let env = RosEnvironment::from_env(args.enclave.as_deref())?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("tokio runtime")?;
    rt.block_on(play(args, env))
}

async fn play(args: PlayArgs, env: RosEnvironment) -> anyhow::Result<()> {
    let remap = remappings(&args.remaps)?;
    let context = env.context()?;
    let mut node = context
        .new_node(NodeName::new("/", "imu_fsda_player").map_err(|e| anyhow::anyhow!("{e:?}"))?, NodeOptions::new().enable_rosout(false))
        .map_err(|e| anyhow::anyhow!("node: {e:?}"))?;
    let qos = QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth: args.queue_depth });

    // One pass to find the topics and their types (streaming, cheap next to playback).
    let (topics, damage) = imu_fsda::bag::bag_info(&args.input);
    if topics.is_empty() {
        if let Some(e) = damage {
            return Err(e).context("reading the bag");
        }
    }
    if let Some(e) = &damage {
        // What a crashed recorder left is still a recording: play it, then report the damage.
        let n: u64 = topics.iter().map(|t| t.count).sum();
        tracing::warn!("{e}: playing what the {n} messages before it hold of the played topics, then exiting with this error");
    }
    if let Some(t) = args.topics.iter().find(|t| !topics.iter().any(|b| &b.topic == *t)) {
        let present: Vec<&str> = topics.iter().map(|b| b.topic.as_str()).collect();
        anyhow::bail!("--topic {t}: not in {} (its topics: {})", args.input.display(), present.join(", "));
    }
    let pubs = create_publishers(&mut node, &topics, &args.topics, &remap, &qos)?;
    anyhow::ensure!(!pubs.is_empty(), "{}: none of its topics has a type play publishes", args.input.display());
    let clock = if args.clock { Some(clock_publisher(&mut node)?) } else { None };
    let latency_sub = match &args.latency_topic {
        Some(t) => Some(latency_subscription(&mut node, t)?),
        None => None,
    };
    let spinner = node.spinner().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let spin = tokio::spawn(async move {
        let _ = spinner.spin().await;
    });
    if !args.wait_for_subscribers_s.is_zero() {
        wait_for_subscribers(&node, &pubs, args.wait_for_subscribers_s).await;
    }
    let probe = latency_sub.map(LatencyProbe::start);

    let played = Playback { args: &args, pubs: &pubs, clock: clock.as_ref(), probe: probe.as_ref() }.run(&topics).await?;
    // Let reliable writers flush (and late outputs arrive) before the participant goes away.
    tokio::time::sleep(Duration::from_millis(if probe.is_some() { 1500 } else { 500 })).await;
    node.stop_spinner();
    spin.abort();
    out!("played {} messages from {} in {:.2} s", played.sent, args.input.display(), played.elapsed_s)?;
    if let Some(e) = played.read_error {
        return Err(e).context(format!("the bag is damaged ({} messages played before it)", played.sent));
    }
    if let (Some(t), Some(probe)) = (&args.latency_topic, probe) {
        out!("latency publish → {t}: {}", probe.finish())?;
    }
    if super::interrupts::requested() {
        return Err(super::interrupts::Interrupted(format!("stopped after {} messages", played.sent)).into());
    }
    Ok(())
}

/// `from:=to` pairs.
fn remappings(remaps: &[String]) -> anyhow::Result<HashMap<String, String>> {
    remaps
        .iter()
        .map(|r| {
            r.split_once(":=")
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .ok_or_else(|| anyhow::anyhow!("remapping {r:?} is not from:=to"))
        })
        .collect()
}

fn clock_publisher(node: &mut ros2_client::Node) -> anyhow::Result<Publisher<Clock>> {
    let topic = node
        .create_topic(
            &Name::parse("/clock").map_err(|e| anyhow::anyhow!("{e:?}"))?,
            MessageTypeName::new("rosgraph_msgs", "Clock"),
            &QosProfile::publisher_default(),
        )
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    node.create_publisher::<Clock>(&topic, None).map_err(|e| anyhow::anyhow!("{e:?}"))
}

/// The reliable subscription end-to-end latency is measured on (the node's `/imu/denoised`).
fn latency_subscription(node: &mut ros2_client::Node, topic: &str) -> anyhow::Result<ros2_client::Subscription<Imu>> {
    let name = Name::parse(topic).map_err(|e| anyhow::anyhow!("topic {topic}: {e:?}"))?;
    let reliable = QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth: 1000 });
    let t = node.create_topic(&name, ros_type_name(Imu::TYPE_NAME), &reliable).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    node.create_subscription::<Imu>(&t, Some(reliable)).map_err(|e| anyhow::anyhow!("{e:?}"))
}

/// End-to-end latency: each published `sensor_msgs/Imu`'s stamp and time, matched by stamp to
/// the output read back on the subscription.
struct LatencyProbe {
    sent_at: Arc<Mutex<HashMap<i64, Instant>>>,
    latency: Arc<Mutex<(LatencyHistogram, u64)>>,
    task: tokio::task::JoinHandle<()>,
}

impl LatencyProbe {
    /// Reads the outputs from now on.
    fn start(sub: ros2_client::Subscription<Imu>) -> Self {
        let sent_at: Arc<Mutex<HashMap<i64, Instant>>> = Arc::default();
        let latency: Arc<Mutex<(LatencyHistogram, u64)>> = Arc::default();
        let (sent, measured) = (sent_at.clone(), latency.clone());
        let task = tokio::spawn(async move {
            let stream = sub.async_stream();
            futures::pin_mut!(stream);
            while let Some(item) = futures::StreamExt::next(&mut stream).await {
                let Ok((msg, _)) = item else { continue };
                let now = Instant::now();
                if let Some(t) = sent.lock().expect("lock").remove(&msg.header.stamp.to_ns()) {
                    let mut l = measured.lock().expect("lock");
                    l.0.record(now.duration_since(t));
                    l.1 += 1;
                }
            }
        });
        LatencyProbe { sent_at, latency, task }
    }

    /// An `Imu` about to be published.
    fn sent(&self, data: &[u8]) {
        if let Ok(msg) = Imu::decode(data) {
            self.sent_at.lock().expect("lock").insert(msg.header.stamp.to_ns(), Instant::now());
        }
    }

    fn finish(self) -> String {
        self.task.abort();
        let l = self.latency.lock().expect("lock");
        let missing = self.sent_at.lock().expect("lock").len();
        format!(
            "{} outputs matched, {missing} inputs without output; p50 {:.0} µs, p99 {:.0} µs",
            l.1,
            l.0.quantile_us(0.5),
            l.0.quantile_us(0.99)
        )
    }
}

/// The bag's messages published in log-time order on the recorded schedule (× `rate`).
struct Playback<'a> {
    args: &'a PlayArgs,
    pubs: &'a HashMap<String, AnyPublisher>,
    clock: Option<&'a Publisher<Clock>>,
    probe: Option<&'a LatencyProbe>,
}

/// What a playback did: messages sent, its wall time, and a read error that ended it.
struct Played {
    sent: u64,
    elapsed_s: f64,
    read_error: Option<imu_fsda::bag::BagError>,
}

impl Playback<'_> {
    async fn run(&self, topics: &[imu_fsda::bag::TopicInfo]) -> anyhow::Result<Played> {
        let start = Instant::now();
        let mut first_log: Option<u64> = None;
        let mut played = Played { sent: 0, elapsed_s: 0.0, read_error: None };
        // Ctrl-C / SIGTERM stops at the next message (or within 0.1 s of a wait) and still says
        // what was played and measured.
        super::interrupts::catch();
        // In log-time order, as it was received when recorded (and as the schedule assumes).
        for m in imu_fsda::bag::messages_in_log_time_order(&self.args.input, topics)? {
            if super::interrupts::requested() {
                break;
            }
            let m = match m {
                Ok(m) => m,
                Err(e) => {
                    played.read_error = Some(e);
                    break;
                }
            };
            let Some(p) = self.pubs.get(&*m.topic) else { continue };
            let t0 = *first_log.get_or_insert(m.log_time_ns);
            if !self.wait_until_due(start, m.log_time_ns.saturating_sub(t0)).await {
                break;
            }
            if let Some(c) = self.clock {
                let _ = c.async_publish(Clock { clock: Time::from_ns(m.log_time_ns as i64) }).await;
            }
            if let (Some(probe), AnyPublisher::Imu(_)) = (self.probe, p) {
                probe.sent(&m.data);
            }
            p.publish(&m.data).await.with_context(|| format!("{} message at {} ns", m.topic, m.log_time_ns))?;
            played.sent += 1;
        }
        played.elapsed_s = start.elapsed().as_secs_f64();
        Ok(played)
    }

    /// Sleeps until `since_first_ns` of bag time (÷ rate) has passed since `start`; false when
    /// interrupted.
    async fn wait_until_due(&self, start: Instant, since_first_ns: u64) -> bool {
        if self.args.rate > 0.0 {
            let due = Duration::from_secs_f64(since_first_ns as f64 * 1e-9 / self.args.rate);
            while let Some(wait) = due.checked_sub(start.elapsed()).filter(|w| !w.is_zero()) {
                if super::interrupts::requested() {
                    return false;
                }
                tokio::time::sleep(wait.min(Duration::from_millis(100))).await;
            }
        }
        !super::interrupts::requested()
    }
}

/// A publisher per played topic (`asked`, or every topic of a type play publishes), on its
/// remapped name; a topic asked for by name whose type play does not publish is an error.
fn create_publishers(
    node: &mut ros2_client::Node,
    topics: &[imu_fsda::bag::TopicInfo],
    asked: &[String],
    remap: &HashMap<String, String>,
    qos: &QosProfile,
) -> anyhow::Result<HashMap<String, AnyPublisher>> {
    let mut pubs: HashMap<String, AnyPublisher> = HashMap::new();
    for t in topics {
        if !asked.is_empty() && !asked.contains(&t.topic) {
            continue;
        }
        let out = remap.get(&t.topic).cloned().unwrap_or_else(|| t.topic.clone());
        let name = Name::parse(&out).map_err(|e| anyhow::anyhow!("topic {out}: {e:?}"))?;
        let topic = node.create_topic(&name, ros_type_name(&t.type_name), qos).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        macro_rules! mk {
            ($v:ident, $t:ty) => {
                AnyPublisher::$v(node.create_publisher::<$t>(&topic, Some(qos.clone())).map_err(|e| anyhow::anyhow!("{e:?}"))?)
            };
        }
        let p = match t.type_name.as_str() {
            x if x == Imu::TYPE_NAME => mk!(Imu, Imu),
            x if x == PoseStamped::TYPE_NAME => mk!(Pose, PoseStamped),
            x if x == Odometry::TYPE_NAME => mk!(Odom, Odometry),
            x if x == Temperature::TYPE_NAME => mk!(Temp, Temperature),
            x if x == Vector3Stamped::TYPE_NAME => mk!(Vec3, Vector3Stamped),
            x if x == DiagnosticArray::TYPE_NAME => mk!(Diag, DiagnosticArray),
            other => {
                // Asked for by name, it is an error; among all of a bag's topics, a note.
                if asked.contains(&t.topic) {
                    anyhow::bail!(
                        "--topic {}: its type {other} is not one play publishes (sensor_msgs Imu and Temperature, geometry_msgs PoseStamped and Vector3Stamped, nav_msgs Odometry, diagnostic_msgs DiagnosticArray)",
                        t.topic
                    );
                }
                tracing::warn!("{}: type {other} is not played", t.topic);
                continue;
            }
        };
        pubs.insert(t.topic.clone(), p);
    }
    Ok(pubs)
}

/// Waits up to `patience` for a subscriber on each topic (playing anyway after it, said), then a
/// moment for discovery on the other side to finish.
async fn wait_for_subscribers(node: &ros2_client::Node, pubs: &HashMap<String, AnyPublisher>, patience: Duration) {
    let deadline = Instant::now() + patience;
    for (topic, p) in pubs {
        let wait = async {
            match p {
                AnyPublisher::Imu(p) => p.wait_for_subscription(node).await,
                AnyPublisher::Pose(p) => p.wait_for_subscription(node).await,
                AnyPublisher::Odom(p) => p.wait_for_subscription(node).await,
                AnyPublisher::Temp(p) => p.wait_for_subscription(node).await,
                AnyPublisher::Vec3(p) => p.wait_for_subscription(node).await,
                AnyPublisher::Diag(p) => p.wait_for_subscription(node).await,
            }
        };
        if tokio::time::timeout(deadline.saturating_duration_since(Instant::now()), wait).await.is_err() {
            tracing::warn!("no subscriber on {topic} after {patience:?}; playing anyway");
        }
    }
    // Matching is not the end of discovery on the other side: give it a moment.
    tokio::time::sleep(Duration::from_millis(300)).await;
}
