//! The node's parameters (`params/imu_fsda.yaml`): reading, checking, remapping, and the rule
//! for relative paths (the file's own folder's).

use crate::setting::InvalidSetting;
use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::status::MAX_DIAGNOSTICS_PERIOD_S;
use super::NodeError;
use crate::infer::PipelineConfig;

/// How the node's services (`~/adapt`, `~/retake_power_on_bias`) sit on DDS: the request id
/// as the related sample identity (`enhanced`: rmw_fastrtps, rmw_connextdds) or in a header in
/// the payload (`cyclone`: rmw_cyclonedds). One per node: a client of the other mapping gets no
/// answer (docs/interop.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ServiceMapping {
    #[default]
    Enhanced,
    Cyclone,
}

impl ServiceMapping {
    pub fn ros2(self) -> ros2_client::service::ServiceMapping {
        match self {
            ServiceMapping::Enhanced => ros2_client::service::ServiceMapping::Enhanced,
            ServiceMapping::Cyclone => ros2_client::service::ServiceMapping::Cyclone,
        }
    }
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
    /// The services' DDS mapping: that of the clients' middleware.
    pub service_mapping: ServiceMapping,
    /// The per-sample pipeline: gaps, rate checks, covariances, initial attitude.
    pub pipeline: PipelineConfig,
    /// On-demand adaptation (`~/adapt` and the ground-truth subscription): off unless the
    /// parameter file turns it on. Whoever publishes the ground truth and calls `~/adapt`
    /// chooses the model the node runs, so a node does not offer it by default.
    pub adapt_enabled: bool,
    /// Ground truth for on-demand adaptation (`~/adapt`, std_srvs/srv/Trigger), buffered with
    /// the input; its type is `ground_truth_type` (geometry_msgs/msg/PoseStamped or
    /// nav_msgs/msg/Odometry). Read only with `adapt_enabled`.
    pub ground_truth_topic: String,
    pub ground_truth_type: String,
    /// Newest seconds of input and ground truth kept for adaptation (bounded ring buffers).
    pub adapt_buffer_seconds: f64,
    /// Of the buffered data, the first `adapt_support_seconds` adapt the model, the rest judges it.
    pub adapt_support_seconds: f64,
    /// Where adapted models are written (`<model name>-adapted-<unix s>.{pt,ot,json}`); empty:
    /// beside the model. Set `model` to one to start with it.
    pub adapted_model_dir: String,
    /// A folder (one per IMU) where each `~/adapt` call's buffered IMU and ground truth are
    /// kept as a bag; a later power-on's `~/adapt` judges what it learns on the newest
    /// `adapt_judge_power_ons` earlier ones there, and only then may it keep what needs them
    /// (the bias offset in motion). Empty: none kept, judged on this power-on alone.
    pub adapt_support_archive: String,
    /// Earlier power-ons in `adapt_support_archive` an adaptation is judged on (the newest).
    pub adapt_judge_power_ons: usize,
    /// The gyro's turn-on bias at earlier power-ons of this IMU (a JSON file,
    /// [`crate::bias_memory`]): read at start, what they predict is removed before the first
    /// standstill; this power-on's standstill estimate is added to it as it is measured.
    /// Empty: none.
    pub power_on_bias_memory: String,
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
            service_mapping: ServiceMapping::Enhanced,
            pipeline: PipelineConfig::default(),
            adapt_enabled: false,
            ground_truth_topic: "/ground_truth/pose".into(),
            ground_truth_type: "geometry_msgs/msg/PoseStamped".into(),
            adapt_buffer_seconds: 120.0,
            adapt_support_seconds: 60.0,
            adapted_model_dir: String::new(),
            adapt_support_archive: String::new(),
            adapt_judge_power_ons: 3,
            power_on_bias_memory: String::new(),
            adapt: crate::adapt::AdaptConfig::default(),
            adapt_thread_nice: 10,
        }
    }
}

impl NodeParams {
    /// Read the `node_name: ros__parameters:` section of a ROS 2 parameter file. `/**` (any
    /// node) is accepted too, as ROS 2 does.
    /// Reads the node's section of a parameter file. Relative paths in it (`model`,
    /// `adapted_model_dir`, `adapt_support_archive`, `power_on_bias_memory`) are taken against the file's own folder, as cargo and docker
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
        for value in [&mut params.model, &mut params.adapted_model_dir, &mut params.adapt_support_archive, &mut params.power_on_bias_memory]
        {
            if !value.is_empty() && Path::new(value.as_str()).is_relative() {
                *value = folder.join(value.as_str()).to_string_lossy().into_owned();
            }
        }
        Ok(params)
    }

    /// Reads `power_on_bias_memory` (if set) into the pipeline's standstill settings: what
    /// earlier power-ons predict for this one. Returns the note for the log and /diagnostics.
    pub fn take_bias_memory(&mut self, set_aside: bool) -> Result<Option<String>, crate::bias_memory::BiasMemoryError> {
        if self.power_on_bias_memory.is_empty() {
            return Ok(None);
        }
        let standstill = &mut self.pipeline.standstill;
        let (prediction, note) =
            crate::bias_memory::prediction_at_start(Path::new(&self.power_on_bias_memory), standstill.min_power_on_spread, set_aside)?;
        standstill.remembered = prediction;
        Ok(Some(note))
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
        let mut params = doc[key].get("ros__parameters").cloned().unwrap_or(serde_yaml::Value::Null);
        fill_platform_preset(&mut params);
        let params: Self = serde_yaml::from_value(params).map_err(|e| NodeError::Params { path: "<yaml>".into(), source: Box::new(e) })?;
        params.validate().map_err(|msg| NodeError::Params { path: "<yaml>".into(), source: msg.into() })?;
        Ok(params)
    }

    /// Refuses values the node cannot run with, naming the key (typos are refused by serde,
    /// inside `pipeline:` too).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.pipeline.validate()?;
        self.adapt.validate()?;
        // Said, not changed without a word (they were taken as 1 and clamped).
        if self.queue_depth == 0 {
            return Err("queue_depth must be at least 1 (a history of 0 messages holds nothing)".into());
        }
        if !(1..=20).contains(&self.adapt_judge_power_ons) {
            return Err(format!(
                "adapt_judge_power_ons must be 1–20 (earlier power-ons an adaptation is judged on), not {}",
                self.adapt_judge_power_ons
            )
            .into());
        }
        if !(0..=19).contains(&self.adapt_thread_nice) {
            return Err(
                format!("adapt_thread_nice must be 0–19 (a niceness at or below the node's own), not {}", self.adapt_thread_nice).into()
            );
        }
        let positive = |x: f64| x.is_finite() && x > 0.0;
        for (key, value) in [
            ("diagnostics_period", self.diagnostics_period),
            ("adapt_buffer_seconds", self.adapt_buffer_seconds),
            ("adapt_support_seconds", self.adapt_support_seconds),
        ] {
            if !positive(value) {
                return Err(format!("{key} must be finite and > 0, not {value}").into());
            }
        }
        // A period a clock cannot count (1e300 s) panicked converting to a Duration.
        if self.diagnostics_period > MAX_DIAGNOSTICS_PERIOD_S {
            return Err(format!(
                "diagnostics_period must be at most {MAX_DIAGNOSTICS_PERIOD_S} s (a day), not {}",
                self.diagnostics_period
            )
            .into());
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
                return Err(format!("{a} and {b} are both {ta}: each stream needs its own topic").into());
            }
        }
        if self.adapt_enabled && self.ground_truth_topic.trim_matches('/').is_empty() {
            return Err("adapt_enabled is true but ground_truth_topic is empty: adaptation needs the ground truth's topic".into());
        }
        if self.adapt_support_seconds >= self.adapt_buffer_seconds {
            return Err(format!(
                "adapt_support_seconds ({}) must be below adapt_buffer_seconds ({}): the rest of the buffer judges the adapted model",
                self.adapt_support_seconds, self.adapt_buffer_seconds
            )
            .into());
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

/// `pipeline.platform`'s settings ([`crate::infer::Platform::preset`]) written into the
/// parameters where they do not set them: the file's own values win.
fn fill_platform_preset(params: &mut serde_yaml::Value) {
    let Some(pipeline) = params.get_mut("pipeline") else { return };
    let Some(platform) = pipeline.get("platform").cloned() else { return };
    // An unknown name is left for serde to refuse with the choices.
    let Ok(platform) = serde_yaml::from_value::<crate::infer::Platform>(platform) else { return };
    for (path, value) in platform.preset() {
        let mut at = &mut *pipeline;
        for key in &path[..path.len() - 1] {
            let Some(map) = at.as_mapping_mut() else { return };
            at = map.entry((*key).into()).or_insert_with(|| serde_yaml::Value::Mapping(Default::default()));
        }
        let (Some(map), Ok(value)) = (at.as_mapping_mut(), serde_yaml::from_str::<serde_yaml::Value>(value)) else { continue };
        map.entry(path[path.len() - 1].into()).or_insert(value);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A platform fills in its settings where the file leaves them, and not where it sets them.
    #[test]
    fn a_platform_fills_in_what_the_file_leaves_unset() {
        let car = "imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: car\n";
        let aided = NodeParams::from_yaml_str(car, "imu_fsda").unwrap().pipeline.gravity_aided;
        assert_eq!((aided.forward_speed_stddev, aided.accel_stddev, aided.block_s), (20.0, 0.5, 1.0));
        let p = NodeParams::from_yaml_str(&format!("{car}      gravity_aided:\n        accel_stddev: 0.7\n"), "imu_fsda").unwrap();
        let aided = &p.pipeline.gravity_aided;
        assert_eq!((aided.forward_speed_stddev, aided.accel_stddev), (20.0, 0.7), "the file's 0.7 stays");
        assert_eq!(p.pipeline.standstill, crate::standstill::StandstillConfig::default(), "the bias seen in motion is not a car's");
        let any = NodeParams::from_yaml_str("imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: any\n", "imu_fsda").unwrap();
        assert_eq!(any.pipeline.gravity_aided, crate::infer::GravityAidedConfig::default());
        for platform in ["multirotor", "legged", "handheld"] {
            let file = format!("imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: {platform}\n");
            let p = NodeParams::from_yaml_str(&file, "imu_fsda").unwrap().pipeline;
            assert!(p.standstill.motion.apply_before_check, "{platform}: the bias seen in motion before the check");
            assert_eq!(p.gravity_aided, crate::infer::GravityAidedConfig::default(), "{platform}: not a car's attitude");
            let own = format!("{file}      standstill:\n        motion:\n          apply_before_check: false\n");
            let p = NodeParams::from_yaml_str(&own, "imu_fsda").unwrap().pipeline;
            assert!(!p.standstill.motion.apply_before_check, "{platform}: the file's false stays");
        }
        let e = NodeParams::from_yaml_str("imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: boat\n", "imu_fsda").unwrap_err();
        assert!(e.to_string().contains("car") || format!("{e:?}").contains("car"), "{e:?}");
    }

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
            ("    adapt_judge_power_ons: 0\n", "adapt_judge_power_ons"),
            ("    adapt_support_seconds: 120.0\n", "adapt_support_seconds"),
            ("    adapt_enabled: true\n    ground_truth_topic: \"\"\n", "ground_truth_topic"),
        ] {
            let err = with(body).unwrap_err().to_string();
            assert!(err.contains(key), "{body}: {err}");
        }
        assert!(with("    pipeline:\n      gap_periods: 1.5\n      gravity_init_seconds: 0.0\n").is_ok());
        NodeParams::default().validate().unwrap();
        assert!(!NodeParams::default().adapt_enabled, "adaptation is opt-in");
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
        assert!(e.to_string().contains("input_topic and output_topic are both /vectornav/imu"), "{e}");
    }
}
