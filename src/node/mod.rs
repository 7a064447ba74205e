//! The ROS 2 node: ros2-client + tokio around [`Pipeline`]. Subscribes to raw IMU
//! (sensor-data QoS), publishes `/imu/denoised` (sensor_msgs/Imu: corrected angular velocity,
//! integrated orientation, accel passed through, header unchanged), `/imu/gyro_correction`
//! (geometry_msgs/Vector3Stamped) and `/diagnostics` (diagnostic_msgs/DiagnosticArray).
//! Nothing below this module knows about DDS.

mod adaptation;
mod endpoints;
mod environment;
mod input_sequence;
mod latency;
mod log_throttle;
mod messages;
mod params;
mod peer_check;
mod power_on;
mod status;
mod support_archive;

use adaptation::{ground_truth_loop, refusing_service_loop, respond, service_loop, RunningJob};
use endpoints::{Endpoints, Served};
pub use environment::{sensor_data_qos, RosEnvironment};
pub use input_sequence::InputSequences;
pub use latency::{LatencyHistogram, SplitLatency, StageLatency};
use messages::topic_name;
pub use messages::{ros_type_name, TriggerRequest, TriggerResponse};
pub use params::{NodeParams, ServiceMapping};
pub use status::*;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;
use ros2_client::{NodeName, NodeOptions, ParameterValue};

use crate::adapt::swap::{Buffers, SeqSample, SwapHandle};
use crate::infer::{CorrectedImu, Pipeline};
use crate::msg::{DiagnosticArray, Imu, Time, Vector3Stamped};

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
/// How long the end of the run waits for an adaptation to stop at its next step.
const ADAPTATION_STOP_WAIT: Duration = Duration::from_secs(15);

/// /diagnostics `adaptation` of a node that does not offer `~/adapt`.
pub const ADAPTATION_OFF: &str = "off: adapt_enabled is false (the parameter file turns it on)";

const ABANDONED_REPLY: &str = "the node is shutting down: the adaptation was abandoned; no model was saved or swapped in";

/// [`run_node`] with the `~/adapt` service (see [`AdaptService`]; nothing without `adapt_enabled`).
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
    let ros_node_name = NodeName::new("/", node_name).map_err(|e| NodeError::Invalid {
        what: "node name",
        value: node_name.into(),
        why: format!("{e:?}"),
    })?;
    let mut node = context.new_node(ros_node_name.clone(), options).map_err(|e| NodeError::Dds(format!("node: {e:?}")))?;

    let (adapt, unavailable) = match adapt {
        _ if !params.adapt_enabled => (None, None),
        AdaptService::Off => (None, None),
        AdaptService::Unavailable(why) => (None, Some(why)),
        AdaptService::On(setup) => (Some(setup), None),
    };
    let buffers = adapt.as_ref().map(|_| Arc::new(Mutex::new(Buffers::new(params.adapt_buffer_seconds))));
    let served = if adapt.is_some() {
        Served::Adaptation
    } else if unavailable.is_some() {
        Served::RefusingAdaptation
    } else {
        Served::Plain
    };
    let Endpoints { subscription, out_pub, corr_pub, diag_pub, gt_source, server, retake_server, own, own_input } =
        Endpoints::create(&mut node, &ros_node_name, &params, served)?;
    let peer_check = peer_check::PeerCheck::new(own);
    let input_writers = peer_check::InputWriters::new(own_input);
    let participant = context.domain_participant();
    let spinner = node.spinner().map_err(|e| NodeError::Dds(format!("{e:?}")))?;

    let memory_writer = power_on::BiasMemoryWriter::new(&params.power_on_bias_memory, &pipeline);
    let stats = Arc::new(Mutex::new(NodeStats {
        power_on_bias_memory: memory_writer.as_ref().map_or(String::new(), power_on::BiasMemoryWriter::started),
        model: pipeline.corrector_name().to_string(),
        security: env.security.clone(),
        window: pipeline.window(),
        model_status,
        warming_up: true,
        adapt_status: match (&adapt, &unavailable) {
            (Some(_), _) => "idle".into(),
            (None, Some(why)) => format!("unavailable: {why}"),
            (None, None) => ADAPTATION_OFF.into(),
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
    // The adaptation running, if any: its request is answered and its thread stopped at shutdown.
    let job = RunningJob::default();
    let tap = buffers.as_ref().map(|b| AdaptTap { buffers: b.clone(), adapting: adapting.clone() });
    // Set by `~/retake_power_on_bias`, taken by the process loop between two samples.
    let retake = Arc::new(AtomicBool::new(false));
    let controls = LoopControls { tap, retake: retake.clone(), input_writers, participant: participant.clone() };
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
            (Some(srv), Some(b), Some(a), _) => service_loop(srv, b, a, &params, stats.clone(), adapting.clone(), &job).await,
            (Some(srv), _, None, Some(why)) => refusing_service_loop(srv, why, &stats).await,
            _ => std::future::pending().await,
        }
    };
    // Shared with the end of the run, which saves what the last tick did not.
    let memory_writer = Arc::new(Mutex::new(memory_writer));
    let diagnostics = publish_diagnostics(
        DiagnosticsTask {
            period: Duration::from_secs_f64(params.diagnostics_period.max(0.01)),
            node_name,
            stats: stats.clone(),
            memory_writer: memory_writer.clone(),
            participant,
            peer_check,
        },
        &node,
        &diag_pub,
    );
    let shutdown = shutdown_signal();
    tokio::select! {
        _ = processing => {}
        _ = diagnostics => {}
        _ = gt_task => {}
        _ = service_task => {}
        _ = retake_task => {}
        _ = shutdown => tracing::info!("shutting down"),
    }
    let open = job.request.lock().expect("request lock").take();
    if let (Some(srv), Some(id)) = (&server, open) {
        respond(srv, id, false, ABANDONED_REPLY.into()).await;
        // A moment for the reliable reply to leave before the writer goes.
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    if let Some(w) = memory_writer.lock().expect("memory lock").as_mut() {
        w.tick(&stats, true);
    }
    // Stop the spinner before the node is dropped so peers hear it leave.
    node.stop_spinner();
    spin.abort();
    let was_adapting = adapting.load(Ordering::Relaxed);
    // Stopped at its next step (a few seconds at most) and joined, so nothing is left inside
    // libtorch when the process exits; one that does not stop in time is left behind.
    let joined = job.cancel_and_join(ADAPTATION_STOP_WAIT);
    let mut s = std::mem::take(&mut *stats.lock().expect("stats lock"));
    if was_adapting {
        tracing::warn!("stopped during an adaptation: it is abandoned, the running model was not changed");
        s.adaptation_abandoned = !joined;
        s.adapt_status = format!(
            "abandoned: the node stopped while it ran ({})",
            if joined { "stopped and joined" } else { "its thread did not stop in time" }
        );
    }
    Ok(s)
}

/// What the /diagnostics publisher works with.
struct DiagnosticsTask<'a> {
    period: Duration,
    node_name: &'a str,
    stats: Arc<Mutex<NodeStats>>,
    memory_writer: Arc<Mutex<Option<power_on::BiasMemoryWriter>>>,
    participant: ros2_client::dds::rustdds::DomainParticipant,
    peer_check: peer_check::PeerCheck,
}

/// Each period: the peers on the node's topics checked against what discovery holds, the
/// status published on /diagnostics, the bias memory saved when it moved.
async fn publish_diagnostics(task: DiagnosticsTask<'_>, node: &ros2_client::Node, diag_pub: &ros2_client::Publisher<DiagnosticArray>) {
    let DiagnosticsTask { period, node_name, stats, memory_writer, participant, mut peer_check } = task;
    let mut tick = tokio::time::interval(period);
    let mut clock = StatusClock::default();
    loop {
        tick.tick().await;
        let writers = participant.discovered_writers();
        let readers = participant.discovered_readers();
        let remotes = writers.iter().map(peer_check::RemoteEndpoint::writer).chain(readers.iter().map(peer_check::RemoteEndpoint::reader));
        for said in peer_check.scan(remotes) {
            tracing::warn!("{said}: it cannot work with this node (docs/interop.md, \"Peers that cannot match\")");
        }
        let stamp = Time::from_ns(node.time_now().to_nanos());
        let msg = {
            let mut s = stats.lock().expect("stats lock");
            let (present, described) = peer_check.present();
            s.incompatible_peers = IncompatiblePeers { said: peer_check.count(), present, described: described.to_vec() };
            let live = clock.tick(&s, status_clock_ns(Instant::now()));
            diagnostics_message(&s, &live, node_name, stamp)
        };
        if let Err(e) = diag_pub.async_publish(msg).await {
            tracing::warn!("diagnostics publish: {e:?}");
        }
        if let Some(w) = memory_writer.lock().expect("memory lock").as_mut() {
            w.tick(&stats, false);
        }
    }
}

/// Ctrl-C, or SIGTERM where there is one (a service manager, `ros2 launch`).
async fn shutdown_signal() {
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
}

/// What the process loop feeds and reads when the adaptation service is on.
struct AdaptTap {
    buffers: Arc<Mutex<Buffers>>,
    adapting: Arc<AtomicBool>,
}

/// What reaches the process loop from the services: the adaptation's tap, and the re-take
/// flag; and the input's writers judged by their discovered type.
struct LoopControls {
    tap: Option<AdaptTap>,
    retake: Arc<AtomicBool>,
    input_writers: peer_check::InputWriters,
    participant: ros2_client::dds::rustdds::DomainParticipant,
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
    let LoopControls { tap, retake, mut input_writers, participant } = controls;
    let stream = subscription.async_stream();
    futures::pin_mut!(stream);
    let mut published = 0u64;
    let mut received_any = false;
    let mut last_frame: Option<String> = None;
    let mut frame_warnings = FrameWarnings::default();
    let mut sequences = input_sequence::InputSequences::default();
    // A peer publishing another type on the input topic errs at its rate: one line a second.
    let mut decode_log = log_throttle::LogThrottle::new(log_throttle::LOG_EVERY);
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
            Ok((m, info)) => {
                sequences.observe(info.publisher_gid(), info.sequence_number());
                let writer = info.publisher_gid().into();
                let discovered = || participant.discovered_writers().iter().map(peer_check::RemoteEndpoint::writer).collect();
                if input_writers.refuses(writer, discovered).is_some() {
                    // Said once, by the peer check on /diagnostics and in the log.
                    stats.lock().expect("stats lock").dropped_wrong_type += 1;
                    continue;
                }
                (m, info.source_timestamp().map(|t| t.to_nanos()))
            }
            Err(e) => {
                if let Some(n) = decode_log.admit(Instant::now()) {
                    tracing::warn!("input decode error: {e:?}{}", log_throttle::unsaid(n));
                }
                stats.lock().expect("stats lock").decode_errors += 1;
                continue;
            }
        };
        let sample = msg.sample();
        if retake.swap(false, Ordering::AcqRel) {
            power_on::retake(&mut pipeline, &stats);
        }
        let result = pipeline.push(&sample);
        let corrected = Instant::now();
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
        let mut publish_times = None;
        if let Ok(c) = &result {
            let start = Instant::now();
            let correction = Vector3Stamped { header: msg.header.clone(), vector: c.correction.into() };
            fill_denoised(&mut msg, c);
            if let Err(e) = out_pub.async_publish(msg).await {
                tracing::warn!("publish: {e:?}");
            }
            let denoised_sent = Instant::now();
            if let Err(e) = corr_pub.async_publish(correction).await {
                tracing::warn!("publish correction: {e:?}");
            }
            publish_times = Some((denoised_sent - start, denoised_sent.elapsed()));
            published += 1;
        } else if let Err(why) = result {
            tracing::debug!("input at {} ns dropped: {why:?}", sample.stamp_ns);
        }
        {
            let mut s = stats.lock().expect("stats lock");
            let in_node = arrived.elapsed();
            s.latency.record(in_node);
            s.stage_latency.correct.record(corrected - arrived);
            if let Some((denoised, correction)) = publish_times {
                s.stage_latency.publish_denoised.record(denoised);
                s.stage_latency.publish_correction.record(correction);
            }
            if let Some(src) = source_ns {
                s.stage_latency.dds_receive.record(Duration::from_nanos((wall_ns(arrived) - src).max(0) as u64));
            }
            if let Some(i) = state {
                s.split_latency.in_node[i].record(in_node);
                if let Some(src) = source_ns {
                    // Clamped at 0: the sender's clock is the same host's, but not monotonic.
                    s.split_latency.write_to_publish[i].record(Duration::from_nanos((wall_ns(Instant::now()) - src).max(0) as u64));
                }
            }
            s.counters = pipeline.counters().clone();
            s.input_sequences.clone_from(&sequences);
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
            s.gravity_aided_blocks = pipeline.gravity_aided_blocks();
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

/// The wall clock at `at` (an instant just taken), ns since the Unix epoch: what a DDS source
/// timestamp is compared with.
fn wall_ns(at: Instant) -> i64 {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
    now - i64::try_from(at.elapsed().as_nanos()).unwrap_or(0)
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
