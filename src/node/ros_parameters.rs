//! The node's parameters on the ROS graph: every parameter it runs with declared under its
//! file's name (`pipeline.standstill.max_bias`), so `ros2 param list / get / dump` show what
//! runs; two switchable at run time (`ros2 param set`), the rest read-only: they were read at
//! start, and the node says so instead of taking a value it would not use.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use ros2_client::{NodeOptions, ParameterValue};

use super::{NodeParams, NodeStats};
use crate::infer::Pipeline;

/// Parameters a client may set while the node runs: what the power-on bias does
/// (imu_tools' users ask for bias estimation switchable at run time), and the new-IMU guard.
pub const AT_RUN_TIME: [&str; 2] = ["pipeline.power_on_bias", "pipeline.model_on_new_imu"];

/// A change a client made, applied by the process loop between two samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunTimeChange {
    PowerOnBias(bool),
    ModelOnNewImu(bool),
}

impl RunTimeChange {
    fn from_parameter(name: &str, value: &ParameterValue) -> Result<Self, String> {
        let on = match value {
            ParameterValue::Boolean(b) => *b,
            other => return Err(format!("{name} is a bool, not {other:?}")),
        };
        match name {
            "pipeline.power_on_bias" => Ok(RunTimeChange::PowerOnBias(on)),
            "pipeline.model_on_new_imu" => Ok(RunTimeChange::ModelOnNewImu(on)),
            _ => Err(format!("{name} is not settable while running")),
        }
    }
}

/// Applies a client's change between two samples, counted on /diagnostics (`parameters_set`).
pub(super) fn apply(pipeline: &mut Pipeline, change: RunTimeChange, stats: &Mutex<NodeStats>) {
    match change {
        RunTimeChange::PowerOnBias(on) => pipeline.set_power_on_bias(on),
        RunTimeChange::ModelOnNewImu(on) => pipeline.set_model_on_new_imu(on),
    }
    if let Ok(mut s) = stats.lock() {
        s.parameters_set += 1;
    }
}

/// Changes set by the parameter services (DDS threads), taken by the process loop: a flag it
/// reads per sample, the list only when the flag is up.
#[derive(Debug, Default)]
pub struct PendingChanges {
    any: AtomicBool,
    changes: Mutex<Vec<RunTimeChange>>,
}

impl PendingChanges {
    fn push(&self, change: RunTimeChange) {
        self.changes.lock().expect("parameter changes lock").push(change);
        self.any.store(true, Ordering::Release);
    }

    /// The changes since the last call, oldest first.
    pub fn take(&self) -> Vec<RunTimeChange> {
        // A load per sample; the write only when a change came.
        if !self.any.load(Ordering::Relaxed) || !self.any.swap(false, Ordering::AcqRel) {
            return Vec::new();
        }
        std::mem::take(&mut *self.changes.lock().expect("parameter changes lock"))
    }
}

/// `options` with every parameter declared at its value, a validator that takes a new value
/// only for [`AT_RUN_TIME`]'s names (a bool), and an action that hands each change of those to
/// `pending`. ros2-client runs both on every declared value at start: the values the node
/// runs with pass, and change nothing.
pub fn declare(options: NodeOptions, params: &NodeParams, pending: Arc<PendingChanges>) -> NodeOptions {
    let declared = declared(params);
    let initial: HashMap<String, ParameterValue> = declared.iter().cloned().collect();
    let current: Mutex<HashMap<String, ParameterValue>> =
        Mutex::new(initial.iter().filter(|(n, _)| AT_RUN_TIME.contains(&n.as_str())).map(|(n, v)| (n.clone(), v.clone())).collect());
    let mut options = options;
    for (name, value) in declared {
        options = options.declare_parameter(&name, value);
    }
    options.parameter_validator(Box::new(move |name: &str, value: &ParameterValue| check(&initial, name, value))).parameter_set_action(
        Box::new(move |name: &str, value: &ParameterValue| {
            if !AT_RUN_TIME.contains(&name) {
                return Ok(());
            }
            let change = RunTimeChange::from_parameter(name, value)?;
            let mut current = current.lock().expect("parameters lock");
            if current.get(name) != Some(value) {
                tracing::info!("parameter {name} set to {value:?} by a client: applied from the next sample");
                current.insert(name.to_string(), value.clone());
                pending.push(change);
            }
            Ok(())
        }),
    )
}

/// A value the node can take: a bool for a run-time switch; for any other parameter only the
/// value it runs with.
fn check(initial: &HashMap<String, ParameterValue>, name: &str, value: &ParameterValue) -> Result<(), String> {
    if AT_RUN_TIME.contains(&name) {
        return RunTimeChange::from_parameter(name, value).map(|_| ());
    }
    if initial.get(name) == Some(value) {
        return Ok(());
    }
    Err(format!(
        "{name} is read-only: read at start from the parameter file (restart the node to change it); settable while running: {}",
        AT_RUN_TIME.join(", ")
    ))
}

/// Every parameter the node runs with, named as in its file (nested keys joined by `.`); a
/// setting that is not set (`null`) is left out.
pub fn declared(params: &NodeParams) -> Vec<(String, ParameterValue)> {
    let mut out = Vec::new();
    match serde_json::to_value(params) {
        Ok(tree) => flatten("", &tree, &mut out),
        Err(e) => tracing::warn!("the parameters could not be listed for the ROS graph: {e}"),
    }
    out
}

fn flatten(prefix: &str, value: &serde_json::Value, out: &mut Vec<(String, ParameterValue)>) {
    use serde_json::Value;
    let leaf = match value {
        Value::Object(map) => {
            for (k, v) in map {
                let name = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                flatten(&name, v, out);
            }
            return;
        }
        Value::Null => return,
        Value::Bool(b) => ParameterValue::Boolean(*b),
        Value::Number(n) => match n.as_i64() {
            Some(i) => ParameterValue::Integer(i),
            None => ParameterValue::Double(n.as_f64().unwrap_or(f64::NAN)),
        },
        Value::String(s) => ParameterValue::String(s.clone()),
        Value::Array(items) => array(items),
    };
    out.push((prefix.to_string(), leaf));
}

/// A list as ROS has them: of bools, integers, doubles or strings (a mixed list as strings).
fn array(items: &[serde_json::Value]) -> ParameterValue {
    use serde_json::Value;
    if items.iter().all(Value::is_boolean) && !items.is_empty() {
        ParameterValue::BooleanArray(items.iter().filter_map(Value::as_bool).collect())
    } else if items.iter().all(Value::is_i64) && !items.is_empty() {
        ParameterValue::IntegerArray(items.iter().filter_map(Value::as_i64).collect())
    } else if items.iter().all(Value::is_number) && !items.is_empty() {
        ParameterValue::DoubleArray(items.iter().filter_map(Value::as_f64).collect())
    } else {
        ParameterValue::StringArray(items.iter().map(|v| v.as_str().map_or_else(|| v.to_string(), str::to_string)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parameters are the file's, by the file's names and types.
    #[test]
    fn the_declared_parameters_are_the_files() {
        let mut params = NodeParams::default();
        params.pipeline.standstill.max_bias = 0.2;
        let declared = declared(&params);
        let get = |n: &str| declared.iter().find(|(name, _)| name == n).map(|(_, v)| v.clone());
        assert_eq!(get("pipeline.standstill.max_bias"), Some(ParameterValue::Double(0.2)));
        assert_eq!(get("pipeline.power_on_bias"), Some(ParameterValue::Boolean(true)));
        assert_eq!(get("input_topic"), Some(ParameterValue::String("/imu/data_raw".into())));
        assert_eq!(get("queue_depth"), Some(ParameterValue::Integer(100)));
        assert!(get("pipeline").is_none(), "only leaves are parameters");
        for name in AT_RUN_TIME {
            assert!(get(name).is_some(), "{name} is declared");
        }
    }

    /// Only the run-time switches take a value, and only a bool; the others say why not.
    #[test]
    fn only_the_run_time_switches_can_be_set() {
        assert_eq!(
            RunTimeChange::from_parameter("pipeline.power_on_bias", &ParameterValue::Boolean(false)),
            Ok(RunTimeChange::PowerOnBias(false))
        );
        assert!(RunTimeChange::from_parameter("pipeline.power_on_bias", &ParameterValue::Integer(0)).unwrap_err().contains("bool"));
        let initial: HashMap<String, ParameterValue> = declared(&NodeParams::default()).into_iter().collect();
        let e = check(&initial, "model", &ParameterValue::String("other.pt".into())).unwrap_err();
        assert!(e.contains("read-only") && e.contains("pipeline.power_on_bias"), "{e}");
        // The value it runs with passes (ros2-client checks every declared value at start).
        assert_eq!(check(&initial, "model", &initial["model"]), Ok(()));
        assert_eq!(check(&initial, "pipeline.model_on_new_imu", &ParameterValue::Boolean(true)), Ok(()));
        let pending = PendingChanges::default();
        assert!(pending.take().is_empty());
        pending.push(RunTimeChange::ModelOnNewImu(true));
        pending.push(RunTimeChange::PowerOnBias(false));
        assert_eq!(pending.take(), vec![RunTimeChange::ModelOnNewImu(true), RunTimeChange::PowerOnBias(false)]);
        assert!(pending.take().is_empty());
    }
}
