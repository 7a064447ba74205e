//! The ROS environment the node runs in (`ROS_DOMAIN_ID`, loopback only, what SROS2 asks for)
//! and the sensor-data QoS.

use std::path::{Path, PathBuf};

use ros2_client::dds::rustdds::DomainParticipantSecurityConfigFiles;
use ros2_client::{Context, QosProfile};

use super::NodeError;

/// Which DDS domain and network the environment asks for: `ROS_DOMAIN_ID`, and
/// `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST|OFF` for loopback only;
/// and whether DDS Security runs, from `ROS_SECURITY_*` as rcl reads them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosEnvironment {
    pub domain_id: u16,
    pub localhost_only: bool,
    /// What the node says of DDS Security on /diagnostics: empty when not asked for.
    pub security: String,
    /// The enclave's folder of security files when DDS Security runs.
    pub security_files: Option<PathBuf>,
}

/// The six files rmw_dds_common reads from an enclave's folder.
const SECURITY_FILES: [&str; 6] =
    ["identity_ca.cert.pem", "cert.pem", "key.pem", "permissions_ca.cert.pem", "governance.p7s", "permissions.p7s"];

/// DDS Security as rcl sets it up: on when `ROS_SECURITY_ENABLE=true`; the enclave's folder is
/// `$ROS_SECURITY_KEYSTORE/enclaves/<enclave>`, the enclave `ROS_SECURITY_ENCLAVE_OVERRIDE`, else
/// `--enclave`, else `/`. Under `Enforce` a missing keystore, folder or file stops the node
/// (never plain DDS where security is enforced); under `Permissive` (rcl's default) the node
/// then runs unsecured and says so. Files that are there but wrong stop it under both, as rmw.
fn security(get: &impl Fn(&str) -> Option<String>, enclave_arg: Option<&str>) -> Result<(String, Option<PathBuf>), NodeError> {
    if get("ROS_SECURITY_ENABLE").is_none_or(|v| v.trim() != "true") {
        return Ok((String::new(), None));
    }
    let enforce = match get("ROS_SECURITY_STRATEGY").unwrap_or_default().trim() {
        "Enforce" => true,
        "" | "Permissive" => false,
        other => return Err(NodeError::Environment(format!("ROS_SECURITY_STRATEGY={other} is neither Enforce nor Permissive"))),
    };
    let enclave = get("ROS_SECURITY_ENCLAVE_OVERRIDE")
        .filter(|e| !e.trim().is_empty())
        .or_else(|| enclave_arg.map(str::to_string))
        .unwrap_or_else(|| "/".into());
    let found = enclave_folder(get("ROS_SECURITY_KEYSTORE").unwrap_or_default().trim(), &enclave);
    match (found, enforce) {
        (Ok(dir), _) => {
            let strategy = if enforce { "Enforce" } else { "Permissive" };
            Ok((format!("on: enclave {enclave} ({}), {strategy}", dir.display()), Some(dir)))
        }
        (Err(why), true) => Err(NodeError::Environment(format!(
            "ROS_SECURITY_ENABLE=true with ROS_SECURITY_STRATEGY=Enforce: {why}; the node does not start on plain DDS where security is enforced"
        ))),
        (Err(why), false) => Ok((format!("off: ROS_SECURITY_ENABLE=true under the Permissive strategy, but {why}: the node runs unsecured"), None)),
    }
}

/// `keystore/enclaves/<enclave>` with the six files there, or what is missing.
fn enclave_folder(keystore: &str, enclave: &str) -> Result<PathBuf, String> {
    if keystore.is_empty() {
        return Err("ROS_SECURITY_KEYSTORE is not set".into());
    }
    if !enclave.starts_with('/') || enclave.split('/').any(|part| part == "..") {
        return Err(format!("the enclave {enclave:?} is not an absolute name such as /imu_fsda"));
    }
    let dir = Path::new(keystore).join("enclaves").join(enclave.trim_start_matches('/'));
    if !dir.is_dir() {
        return Err(format!("the enclave's folder {} does not exist", dir.display()));
    }
    let missing: Vec<&str> = SECURITY_FILES.iter().copied().filter(|f| !dir.join(f).is_file()).collect();
    if !missing.is_empty() {
        return Err(format!("{} lacks {}", dir.display(), missing.join(", ")));
    }
    Ok(dir)
}

impl RosEnvironment {
    /// The environment of this process; `enclave` is `--enclave` (rcl's `--ros-args --enclave`).
    pub fn from_env(enclave: Option<&str>) -> Result<Self, NodeError> {
        Self::from_vars(|k| std::env::var(k).ok(), enclave)
    }

    pub fn from_vars(get: impl Fn(&str) -> Option<String>, enclave: Option<&str>) -> Result<Self, NodeError> {
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
        let (security, security_files) = security(&get, enclave)?;
        match (&security_files, security.is_empty()) {
            (Some(_), _) => tracing::info!("DDS Security {security}"),
            (None, false) => tracing::warn!("DDS Security {security}"),
            (None, true) => {}
        }
        Ok(RosEnvironment { domain_id, localhost_only, security, security_files })
    }

    /// A ros2-client context on this domain (loopback only when asked), secured when asked.
    pub fn context(&self) -> Result<Context, NodeError> {
        let mut b = ros2_client::dds::rustdds::DomainParticipantBuilder::new(self.domain_id);
        if self.localhost_only {
            b = b.with_only_networks([std::net::IpAddr::from([127, 0, 0, 1])]);
        }
        if let Some(dir) = &self.security_files {
            // SROS2's keys are not encrypted: no password.
            b = b.builtin_security(DomainParticipantSecurityConfigFiles::with_ros_default_names(dir, String::new()));
        }
        let dp = b.build().map_err(|e| match &self.security_files {
            Some(dir) => NodeError::Environment(format!("DDS Security with the files in {}: {e}", dir.display())),
            None => NodeError::Dds(format!("domain participant: {e:?}")),
        })?;
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

    fn vars<'a>(pairs: &'a [(&'static str, String)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |k: &str| pairs.iter().find(|(a, _)| *a == k).map(|(_, v)| v.clone())
    }

    fn owned(pairs: &[(&'static str, &str)]) -> Vec<(&'static str, String)> {
        pairs.iter().map(|(k, v)| (*k, v.to_string())).collect()
    }

    #[test]
    fn environment() {
        let plain = RosEnvironment::from_vars(vars(&[]), None).unwrap();
        assert_eq!(plain, RosEnvironment { domain_id: 0, localhost_only: false, security: String::new(), security_files: None });
        let e = RosEnvironment::from_vars(vars(&owned(&[("ROS_DOMAIN_ID", "42"), ("ROS_LOCALHOST_ONLY", "1")])), None).unwrap();
        assert_eq!((e.domain_id, e.localhost_only), (42, true));
        assert!(RosEnvironment::from_vars(vars(&owned(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "localhost")])), None).unwrap().localhost_only);
        assert!(RosEnvironment::from_vars(vars(&owned(&[("ROS_DOMAIN_ID", "abc")])), None).is_err());
        assert!(RosEnvironment::from_vars(vars(&owned(&[("ROS_DOMAIN_ID", "300")])), None).is_err());
    }

    /// An enclave's folder with the six files rmw reads (their content is not looked at here).
    fn keystore_with(enclave: &str, files: &[&str]) -> tempfile::TempDir {
        let ks = tempfile::tempdir().unwrap();
        let dir = ks.path().join("enclaves").join(enclave.trim_start_matches('/'));
        std::fs::create_dir_all(&dir).unwrap();
        for f in files {
            std::fs::write(dir.join(f), "x").unwrap();
        }
        ks
    }

    /// Security asked for and enforced without its files: a clear error naming what is missing,
    /// never plain DDS; permissive: unsecured, said; found: the enclave's folder, as rcl finds it.
    #[test]
    fn enforced_security_without_its_files_is_refused_not_ignored() {
        let enforced = |keystore: &str| {
            owned(&[("ROS_SECURITY_ENABLE", "true"), ("ROS_SECURITY_STRATEGY", "Enforce"), ("ROS_SECURITY_KEYSTORE", keystore)])
        };
        let e = RosEnvironment::from_vars(vars(&enforced("/nonexistent")), None).unwrap_err().to_string();
        assert!(e.contains("Enforce") && e.contains("/nonexistent/enclaves") && e.contains("does not start on plain DDS"), "{e}");
        let partial = keystore_with("/imu_fsda", &SECURITY_FILES[..4]);
        let ks = partial.path().to_str().unwrap();
        let e = RosEnvironment::from_vars(vars(&enforced(ks)), Some("/imu_fsda")).unwrap_err().to_string();
        assert!(e.contains("lacks governance.p7s, permissions.p7s"), "{e}");
        let permissive = RosEnvironment::from_vars(vars(&owned(&[("ROS_SECURITY_ENABLE", "true")])), None).unwrap();
        assert!(permissive.security.contains("runs unsecured") && permissive.security_files.is_none(), "{}", permissive.security);
        let disabled = owned(&[("ROS_SECURITY_ENABLE", "false"), ("ROS_SECURITY_STRATEGY", "Enforce")]);
        assert!(RosEnvironment::from_vars(vars(&disabled), None).unwrap().security.is_empty());
        let strict = owned(&[("ROS_SECURITY_ENABLE", "true"), ("ROS_SECURITY_STRATEGY", "Strict")]);
        assert!(RosEnvironment::from_vars(vars(&strict), None).is_err());

        let full = keystore_with("/robot/imu_fsda", &SECURITY_FILES);
        let ks = full.path().to_str().unwrap();
        let found = RosEnvironment::from_vars(vars(&enforced(ks)), Some("/robot/imu_fsda")).unwrap();
        assert_eq!(found.security_files.as_deref(), Some(full.path().join("enclaves/robot/imu_fsda").as_path()));
        assert!(found.security.starts_with("on: enclave /robot/imu_fsda"), "{}", found.security);
        // The override wins over --enclave, as in rcl; a relative or climbing name is refused.
        let mut overridden = enforced(ks);
        overridden.push(("ROS_SECURITY_ENCLAVE_OVERRIDE", "/robot/imu_fsda".into()));
        assert!(RosEnvironment::from_vars(vars(&overridden), Some("/other")).unwrap().security_files.is_some());
        assert!(RosEnvironment::from_vars(vars(&enforced(ks)), Some("robot/imu_fsda")).is_err());
        assert!(RosEnvironment::from_vars(vars(&enforced(ks)), Some("/robot/../robot/imu_fsda")).is_err());
    }
}
