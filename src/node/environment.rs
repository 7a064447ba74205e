//! The ROS environment the node runs in (`ROS_DOMAIN_ID`, loopback only, what SROS2 asks for)
//! and the sensor-data QoS.

use ros2_client::{Context, QosProfile};

use super::NodeError;

/// Which DDS domain and network the environment asks for: `ROS_DOMAIN_ID`, and
/// `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST|OFF` for loopback only.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosEnvironment {
    pub domain_id: u16,
    pub localhost_only: bool,
    /// What the node says of DDS Security (`ROS_SECURITY_*`): empty when not asked for.
    pub security: String,
}

/// `ROS_SECURITY_ENABLE=true` read as rcl reads it. The node does not run DDS Security: under
/// `Enforce` (what a secured robot sets) it refuses to start, never falling back to plain DDS
/// without a word; under `Permissive` (rcl's default strategy: security where its files are
/// found) it runs unsecured and says so at start and on /diagnostics.
fn security(get: &impl Fn(&str) -> Option<String>) -> Result<String, NodeError> {
    if get("ROS_SECURITY_ENABLE").is_none_or(|v| v.trim() != "true") {
        return Ok(String::new());
    }
    let keystore = get("ROS_SECURITY_KEYSTORE").unwrap_or_default();
    match get("ROS_SECURITY_STRATEGY").unwrap_or_default().trim() {
        "Enforce" => Err(NodeError::Environment(format!(
            "ROS_SECURITY_ENABLE=true with ROS_SECURITY_STRATEGY=Enforce (keystore {keystore:?}): this node does not implement DDS Security, and does not start on plain DDS where security is enforced"
        ))),
        "" | "Permissive" => Ok(format!(
            "off: ROS_SECURITY_ENABLE=true under the Permissive strategy, but this node does not implement DDS Security: it runs unsecured (keystore {keystore:?} not used)"
        )),
        other => Err(NodeError::Environment(format!("ROS_SECURITY_STRATEGY={other} is neither Enforce nor Permissive"))),
    }
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
        let security = security(&get)?;
        if !security.is_empty() {
            tracing::warn!("DDS Security {security}");
        }
        Ok(RosEnvironment { domain_id, localhost_only, security })
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn environment() {
        let env =
            |pairs: &'static [(&'static str, &'static str)]| move |k: &str| pairs.iter().find(|(a, _)| *a == k).map(|(_, v)| v.to_string());
        assert_eq!(
            RosEnvironment::from_vars(env(&[])).unwrap(),
            RosEnvironment { domain_id: 0, localhost_only: false, security: String::new() }
        );
        assert_eq!(
            RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "42"), ("ROS_LOCALHOST_ONLY", "1")])).unwrap(),
            RosEnvironment { domain_id: 42, localhost_only: true, security: String::new() }
        );
        assert!(RosEnvironment::from_vars(env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "localhost")])).unwrap().localhost_only);
        assert!(RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "abc")])).is_err());
        assert!(RosEnvironment::from_vars(env(&[("ROS_DOMAIN_ID", "300")])).is_err());
    }

    /// Security asked for and enforced: a clear error, never plain DDS; permissive: said.
    #[test]
    fn enforced_security_is_refused_not_ignored() {
        let env =
            |pairs: &'static [(&'static str, &'static str)]| move |k: &str| pairs.iter().find(|(a, _)| *a == k).map(|(_, v)| v.to_string());
        const ENFORCED: &[(&str, &str)] =
            &[("ROS_SECURITY_ENABLE", "true"), ("ROS_SECURITY_STRATEGY", "Enforce"), ("ROS_SECURITY_KEYSTORE", "/nonexistent")];
        let e = RosEnvironment::from_vars(env(ENFORCED)).unwrap_err().to_string();
        assert!(e.contains("Enforce") && e.contains("does not start on plain DDS"), "{e}");
        let permissive = RosEnvironment::from_vars(env(&[("ROS_SECURITY_ENABLE", "true")])).unwrap();
        assert!(permissive.security.contains("runs unsecured"), "{}", permissive.security);
        assert!(RosEnvironment::from_vars(env(&[("ROS_SECURITY_ENABLE", "false"), ("ROS_SECURITY_STRATEGY", "Enforce")]))
            .unwrap()
            .security
            .is_empty());
        assert!(RosEnvironment::from_vars(env(&[("ROS_SECURITY_ENABLE", "true"), ("ROS_SECURITY_STRATEGY", "Strict")])).is_err());
    }
}
