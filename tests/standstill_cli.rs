//! The power-on bias where the IMU misbehaves at the CLI: a part whose zero-rate offset is
//! beyond `standstill.max_bias` (0.15 rad/s; some consumer gyros reach ±20 °/s), at rest: no
//! standstill is taken, and `eval` and replay's /diagnostics say why and what to set; raised as
//! they say, the rest measures it. An IMU power-cycled under a running node (a hole in its
//! stream, a new turn-on bias): the next standstill is taken as a new power-on's.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;

use common::{bin, eval_power_on_bias, ok};
use imu_fsda::bag::{read_recording, BagReader, RecordingTopics};
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

/// The last value of a /diagnostics key replay wrote into `out`.
fn last_said(out: &Path, key: &str) -> Option<String> {
    BagReader::open(out)
        .unwrap()
        .map(|m| m.unwrap())
        .filter(|m| &*m.topic == "/diagnostics")
        .filter_map(|m| {
            let status = DiagnosticArray::decode(&m.data).unwrap().status.remove(0);
            status.values.into_iter().find(|kv| kv.key == key).map(|kv| kv.value)
        })
        .last()
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
    let said = last_said(&out, "rate_above_max_bias");
    assert!(said.as_ref().is_some_and(|s| s.contains("raise max_bias above 0.3")), "{said:?}");

    let params = d.path().join("params.yaml");
    std::fs::write(&params, "imu_fsda:\n  ros__parameters:\n    pipeline:\n      standstill:\n        max_bias: 0.5\n").unwrap();
    let raised = eval_power_on_bias(&bag, &[OsStr::new("--params"), params.as_os_str()], d.path());
    let note = raised["note"].as_str().unwrap_or_default();
    assert!(note.starts_with("power-on bias [0.3") && !note.contains("max_bias"), "{note}");
}

/// Two simulated power-ons of one MPU-9250 (turn-on biases drawn apart), each starting with 5 s
/// at rest, played as one stream with a 3-s hole between them: replay ends with the second
/// power-on's bias, as `eval` measures it on that power-on alone, and says one new power-on.
#[test]
fn an_imu_power_cycled_under_the_node_gets_its_new_bias() {
    let d = tempfile::tempdir().unwrap();
    let power_on = |k: &str| {
        let bag = d.path().join(format!("p{k}.mcap"));
        ok(Command::new(bin())
            .args(["simulate", "--profile", "quadruped", "--grade", "mpu-9250", "--datasheet-errors", "--seconds", "20", "--seed", "6"])
            .args(["--power-on", k, "--rest-s", "5", "-o"])
            .arg(&bag));
        bag
    };
    let (first, second) = (power_on("1"), power_on("2"));
    let (mut rec, _) = read_recording(&first, &RecordingTopics::default()).unwrap();
    let (next, _) = read_recording(&second, &RecordingTopics::default()).unwrap();
    let shift = rec.imu.last().unwrap().stamp_ns + 3_000_000_000 - next.imu[0].stamp_ns;
    rec.imu.extend(next.imu.iter().map(|s| imu_fsda::core::ImuSample { stamp_ns: s.stamp_ns + shift, ..*s }));
    rec.ground_truth.extend(next.ground_truth.iter().map(|p| imu_fsda::core::PoseSample { stamp_ns: p.stamp_ns + shift, ..*p }));
    rec.temperature.clear();
    let both = d.path().join("both.mcap");
    imu_fsda::bag::write_recording(&both, &rec).unwrap();

    let alone = eval_power_on_bias(&second, &[], d.path());
    let joined = eval_power_on_bias(&both, &[], d.path());
    assert!(joined["note"].as_str().unwrap().contains("1 standstill(s) after a hole"), "{joined}");
    let out = d.path().join("out.mcap");
    ok(Command::new(bin()).arg("replay").arg(&both).arg("-o").arg(&out).args(["--model", ""]));
    assert_eq!(last_said(&out, "power_on_bias_new_power_ons").as_deref(), Some("1"));
    let said = last_said(&out, "power_on_bias_rad_s").unwrap();
    let bias: Vec<f64> = said.split_whitespace().map(|v| v.parse().unwrap()).collect();
    let note = alone["note"].as_str().unwrap();
    let inner = &note[note.find('[').unwrap() + 1..note.find(']').unwrap()];
    let expected: Vec<f64> = inner.split(", ").map(|v| v.parse().unwrap()).collect();
    assert!(bias.iter().zip(&expected).all(|(b, e)| (b - e).abs() < 2e-3), "{bias:?} against {expected:?} ({note})");
}
