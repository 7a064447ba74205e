//! `imu-fsda train` with `dataset.power_on_bias: remove` on simulated power-ons of one
//! consumer IMU: each training recording's turn-on bias (the simulation's truth) is what the
//! exported model remembers for that IMU, the model is marked to run after the node's power-on
//! bias, and `eval` runs it so when the IMU is named (issue 49, item 2; docs/training.md).

use std::path::Path;
use std::process::Command;

use imu_fsda::model::export::load_metadata;

mod common;
use common::bin;

/// Power-on `k` of one simulated MPU-9250 (the same lasting scale error, a new turn-on bias):
/// its config in `dir`, and the turn-on bias the simulator applied.
fn power_on(dir: &Path, k: u64) -> [f64; 3] {
    let config = dir.join(format!("p{k}.yaml"));
    std::fs::write(
        &config,
        format!(
            "profile: handheld\ngrade: mpu-9250\nrate_hz: 200\nseconds: 40\nseed: 11\ndatasheet_errors: true\npower_on: {k}\nrest_s: 3\n\
             terms:\n  - {{term: gyro_scale, scale: [0.021, -0.027, 0.014]}}\n"
        ),
    )
    .unwrap();
    let truth = dir.join(format!("p{k}.truth.yaml"));
    let out = Command::new(bin())
        .args(["simulate", "--config"])
        .arg(&config)
        .arg("--output")
        .arg(dir.join(format!("p{k}.mcap")))
        .arg("--truth")
        .arg(&truth)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let truth: serde_yaml::Value = serde_yaml::from_str(&std::fs::read_to_string(&truth).unwrap()).unwrap();
    let bias = truth["applied"].as_sequence().unwrap().iter().find(|t| t["term"].as_str() == Some("gyro_bias")).expect("a turn-on bias")
        ["bias"]
        .clone();
    let bias: Vec<f64> = serde_yaml::from_value(bias).unwrap();
    [bias[0], bias[1], bias[2]]
}

#[test]
fn each_power_ons_bias_is_removed_remembered_and_removed_again_at_run_time() {
    let dir = tempfile::tempdir().unwrap();
    let truths: Vec<[f64; 3]> = (1..=4).map(|k| power_on(dir.path(), k)).collect();
    // A consumer part's turn-on bias changes between power-ons by far more than a rest's σ.
    let spread =
        (0..3).map(|a| truths.iter().map(|t| t[a]).fold(f64::MIN, f64::max) - truths.iter().map(|t| t[a]).fold(f64::MAX, f64::min));
    assert!(spread.fold(0.0, f64::max) > 0.02, "{truths:?}");

    let config = dir.path().join("unit.yaml");
    std::fs::write(
        &config,
        "model: {mode: fsda_f}\n\
         dataset:\n  power_on_bias: remove\n  train:\n    - {simulate: p1.yaml, imu: unit}\n    - {simulate: p2.yaml, imu: unit}\n    - {simulate: p3.yaml, imu: unit}\n  support_seconds: 20\n\
         train:\n  epochs: 2\n  schedule: {kind: constant}\n  maml: {support_window_samples: 1200, query_window_samples: 1200}\n  threads: 1\n",
    )
    .unwrap();
    let out = Command::new(bin())
        .args(["train", "--config"])
        .arg(&config)
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--no-progress", "--name", "unit"])
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert_eq!(log.matches("power-on bias [").count(), 3, "each recording's removal said: {log}");

    let meta = load_metadata(&dir.path().join("unit.json")).unwrap();
    assert!(meta.power_on_bias_removed);
    let remembered = &meta.trained_power_on_biases["unit"];
    assert_eq!(remembered.len(), 3);
    for (r, truth) in remembered.iter().zip(&truths) {
        // The 3-s rest's estimate: the turn-on bias within the noise and random walk of 3 s.
        let off = (0..3).map(|a| (r.bias_rad_s[a] - truth[a]).abs()).fold(0.0, f64::max);
        assert!(off < 2e-3 && r.still_s >= 2.0, "{} measured {:?}, simulated {truth:?}", r.recording, r.bias_rad_s);
    }

    // Named as the IMU it was trained on, eval runs it after this power-on's own bias; unnamed,
    // it is a new IMU's model and not applied.
    let bag = dir.path().join("p4.mcap");
    let eval = |imu: &[&str]| {
        let out = Command::new(bin()).arg("eval").arg(&bag).arg("--model").arg(dir.path().join("unit.pt")).args(imu).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let named = eval(&["--imu", "unit"]);
    assert!(named.contains("with each recording's power-on bias removed") && !named.contains("as deployed"), "{named}");
    let unnamed = eval(&[]);
    assert!(unnamed.contains("unit as deployed") && unnamed.contains("model not applied"), "{unnamed}");
}
