//! The ROS 2 node: ros2-client + tokio around [`Pipeline`]. Subscribes to raw IMU
//! (sensor-data QoS), publishes `/imu/denoised` (sensor_msgs/Imu: corrected angular velocity,
//! integrated orientation, accel passed through, header unchanged), `/imu/gyro_correction`
//! (geometry_msgs/Vector3Stamped) and `/diagnostics` (diagnostic_msgs/DiagnosticArray).
//! Nothing below this module knows about DDS.

mod power_on;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::{Context, MessageTypeName, Name, NodeName, NodeOptions, ParameterValue, QosProfile};
use serde::{Deserialize, Serialize};

use crate::adapt::swap::{warm_up, Buffers, SeqSample, SwapHandle};
use crate::infer::{CorrectedImu, Counters, GyroCorrector, ModelCorrector, Pipeline, PipelineConfig};
use crate::msg::{DiagnosticArray, DiagnosticStatus, Header, Imu, KeyValue, RosMessage, Time, Vector3Stamped};

impl ros2_client::Message for Imu {}
impl ros2_client::Message for Vector3Stamped {}
impl ros2_client::Message for DiagnosticArray {}
impl ros2_client::Message for crate::msg::PoseStamped {}
impl ros2_client::Message for crate::msg::Odometry {}
impl ros2_client::Message for crate::msg::Temperature {}
impl ros2_client::Message for TriggerRequest {}
impl ros2_client::Message for TriggerResponse {}

/// std_srvs/srv/Trigger's request (ROS 2 gives an empty struct this one member in CDR).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct TriggerRequest {
    pub structure_needs_at_least_one_member: u8,
}

/// std_srvs/srv/Trigger's response.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct TriggerResponse {
    pub success: bool,
    pub message: String,
}

#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error("{path}: {source}")]
    Params {
        path: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{path}: no `{node}: ros__parameters:` section (sections: {found})")]
    NoSection { path: String, node: String, found: String },
    #[error("invalid topic name {name:?}: {why}")]
    TopicName { name: String, why: String },
    #[error("invalid {what} {value:?}: {why}")]
    Invalid { what: &'static str, value: String, why: String },
    #[error("DDS: {0}")]
    Dds(String),
    #[error("invalid environment: {0}")]
    Environment(String),
}

/// The node's parameters, as in `params/imu_fsda.yaml` (`imu_fsda: ros__parameters: …`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NodeParams {
    /// Raw IMU input (sensor_msgs/Imu), sensor-data QoS: best effort, keep last `queue_depth`.
    pub input_topic: String,
    /// Corrected output (sensor_msgs/Imu), reliable, keep last `queue_depth`.
    pub output_topic: String,
    /// The estimated gyro correction ω̂ − ω (geometry_msgs/Vector3Stamped).
    pub correction_topic: String,
    /// diagnostic_msgs/DiagnosticArray, once per `diagnostics_period`.
    pub diagnostics_topic: String,
    /// TorchScript model exported by `imu-fsda train` (`.pt`, with its `.json` and `.ot`
    /// beside it); empty: no model, the gyro passes through (a loud warning).
    pub model: String,
    /// Which IMU this is, for a model that knows IMUs by name (one Ĉ_ω per IMU,
    /// `imu_gyro_calibrations`, or a correction gain per IMU, `imu_correction_gains`, in its
    /// `.json`, e.g. `euroc`, `tumvi`): that IMU's Ĉ_ω and gain. Empty: the model's own Ĉ_ω
    /// and all of its correction (a new IMU; an adapted model). An unknown name stops the node
    /// at start-up.
    pub imu_calibration: String,
    /// DDS history depth of the input and output topics.
    pub queue_depth: usize,
    /// Seconds between /diagnostics messages.
    pub diagnostics_period: f64,
    /// Take time from /clock (replays); ROS's standard parameter.
    pub use_sim_time: bool,
    /// The per-sample pipeline: gaps, rate checks, covariances, initial attitude.
    pub pipeline: PipelineConfig,
    /// Ground truth for on-demand adaptation (`~/adapt`, std_srvs/srv/Trigger), buffered with
    /// the input; its type is `ground_truth_type` (geometry_msgs/msg/PoseStamped or
    /// nav_msgs/msg/Odometry). Empty: no adaptation service.
    pub ground_truth_topic: String,
    pub ground_truth_type: String,
    /// Newest seconds of input and ground truth kept for adaptation (bounded ring buffers).
    pub adapt_buffer_seconds: f64,
    /// Of the buffered data, the first `adapt_support_seconds` adapt the model, the rest judges it.
    pub adapt_support_seconds: f64,
    /// Where adapted models are written (`<model name>-adapted-<unix s>.{pt,ot,json}`); empty:
    /// beside the model. Set `model` to one to start with it.
    pub adapted_model_dir: String,
    /// Inner-loop settings (crate::adapt::AdaptConfig).
    pub adapt: crate::adapt::AdaptConfig,
    /// Nice value of the adaptation thread (0 = the node's priority … 19 = lowest): it yields
    /// the cores to the real-time path (and to anything else running at a higher priority).
    pub adapt_thread_nice: i32,
}

impl Default for NodeParams {
    fn default() -> Self {
        NodeParams {
            input_topic: "/imu/data_raw".into(),
            output_topic: "/imu/denoised".into(),
            correction_topic: "/imu/gyro_correction".into(),
            diagnostics_topic: "/diagnostics".into(),
            model: String::new(),
            imu_calibration: String::new(),
            queue_depth: 100,
            diagnostics_period: 1.0,
            use_sim_time: false,
            pipeline: PipelineConfig::default(),
            ground_truth_topic: "/ground_truth/pose".into(),
            ground_truth_type: "geometry_msgs/msg/PoseStamped".into(),
            adapt_buffer_seconds: 120.0,
            adapt_support_seconds: 60.0,
            adapted_model_dir: String::new(),
            adapt: crate::adapt::AdaptConfig::default(),
            adapt_thread_nice: 10,
        }
    }
}

impl NodeParams {
    /// Read the `node_name: ros__parameters:` section of a ROS 2 parameter file. `/**` (any
    /// node) is accepted too, as ROS 2 does.
    /// Reads the node's section of a parameter file. Relative paths in it (`model`,
    /// `adapted_model_dir`) are taken against the file's own folder, as cargo and docker
    /// compose do: the node finds them from a launch file or a service unit started anywhere.
    pub fn from_yaml_file(path: &Path, node_name: &str) -> Result<Self, NodeError> {
        let text =
            std::fs::read_to_string(path).map_err(|e| NodeError::Params { path: path.display().to_string(), source: Box::new(e) })?;
        let mut params = Self::from_yaml_str(&text, node_name).map_err(|e| match e {
            NodeError::Params { source, .. } => NodeError::Params { path: path.display().to_string(), source },
            NodeError::NoSection { node, found, .. } => NodeError::NoSection { path: path.display().to_string(), node, found },
            other => other,
        })?;
        let folder = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        for value in [&mut params.model, &mut params.adapted_model_dir] {
            if !value.is_empty() && Path::new(value.as_str()).is_relative() {
                *value = folder.join(value.as_str()).to_string_lossy().into_owned();
            }
        }
        Ok(params)
    }

    pub fn from_yaml_str(text: &str, node_name: &str) -> Result<Self, NodeError> {
        let doc: BTreeMap<String, serde_yaml::Value> =
            serde_yaml::from_str(text).map_err(|e| NodeError::Params { path: "<yaml>".into(), source: Box::new(e) })?;
        let slashed = format!("/{node_name}");
        let key = [node_name, slashed.as_str(), "/**"].into_iter().find(|k| doc.contains_key(*k));
        let Some(key) = key else {
            return Err(NodeError::NoSection {
                path: "<yaml>".into(),
                node: node_name.into(),
                found: doc.keys().cloned().collect::<Vec<_>>().join(", "),
            });
        };
        let params = doc[key].get("ros__parameters").cloned().unwrap_or(serde_yaml::Value::Null);
        let params: Self = serde_yaml::from_value(params).map_err(|e| NodeError::Params { path: "<yaml>".into(), source: Box::new(e) })?;
        params.validate().map_err(|msg| NodeError::Params { path: "<yaml>".into(), source: msg.into() })?;
        Ok(params)
    }

    /// Refuses values the node cannot run with, naming the key (typos are refused by serde,
    /// inside `pipeline:` too).
    pub fn validate(&self) -> Result<(), String> {
        self.pipeline.validate()?;
        self.adapt.validate()?;
        // Said, not changed without a word (they were taken as 1 and clamped).
        if self.queue_depth == 0 {
            return Err("queue_depth must be at least 1 (a history of 0 messages holds nothing)".into());
        }
        if !(0..=19).contains(&self.adapt_thread_nice) {
            return Err(format!("adapt_thread_nice must be 0–19 (a niceness at or below the node's own), not {}", self.adapt_thread_nice));
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        for (key, value) in [
            ("diagnostics_period", self.diagnostics_period),
            ("adapt_buffer_seconds", self.adapt_buffer_seconds),
            ("adapt_support_seconds", self.adapt_support_seconds),
        ] {
            if !positive(value) {
                return Err(format!("{key} must be finite and > 0, not {value}"));
            }
        }
        // A period a clock cannot count (1e300 s) panicked converting to a Duration.
        if self.diagnostics_period > MAX_DIAGNOSTICS_PERIOD_S {
            return Err(format!(
                "diagnostics_period must be at most {MAX_DIAGNOSTICS_PERIOD_S} s (a day), not {}",
                self.diagnostics_period
            ));
        }
        // One topic for two streams would mix them (raw and denoised on one topic), or feed
        // the node its own output.
        let topics = [
            ("input_topic", &self.input_topic),
            ("output_topic", &self.output_topic),
            ("correction_topic", &self.correction_topic),
            ("diagnostics_topic", &self.diagnostics_topic),
            ("ground_truth_topic", &self.ground_truth_topic),
        ];
        for (i, (a, ta)) in topics.iter().enumerate() {
            if let Some((b, _)) = topics[i + 1..].iter().find(|(_, tb)| tb == ta) {
                return Err(format!("{a} and {b} are both {ta}: each stream needs its own topic"));
            }
        }
        if self.adapt_support_seconds >= self.adapt_buffer_seconds {
            return Err(format!(
                "adapt_support_seconds ({}) must be below adapt_buffer_seconds ({}): the rest of the buffer judges the adapted model",
                self.adapt_support_seconds, self.adapt_buffer_seconds
            ));
        }
        Ok(())
    }

    /// Apply `from:=to` topic remappings (as `--ros-args -r`).
    pub fn remap(&mut self, rule: &str) -> Result<(), NodeError> {
        let (from, to) =
            rule.split_once(":=").filter(|(f, t)| !f.trim_matches('/').is_empty() && !t.trim_matches('/').is_empty()).ok_or_else(|| {
                NodeError::Invalid { what: "remapping", value: rule.into(), why: "a remapping is from:=to, both names given".into() }
            })?;
        let norm = |t: &str| if t.starts_with('/') { t.to_string() } else { format!("/{t}") };
        let (from, to) = (norm(from), norm(to));
        let mut hit = false;
        for t in [
            &mut self.input_topic,
            &mut self.output_topic,
            &mut self.correction_topic,
            &mut self.diagnostics_topic,
            &mut self.ground_truth_topic,
        ] {
            if *t == from {
                *t = to.clone();
                hit = true;
            }
        }
        if !hit {
            tracing::warn!("remapping {rule}: no topic of this node is named {from}");
        }
        Ok(())
    }
}

/// Which DDS domain and network the environment asks for: `ROS_DOMAIN_ID`, and
/// `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST|OFF` for loopback only.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RosEnvironment {
    pub domain_id: u16,
    pub localhost_only: bool,
}

impl RosEnvironment {
    pub fn from_env() -> Result<Self, NodeError> {
        Self::from_vars(|k| std::env::var(k).ok())
    }

    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Self, NodeError> {
        let domain_id = match get("ROS_DOMAIN_ID").filter(|s| !s.trim().is_empty()) {
            None => 0,
            Some(s) => s
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= 232)
                .ok_or_else(|| NodeError::Environment(format!("ROS_DOMAIN_ID={s} is not a domain id 0–232")))?,
        };
        let localhost_only = get("ROS_LOCALHOST_ONLY").is_some_and(|v| v.trim() == "1")
            || get("ROS_AUTOMATIC_DISCOVERY_RANGE").is_some_and(|v| matches!(v.trim().to_ascii_uppercase().as_str(), "LOCALHOST" | "OFF"));
        Ok(RosEnvironment { domain_id, localhost_only })
    }

    /// A ros2-client context on this domain (loopback only when asked).
    pub fn context(&self) -> Result<Context, NodeError> {
        let mut b = ros2_client::dds::rustdds::DomainParticipantBuilder::new(self.domain_id);
        if self.localhost_only {
            b = b.with_only_networks([std::net::IpAddr::from([127, 0, 0, 1])]);
        }
        let dp = b.build().map_err(|e| NodeError::Dds(format!("domain participant: {e:?}")))?;
        Context::from_domain_participant(dp).map_err(|e| NodeError::Dds(format!("context: {e:?}")))
    }
}

/// The sensor-data QoS profile of ROS 2 (rmw_qos_profile_sensor_data): best effort, volatile,
/// keep last `depth`.
pub fn sensor_data_qos(depth: usize) -> QosProfile {
    QosProfile::subscription_default().history(ros2_client::qos::History::KeepLast { depth })
}

/// Fill an output Imu from the input message (header kept) and a corrected sample.
pub fn fill_denoised(msg: &mut Imu, c: &CorrectedImu) {
    msg.angular_velocity = c.gyro.into();
    // REP 145 / sensor_msgs: all zeros is "unknown", −1 first "not measured".
    let input = &msg.angular_velocity_covariance.0;
    let input_known = input[0] >= 0.0 && input.iter().any(|v| *v != 0.0) && input.iter().all(|v| v.is_finite());
    if !(c.passed_through && input_known) {
        msg.angular_velocity_covariance.0 = [c.gyro_variance, 0.0, 0.0, 0.0, c.gyro_variance, 0.0, 0.0, 0.0, c.gyro_variance];
    }
    // The bias left in the gyro is an error of every sample: on the diagonal, beside the noise.
    for k in [0, 4, 8] {
        msg.angular_velocity_covariance.0[k] += c.gyro_bias_variance;
    }
    msg.linear_acceleration = c.accel.into();
    match &c.orientation {
        Some((q, cov)) => {
            msg.orientation = (*q).into();
            // Row-major, about world x, y, z (REP 145).
            for r in 0..3 {
                for k in 0..3 {
                    msg.orientation_covariance.0[3 * r + k] = cov[(r, k)];
                }
            }
        }
        None => {
            msg.orientation = crate::msg::Quaternion::default();
            msg.orientation_covariance.0 = [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        }
    }
}

/// Latency histogram in fixed 10 µs bins up to 100 ms (no allocation per sample).
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    bins: Vec<u64>,
    count: u64,
    max_us: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram { bins: vec![0; 10_001], count: 0, max_us: 0.0 }
    }
}

impl LatencyHistogram {
    const BIN_US: f64 = 10.0;
    pub fn record(&mut self, d: Duration) {
        let us = d.as_secs_f64() * 1e6;
        let i = ((us / Self::BIN_US) as usize).min(self.bins.len() - 1);
        self.bins[i] += 1;
        self.count += 1;
        self.max_us = self.max_us.max(us);
    }
    /// Quantile in µs (upper edge of the bin), 0 when empty.
    pub fn quantile_us(&self, q: f64) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let target = (q * self.count as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, b) in self.bins.iter().enumerate() {
            seen += b;
            if seen >= target {
                return ((i + 1) as f64 * Self::BIN_US).min(self.max_us.max(Self::BIN_US));
            }
        }
        self.max_us
    }
    pub fn count(&self) -> u64 {
        self.count
    }
    /// Largest value recorded, µs (exact, not binned).
    pub fn max_us(&self) -> f64 {
        self.max_us
    }
    /// p50 / p99 / max / count as JSON (the node's `--stats-json`, benchmarks).
    pub fn summary_json(&self) -> serde_json::Value {
        serde_json::json!({"p50_us": self.quantile_us(0.5), "p99_us": self.quantile_us(0.99), "max_us": self.max_us, "count": self.count})
    }
}

/// Per-sample latencies split by whether an adaptation was running when the sample was
/// processed (index 0: idle, 1: adapting), to check the adaptation does not starve the
/// real-time path.
#[derive(Debug, Clone, Default)]
pub struct SplitLatency {
    /// In the node: input taken from the subscription → outputs published.
    pub in_node: [LatencyHistogram; 2],
    /// Writer to publish: the input's DDS source timestamp (the sender's clock; same host)
    /// → outputs published. Includes DDS delivery and any wait for a tokio worker.
    pub write_to_publish: [LatencyHistogram; 2],
}

impl SplitLatency {
    pub fn summary_json(&self) -> serde_json::Value {
        let side = |i: usize| serde_json::json!({"in_node": self.in_node[i].summary_json(), "write_to_publish": self.write_to_publish[i].summary_json()});
        serde_json::json!({"idle": side(0), "adapting": side(1)})
    }
}

/// Longest `diagnostics_period`, s.
pub const MAX_DIAGNOSTICS_PERIOD_S: f64 = 86_400.0;

/// What the diagnostics report (shared between the processing and diagnostics tasks).
#[derive(Debug, Default)]
pub struct NodeStats {
    pub counters: Counters,
    pub latency: LatencyHistogram,
    pub frame_changes: u64,
    pub decode_errors: u64,
    pub frame_id: String,
    pub last_stamp_ns: i64,
    /// When the last input arrived, on the status clock's time line ([`StatusClock`]).
    pub last_input_ns: Option<i64>,
    pub warming_up: bool,
    pub rate_off_nominal: bool,
    /// The input is fed to the model in the model's periods ([`crate::resample`]).
    pub resampling: bool,
    /// Which correction runs on this IMU and why ([`crate::infer::choose`]).
    pub correction: &'static str,
    pub correction_reason: &'static str,
    /// This power-on's gyro bias in force (from the standstills, or before one the bias seen in
    /// motion), where it comes from, and whether the platform stands now.
    pub power_on_bias: Option<crate::standstill::BiasEstimate>,
    pub power_on_bias_from: &'static str,
    /// What the standstills alone measured: what `~/adapt` removes from a buffer that no
    /// longer holds one.
    pub standstill_bias: Option<crate::standstill::BiasEstimate>,
    pub standstills: crate::standstill::StandstillCounters,
    pub standing: bool,
    /// Times `~/retake_power_on_bias` made the node forget the power-on bias.
    pub power_on_bias_retakes: u64,
    pub model: String,
    pub window: usize,
    pub model_status: String,
    /// Adaptation (empty when the service is off): idle / running / the last result.
    pub adapt_status: String,
    pub adaptations: u64,
    pub adapt_query_aoe_before_deg: Option<f64>,
    pub adapt_query_aoe_after_deg: Option<f64>,
    pub adapt_seconds: Option<f64>,
    /// Latencies split by adaptation state (recorded only when the service is on).
    pub split_latency: SplitLatency,
    /// The node stopped while an adaptation ran on its thread: abandoned, the running model
    /// unchanged. The process must then end without running libtorch's exit-time destructors
    /// under that thread (it crashed with SIGSEGV): see `imu-fsda node`.
    pub adaptation_abandoned: bool,
}

/// No input for this long after the first, s: the status says the input stopped.
pub const INPUT_STALE_AFTER_S: f64 = 1.0;
/// How long a drop, gap, clock jump, missed sample or frame_id change keeps the status at
/// WARN, s. The counters stay cumulative; the level says what is happening now.
pub const EVENT_WARN_S: f64 = 10.0;

/// The status over time, on the node's clock or a replayed bag's: the input rate over the
/// last second or more (0 once the input stops), how long since the last input and since the
/// last counted event. A dead driver must show, and one restart must not mark the sensor
/// degraded for the rest of the run.
#[derive(Debug, Default)]
pub struct StatusClock {
    rate_from: Option<(i64, u64)>,
    rate_hz: f64,
    events: u64,
    last_event_ns: Option<i64>,
}

/// What [`StatusClock::tick`] measured, for [`diagnostics_message`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Liveness {
    pub input_rate_hz: f64,
    /// Seconds since the last input, once one arrived.
    pub since_input_s: Option<f64>,
    /// Seconds since a counted event was first seen, if any was.
    pub since_event_s: Option<f64>,
}

/// Events that put the status at WARN while recent.
fn events(stats: &NodeStats) -> u64 {
    let c = &stats.counters;
    c.dropped() + c.gaps + c.clock_jumps + c.missed_samples + c.saturated_samples + stats.frame_changes
}

impl StatusClock {
    /// Measure the rate from `now_ns`, when `received` inputs had arrived (the first input of
    /// a replay, not its first tick). Without it the first tick starts the clock.
    pub fn start(&mut self, now_ns: i64, received: u64) {
        self.rate_from.get_or_insert((now_ns, received));
    }

    /// At a diagnostics tick `now_ns`, on the clock of `stats.last_input_ns`.
    pub fn tick(&mut self, stats: &NodeStats, now_ns: i64) -> Liveness {
        let received = stats.counters.received;
        let (t0, n0) = *self.rate_from.get_or_insert((now_ns, received));
        if now_ns - t0 >= 1_000_000_000 {
            self.rate_hz = received.saturating_sub(n0) as f64 / ((now_ns - t0) as f64 * 1e-9);
            self.rate_from = Some((now_ns, received));
        }
        let e = events(stats);
        if e > self.events {
            self.events = e;
            self.last_event_ns = Some(now_ns);
        }
        let since = |t: i64| (now_ns - t).max(0) as f64 * 1e-9;
        Liveness {
            input_rate_hz: self.rate_hz,
            since_input_s: stats.last_input_ns.map(since),
            since_event_s: self.last_event_ns.map(since),
        }
    }
}

/// The counted events, for the status message ("19 inputs dropped, 1 clock jump back followed").
fn event_list(stats: &NodeStats) -> String {
    let c = &stats.counters;
    let mut parts = vec![format!("{} inputs dropped", c.dropped()), format!("{} gaps", c.gaps)];
    if c.clock_jumps > 0 {
        parts.push(format!("{} clock jumps back followed", c.clock_jumps));
    }
    if c.missed_samples > 0 {
        parts.push(format!("{} samples missed in holes of the stamps", c.missed_samples));
    }
    if stats.frame_changes > 0 {
        parts.push(format!("{} input frame_id changes (two IMUs on one topic?)", stats.frame_changes));
    }
    if c.saturated_samples > 0 {
        parts.push(format!("{} samples clipped at the sensor's range", c.saturated_samples));
    }
    parts.join(", ")
}

/// Build the /diagnostics message from the stats and what the status clock measured.
pub fn diagnostics_message(stats: &NodeStats, live: &Liveness, node_name: &str, stamp: Time) -> DiagnosticArray {
    let c = &stats.counters;
    let recent = live.since_event_s.is_some_and(|s| s < EVENT_WARN_S);
    // A driver gone silent is the worst news, whatever the model's state.
    let (level, message) = if let Some(s) = live.since_input_s.filter(|s| *s > INPUT_STALE_AFTER_S && c.received > 0) {
        let model = if stats.model_status != "ok" { format!("; {}", stats.model_status) } else { String::new() };
        (DiagnosticStatus::ERROR, format!("no input for {s:.1} s{model}"))
    } else if stats.model_status != "ok" {
        (DiagnosticStatus::WARN, stats.model_status.clone())
    } else if c.received == 0 {
        (DiagnosticStatus::STALE, "no input yet".to_string())
    } else if stats.rate_off_nominal && !stats.resampling {
        (DiagnosticStatus::WARN, "input rate off nominal".to_string())
    } else if recent {
        // Before "warming up": a stream whose every sample is a gap warms up for ever.
        let warming = if stats.warming_up { " (warming up)" } else { "" };
        (DiagnosticStatus::WARN, format!("running{warming}; {}", event_list(stats)))
    } else if stats.warming_up {
        (DiagnosticStatus::OK, "warming up".to_string())
    } else if live.since_event_s.is_some() {
        (DiagnosticStatus::OK, format!("running; earlier: {}", event_list(stats)))
    } else {
        (DiagnosticStatus::OK, "running".to_string())
    };
    let kv = |k: &str, v: String| KeyValue { key: k.into(), value: v };
    let values = vec![
        kv("model", stats.model.clone()),
        kv("window_samples", stats.window.to_string()),
        kv("input_rate_hz", format!("{:.2}", live.input_rate_hz)),
        kv("resampled_to_model_rate", stats.resampling.to_string()),
        kv("correction", stats.correction.to_string()),
        kv("correction_reason", stats.correction_reason.to_string()),
        kv(
            "power_on_bias_rad_s",
            stats.power_on_bias.map_or(String::new(), |e| format!("{:.6} {:.6} {:.6}", e.bias.x, e.bias.y, e.bias.z)),
        ),
        kv("power_on_bias_stddev_rad_s", stats.power_on_bias.map_or(String::new(), |e| format!("{:.2e}", e.variance.max().sqrt()))),
        kv("power_on_bias_from", stats.power_on_bias_from.to_string()),
        kv("power_on_bias_standstill_s", stats.power_on_bias.map_or(String::new(), |e| format!("{:.1}", e.still_s))),
        kv("standing", stats.standing.to_string()),
        kv("standstill_windows", stats.standstills.still_windows.to_string()),
        kv("power_on_bias_retakes", stats.power_on_bias_retakes.to_string()),
        kv("latency_p50_us", format!("{:.0}", stats.latency.quantile_us(0.5))),
        kv("latency_p99_us", format!("{:.0}", stats.latency.quantile_us(0.99))),
        kv("received", c.received.to_string()),
        kv("published", c.processed.to_string()),
        kv("dropped_non_finite", c.dropped_non_finite.to_string()),
        kv("dropped_implausible", c.dropped_implausible.to_string()),
        kv("dropped_duplicate_stamp", c.dropped_duplicate_stamp.to_string()),
        kv("dropped_backwards_stamp", c.dropped_backwards_stamp.to_string()),
        kv("decode_errors", stats.decode_errors.to_string()),
        kv("gaps_reset", c.gaps.to_string()),
        kv("clock_jumps", c.clock_jumps.to_string()),
        kv("rate_changes", c.rate_changes.to_string()),
        kv("frame_id_changes", stats.frame_changes.to_string()),
        kv("warmup_samples", c.warmup_samples.to_string()),
        kv("missed_samples", c.missed_samples.to_string()),
        kv("saturated_samples", c.saturated_samples.to_string()),
    ];
    let mut values = values;
    if !stats.adapt_status.is_empty() {
        let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:.3}"));
        values.push(kv("adaptation", stats.adapt_status.clone()));
        values.push(kv("adaptations", stats.adaptations.to_string()));
        values.push(kv("adapt_query_aoe_before_deg", f(stats.adapt_query_aoe_before_deg)));
        values.push(kv("adapt_query_aoe_after_deg", f(stats.adapt_query_aoe_after_deg)));
        values.push(kv("adapt_seconds", f(stats.adapt_seconds)));
        for (i, state) in ["idle", "adapting"].iter().enumerate() {
            let h = &stats.split_latency.in_node[i];
            values.push(kv(&format!("latency_{state}_p99_us"), format!("{:.0}", h.quantile_us(0.99))));
            values.push(kv(&format!("latency_{state}_max_us"), format!("{:.0}", h.max_us())));
        }
    }
    DiagnosticArray {
        header: Header { stamp, frame_id: String::new() },
        status: vec![DiagnosticStatus {
            level,
            name: format!("{node_name}: gyro denoiser"),
            message,
            hardware_id: stats.frame_id.clone(),
            values,
        }],
    }
}

fn topic_name(name: &str) -> Result<Name, NodeError> {
    Name::parse(name).map_err(|e| NodeError::TopicName { name: name.into(), why: format!("{e:?}") })
}

fn type_name<M: RosMessage>() -> MessageTypeName {
    ros_type_name(M::TYPE_NAME)
}

/// `pkg/msg/Name` → ros2-client's type name.
pub fn ros_type_name(ros: &str) -> MessageTypeName {
    let pkg = ros.split('/').next().unwrap_or("");
    let name = ros.rsplit('/').next().unwrap_or("");
    MessageTypeName::new(pkg, name)
}

/// How the node ends: at Ctrl-C / SIGTERM, or (for tests and benchmarks) after a number of
/// published messages or an idle time.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunLimits {
    pub max_messages: Option<u64>,
    pub idle_exit: Option<Duration>,
}

/// Run the node until a signal (or a limit). Returns the final statistics.
pub async fn run_node(
    node_name: &str,
    params: NodeParams,
    env: RosEnvironment,
    pipeline: Pipeline,
    model_status: String,
    limits: RunLimits,
) -> Result<NodeStats, NodeError> {
    run_node_with_adaptation(node_name, params, env, pipeline, model_status, limits, AdaptService::Off).await
}

/// What the adaptation service needs: the handle on the pipeline's [`SwappableCorrector`]
/// (crate::adapt::swap) and the model file it runs (the meta-learned initialisation).
pub struct AdaptSetup {
    pub handle: SwapHandle,
    pub model: PathBuf,
    /// The IMU's Ĉ_ω to start from (`NodeParams::imu_calibration`).
    pub imu: Option<String>,
}

/// Whether the node offers `~/adapt`.
pub enum AdaptService {
    /// Not offered (no ground-truth topic: adaptation is not configured).
    Off,
    /// Offered, but every call is answered at once with success = false and this reason (a
    /// ground-truth topic is set but there is no model to adapt): a client gets an answer
    /// instead of waiting for a service that is not there.
    Unavailable(String),
    /// Offered and working.
    On(AdaptSetup),
}

/// The reply to a call still running when the node stops.
const ABANDONED_REPLY: &str = "the node is shutting down: the adaptation was abandoned; no model was saved or swapped in";

/// [`run_node`] with the `~/adapt` service (see [`AdaptService`]; nothing without `ground_truth_topic`).
pub async fn run_node_with_adaptation(
    node_name: &str,
    params: NodeParams,
    env: RosEnvironment,
    pipeline: Pipeline,
    model_status: String,
    limits: RunLimits,
    adapt: AdaptService,
) -> Result<NodeStats, NodeError> {
    let context = env.context()?;
    let mut options = NodeOptions::new().enable_rosout(false);
    if params.use_sim_time {
        options = options.declare_parameter("use_sim_time", ParameterValue::Boolean(true));
    }
    let mut node = context
        .new_node(
            NodeName::new("/", node_name).map_err(|e| NodeError::Invalid {
                what: "node name",
                value: node_name.into(),
                why: format!("{e:?}"),
            })?,
            options,
        )
        .map_err(|e| NodeError::Dds(format!("node: {e:?}")))?;

    let depth = params.queue_depth.max(1);
    let sensor_qos = sensor_data_qos(depth);
    let reliable_qos = QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth });
    let dds = |e: ros2_client::CreateError| NodeError::Dds(format!("{e:?}"));
    let input_topic = node.create_topic(&topic_name(&params.input_topic)?, type_name::<Imu>(), &sensor_qos).map_err(dds)?;
    let output_topic = node.create_topic(&topic_name(&params.output_topic)?, type_name::<Imu>(), &reliable_qos).map_err(dds)?;
    let correction_topic =
        node.create_topic(&topic_name(&params.correction_topic)?, type_name::<Vector3Stamped>(), &reliable_qos).map_err(dds)?;
    let diag_topic =
        node.create_topic(&topic_name(&params.diagnostics_topic)?, type_name::<DiagnosticArray>(), &reliable_qos).map_err(dds)?;
    let subscription = node.create_subscription::<Imu>(&input_topic, Some(sensor_qos.clone())).map_err(dds)?;
    let out_pub = node.create_publisher::<Imu>(&output_topic, Some(reliable_qos.clone())).map_err(dds)?;
    let corr_pub = node.create_publisher::<Vector3Stamped>(&correction_topic, Some(reliable_qos.clone())).map_err(dds)?;
    let diag_pub = node.create_publisher::<DiagnosticArray>(&diag_topic, Some(reliable_qos)).map_err(dds)?;
    let (adapt, unavailable) = match adapt {
        _ if params.ground_truth_topic.is_empty() => (None, None),
        AdaptService::Off => (None, None),
        AdaptService::Unavailable(why) => (None, Some(why)),
        AdaptService::On(setup) => (Some(setup), None),
    };
    let buffers = adapt.as_ref().map(|_| Arc::new(Mutex::new(Buffers::new(params.adapt_buffer_seconds))));
    let mut gt_source: Option<GroundTruthSub> = None;
    let mut server: Option<ros2_client::service::Server<TriggerRequest, TriggerResponse>> = None;
    if adapt.is_some() {
        let gt_qos = sensor_data_qos(depth.max(50));
        let name = topic_name(&params.ground_truth_topic)?;
        gt_source = Some(match params.ground_truth_type.as_str() {
            "geometry_msgs/msg/PoseStamped" | "geometry_msgs/PoseStamped" => {
                let t = node.create_topic(&name, type_name::<crate::msg::PoseStamped>(), &gt_qos).map_err(dds)?;
                GroundTruthSub::Pose(node.create_subscription(&t, Some(gt_qos.clone())).map_err(dds)?)
            }
            "nav_msgs/msg/Odometry" | "nav_msgs/Odometry" => {
                let t = node.create_topic(&name, type_name::<crate::msg::Odometry>(), &gt_qos).map_err(dds)?;
                GroundTruthSub::Odometry(node.create_subscription(&t, Some(gt_qos.clone())).map_err(dds)?)
            }
            other => {
                return Err(NodeError::Invalid {
                    what: "ground_truth_type",
                    value: other.into(),
                    why: "geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry".into(),
                })
            }
        });
    }
    if adapt.is_some() || unavailable.is_some() {
        let service_qos = QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth: 10 });
        let srv_name = topic_name(&format!("/{node_name}/adapt"))?;
        server = Some(
            node.create_server::<TriggerRequest, TriggerResponse>(
                ros2_client::service::ServiceMapping::Enhanced,
                &srv_name,
                &ros2_client::ServiceTypeName::new("std_srvs", "Trigger"),
                service_qos.clone(),
                service_qos,
            )
            .map_err(dds)?,
        );
    }
    let retake_server = if params.pipeline.power_on_bias { Some(power_on::retake_server(&mut node, node_name)?) } else { None };
    let spinner = node.spinner().map_err(dds)?;

    let stats = Arc::new(Mutex::new(NodeStats {
        model: pipeline.corrector_name().to_string(),
        window: pipeline.window(),
        model_status,
        warming_up: true,
        adapt_status: match (&adapt, &unavailable) {
            (Some(_), _) => "idle".into(),
            (None, Some(why)) => format!("unavailable: {why}"),
            (None, None) => String::new(),
        },
        ..Default::default()
    }));
    tracing::info!(input = %params.input_topic, output = %params.output_topic, domain = env.domain_id, localhost_only = env.localhost_only, "node {node_name} up");

    let spin = tokio::spawn(async move {
        if let Err(e) = spinner.spin().await {
            tracing::error!("spinner: {e:?}");
        }
    });

    // Set while an adaptation job runs (by the service before it spawns the job, cleared by
    // the job's thread as it ends): the process loop files its latencies under it.
    let adapting = Arc::new(AtomicBool::new(false));
    // The request a running adaptation will answer: answered at shutdown if it is still open.
    let open_request: Mutex<Option<ros2_client::RmwRequestId>> = Mutex::new(None);
    let tap = buffers.as_ref().map(|b| AdaptTap { buffers: b.clone(), adapting: adapting.clone() });
    // Set by `~/retake_power_on_bias`, taken by the process loop between two samples.
    let retake = Arc::new(AtomicBool::new(false));
    let controls = LoopControls { tap, retake: retake.clone() };
    let processing = process_loop(&subscription, &out_pub, &corr_pub, pipeline, stats.clone(), limits, controls);
    let retake_task = async {
        match &retake_server {
            Some(srv) => power_on::retake_service_loop(srv, &retake).await,
            None => std::future::pending().await,
        }
    };
    let gt_task = async {
        match (&gt_source, &buffers) {
            (Some(src), Some(b)) => ground_truth_loop(src, b).await,
            _ => std::future::pending().await,
        }
    };
    let service_task = async {
        match (&server, &buffers, &adapt, &unavailable) {
            (Some(srv), Some(b), Some(a), _) => service_loop(srv, b, a, &params, stats.clone(), adapting.clone(), &open_request).await,
            (Some(srv), _, None, Some(why)) => refusing_service_loop(srv, why).await,
            _ => std::future::pending().await,
        }
    };
    let diag_stats = stats.clone();
    let node_name_owned = node_name.to_string();
    let period = Duration::from_secs_f64(params.diagnostics_period.max(0.01));
    let node_ref = &node;
    let diagnostics = async move {
        let mut tick = tokio::time::interval(period);
        let mut clock = StatusClock::default();
        loop {
            tick.tick().await;
            let stamp = Time::from_ns(node_ref.time_now().to_nanos());
            let msg = {
                let s = diag_stats.lock().expect("stats lock");
                let live = clock.tick(&s, status_clock_ns(Instant::now()));
                diagnostics_message(&s, &live, &node_name_owned, stamp)
            };
            if let Err(e) = diag_pub.async_publish(msg).await {
                tracing::warn!("diagnostics publish: {e:?}");
            }
        }
    };
    let shutdown = async {
        #[cfg(unix)]
        {
            let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending().await } } => {}
            }
        }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
    };
    tokio::select! {
        _ = processing => {}
        _ = diagnostics => {}
        _ = gt_task => {}
        _ = service_task => {}
        _ = retake_task => {}
        _ = shutdown => tracing::info!("shutting down"),
    }
    let open = open_request.lock().expect("request lock").take();
    if let (Some(srv), Some(id)) = (&server, open) {
        respond(srv, id, false, ABANDONED_REPLY.into()).await;
        // A moment for the reliable reply to leave before the writer goes.
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Stop the spinner before the node is dropped so peers hear it leave.
    node.stop_spinner();
    spin.abort();
    let mut s = std::mem::take(&mut *stats.lock().expect("stats lock"));
    if adapting.load(Ordering::Relaxed) {
        tracing::warn!("stopped during an adaptation: it is abandoned, the running model was not changed");
        s.adaptation_abandoned = true;
        s.adapt_status = "abandoned: the node stopped while it ran".into();
    }
    Ok(s)
}

/// What the process loop feeds and reads when the adaptation service is on.
struct AdaptTap {
    buffers: Arc<Mutex<Buffers>>,
    adapting: Arc<AtomicBool>,
}

/// What reaches the process loop from the services: the adaptation's tap, and the re-take flag.
struct LoopControls {
    tap: Option<AdaptTap>,
    retake: Arc<AtomicBool>,
}

async fn process_loop(
    subscription: &ros2_client::Subscription<Imu>,
    out_pub: &ros2_client::Publisher<Imu>,
    corr_pub: &ros2_client::Publisher<Vector3Stamped>,
    mut pipeline: Pipeline,
    stats: Arc<Mutex<NodeStats>>,
    limits: RunLimits,
    controls: LoopControls,
) {
    let LoopControls { tap, retake } = controls;
    let stream = subscription.async_stream();
    futures::pin_mut!(stream);
    let mut published = 0u64;
    let mut received_any = false;
    let mut last_frame: Option<String> = None;
    let mut frame_warnings = FrameWarnings::default();
    loop {
        // Idle counts from the first input, published or dropped (an all-NaN stream ends too).
        let next = match limits.idle_exit {
            Some(idle) if received_any => match tokio::time::timeout(idle, stream.next()).await {
                Ok(x) => x,
                Err(_) => return,
            },
            _ => stream.next().await,
        };
        let Some(item) = next else { return };
        received_any = true;
        let arrived = Instant::now();
        let state = tap.as_ref().map(|t| usize::from(t.adapting.load(Ordering::Relaxed)));
        let (mut msg, source_ns) = match item {
            Ok((m, info)) => (m, info.source_timestamp().map(|t| t.to_nanos())),
            Err(e) => {
                tracing::warn!("input decode error: {e:?}");
                stats.lock().expect("stats lock").decode_errors += 1;
                continue;
            }
        };
        let sample = msg.sample();
        if retake.swap(false, Ordering::AcqRel) {
            power_on::retake(&mut pipeline, &stats);
        }
        let result = pipeline.push(&sample);
        let mut frame_changed = false;
        if last_frame.as_deref() != Some(msg.header.frame_id.as_str()) {
            frame_changed = last_frame.is_some();
            if frame_changed {
                frame_warnings.changed(arrived, last_frame.as_deref().unwrap_or_default(), &msg.header.frame_id);
            }
            last_frame = Some(msg.header.frame_id.clone());
        }
        if let (Ok(c), Some(t)) = (&result, &tap) {
            let seq = pipeline.counters().processed;
            let mut b = t.buffers.lock().expect("buffers lock");
            b.push_imu(SeqSample { seq, sample, reset_before: c.after_gap });
            b.model_fed_periods = pipeline.resampling();
        }
        if let Ok(c) = &result {
            let correction = Vector3Stamped { header: msg.header.clone(), vector: c.correction.into() };
            fill_denoised(&mut msg, c);
            if let Err(e) = out_pub.async_publish(msg).await {
                tracing::warn!("publish: {e:?}");
            }
            if let Err(e) = corr_pub.async_publish(correction).await {
                tracing::warn!("publish correction: {e:?}");
            }
            published += 1;
        } else if let Err(why) = result {
            tracing::debug!("input at {} ns dropped: {why:?}", sample.stamp_ns);
        }
        {
            let mut s = stats.lock().expect("stats lock");
            let in_node = arrived.elapsed();
            s.latency.record(in_node);
            if let Some(i) = state {
                s.split_latency.in_node[i].record(in_node);
                if let Some(src) = source_ns {
                    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
                    // Clamped at 0: the sender's clock is the same host's, but not monotonic.
                    s.split_latency.write_to_publish[i].record(Duration::from_nanos((now - src).max(0) as u64));
                }
            }
            s.counters = pipeline.counters().clone();
            if frame_changed {
                s.frame_changes += 1;
            }
            if let Some(f) = &last_frame {
                if s.frame_id != *f {
                    s.frame_id.clone_from(f);
                }
            }
            s.last_stamp_ns = sample.stamp_ns;
            s.last_input_ns = Some(status_clock_ns(arrived));
            s.warming_up = result.as_ref().is_ok_and(|c| c.warming_up);
            // Said once in the log when it starts: /diagnostics alone was easy to miss.
            if pipeline.resampling() != s.resampling {
                if pipeline.resampling() {
                    tracing::info!(
                        "input at {:.1} Hz, the model at {:.1} Hz: the input is fed to the model in its periods (the mean rate over each), and each sample gets the last period's correction",
                        pipeline.input_rate_hz().unwrap_or(f64::NAN),
                        pipeline.corrector_rate_hz().unwrap_or(f64::NAN)
                    );
                } else {
                    tracing::info!(
                        "input back at {:.1} Hz, the model's rate: fed to it sample by sample",
                        pipeline.input_rate_hz().unwrap_or(f64::NAN)
                    );
                }
            }
            s.resampling = pipeline.resampling();
            s.take_power_on(&pipeline);
            if pipeline.rate_off_nominal() && !s.rate_off_nominal && !pipeline.resampling() {
                tracing::warn!(
                    "input rate off nominal: {:.1} Hz against the {:.1} Hz {}; a model counts samples, so its window now spans another time",
                    pipeline.input_rate_hz().unwrap_or(f64::NAN),
                    pipeline.nominal_rate_hz().unwrap_or(f64::NAN),
                    if pipeline.corrector_rate_hz().is_some() { "the model was trained at" } else { "first measured" }
                );
            }
            s.rate_off_nominal = pipeline.rate_off_nominal();
        }
        if limits.max_messages.is_some_and(|m| published >= m) {
            return;
        }
    }
}

/// The node's status clock: monotonic ns since the first reading (the wall clock may step).
fn status_clock_ns(at: Instant) -> i64 {
    static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    let epoch = *EPOCH.get_or_init(Instant::now);
    i64::try_from(at.saturating_duration_since(epoch).as_nanos()).unwrap_or(i64::MAX)
}

/// The log line for input frame_id changes: the first at once, then at most one every 10 s
/// with the count between (two IMUs on one topic changed it at every message: 1199 lines in 3 s).
#[derive(Default)]
struct FrameWarnings {
    last_warned: Option<Instant>,
    since: u64,
}

impl FrameWarnings {
    fn changed(&mut self, now: Instant, from: &str, to: &str) {
        self.since += 1;
        if self.last_warned.is_none_or(|t| now.duration_since(t) >= Duration::from_secs(10)) {
            let more = if self.since > 1 {
                format!(" ({} changes since the last warning: two IMUs on one topic?)", self.since)
            } else {
                String::new()
            };
            tracing::warn!("input frame_id changed from {from:?} to {to:?}; passed through{more}");
            self.last_warned = Some(now);
            self.since = 0;
        }
    }
}

enum GroundTruthSub {
    Pose(ros2_client::Subscription<crate::msg::PoseStamped>),
    Odometry(ros2_client::Subscription<crate::msg::Odometry>),
}

async fn ground_truth_loop(src: &GroundTruthSub, buffers: &Arc<Mutex<Buffers>>) {
    let mut rejected = 0u64;
    let mut push = |p: Option<crate::core::PoseSample>| {
        let ok = p.is_some_and(|p| buffers.lock().expect("buffers lock").push_ground_truth(p));
        if !ok {
            rejected += 1;
            if rejected.is_power_of_two() {
                tracing::warn!("{rejected} ground-truth messages ignored (invalid or out of order)");
            }
        }
    };
    match src {
        GroundTruthSub::Pose(sub) => {
            let stream = sub.async_stream();
            futures::pin_mut!(stream);
            while let Some(m) = stream.next().await {
                if let Ok((m, _)) = m {
                    push(m.sample());
                }
            }
        }
        GroundTruthSub::Odometry(sub) => {
            let stream = sub.async_stream();
            futures::pin_mut!(stream);
            while let Some(m) = stream.next().await {
                if let Ok((m, _)) = m {
                    push(m.sample());
                }
            }
        }
    }
}

/// The result of one adaptation job (run on its own thread).
struct JobResult {
    success: bool,
    message: String,
    report: Option<crate::adapt::AdaptReport>,
    model_name: Option<String>,
}

/// `~/adapt`: one adaptation at a time, on a blocking thread; a second request while one runs
/// is answered at once with success = false.
async fn service_loop(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    buffers: &Arc<Mutex<Buffers>>,
    setup: &AdaptSetup,
    params: &NodeParams,
    stats: Arc<Mutex<NodeStats>>,
    adapting: Arc<AtomicBool>,
    open_request: &Mutex<Option<ros2_client::RmwRequestId>>,
) {
    let mut running: Option<(ros2_client::RmwRequestId, tokio::sync::oneshot::Receiver<JobResult>, Instant)> = None;
    loop {
        let finished = async {
            match running.as_mut() {
                Some((_, rx, _)) => rx.await.ok(),
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            req = server.async_receive_request() => {
                let id = match req {
                    Ok((id, _)) => id,
                    Err(e) => {
                        tracing::warn!("~/adapt request: {e:?}");
                        continue;
                    }
                };
                if let Some((_, _, started)) = &running {
                    let msg = format!("an adaptation is already running (started {:.1} s ago); the current model keeps running — call again when it ends", started.elapsed().as_secs_f64());
                    respond(server, id, false, msg).await;
                    continue;
                }
                let (imu, gt): (Vec<SeqSample>, Vec<crate::core::PoseSample>) = {
                    let b = buffers.lock().expect("buffers lock");
                    (b.imu.iter().copied().collect(), b.ground_truth.iter().copied().collect())
                };
                let (tx, rx) = tokio::sync::oneshot::channel();
                let job = Job {
                    model: setup.model.clone(),
                    imu_calibration: setup.imu.clone(),
                    handle: setup.handle.clone(),
                    buffers: buffers.clone(),
                    imu,
                    gt,
                    support_seconds: params.adapt_support_seconds,
                    ground_truth: format!("{} as {}", params.ground_truth_topic, params.ground_truth_type),
                    out_dir: params.adapted_model_dir.clone(),
                    cfg: params.adapt.clone(),
                    known_power_on_bias: stats.lock().ok().and_then(|s| s.standstill_bias),
                };
                adapting.store(true, Ordering::Relaxed);
                let flag = adapting.clone();
                let nice = params.adapt_thread_nice.clamp(0, 19);
                let spawned = std::thread::Builder::new().name("imu-fsda-adapt".into()).spawn(move || {
                    // Below the real-time path: the scheduler serves the node's threads first.
                    lower_thread_priority(nice);
                    let res = job.run();
                    flag.store(false, Ordering::Relaxed);
                    let _ = tx.send(res);
                });
                if let Err(e) = spawned {
                    adapting.store(false, Ordering::Relaxed);
                    respond(server, id, false, format!("cannot start the adaptation thread: {e}")).await;
                    continue;
                }
                stats.lock().expect("stats lock").adapt_status = "running".into();
                tracing::info!("adaptation started");
                *open_request.lock().expect("request lock") = Some(id);
                running = Some((id, rx, Instant::now()));
            }
            res = finished => {
                let Some((id, _, started)) = running.take() else { continue };
                *open_request.lock().expect("request lock") = None;
                // Normally cleared by the job's thread; also when that thread died.
                adapting.store(false, Ordering::Relaxed);
                let res = res.unwrap_or(JobResult { success: false, message: "the adaptation thread died".into(), report: None, model_name: None });
                {
                    let mut s = stats.lock().expect("stats lock");
                    s.adaptations += 1;
                    s.adapt_seconds = Some(started.elapsed().as_secs_f64());
                    if let Some(r) = &res.report {
                        s.adapt_query_aoe_before_deg = Some(r.query_before.aoe_deg);
                        // The candidate kept (the adapted networks where none was).
                        s.adapt_query_aoe_after_deg = Some(r.kept_query().unwrap_or(&r.query_after).aoe_deg);
                    }
                    if let Some(n) = &res.model_name {
                        s.model.clone_from(n);
                    }
                    s.adapt_status = format!("{}: {}", if res.success { "accepted" } else { "not applied" }, res.message);
                }
                tracing::info!("adaptation finished: {}", res.message);
                respond(server, id, res.success, res.message).await;
            }
        }
    }
}

/// `~/adapt` with nothing to adapt: every call is answered at once with the reason.
async fn refusing_service_loop(server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>, why: &str) {
    loop {
        match server.async_receive_request().await {
            Ok((id, _)) => respond(server, id, false, format!("cannot adapt: {why}")).await,
            Err(e) => tracing::warn!("~/adapt request: {e:?}"),
        }
    }
}

/// Lowers the calling thread's scheduling priority to `nice` (Linux: `setpriority` on the
/// thread id changes that thread only). Failure only costs latency: logged, not fatal.
fn lower_thread_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain syscalls on the calling thread's own id; no memory is passed.
        let rc = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, nice)
        };
        if rc != 0 {
            tracing::warn!("adaptation thread: setpriority(nice {nice}) failed: {}", std::io::Error::last_os_error());
        } else {
            tracing::debug!("adaptation thread at nice {nice}");
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = nice;
}

async fn respond(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    id: ros2_client::RmwRequestId,
    success: bool,
    message: String,
) {
    if let Err(e) = server.async_send_response(id, TriggerResponse { success, message }).await {
        tracing::warn!("~/adapt response: {e:?}");
    }
}

struct Job {
    model: PathBuf,
    imu_calibration: Option<String>,
    handle: SwapHandle,
    buffers: Arc<Mutex<Buffers>>,
    imu: Vec<SeqSample>,
    gt: Vec<crate::core::PoseSample>,
    support_seconds: f64,
    /// "<topic> as <type>", for the reply when none arrived.
    ground_truth: String,
    out_dir: String,
    cfg: crate::adapt::AdaptConfig,
    /// The node's power-on bias from a standstill at the request, if any.
    known_power_on_bias: Option<crate::standstill::BiasEstimate>,
}

impl Job {
    fn run(self) -> JobResult {
        match self.run_inner() {
            Ok(r) => r,
            Err(e) => {
                JobResult { success: false, message: format!("{e:#}; the current model keeps running"), report: None, model_name: None }
            }
        }
    }

    fn run_inner(&self) -> anyhow::Result<JobResult> {
        use anyhow::Context;
        // Off the real-time path, one intra-op thread (the node's setting).
        tch::set_num_threads(1);
        let t0 = Instant::now();
        let meta = crate::model::predict::metadata_path(&self.model);
        let loaded = crate::model::export::load_net(&meta, tch::Device::Cpu).with_context(|| format!("loading {}", meta.display()))?;
        loaded.select_imu(self.imu_calibration.as_deref())?;
        anyhow::ensure!(!self.imu.is_empty(), "no input buffered yet");
        // A publisher of another type on the topic is not matched by DDS, and nothing else says so.
        anyhow::ensure!(
            !self.gt.is_empty(),
            "no ground truth received yet on {} (a publisher of another type there is not matched: set ground_truth_type)",
            self.ground_truth
        );
        let rec = crate::core::Recording {
            name: "node buffer".into(),
            imu: self.imu.iter().map(|s| s.sample).collect(),
            ground_truth: self.gt.clone(),
            temperature: Vec::new(),
        };
        let (support, query) = crate::adapt::split_recording(&rec, self.support_seconds, None, &self.cfg);
        anyhow::ensure!(
            !query.imu.is_empty(),
            "only {:.1} s buffered: nothing after the {} s support set to judge the adaptation on",
            rec.imu_seconds(),
            self.support_seconds
        );
        let outcome = crate::adapt::adapt_knowing(&loaded, &support, &query, &self.cfg, self.known_power_on_bias.as_ref())?;
        let r = outcome.report;
        let figures = format!(
            "query AOE {:.3}° → {:.3}° (raw gyro {:.3}°), support {:.1} s, query {:.1} s, {} steps in {:.1} s",
            r.query_before.aoe_deg,
            r.kept_query().unwrap_or(&r.query_after).aoe_deg,
            r.query_raw.aoe_deg,
            r.support_seconds,
            r.query_seconds,
            r.steps,
            r.step_seconds
        );
        let figures = match r.kind {
            Some(k) => format!("{}: {figures}", k.name()),
            None => figures,
        };
        let Some(adapted) = outcome.adapted else {
            return Ok(JobResult { success: false, message: format!("{}; {figures}", r.verdict), report: Some(r), model_name: None });
        };
        let dir =
            if self.out_dir.is_empty() { meta.parent().unwrap_or(Path::new(".")).to_path_buf() } else { PathBuf::from(&self.out_dir) };
        let unix = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        let name = format!("{}-adapted-{unix}", loaded.metadata.name);
        let paths = crate::adapt::save_adapted(&adapted, &r, &dir, &name)?;
        // Its own (adapted) Ĉ_ω.
        let mut corrector = ModelCorrector::load(&paths.torchscript, None)?;
        // Warm the new streaming model on the recent history, then hand it over: the
        // pipeline catches up on what arrived meanwhile and swaps between two samples. While
        // the model is fed periods, the buffer's samples are not its inputs: offered cold, it
        // is warmed at the swap on the corrector's own.
        let (history, periods): (Vec<SeqSample>, bool) = {
            let b = self.buffers.lock().expect("buffers lock");
            let n = corrector.window() + 1;
            (b.imu.iter().skip(b.imu.len().saturating_sub(n)).copied().collect(), b.model_fed_periods)
        };
        let (swaps_before, _) = self.handle.swaps();
        if periods {
            self.handle.offer_cold(Box::new(corrector));
        } else {
            let fed = warm_up(&mut corrector, &history);
            self.handle.offer(Box::new(corrector), fed);
        }
        let wait = Instant::now();
        while self.handle.swaps().0 == swaps_before && wait.elapsed() < Duration::from_secs(5) {
            std::thread::sleep(Duration::from_millis(2));
        }
        let swapped = match self.handle.swaps() {
            (n, Some((seq, fed))) if n > swaps_before && periods => {
                format!("swapped in at model period {seq} (warmed on the last {fed} periods the model was fed)")
            }
            (n, Some((seq, caught_up))) if n > swaps_before => format!("swapped in at sample {seq} (caught up {caught_up} samples)"),
            _ => "will be swapped in at the next sample".to_string(),
        };
        Ok(JobResult {
            success: true,
            message: format!(
                "adapted: {figures}; saved {}; {swapped}; total {:.1} s",
                paths.torchscript.display(),
                t0.elapsed().as_secs_f64()
            ),
            report: Some(r),
            model_name: Some(name),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A relative path in a parameter file is the file's folder's, whatever the working folder.
    #[test]
    fn relative_paths_are_the_parameter_files_own() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("params");
        std::fs::create_dir_all(&sub).unwrap();
        let file = sub.join("p.yaml");
        std::fs::write(&file, "imu_fsda:\n  ros__parameters:\n    model: ../models/m.pt\n    adapted_model_dir: /abs/dir\n").unwrap();
        let p = NodeParams::from_yaml_file(&file, "imu_fsda").unwrap();
        assert_eq!(Path::new(&p.model), sub.join("../models/m.pt"));
        assert_eq!(p.adapted_model_dir, "/abs/dir");
    }

    /// Without a model the input's own gyro covariance is published, where it gives one; a
    /// model's output, or an input that says "unknown", gets the configured variance.
    #[test]
    fn a_pass_through_keeps_the_inputs_gyro_covariance() {
        let s = crate::core::ImuSample {
            stamp_ns: 5,
            gyro: nalgebra::Vector3::new(0.1, 0.2, 0.3),
            accel: nalgebra::Vector3::new(0.0, 0.0, 9.8),
        };
        let c = CorrectedImu {
            stamp_ns: 5,
            gyro: s.gyro,
            correction: nalgebra::Vector3::zeros(),
            accel: s.accel,
            gyro_variance: 2.5e-5,
            gyro_bias_variance: 0.0,
            passed_through: true,
            orientation: None,
            warming_up: false,
            after_gap: false,
        };
        let own = [1e-4, 2e-6, 0.0, 2e-6, 1e-4, 0.0, 0.0, 0.0, 3e-4];
        let published = |input: [f64; 9], c: &CorrectedImu| {
            let mut msg = Imu::from_sample(&s, "imu");
            msg.angular_velocity_covariance.0 = input;
            fill_denoised(&mut msg, c);
            msg.angular_velocity_covariance.0
        };
        let configured = [2.5e-5, 0.0, 0.0, 0.0, 2.5e-5, 0.0, 0.0, 0.0, 2.5e-5];
        assert_eq!(published(own, &c), own);
        assert_eq!(published([0.0; 9], &c), configured);
        assert_eq!(published([-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], &c), configured);
        assert_eq!(published(own, &CorrectedImu { passed_through: false, ..c }), configured);
        // The power-on bias removed: its estimate's variance on the input's diagonal.
        let debiased = published(own, &CorrectedImu { gyro_bias_variance: 1e-6, ..c });
        assert_eq!(debiased, [1e-4 + 1e-6, 2e-6, 0.0, 2e-6, 1e-4 + 1e-6, 0.0, 0.0, 0.0, 3e-4 + 1e-6]);
    }

    #[test]
    fn params_from_ros2_yaml() {
        let yaml =
            "imu_fsda:\n  ros__parameters:\n    input_topic: /robot/imu\n    queue_depth: 5\n    pipeline:\n      gap_periods: 3.0\n";
        let p = NodeParams::from_yaml_str(yaml, "imu_fsda").unwrap();
        assert_eq!(p.input_topic, "/robot/imu");
        assert_eq!(p.queue_depth, 5);
        assert_eq!(p.pipeline.gap_periods, 3.0);
        assert_eq!(p.output_topic, "/imu/denoised");
        let any = NodeParams::from_yaml_str("/**:\n  ros__parameters:\n    use_sim_time: true\n", "imu_fsda").unwrap();
        assert!(any.use_sim_time);
        assert!(matches!(NodeParams::from_yaml_str("other:\n  ros__parameters: {}\n", "imu_fsda"), Err(NodeError::NoSection { .. })));
        assert!(NodeParams::from_yaml_str("imu_fsda:\n  ros__parameters:\n    input_topik: /x\n", "imu_fsda").is_err(), "typos are errors");
    }

    /// Values the node cannot run with are refused at start, naming the key.
    #[test]
    fn params_out_of_range_are_refused() {
        let with = |body: &str| NodeParams::from_yaml_str(&format!("imu_fsda:\n  ros__parameters:\n{body}"), "imu_fsda");
        for (body, key) in [
            ("    pipeline:\n      gap_periods: -5.0\n", "gap_periods"),
            ("    pipeline:\n      gap_periods: 1.0\n", "gap_periods"),
            ("    pipeline:\n      nominal_rate_hz: .nan\n", "nominal_rate_hz"),
            ("    pipeline:\n      initial_tilt_variance: -1.0e-4\n", "initial_tilt_variance"),
            ("    pipeline:\n      rate_tolerance: 0.0\n", "rate_tolerance"),
            ("    diagnostics_period: .inf\n", "diagnostics_period"),
            ("    diagnostics_period: 1.0e300\n", "diagnostics_period"),
            ("    pipeline:\n      gap_period: 3.0\n", "gap_period"),
            ("    pipeline:\n      bias_stddev: -1.0\n", "bias_stddev"),
            ("    queue_depth: 0\n", "queue_depth"),
            ("    adapt_thread_nice: -5\n", "adapt_thread_nice"),
            ("    adapt_support_seconds: 120.0\n", "adapt_support_seconds"),
        ] {
            let err = with(body).unwrap_err().to_string();
            assert!(err.contains(key), "{body}: {err}");
        }
        assert!(with("    pipeline:\n      gap_periods: 1.5\n      gravity_init_seconds: 0.0\n").is_ok());
        NodeParams::default().validate().unwrap();
    }

    /// The level follows what happens now: a stopped input is an error, an event is a warning
    /// for [`EVENT_WARN_S`], and the input rate falls to 0 when the input stops.
    #[test]
    fn the_status_follows_the_input_over_time() {
        let s = 1_000_000_000i64;
        let mut stats = NodeStats { model_status: "ok".into(), ..Default::default() };
        let mut clock = StatusClock::default();
        let status = |stats: &NodeStats, clock: &mut StatusClock, now: i64| {
            let live = clock.tick(stats, now);
            let d = diagnostics_message(stats, &live, "n", Time::from_ns(now));
            let rate = d.status[0].values.iter().find(|kv| kv.key == "input_rate_hz").unwrap().value.clone();
            (d.status[0].level, d.status[0].message.clone(), rate)
        };
        assert_eq!(status(&stats, &mut clock, 0).0, DiagnosticStatus::STALE);
        // 200 Hz for 3 s, one clock jump back followed at 1 s.
        for t in 1..=3 {
            stats.counters.received = 200 * t as u64;
            stats.last_input_ns = Some(t * s);
            stats.counters.clock_jumps = u64::from(t >= 1);
            stats.counters.dropped_backwards_stamp = if t >= 1 { 19 } else { 0 };
            let (level, message, rate) = status(&stats, &mut clock, t * s);
            assert_eq!(level, DiagnosticStatus::WARN, "{message}");
            assert!(message.contains("19 inputs dropped") && message.contains("1 clock jumps back followed"), "{message}");
            if t >= 2 {
                assert_eq!(rate, "200.00");
            }
        }
        // Still receiving 11 s after the event: OK, the counts kept as earlier events.
        stats.counters.received = 200 * 12;
        stats.last_input_ns = Some(12 * s);
        let (level, message, _) = status(&stats, &mut clock, 12 * s);
        assert_eq!(level, DiagnosticStatus::OK, "{message}");
        assert!(message.starts_with("running; earlier: 19 inputs dropped"), "{message}");
        // The input stops: an error after a second, and the rate falls to 0.
        let (level, message, _) = status(&stats, &mut clock, 12 * s + s / 2);
        assert_eq!(level, DiagnosticStatus::OK, "{message}");
        let (level, message, _) = status(&stats, &mut clock, 15 * s);
        assert_eq!((level, message.as_str()), (DiagnosticStatus::ERROR, "no input for 3.0 s"));
        assert_eq!(status(&stats, &mut clock, 17 * s).2, "0.00");
        // A pass-through node's silent driver is still an error, not its model's warning.
        stats.model_status = "no model: pass-through".into();
        let (level, message, _) = status(&stats, &mut StatusClock::default(), 15 * s);
        assert_eq!((level, message.as_str()), (DiagnosticStatus::ERROR, "no input for 3.0 s; no model: pass-through"));
        stats.model_status = "ok".into();
        // An input off the model's rate fed to it in its periods is running, not a warning.
        let mut fast = NodeStats { model_status: "ok".into(), rate_off_nominal: true, last_input_ns: Some(s), ..Default::default() };
        fast.counters.received = 1000;
        let live = StatusClock::default().tick(&fast, s);
        assert_eq!(diagnostics_message(&fast, &live, "n", Time::from_ns(s)).status[0].level, DiagnosticStatus::WARN);
        fast.resampling = true;
        let d = diagnostics_message(&fast, &live, "n", Time::from_ns(s));
        assert_eq!(d.status[0].level, DiagnosticStatus::OK, "{}", d.status[0].message);
        assert!(d.status[0].values.iter().any(|kv| kv.key == "resampled_to_model_rate" && kv.value == "true"));
        // A new event while running warns again, and names a frame_id change.
        stats.counters.received += 1;
        stats.last_input_ns = Some(17 * s + 1);
        stats.frame_changes = 1;
        let (level, message, _) = status(&stats, &mut clock, 17 * s + 2);
        assert_eq!(level, DiagnosticStatus::WARN, "{message}");
        assert!(message.contains("1 input frame_id changes"), "{message}");
    }

    #[test]
    fn remapping() {
        let mut p = NodeParams::default();
        p.remap("/imu/data_raw:=/vectornav/imu").unwrap();
        p.remap("imu/denoised:=imu/clean").unwrap();
        assert_eq!(p.input_topic, "/vectornav/imu");
        assert_eq!(p.output_topic, "/imu/clean");
        assert!(p.remap("nonsense").is_err());
        for empty in [":=/x", "/a:=", "/:=/x", ":="] {
            assert!(p.remap(empty).is_err(), "{empty}");
        }
        // A remapping onto another stream's topic: the node would subscribe to its own output.
        p.remap("/imu/clean:=/vectornav/imu").unwrap();
        let e = p.validate().unwrap_err();
        assert!(e.contains("input_topic and output_topic are both /vectornav/imu"), "{e}");
    }

    #[test]
    fn environment() {
        let env =
            |pairs: &'static [(&'static str, &'static str)]| move |k: &str| pairs.iter().find(|(a, _)| *a == k).map(|(_, v)| v.to_string());
        assert_eq!(RosEnvironment::from_vars(env(&[])).unwrap(), RosEnvironment { domain_id: 0, localhost_only: false });
        assert_eq!(
            RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "42"), ("ROS_LOCALHOST_ONLY", "1")])).unwrap(),
            RosEnvironment { domain_id: 42, localhost_only: true }
        );
        assert!(RosEnvironment::from_vars(env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "localhost")])).unwrap().localhost_only);
        assert!(RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "abc")])).is_err());
        assert!(RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "300")])).is_err());
    }

    #[test]
    fn latency_quantiles() {
        let mut h = LatencyHistogram::default();
        for us in 1..=100 {
            h.record(Duration::from_micros(us * 10));
        }
        assert!((h.quantile_us(0.5) - 500.0).abs() <= 10.0, "{}", h.quantile_us(0.5));
        assert!((h.quantile_us(0.99) - 990.0).abs() <= 10.0);
    }
}
