//! The node's messages as ros2-client sees them: the `Message` impls, std_srvs/Trigger, and
//! topic and type names.

use ros2_client::{MessageTypeName, Name};
use serde::{Deserialize, Serialize};

use super::NodeError;
use crate::msg::{DiagnosticArray, Imu, RosMessage, Vector3Stamped};

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

pub(super) fn topic_name(name: &str) -> Result<Name, NodeError> {
    Name::parse(name).map_err(|e| NodeError::TopicName { name: name.into(), why: format!("{e:?}") })
}

pub(super) fn type_name<M: RosMessage>() -> MessageTypeName {
    ros_type_name(M::TYPE_NAME)
}

/// `pkg/msg/Name` → ros2-client's type name.
pub fn ros_type_name(ros: &str) -> MessageTypeName {
    let pkg = ros.split('/').next().unwrap_or("");
    let name = ros.rsplit('/').next().unwrap_or("");
    MessageTypeName::new(pkg, name)
}
