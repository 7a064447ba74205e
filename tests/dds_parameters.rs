//! The node's parameters on the ROS graph, as `ros2 param list / get / set` uses them, over DDS
//! against an independent peer (tests/python/params_peer.py on PyPI cyclonedds, no ROS 2
//! library), in a private network namespace. See docs/node.md, "Parameters".

mod common;

use std::sync::Mutex;
use std::time::Duration;

use common::prerequisites;
use common::python_peer::{diag_values, run, value};
use serde_json::Value;

static SERIAL: Mutex<()> = Mutex::new(());

/// Bound of the run; a passing one takes ~15 s.
const RUN_TIMEOUT: Duration = Duration::from_secs(60);

fn hex(v: &Value) -> f64 {
    f64::from_bits(u64::from_str_radix(v.as_str().expect("hex float"), 16).expect("hex float"))
}

/// Every parameter of the file is listed and read back at its value; a read-only one is refused
/// with the reason; `pipeline.power_on_bias` set to false while MH_04 streams takes effect
/// between two samples: before, the node removes the bias its rest measured; after, it
/// publishes the gyro as measured, and says so on /diagnostics.
#[test]
fn parameters_are_listed_read_and_switched_at_run_time_over_dds() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Ok(pre) = prerequisites().map_err(|why| common::skip_or_fail("dds_parameters", &why)) else { return };
    let Ok(seq) = common::euroc_sequence("MH_04_difficult", &[]).map_err(|why| common::skip_or_fail("dds_parameters", &why)) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let csv = seq.join("imu0/data.csv");
    let o = run(
        &pre,
        dir.path(),
        "parameters",
        &["--model", ""],
        "params_peer.py",
        &["--csv", csv.to_str().unwrap(), "--count", "3000"],
        RUN_TIMEOUT,
    );
    let (p, logs) = (&o.peer, &o.logs);
    assert_eq!(p["matched"], true, "the peer never matched the node\n{logs}");
    assert_eq!(o.rc, vec![0, 0], "peer / node exit codes\n{logs}");

    let listed: Vec<&str> = p["listed"].as_array().unwrap().iter().filter_map(Value::as_str).collect();
    for name in ["model", "input_topic", "pipeline.power_on_bias", "pipeline.model_on_new_imu", "pipeline.standstill.motion.max_mean_nis"] {
        assert!(listed.contains(&name), "{name} not listed: {listed:?}");
    }
    let got = &p["got_before"];
    assert_eq!((got["pipeline.power_on_bias"]["type"].as_u64(), got["pipeline.power_on_bias"]["bool"].as_bool()), (Some(1), Some(true)));
    assert_eq!(got["pipeline.standstill.max_bias"]["type"].as_u64(), Some(3), "a double: {got}");
    assert_eq!(hex(&got["pipeline.standstill.max_bias"]["double"]), 0.15);
    assert_eq!(got["input_topic"]["string"], "/imu/data_raw");
    assert_eq!(got["not_a_parameter"]["type"].as_u64(), Some(0), "not set: {got}");

    let refused = &p["set_read_only"][0];
    assert_eq!(refused["successful"], false, "{refused}");
    assert!(refused["reason"].as_str().unwrap().contains("read-only"), "{refused}");
    assert_eq!(p["set_power_on_bias"][0]["successful"], true, "{}", p["set_power_on_bias"]);
    assert_eq!((p["got_after"]["type"].as_u64(), p["got_after"]["bool"].as_bool()), (Some(1), Some(false)), "{}", p["got_after"]);

    // Output k answers input k (the peer waits for every output before each step).
    let sent = p["sent"].as_array().unwrap();
    let out = p["denoised"].as_array().unwrap();
    assert_eq!(out.len(), sent.len(), "one output per input\n{logs}");
    let switched = p["switched_after_rows"].as_u64().unwrap() as usize;
    let raw = |k: usize| {
        let (s, d) = (&sent[k], &out[k]);
        assert_eq!(s["stamp_ns"], d["stamp_ns"], "output {k} answers input {k}");
        (0..3).all(|i| hex(&s["gyro"][i]) == hex(&d["angular_velocity"][i]))
    };
    assert!(!raw(switched - 1), "before the switch the power-on bias was removed\n{logs}");
    let after: Vec<usize> = (switched..sent.len()).filter(|&k| !raw(k)).collect();
    assert!(after.is_empty(), "after the switch the gyro as measured; corrected: {:?}\n{logs}", &after[..after.len().min(5)]);

    let values: Vec<&serde_json::Map<String, Value>> = p["diagnostics"].as_array().unwrap().iter().filter_map(diag_values).collect();
    let last = values
        .iter()
        .rev()
        .find(|v| value(v, "received") == sent.len().to_string())
        .unwrap_or_else(|| panic!("no final /diagnostics\n{logs}"));
    assert_eq!(value(last, "parameters_set"), "1");
    assert_eq!(value(last, "correction"), "raw", "{last:?}");
    assert_eq!(o.node_stats["parameters_set"].as_u64(), Some(1), "{}", o.node_stats);
}
