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
mod process_loop;
mod ros_parameters;
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

use ros2_client::{NodeName, NodeOptions};

use crate::adapt::swap::{Buffers, SwapHandle};
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
    let (mut node, ros_node_name, parameter_changes) = ros_node(&context, node_name, &params)?;

    let adapt = adapt.allowed_by(&params);
    let buffers = matches!(adapt, AdaptService::On(_)).then(|| Arc::new(Mutex::new(Buffers::new(params.adapt_buffer_seconds))));
    let Endpoints { subscription, out_pub, corr_pub, diag_pub, gt_source, server, retake_server, own, own_input } =
        Endpoints::create(&mut node, &ros_node_name, &params, adapt.served())?;
    let peer_check = peer_check::PeerCheck::new(own);
    let input_writers = peer_check::InputWriters::new(own_input);
    let participant = context.domain_participant();
    let spinner = node.spinner().map_err(|e| NodeError::Dds(format!("{e:?}")))?;

    let memory_writer = power_on::BiasMemoryWriter::new(&params.power_on_bias_memory, &pipeline);
    let stats = Arc::new(Mutex::new(initial_stats(&pipeline, memory_writer.as_ref(), &env, model_status, &adapt)));
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
    let tap = buffers.as_ref().map(|b| process_loop::AdaptTap { buffers: b.clone(), adapting: adapting.clone() });
    // Set by `~/retake_power_on_bias`, taken by the process loop between two samples.
    let retake = Arc::new(AtomicBool::new(false));
    let controls =
        process_loop::LoopControls { tap, retake: retake.clone(), parameter_changes, input_writers, participant: participant.clone() };
    let heard = HeardOutputs::default();
    let topics = process_loop::Topics { denoised_heard: &heard.denoised, input: &subscription, denoised: &out_pub, correction: &corr_pub };
    let processing = process_loop::process_loop(topics, pipeline, stats.clone(), limits, controls);
    let retake_task = async {
        match &retake_server {
            Some(srv) => power_on::retake_service_loop(srv, &retake, &stats).await,
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
        match (&server, &buffers, &adapt) {
            (Some(srv), Some(b), AdaptService::On(a)) => service_loop(srv, b, a, &params, stats.clone(), adapting.clone(), &job).await,
            (Some(srv), _, AdaptService::Unavailable(why)) => refusing_service_loop(srv, why, &stats).await,
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
            outputs: OutputPublishers { denoised: &out_pub, correction: &corr_pub, heard: &heard },
        },
        &node,
        &diag_pub,
    );
    let hearing = heard.wait(&node, &out_pub, &corr_pub);
    let shutdown = shutdown_signal();
    tokio::select! {
        _ = processing => {}
        _ = diagnostics => {}
        _ = gt_task => {}
        _ = service_task => {}
        _ = retake_task => {}
        _ = hearing => {}
        _ = shutdown => tracing::info!("shutting down"),
    }
    let end = RunEnd { server: server.as_ref(), job: &job, memory_writer: &memory_writer, stats: &stats, adapting: &adapting };
    let stats = end.finish().await;
    // Stop the spinner before the node is dropped so peers hear it leave.
    node.stop_spinner();
    spin.abort();
    Ok(stats)
}

/// What /diagnostics says before the first sample: the model, its window, the security, the
/// bias memory and the adaptation service.
fn initial_stats(
    pipeline: &Pipeline,
    memory_writer: Option<&power_on::BiasMemoryWriter>,
    env: &RosEnvironment,
    model_status: String,
    adapt: &AdaptService,
) -> NodeStats {
    NodeStats {
        power_on_bias_memory: match (memory_writer, pipeline.remembered_bias()) {
            (Some(w), _) => w.started(),
            // No file: a model trained without its recordings' power-on biases predicts from them.
            (None, Some(p)) => format!("no file; the model's training recordings of this IMU: {}", p.describe()),
            (None, None) => String::new(),
        },
        model: pipeline.corrector_name().to_string(),
        security: env.security.clone(),
        window: pipeline.window(),
        model_status,
        warming_up: true,
        adapt_status: adapt.status(),
        ..Default::default()
    }
}

/// The ROS node on `context`, every parameter declared (`ros2 param get`), two settable while
/// running: their changes are handed over through the returned [`ros_parameters::PendingChanges`].
fn ros_node(
    context: &ros2_client::Context,
    node_name: &str,
    params: &NodeParams,
) -> Result<(ros2_client::Node, NodeName, Arc<ros_parameters::PendingChanges>), NodeError> {
    let changes = Arc::new(ros_parameters::PendingChanges::default());
    let options = ros_parameters::declare(NodeOptions::new().enable_rosout(false), params, changes.clone());
    let name = NodeName::new("/", node_name).map_err(|e| NodeError::Invalid {
        what: "node name",
        value: node_name.into(),
        why: format!("{e:?}"),
    })?;
    let node = context.new_node(name.clone(), options).map_err(|e| NodeError::Dds(format!("node: {e:?}")))?;
    Ok((node, name, changes))
}

impl AdaptService {
    /// The service as the parameters allow it: off unless `adapt_enabled`.
    fn allowed_by(self, params: &NodeParams) -> Self {
        if params.adapt_enabled {
            self
        } else {
            AdaptService::Off
        }
    }

    fn served(&self) -> Served {
        match self {
            AdaptService::On(_) => Served::Adaptation,
            AdaptService::Unavailable(_) => Served::RefusingAdaptation,
            AdaptService::Off => Served::Plain,
        }
    }

    /// /diagnostics `adaptation` at start.
    fn status(&self) -> String {
        match self {
            AdaptService::On(_) => "idle".into(),
            AdaptService::Unavailable(why) => format!("unavailable: {why}"),
            AdaptService::Off => ADAPTATION_OFF.into(),
        }
    }
}

/// The end of a run: a call still open answered, the bias memory saved, a running adaptation
/// stopped and joined, the statistics taken.
struct RunEnd<'a> {
    server: Option<&'a ros2_client::service::Server<TriggerRequest, TriggerResponse>>,
    job: &'a RunningJob,
    memory_writer: &'a Mutex<Option<power_on::BiasMemoryWriter>>,
    stats: &'a Mutex<NodeStats>,
    adapting: &'a AtomicBool,
}

impl RunEnd<'_> {
    async fn finish(self) -> NodeStats {
        let open = self.job.request.lock().expect("request lock").take();
        if let (Some(srv), Some(id)) = (self.server, open) {
            respond(srv, id, false, ABANDONED_REPLY.into()).await;
            // A moment for the reliable reply to leave before the writer goes.
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        if let Some(w) = self.memory_writer.lock().expect("memory lock").as_mut() {
            w.tick(self.stats, true);
        }
        let was_adapting = self.adapting.load(Ordering::Relaxed);
        // Stopped at its next step (a few seconds at most) and joined, so nothing is left inside
        // libtorch when the process exits; one that does not stop in time is left behind.
        let joined = self.job.cancel_and_join(ADAPTATION_STOP_WAIT);
        let mut s = std::mem::take(&mut *self.stats.lock().expect("stats lock"));
        if was_adapting {
            tracing::warn!("stopped during an adaptation: it is abandoned, the running model was not changed");
            s.adaptation_abandoned = !joined;
            s.adapt_status = format!(
                "abandoned: the node stopped while it ran ({})",
                if joined { "stopped and joined" } else { "its thread did not stop in time" }
            );
        }
        s
    }
}

/// What the /diagnostics publisher works with.
struct DiagnosticsTask<'a> {
    period: Duration,
    node_name: &'a str,
    stats: Arc<Mutex<NodeStats>>,
    memory_writer: Arc<Mutex<Option<power_on::BiasMemoryWriter>>>,
    participant: ros2_client::dds::rustdds::DomainParticipant,
    peer_check: peer_check::PeerCheck,
    outputs: OutputPublishers<'a>,
}

/// The output topics whose matched readers /diagnostics counts.
struct OutputPublishers<'a> {
    denoised: &'a ros2_client::Publisher<Imu>,
    correction: &'a ros2_client::Publisher<Vector3Stamped>,
    heard: &'a HeardOutputs,
}

impl OutputPublishers<'_> {
    /// The readers each output has matched. Asked of the node only once one has: before,
    /// ros2-client logs an error at every call for a writer it holds no match for.
    fn subscription_counts(&self, node: &ros2_client::Node) -> SubscriptionCounts {
        let heard = |flag: &AtomicBool| flag.load(Ordering::Relaxed);
        SubscriptionCounts {
            denoised: if heard(&self.heard.denoised) { self.denoised.get_subscription_count(node) } else { 0 },
            correction: if heard(&self.heard.correction) { self.correction.get_subscription_count(node) } else { 0 },
        }
    }
}

/// Set once a reader has matched each output (ros2-client's wait for a subscription), read by
/// the process loop per sample without asking the node.
#[derive(Default)]
struct HeardOutputs {
    denoised: AtomicBool,
    correction: AtomicBool,
}

impl HeardOutputs {
    /// Sets each flag when its first reader matches, then waits for ever (a `select!` arm).
    async fn wait(
        &self,
        node: &ros2_client::Node,
        denoised: &ros2_client::Publisher<Imu>,
        correction: &ros2_client::Publisher<Vector3Stamped>,
    ) {
        let first = async {
            denoised.wait_for_subscription(node).await;
            self.denoised.store(true, Ordering::Relaxed);
        };
        let second = async {
            correction.wait_for_subscription(node).await;
            self.correction.store(true, Ordering::Relaxed);
        };
        futures::join!(first, second);
        std::future::pending::<()>().await;
    }
}

/// Each period: the peers on the node's topics checked against what discovery holds, the
/// status published on /diagnostics, the bias memory saved when it moved.
async fn publish_diagnostics(task: DiagnosticsTask<'_>, node: &ros2_client::Node, diag_pub: &ros2_client::Publisher<DiagnosticArray>) {
    let DiagnosticsTask { period, node_name, stats, memory_writer, participant, mut peer_check, outputs } = task;
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
            s.subscription_counts = outputs.subscription_counts(node);
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

/// The node's status clock: monotonic ns since the first reading (the wall clock may step).
fn status_clock_ns(at: Instant) -> i64 {
    static EPOCH: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    let epoch = *EPOCH.get_or_init(Instant::now);
    i64::try_from(at.saturating_duration_since(epoch).as_nanos()).unwrap_or(i64::MAX)
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
