//! The node's per-message loop: each `sensor_msgs/Imu` in is admitted (decoded, from a writer
//! of the node's type), corrected by the pipeline, published as `/imu/denoised` and
//! `/imu/gyro_correction`, and accounted for in the node's statistics.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::StreamExt;

use super::{fill_denoised, input_sequence, log_throttle, peer_check, power_on, status_clock_ns, NodeStats, RunLimits};
use crate::adapt::swap::{Buffers, SeqSample};
use crate::core::ImuSample;
use crate::infer::{CorrectedImu, Pipeline};
use crate::msg::{Imu, Vector3Stamped};

/// What the process loop feeds and reads when the adaptation service is on.
pub(super) struct AdaptTap {
    pub(super) buffers: Arc<Mutex<Buffers>>,
    pub(super) adapting: Arc<AtomicBool>,
}

/// What reaches the process loop from the services: the adaptation's tap, and the re-take
/// flag; and the input's writers judged by their discovered type.
pub(super) struct LoopControls {
    pub(super) tap: Option<AdaptTap>,
    pub(super) retake: Arc<AtomicBool>,
    /// What clients set of the run-time parameters ([`super::ros_parameters::AT_RUN_TIME`]).
    pub(super) parameter_changes: Arc<super::ros_parameters::PendingChanges>,
    pub(super) input_writers: peer_check::InputWriters,
    pub(super) participant: ros2_client::dds::rustdds::DomainParticipant,
}

/// The node's three data topics, and whether a reader has matched /imu/denoised yet.
pub(super) struct Topics<'a> {
    pub(super) denoised_heard: &'a AtomicBool,
    pub(super) input: &'a ros2_client::Subscription<Imu>,
    pub(super) denoised: &'a ros2_client::Publisher<Imu>,
    pub(super) correction: &'a ros2_client::Publisher<Vector3Stamped>,
}

/// Runs until the input ends, the node has published `limits.max_messages`, or it has been
/// idle for `limits.idle_exit` after its first input.
pub(super) async fn process_loop(
    topics: Topics<'_>,
    mut pipeline: Pipeline,
    stats: Arc<Mutex<NodeStats>>,
    limits: RunLimits,
    controls: LoopControls,
) {
    let LoopControls { tap, retake, parameter_changes, input_writers, participant } = controls;
    let stream = topics.input.async_stream();
    futures::pin_mut!(stream);
    let mut intake = Intake::new(input_writers, participant);
    let mut frames = FrameTracker::default();
    let mut published = 0u64;
    loop {
        // Idle counts from the first input, published or dropped (an all-NaN stream ends too).
        let next = match limits.idle_exit {
            Some(idle) if intake.received_any => match tokio::time::timeout(idle, stream.next()).await {
                Ok(x) => x,
                Err(_) => return,
            },
            _ => stream.next().await,
        };
        let Some(item) = next else { return };
        intake.received_any = true;
        let arrived = Instant::now();
        let adaptation_state = tap.as_ref().map(|t| usize::from(t.adapting.load(Ordering::Relaxed)));
        let Some((msg, source_ns)) = intake.admit(item, &stats) else { continue };
        let sample = msg.sample();
        if retake.swap(false, Ordering::AcqRel) {
            power_on::retake(&mut pipeline, &stats);
        }
        for change in parameter_changes.take() {
            super::ros_parameters::apply(&mut pipeline, change, &stats);
        }
        let result = pipeline.push(&sample);
        let corrected = Instant::now();
        let frame_changed = frames.observe(arrived, &msg.header.frame_id);
        if let (Ok(c), Some(t)) = (&result, &tap) {
            let mut b = t.buffers.lock().expect("buffers lock");
            b.push_imu(SeqSample { seq: pipeline.counters().processed, sample, reset_before: c.after_gap });
            b.model_fed_periods = pipeline.resampling();
        }
        // Until a reader has matched /imu/denoised, an output is for nobody (volatile): counted.
        let mut unheard = false;
        let publish_times = match &result {
            Ok(c) => {
                published += 1;
                unheard = !topics.denoised_heard.load(Ordering::Relaxed);
                Some(publish(&topics, msg, c).await)
            }
            Err(why) => {
                tracing::debug!("input at {} ns dropped: {why:?}", sample.stamp_ns);
                None
            }
        };
        {
            let mut s = stats.lock().expect("stats lock");
            let timing = Timing { arrived, corrected, publish_times, source_ns, adaptation_state };
            record_latency(&mut s, &timing);
            s.denoised_before_a_reader += u64::from(unheard);
            let handled = Handled { sample: &sample, arrived, result: &result, frame_changed };
            record_status(&mut s, &pipeline, &intake.sequences, &frames, &handled);
        }
        if limits.max_messages.is_some_and(|m| published >= m) {
            return;
        }
    }
}

/// The input's admission: decode errors and writers of another type counted and dropped,
/// every writer's sequence numbers followed.
struct Intake {
    input_writers: peer_check::InputWriters,
    participant: ros2_client::dds::rustdds::DomainParticipant,
    sequences: input_sequence::InputSequences,
    /// A peer publishing another type on the input topic errs at its rate: one line a second.
    decode_log: log_throttle::LogThrottle,
    received_any: bool,
}

type Received = Result<(Imu, ros2_client::MessageInfo), ros2_client::ReadError>;

impl Intake {
    fn new(input_writers: peer_check::InputWriters, participant: ros2_client::dds::rustdds::DomainParticipant) -> Self {
        Intake {
            input_writers,
            participant,
            sequences: input_sequence::InputSequences::default(),
            decode_log: log_throttle::LogThrottle::new(log_throttle::LOG_EVERY),
            received_any: false,
        }
    }

    /// The message and its DDS source timestamp (ns), or `None` where it is not one to use.
    fn admit(&mut self, item: Received, stats: &Mutex<NodeStats>) -> Option<(Imu, Option<i64>)> {
        match item {
            Ok((m, info)) => {
                self.sequences.observe(info.publisher_gid(), info.sequence_number());
                let writer = info.publisher_gid().into();
                let participant = &self.participant;
                let discovered = || participant.discovered_writers().iter().map(peer_check::RemoteEndpoint::writer).collect();
                if self.input_writers.refuses(writer, discovered).is_some() {
                    // Said once, by the peer check on /diagnostics and in the log.
                    stats.lock().expect("stats lock").dropped_wrong_type += 1;
                    return None;
                }
                Some((m, info.source_timestamp().map(|t| t.to_nanos())))
            }
            Err(e) => {
                if let Some(n) = self.decode_log.admit(Instant::now()) {
                    tracing::warn!("input decode error: {e:?}{}", log_throttle::unsaid(n));
                }
                stats.lock().expect("stats lock").decode_errors += 1;
                None
            }
        }
    }
}

/// `/imu/denoised` and `/imu/gyro_correction` for one corrected sample; the time each send
/// took (fill and encode included).
async fn publish(topics: &Topics<'_>, mut msg: Imu, c: &CorrectedImu) -> (Duration, Duration) {
    let start = Instant::now();
    let correction = Vector3Stamped { header: msg.header.clone(), vector: c.correction.into() };
    fill_denoised(&mut msg, c);
    if let Err(e) = topics.denoised.async_publish(msg).await {
        tracing::warn!("publish: {e:?}");
    }
    let denoised_sent = Instant::now();
    if let Err(e) = topics.correction.async_publish(correction).await {
        tracing::warn!("publish correction: {e:?}");
    }
    (denoised_sent - start, denoised_sent.elapsed())
}

/// When one message's stages ended.
struct Timing {
    arrived: Instant,
    corrected: Instant,
    /// The two sends' durations, where the sample was published.
    publish_times: Option<(Duration, Duration)>,
    /// The writer's DDS source timestamp, ns.
    source_ns: Option<i64>,
    /// 1 while an adaptation runs, 0 otherwise (`None`: no adaptation service).
    adaptation_state: Option<usize>,
}

fn record_latency(s: &mut NodeStats, t: &Timing) {
    let in_node = t.arrived.elapsed();
    s.latency.record(in_node);
    s.stage_latency.correct.record(t.corrected - t.arrived);
    if let Some((denoised, correction)) = t.publish_times {
        s.stage_latency.publish_denoised.record(denoised);
        s.stage_latency.publish_correction.record(correction);
    }
    if let Some(src) = t.source_ns {
        s.stage_latency.dds_receive.record(Duration::from_nanos((wall_ns(t.arrived) - src).max(0) as u64));
    }
    if let Some(i) = t.adaptation_state {
        s.split_latency.in_node[i].record(in_node);
        if let Some(src) = t.source_ns {
            // Clamped at 0: the sender's clock is the same host's, but not monotonic.
            s.split_latency.write_to_publish[i].record(Duration::from_nanos((wall_ns(Instant::now()) - src).max(0) as u64));
        }
    }
}

/// One input as the loop handled it: what the status records of it.
struct Handled<'a> {
    sample: &'a ImuSample,
    arrived: Instant,
    result: &'a Result<CorrectedImu, crate::infer::Dropped>,
    frame_changed: bool,
}

/// The pipeline's state after one message, into the statistics /diagnostics reads.
fn record_status(
    s: &mut NodeStats,
    pipeline: &Pipeline,
    sequences: &input_sequence::InputSequences,
    frames: &FrameTracker,
    handled: &Handled<'_>,
) {
    let Handled { sample, arrived, result, frame_changed } = *handled;
    s.counters = pipeline.counters().clone();
    s.input_sequences.clone_from(sequences);
    if frame_changed {
        s.frame_changes += 1;
    }
    if let Some(f) = &frames.last {
        if s.frame_id != *f {
            s.frame_id.clone_from(f);
        }
    }
    s.last_stamp_ns = sample.stamp_ns;
    s.last_input_ns = Some(status_clock_ns(arrived));
    s.warming_up = result.as_ref().is_ok_and(|c| c.warming_up);
    say_rate_changes(s, pipeline);
    s.resampling = pipeline.resampling();
    s.take_orientation(pipeline);
    s.take_power_on(pipeline);
    s.rate_off_nominal = pipeline.rate_off_nominal();
}

/// Said once in the log when it starts (/diagnostics alone was easy to miss): the input fed to
/// the model in its periods, or back at its rate; an input rate off nominal, not resampled.
fn say_rate_changes(s: &NodeStats, pipeline: &Pipeline) {
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
    if pipeline.rate_off_nominal() && !s.rate_off_nominal && !pipeline.resampling() {
        tracing::warn!(
            "input rate off nominal: {:.1} Hz against the {:.1} Hz {}; a model counts samples, so its window now spans another time",
            pipeline.input_rate_hz().unwrap_or(f64::NAN),
            pipeline.nominal_rate_hz().unwrap_or(f64::NAN),
            if pipeline.corrector_rate_hz().is_some() { "the model was trained at" } else { "first measured" }
        );
    }
}

/// The wall clock at `at` (an instant just taken), ns since the Unix epoch: what a DDS source
/// timestamp is compared with.
fn wall_ns(at: Instant) -> i64 {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
    now - i64::try_from(at.elapsed().as_nanos()).unwrap_or(0)
}

/// The input's frame_id, and its changes said in the log.
#[derive(Default)]
struct FrameTracker {
    last: Option<String>,
    warnings: FrameWarnings,
}

impl FrameTracker {
    /// True where `frame_id` differs from the last message's (not at the first).
    fn observe(&mut self, arrived: Instant, frame_id: &str) -> bool {
        if self.last.as_deref() == Some(frame_id) {
            return false;
        }
        let changed = self.last.is_some();
        if changed {
            self.warnings.changed(arrived, self.last.as_deref().unwrap_or_default(), frame_id);
        }
        self.last = Some(frame_id.to_string());
        changed
    }
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

    #[test]
    fn a_frame_change_is_counted_from_the_second_frame_on() {
        let mut f = FrameTracker::default();
        let now = Instant::now();
        assert!(!f.observe(now, "imu_link"), "the first frame is no change");
        assert!(!f.observe(now, "imu_link"));
        assert!(f.observe(now, "imu_2"));
        assert!(f.observe(now, "imu_link"));
        assert_eq!(f.last.as_deref(), Some("imu_link"));
        assert_eq!(f.warnings.since, 1, "the second change within 10 s is counted, not said");
    }
}
