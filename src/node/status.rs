//! What /diagnostics says: the node's statistics, its liveness (input stale, events) and the
//! DiagnosticArray built from them.

use super::latency::{LatencyHistogram, SplitLatency, StageLatency};
use crate::infer::Counters;
use crate::msg::{DiagnosticArray, DiagnosticStatus, Header, KeyValue, Time};

/// Longest `diagnostics_period`, s.
pub const MAX_DIAGNOSTICS_PERIOD_S: f64 = 86_400.0;

/// What the diagnostics report (shared between the processing and diagnostics tasks).
#[derive(Debug, Default)]
pub struct NodeStats {
    pub counters: Counters,
    /// The gravity-aided attitude's blocks used and left out (`orientation: gravity_aided`);
    /// `None`: the orientation is integrated open loop.
    pub gravity_aided_blocks: Option<(u64, u64)>,
    /// The gravity-aided filter's forward speed and its σ, m/s (`platform: car`).
    pub forward_speed: Option<(f64, f64)>,
    /// Seconds the gravity-aided attitude was run again over at the first standstill.
    pub attitude_hindsight_s: Option<f64>,
    pub latency: LatencyHistogram,
    pub frame_changes: u64,
    pub decode_errors: u64,
    /// Input samples from a writer whose discovered type is not the node's ([`super::peer_check::InputWriters`]).
    pub dropped_wrong_type: u64,
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
    /// A still body read at a steady rate above `standstill.max_bias` (said only when one was).
    pub rate_above_max_bias: Option<crate::standstill::RateAboveMaxBias>,
    /// Times `~/retake_power_on_bias` made the node forget the power-on bias (the calls
    /// between two samples are one).
    pub power_on_bias_retakes: u64,
    /// Service requests that did not decode (either service), every one.
    pub service_request_errors: u64,
    /// Calls of `~/retake_power_on_bias`, every one; and the last caller.
    pub power_on_bias_retake_calls: u64,
    pub retake_requested_by: String,
    /// Run-time parameters set by clients (`ros2 param set`) since the start.
    pub parameters_set: u64,
    /// What the bias memory (`power_on_bias_memory`) predicted at start and whether this
    /// power-on's bias was saved to it (empty: no memory).
    pub power_on_bias_memory: String,
    pub model: String,
    pub window: usize,
    pub model_status: String,
    /// Adaptation (empty when the service is off): idle / running / the last result.
    pub adapt_status: String,
    /// DDS Security as the environment set it up ([`super::RosEnvironment`]): empty when not asked for.
    pub security: String,
    /// The input writers' sequence numbers: what DDS lost before and after the first sample.
    pub input_sequences: super::InputSequences,
    pub adaptations: u64,
    pub adapt_query_aoe_before_deg: Option<f64>,
    pub adapt_query_aoe_after_deg: Option<f64>,
    pub adapt_seconds: Option<f64>,
    /// The DDS identity of the last `~/adapt` caller ([`super::adaptation::caller_of`]).
    pub adapt_requested_by: String,
    /// `~/adapt` calls refused (one already running, or the service cannot adapt): counted
    /// every one, logged at most once a second.
    pub adapt_calls_refused: u64,
    /// Latencies split by adaptation state (recorded only when the service is on).
    pub split_latency: SplitLatency,
    /// The in-node latency by stage, and DDS receive before it.
    pub stage_latency: StageLatency,
    /// The node stopped while an adaptation ran on its thread and the thread did not stop at
    /// its next step in time (it is cancelled and joined otherwise): the running model
    /// unchanged. The process must then end without running libtorch's exit-time destructors
    /// under that thread (it crashed with SIGSEGV): see `imu-fsda node`.
    pub adaptation_abandoned: bool,
    /// Peers on the node's topics that cannot work with it ([`super::peer_check`]).
    pub incompatible_peers: IncompatiblePeers,
    /// Readers matched to /imu/denoised and /imu/gyro_correction at the last diagnostics tick.
    /// A sample published before a reader is matched is, by DDS's volatile durability, not
    /// for it: a peer that must see every output waits for its own reader to be counted here.
    pub subscription_counts: SubscriptionCounts,
    /// Outputs published on /imu/denoised before any reader had matched it (nobody got them).
    pub denoised_before_a_reader: u64,
}

impl NodeStats {
    /// Which orientation the pipeline publishes, for /diagnostics `orientation`.
    pub fn take_orientation(&mut self, pipeline: &crate::infer::Pipeline) {
        self.gravity_aided_blocks = pipeline.gravity_aided_blocks();
        self.forward_speed = pipeline.gravity_aided_forward_speed();
        self.attitude_hindsight_s = pipeline.attitude_hindsight_s();
    }
}

/// How many readers each output topic has matched (ROS's "subscription count").
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct SubscriptionCounts {
    pub denoised: usize,
    pub correction: usize,
}

/// What [`super::peer_check::PeerCheck`] found, as the status shows it.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct IncompatiblePeers {
    /// Found since the start, each once.
    pub said: u64,
    /// In discovery now, and the first few of them described.
    pub present: usize,
    pub described: Vec<String>,
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
    let (level, message) = level_and_message(stats, live);
    let mut values = key_values(stats, live);
    adaptation_values(stats, &mut values);
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

/// The status's level and one-line message: the worst news first.
fn level_and_message(stats: &NodeStats, live: &Liveness) -> (u8, String) {
    let c = &stats.counters;
    let recent = live.since_event_s.is_some_and(|s| s < EVENT_WARN_S);
    // A driver gone silent is the worst news, whatever the model's state.
    if let Some(s) = live.since_input_s.filter(|s| *s > INPUT_STALE_AFTER_S && c.received > 0) {
        let model = if stats.model_status != "ok" { format!("; {}", stats.model_status) } else { String::new() };
        (DiagnosticStatus::ERROR, format!("no input for {s:.1} s{model}"))
    } else if stats.model_status != "ok" {
        (DiagnosticStatus::WARN, stats.model_status.clone())
    } else if let Some(first) = stats.incompatible_peers.described.first() {
        // Before "no input yet": a writer of another type on the input is often why.
        let n = stats.incompatible_peers.present;
        (DiagnosticStatus::WARN, format!("{n} peer(s) on its topics cannot work with it: {first}"))
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
    }
}

fn kv(k: &str, v: String) -> KeyValue {
    KeyValue { key: k.into(), value: v }
}

/// The values every status carries, and those present only when they say something.
fn key_values(stats: &NodeStats, live: &Liveness) -> Vec<KeyValue> {
    let c = &stats.counters;
    let mut values = vec![
        kv("model", stats.model.clone()),
        kv("window_samples", stats.window.to_string()),
        kv("input_rate_hz", format!("{:.2}", live.input_rate_hz)),
        kv("resampled_to_model_rate", stats.resampling.to_string()),
        kv("correction", stats.correction.to_string()),
        kv("correction_reason", stats.correction_reason.to_string()),
        kv(
            "orientation",
            match stats.gravity_aided_blocks {
                None => "open loop".to_string(),
                Some((used, left_out)) => {
                    let car = stats.forward_speed.map_or(String::new(), |(u, s)| format!("; a car, forward speed {u:.1} ± {s:.1} m/s"));
                    let hindsight = stats
                        .attitude_hindsight_s
                        .map_or(String::new(), |s| format!("; its first {s:.1} s run again with the first standstill's bias"));
                    format!("gravity aided: {used} blocks of gravity used, {left_out} left out{car}{hindsight}")
                }
            },
        ),
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
        kv("power_on_bias_retake_calls", stats.power_on_bias_retake_calls.to_string()),
        kv("power_on_bias_new_power_ons", stats.standstills.new_power_ons.to_string()),
        kv("retake_requested_by", stats.retake_requested_by.clone()),
        kv("service_request_errors", stats.service_request_errors.to_string()),
        kv("parameters_set", stats.parameters_set.to_string()),
        kv("power_on_bias_memory", stats.power_on_bias_memory.clone()),
        kv("latency_p50_us", format!("{:.0}", stats.latency.quantile_us(0.5))),
        kv("latency_p99_us", format!("{:.0}", stats.latency.quantile_us(0.99))),
        kv("received", c.received.to_string()),
        kv("published", c.processed.to_string()),
        kv("dropped_non_finite", c.dropped_non_finite.to_string()),
        kv("dropped_implausible", c.dropped_implausible.to_string()),
        kv("dropped_duplicate_stamp", c.dropped_duplicate_stamp.to_string()),
        kv("dropped_backwards_stamp", c.dropped_backwards_stamp.to_string()),
        kv("decode_errors", stats.decode_errors.to_string()),
        kv("dropped_wrong_type", stats.dropped_wrong_type.to_string()),
        kv("input_writers", stats.input_sequences.writers().to_string()),
        kv("denoised_subscription_count", stats.subscription_counts.denoised.to_string()),
        kv("correction_subscription_count", stats.subscription_counts.correction.to_string()),
        kv("denoised_published_before_a_reader", stats.denoised_before_a_reader.to_string()),
        kv("input_published_before_first", stats.input_sequences.before_first.to_string()),
        kv("input_lost", stats.input_sequences.lost.to_string()),
        kv("input_out_of_order", stats.input_sequences.out_of_order.to_string()),
        kv("gaps_reset", c.gaps.to_string()),
        kv("clock_jumps", c.clock_jumps.to_string()),
        kv("rate_changes", c.rate_changes.to_string()),
        kv("frame_id_changes", stats.frame_changes.to_string()),
        kv("warmup_samples", c.warmup_samples.to_string()),
        kv("missed_samples", c.missed_samples.to_string()),
        kv("saturated_samples", c.saturated_samples.to_string()),
        kv("incompatible_peers", stats.incompatible_peers.present.to_string()),
        kv("incompatible_peers_said", stats.incompatible_peers.said.to_string()),
    ];
    if let Some(r) = &stats.rate_above_max_bias {
        values.push(kv("rate_above_max_bias", r.says()));
    }
    if !stats.incompatible_peers.described.is_empty() {
        values.push(kv("incompatible_peer_list", stats.incompatible_peers.described.join("; ")));
    }
    if !stats.security.is_empty() {
        values.push(kv("security", stats.security.clone()));
    }
    values
}

/// What the adaptation service did, when it is on.
fn adaptation_values(stats: &NodeStats, values: &mut Vec<KeyValue>) {
    if stats.adapt_status == super::ADAPTATION_OFF {
        values.push(kv("adaptation", stats.adapt_status.clone()));
    } else if !stats.adapt_status.is_empty() {
        let f = |v: Option<f64>| v.map_or(String::new(), |x| format!("{x:.3}"));
        values.push(kv("adaptation", stats.adapt_status.clone()));
        values.push(kv("adaptations", stats.adaptations.to_string()));
        values.push(kv("adapt_query_aoe_before_deg", f(stats.adapt_query_aoe_before_deg)));
        values.push(kv("adapt_query_aoe_after_deg", f(stats.adapt_query_aoe_after_deg)));
        values.push(kv("adapt_seconds", f(stats.adapt_seconds)));
        values.push(kv("adapt_requested_by", stats.adapt_requested_by.clone()));
        values.push(kv("adapt_calls_refused", stats.adapt_calls_refused.to_string()));
        for (i, state) in ["idle", "adapting"].iter().enumerate() {
            let h = &stats.split_latency.in_node[i];
            values.push(kv(&format!("latency_{state}_p99_us"), format!("{:.0}", h.quantile_us(0.99))));
            values.push(kv(&format!("latency_{state}_max_us"), format!("{:.0}", h.max_us())));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
