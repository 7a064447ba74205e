//! The node's share of the power-on bias: what /diagnostics says of it, and
//! `~/retake_power_on_bias` (std_srvs/Trigger), which makes the node forget the bias measured
//! so the next standstill measures it afresh: after the IMU was power-cycled under a running
//! node, or a standstill the user knows was not one.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::log_throttle::{self, LogThrottle, LOG_EVERY};

use super::{topic_name, NodeError, NodeStats, ServiceMapping, TriggerRequest, TriggerResponse};
use crate::infer::Pipeline;

/// The reply to a re-take.
pub const RETAKE_REPLY: &str =
    "power-on bias forgotten: the next standstill (0.5 s or more at rest) measures it afresh; until then only what gravity reveals of it in motion is removed";

type Server = ros2_client::service::Server<TriggerRequest, TriggerResponse>;

/// The `~/retake_power_on_bias` server (the `service_mapping` of `~/adapt`).
pub(super) fn retake_server(node: &mut ros2_client::Node, node_name: &str, mapping: ServiceMapping) -> Result<Server, NodeError> {
    node.create_server::<TriggerRequest, TriggerResponse>(
        mapping.ros2(),
        &topic_name(&format!("/{node_name}/retake_power_on_bias"))?,
        &ros2_client::ServiceTypeName::new("std_srvs", "Trigger"),
        super::endpoints::service_qos(),
        super::endpoints::service_qos(),
    )
    .map_err(|e| NodeError::Dds(format!("{e:?}")))
}

/// Answers every call at once; the process loop forgets the bias before its next sample (the
/// calls that reach it between two samples are one re-take). Every call is counted and its
/// caller kept for /diagnostics; a flood is logged one line a second.
pub(super) async fn retake_service_loop(server: &Server, retake: &AtomicBool, stats: &Mutex<NodeStats>) {
    let (mut log, mut bad_log) = (LogThrottle::new(LOG_EVERY), LogThrottle::new(LOG_EVERY));
    loop {
        match server.async_receive_request().await {
            Ok((id, _)) => {
                let caller = super::adaptation::caller_of(&id);
                retake.store(true, Ordering::Release);
                // At the default level: it changes what the node removes.
                if let Some(n) = log.admit(Instant::now()) {
                    tracing::warn!("~/retake_power_on_bias called by {caller}: {RETAKE_REPLY}{}", log_throttle::unsaid(n));
                }
                if let Ok(mut s) = stats.lock() {
                    s.power_on_bias_retake_calls += 1;
                    s.retake_requested_by = caller;
                }
                let reply = TriggerResponse { success: true, message: RETAKE_REPLY.into() };
                super::endpoints::reply_spaced(server, id, reply, "~/retake_power_on_bias").await;
            }
            Err(e) => super::endpoints::bad_request("~/retake_power_on_bias", &e, &mut bad_log, stats),
        }
    }
}

/// Between two samples: forget the bias, and count it.
pub(super) fn retake(pipeline: &mut Pipeline, stats: &Arc<Mutex<NodeStats>>) {
    pipeline.retake_power_on_bias();
    if let Ok(mut s) = stats.lock() {
        s.power_on_bias_retakes += 1;
    }
}

impl NodeStats {
    /// The pipeline's correction and power-on bias, as /diagnostics says them; logs a change of
    /// correction (a model swapped in) and the first power-on bias.
    pub fn take_power_on(&mut self, pipeline: &crate::infer::Pipeline) {
        let (correction, why) = pipeline.correction();
        if correction.name() != self.correction {
            tracing::info!("correction: {} ({why})", correction.name());
        }
        let estimate = pipeline.power_on_bias().copied();
        if let (false, Some(e)) = (self.power_on_bias_from.starts_with("standstill"), &estimate) {
            tracing::info!(
                "power-on gyro bias [{:.5}, {:.5}, {:.5}] rad/s measured at a standstill (σ {:.1e}){}",
                e.bias.x,
                e.bias.y,
                e.bias.z,
                e.variance.max().sqrt(),
                if correction.removes_power_on_bias() {
                    ", removed from the gyro"
                } else {
                    ": reported, not removed (the model was trained on this IMU)"
                }
            );
        }
        self.correction = correction.name();
        self.correction_reason = why;
        self.power_on_bias = pipeline.bias_in_force();
        self.standstill_bias = estimate;
        self.power_on_bias_from = pipeline.bias_source();
        self.standstills = *pipeline.standstill_counters();
        self.standing = pipeline.standing();
        let above = pipeline.rate_above_max_bias();
        if let (None, Some(r)) = (&self.rate_above_max_bias, &above) {
            tracing::warn!("no standstill taken: {}", r.says());
        }
        self.rate_above_max_bias = above;
    }
}

/// Adds this power-on's standstill estimate to the bias memory file as it is measured (on the
/// diagnostics tick, off the per-sample path). The file is read afresh before each write and
/// never overwritten when it cannot be read: what it holds is not lost.
pub(super) struct BiasMemoryWriter {
    path: std::path::PathBuf,
    started_unix_s: u64,
    /// What the memory predicted at start, said on /diagnostics.
    predicted: String,
    /// What was last written, and under which take.
    saved: Option<(crate::standstill::BiasEstimate, u64)>,
    /// The prediction, and whether this power-on's standstills contradicted it.
    prediction: Option<crate::standstill::BiasPrediction>,
    contradiction: Option<String>,
}

impl BiasMemoryWriter {
    pub(super) fn new(path: &str, pipeline: &Pipeline) -> Option<Self> {
        (!path.is_empty()).then(|| BiasMemoryWriter {
            path: path.into(),
            started_unix_s: std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()),
            predicted: pipeline
                .remembered_bias()
                .map_or_else(|| "fewer than two earlier power-ons: nothing predicted".to_string(), |p| p.describe()),
            saved: None,
            prediction: pipeline.remembered_bias().filter(|p| p.applies_any()),
            contradiction: None,
        })
    }

    /// On the diagnostics tick (`at_exit` false) and once at exit, when the last estimate is
    /// saved whatever it changed.
    pub(super) fn tick(&mut self, stats: &Mutex<NodeStats>, at_exit: bool) {
        let (estimate, retakes) = match stats.lock() {
            // A re-take on demand, or one the detector made after a hole in the input.
            Ok(s) => (s.standstill_bias, s.power_on_bias_retakes + s.standstills.new_power_ons),
            Err(_) => return,
        };
        let due = |e: &crate::standstill::BiasEstimate| match &self.saved {
            None => true,
            Some((saved, take)) => *take != retakes || (e.at_ns != saved.at_ns && (at_exit || worth_saving(saved, e))),
        };
        let saved = match estimate.filter(due) {
            None => None,
            Some(e) => {
                // A re-take follows a power cycle under the running node: a new power-on.
                let power_on = format!("node started {} s, take {}", self.started_unix_s, retakes + 1);
                let result = crate::bias_memory::BiasMemory::load(&self.path).and_then(|mut m| {
                    m.remember(&power_on, &e);
                    m.save(&self.path).map(|()| m.power_ons.len())
                });
                self.saved = Some((e, retakes));
                Some(result)
            }
        };
        let Some(saved) = saved else { return };
        if let (None, Some(p), Some(e)) = (&self.contradiction, &self.prediction, &estimate) {
            self.contradiction = p.contradicted_by(e);
            if let Some(c) = &self.contradiction {
                tracing::warn!("power_on_bias_memory {}: {c}", self.path.display());
            }
        }
        let said = self.contradiction.as_ref().map_or(String::new(), |c| format!("; {c}"));
        let note = match saved {
            Ok(n) => format!("{}{said}; this power-on's bias saved ({n} power-ons in {})", self.predicted, self.path.display()),
            Err(e) => {
                tracing::warn!("{e}");
                format!("{}{said}; not saved: {e}", self.predicted)
            }
        };
        if let Ok(mut s) = stats.lock() {
            s.power_on_bias_memory = note;
        }
    }

    pub(super) fn started(&self) -> String {
        self.predicted.clone()
    }
}

/// A standstill that goes on refines its estimate at every window; the file is rewritten only
/// where that changes what it holds: a mean moved by more than the σ saved, or a variance
/// halved. (Rewriting it at every diagnostics tick while a robot stands wore the storage for
/// nothing; what a power loss between two saves costs is a refinement, never the entry.)
fn worth_saving(saved: &crate::standstill::BiasEstimate, now: &crate::standstill::BiasEstimate) -> bool {
    (0..3).any(|k| (now.bias[k] - saved.bias[k]).abs() > saved.variance[k].sqrt() || now.variance[k] < 0.5 * saved.variance[k])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::standstill::BiasEstimate;
    use nalgebra::Vector3;

    fn writer(path: &std::path::Path) -> BiasMemoryWriter {
        BiasMemoryWriter {
            path: path.into(),
            started_unix_s: 1,
            predicted: String::new(),
            saved: None,
            prediction: None,
            contradiction: None,
        }
    }

    /// Ten minutes standing, the estimate refined every second: the file is written when it
    /// would say something new (about log₂ of the refinements), and at exit with the last one.
    #[test]
    fn a_long_standstill_rewrites_the_memory_only_when_it_says_something_new() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("bias.json");
        let mut w = writer(&path);
        let stats = Mutex::new(NodeStats::default());
        let mut writes = 0;
        let mut last = String::new();
        let estimate_after = |k: u32| BiasEstimate {
            bias: Vector3::new(0.01, -0.02, 0.003 + 1e-5 / f64::from(k)),
            variance: Vector3::repeat(1e-6 / f64::from(k)),
            at_ns: i64::from(k) * 1_000_000_000,
            still_s: f64::from(k),
        };
        for k in 1..=600 {
            stats.lock().unwrap().standstill_bias = Some(estimate_after(k));
            w.tick(&stats, false);
            let now = std::fs::read_to_string(&path).unwrap();
            if now != last {
                writes += 1;
                last = now;
            }
        }
        assert!((8..=12).contains(&writes), "{writes} writes in 600 ticks");
        w.tick(&stats, true);
        let memory = crate::bias_memory::BiasMemory::load(&path).unwrap();
        assert_eq!(memory.power_ons.len(), 1, "{memory:?}");
        assert_eq!(memory.power_ons[0].still_s, 600.0, "the exit saves the last estimate");
        // A re-take is a new power-on: saved at once, as a second entry.
        stats.lock().unwrap().power_on_bias_retakes = 1;
        w.tick(&stats, false);
        assert_eq!(crate::bias_memory::BiasMemory::load(&path).unwrap().power_ons.len(), 2);
        // So is one the detector took after a hole in the input (the IMU power-cycled).
        stats.lock().unwrap().standstills.new_power_ons = 1;
        w.tick(&stats, false);
        assert_eq!(crate::bias_memory::BiasMemory::load(&path).unwrap().power_ons.len(), 3);
    }
}
