//! The node's DDS endpoints, made from its parameters: the input, the outputs and
//! /diagnostics; the ground truth and `~/adapt` where adaptation is served; `~/retake_power_on_bias`
//! where the power-on bias is measured; and the node's own endpoints as discovery names them
//! (what [`super::peer_check`] compares peers against).

use ros2_client::service::Server;
use ros2_client::{MessageTypeName, Node, NodeName, Publisher, QosProfile, Subscription};

use super::adaptation::GroundTruthSub;
use super::log_throttle::{self, LogThrottle};
use super::messages::{topic_name, type_name, TriggerRequest, TriggerResponse};
use super::peer_check::OwnEndpoint;
use super::{power_on, sensor_data_qos, NodeError, NodeParams};
use crate::msg::{DiagnosticArray, Imu, Odometry, PoseStamped, Vector3Stamped};

/// Which services the node offers besides the topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Served {
    /// No `~/adapt`.
    Plain,
    /// `~/adapt`, answering every call that it cannot adapt (no model): no ground truth read.
    RefusingAdaptation,
    /// `~/adapt` and the ground truth it adapts on.
    Adaptation,
}

pub(super) struct Endpoints {
    pub subscription: Subscription<Imu>,
    pub out_pub: Publisher<Imu>,
    pub corr_pub: Publisher<Vector3Stamped>,
    pub diag_pub: Publisher<DiagnosticArray>,
    pub gt_source: Option<GroundTruthSub>,
    pub server: Option<Server<TriggerRequest, TriggerResponse>>,
    pub retake_server: Option<Server<TriggerRequest, TriggerResponse>>,
    /// The node's topics as discovery names them.
    pub own: Vec<OwnEndpoint>,
    /// The input's among them (what its writers are judged against).
    pub own_input: OwnEndpoint,
}

impl Endpoints {
    pub(super) fn create(node: &mut Node, node_name: &NodeName, params: &NodeParams, served: Served) -> Result<Self, NodeError> {
        let depth = params.queue_depth.max(1);
        let sensor_qos = sensor_data_qos(depth);
        let reliable_qos = QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth });
        let dds = |e: ros2_client::CreateError| NodeError::Dds(format!("{e:?}"));
        let mut own = Vec::new();
        let mut topic = |name: &str, type_name: MessageTypeName, qos: &QosProfile, writes: bool| {
            let ros_name = topic_name(name)?;
            own.push(OwnEndpoint::new(&ros_name, node_name, &type_name, qos, writes));
            node.create_topic(&ros_name, type_name, qos).map_err(dds)
        };
        let input_topic = topic(&params.input_topic, type_name::<Imu>(), &sensor_qos, false)?;
        let output_topic = topic(&params.output_topic, type_name::<Imu>(), &reliable_qos, true)?;
        let correction_topic = topic(&params.correction_topic, type_name::<Vector3Stamped>(), &reliable_qos, true)?;
        let diag_topic = topic(&params.diagnostics_topic, type_name::<DiagnosticArray>(), &reliable_qos, true)?;
        let gt_qos = sensor_data_qos(depth.max(50));
        let gt_topic = match served {
            Served::Adaptation => Some(match params.ground_truth_type.as_str() {
                "geometry_msgs/msg/PoseStamped" | "geometry_msgs/PoseStamped" => {
                    (true, topic(&params.ground_truth_topic, type_name::<PoseStamped>(), &gt_qos, false)?)
                }
                "nav_msgs/msg/Odometry" | "nav_msgs/Odometry" => {
                    (false, topic(&params.ground_truth_topic, type_name::<Odometry>(), &gt_qos, false)?)
                }
                other => {
                    return Err(NodeError::Invalid {
                        what: "ground_truth_type",
                        value: other.into(),
                        why: "geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry".into(),
                    })
                }
            }),
            Served::Plain | Served::RefusingAdaptation => None,
        };
        // The input's topic was made first.
        let own_input = own[0].clone();
        let subscription = node.create_subscription::<Imu>(&input_topic, Some(sensor_qos.clone())).map_err(dds)?;
        let out_pub = node.create_publisher::<Imu>(&output_topic, Some(reliable_qos.clone())).map_err(dds)?;
        let corr_pub = node.create_publisher::<Vector3Stamped>(&correction_topic, Some(reliable_qos.clone())).map_err(dds)?;
        let diag_pub = node.create_publisher::<DiagnosticArray>(&diag_topic, Some(reliable_qos)).map_err(dds)?;
        let gt_source = match gt_topic {
            Some((true, t)) => Some(GroundTruthSub::Pose(node.create_subscription(&t, Some(gt_qos)).map_err(dds)?)),
            Some((false, t)) => Some(GroundTruthSub::Odometry(node.create_subscription(&t, Some(gt_qos)).map_err(dds)?)),
            None => None,
        };
        let server = match served {
            Served::Plain => None,
            Served::RefusingAdaptation | Served::Adaptation => {
                let name = topic_name(&format!("/{}/adapt", node_name.base_name()))?;
                Some(
                    node.create_server::<TriggerRequest, TriggerResponse>(
                        params.service_mapping.ros2(),
                        &name,
                        &ros2_client::ServiceTypeName::new("std_srvs", "Trigger"),
                        service_qos(),
                        service_qos(),
                    )
                    .map_err(dds)?,
                )
            }
        };
        let retake_server = if params.pipeline.power_on_bias {
            Some(power_on::retake_server(node, node_name.base_name(), params.service_mapping)?)
        } else {
            None
        };
        Ok(Endpoints { subscription, out_pub, corr_pub, diag_pub, gt_source, server, retake_server, own, own_input })
    }
}

/// A service's requests and replies: reliable, as ROS's service profile, and kept 100 deep
/// where ROS keeps 10, so that a burst of calls faster than the service loop takes them (or
/// than the client acknowledges the replies) is answered whole rather than thinned by a
/// history (the depth is not part of QoS matching).
pub(super) fn service_qos() -> QosProfile {
    QosProfile::publisher_default().history(ros2_client::qos::History::KeepLast { depth: 100 })
}

/// A request that does not decode (another layout under the service's type name, a wrong
/// size): counted (`service_request_errors` on /diagnostics) and logged at most a line a
/// second, whatever the rate it comes at; nothing is answered (its id is not known).
pub(super) fn bad_request(service: &str, err: &impl std::fmt::Debug, log: &mut LogThrottle, stats: &std::sync::Mutex<super::NodeStats>) {
    if let Ok(mut s) = stats.lock() {
        s.service_request_errors += 1;
    }
    if let Some(n) = log.admit(std::time::Instant::now()) {
        tracing::warn!("{service}: a request that does not decode, not answered: {err:?}{}", log_throttle::unsaid(n));
    }
}

/// Sends a service's reply, then waits [`REPLY_SPACING`]: a flood answered in one burst lost
/// 10 of 50 replies to a Cyclone DDS client in 3 of 6 runs, never repaired (tests/dds_adapt.rs,
/// the flood). A failed send is logged under `service`.
pub(super) async fn reply_spaced(
    server: &ros2_client::service::Server<TriggerRequest, TriggerResponse>,
    id: ros2_client::RmwRequestId,
    reply: TriggerResponse,
    service: &str,
) {
    if let Err(e) = server.async_send_response(id, reply).await {
        tracing::warn!("{service} response: {e:?}");
    }
    tokio::time::sleep(REPLY_SPACING).await;
}

/// The least time between two replies of a service.
const REPLY_SPACING: std::time::Duration = std::time::Duration::from_millis(1);

#[cfg(test)]
mod tests {
    use super::*;

    /// A flood of requests that do not decode: every one counted, the log throttled, nothing
    /// else of the node's state touched.
    #[test]
    fn requests_that_do_not_decode_are_counted_every_one() {
        let stats = std::sync::Mutex::new(super::super::NodeStats::default());
        let mut log = LogThrottle::new(log_throttle::LOG_EVERY);
        for _ in 0..50 {
            bad_request("~/adapt", &"CDR: unexpected end of input", &mut log, &stats);
        }
        let s = stats.lock().unwrap();
        assert_eq!(s.service_request_errors, 50);
        assert_eq!((s.adapt_calls_refused, s.power_on_bias_retake_calls, s.power_on_bias_retakes), (0, 0, 0));
        // Within the second the 49 after the first are left unsaid, and said with the next line.
        assert_eq!(log.admit(std::time::Instant::now()), None);
    }
}
