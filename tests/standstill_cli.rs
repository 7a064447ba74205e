//! A part whose zero-rate offset is beyond `standstill.max_bias` (0.15 rad/s; some consumer
//! gyros reach ±20 °/s), at rest: no standstill is taken, and `eval` and replay's /diagnostics
//! say why and what to set; raised as they say, the rest measures it.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{bin, eval_power_on_bias, ok};
use imu_fsda::bag::BagReader;
use imu_fsda::msg::{DiagnosticArray, RosMessage};

/// A simulated ADIS16448 with 5 s at rest, 0.3 rad/s added to its gyro's x.
fn beyond_max_bias(dir: &Path) -> PathBuf {
    let sim = dir.join("sim.mcap");
    ok(Command::new(bin())
        .args(["simulate", "--profile", "quadruped", "--grade", "adis16448", "--seconds", "20", "--seed", "4", "--rest-s", "5", "-o"])
        .arg(&sim));
    let bag = dir.join("offset.mcap");
    ok(Command::new(bin()).arg("inject").arg(&sim).args(["--term", "{term: gyro_bias, bias: [0.3, 0, 0]}", "-o"]).arg(&bag));
    bag
}

#[test]
fn a_bias_beyond_max_bias_is_said_with_what_to_set() {
    let d = tempfile::tempdir().unwrap();
    let bag = beyond_max_bias(d.path());
    let row = eval_power_on_bias(&bag, &[], d.path());
    let note = row["note"].as_str().unwrap_or_default();
    assert!(note.starts_with("no standstill"), "{note}");
    assert!(note.contains("above standstill.max_bias 0.15") && note.contains("is this IMU's bias"), "{note}");

    let out = d.path().join("out.mcap");
    ok(Command::new(bin()).arg("replay").arg(&bag).arg("-o").arg(&out).args(["--model", ""]));
    let said: Vec<String> = BagReader::open(&out)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| &*m.topic == "/diagnostics")
        .filter_map(|m| {
            let status = DiagnosticArray::decode(&m.data).unwrap().status.remove(0);
            status.values.into_iter().find(|kv| kv.key == "rate_above_max_bias").map(|kv| kv.value)
        })
        .collect();
    assert!(said.last().is_some_and(|s| s.contains("raise max_bias above 0.3")), "{said:?}");

    let params = d.path().join("params.yaml");
    std::fs::write(&params, "imu_fsda:\n  ros__parameters:\n    pipeline:\n      standstill:\n        max_bias: 0.5\n").unwrap();
    let raised = eval_power_on_bias(&bag, &[OsStr::new("--params"), params.as_os_str()], d.path());
    let note = raised["note"].as_str().unwrap_or_default();
    assert!(note.starts_with("power-on bias [0.3") && !note.contains("max_bias"), "{note}");
}
