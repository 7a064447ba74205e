//! `imu-fsda diagnose` says when the catalogue does not explain a recording. A gyro gain that
//! changes mid-recording (a driver switching its range) is no catalogue term (a scale is
//! constant): the report must name gyro_x as unexplained, call the terms
//! the best catalogue fit, never say "Nothing left out", and the CLI's first line must say it.
//! The same bag without the change (a gyro scale, a catalogue term) is explained. (A bias
//! jump is not used: the estimated bias walk can take a single step.)

use std::path::Path;
use std::process::{Command, Output};

use imu_fsda::bag::{read_recording, write_recording, RecordingTopics};

mod common;
use common::bin;

fn simulate(out: &Path, terms: &[&str]) {
    let mut cmd = Command::new(bin());
    cmd.args(["simulate", "--profile", "handheld", "--grade", "bmi160", "--seconds", "40", "--seed", "7"]);
    for t in terms {
        cmd.args(["--term", t]);
    }
    let o = cmd.arg("-o").arg(out).output().expect("spawn");
    assert!(o.status.success(), "simulate: {}", String::from_utf8_lossy(&o.stderr));
}

/// Diagnose `real` against a simulation of its own ground truth (bmi160's densities).
fn diagnose(dir: &Path, real: &Path, out: &Path) -> (Output, serde_json::Value) {
    let model = dir.join("noise.yaml");
    std::fs::write(
        &model,
        "gyro_noise_density: 0.00016\naccel_noise_density: 0.0028\ngyro_bias_random_walk: 0.000022\naccel_bias_random_walk: 0.00086\n",
    )
    .unwrap();
    let o = Command::new(bin())
        .args(["diagnose", "--gt-smoothing", "0", "--noise-model"])
        .arg(&model)
        .arg("--real")
        .arg(real)
        .arg("-o")
        .arg(out)
        .output()
        .expect("spawn");
    assert!(o.status.success(), "diagnose: {}", String::from_utf8_lossy(&o.stderr));
    let report = serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    (o, report)
}

#[test]
fn a_gain_change_is_reported_as_unexplained() {
    let d = tempfile::tempdir().unwrap();
    let real = d.path().join("real.mcap");
    simulate(&real, &["{term: gyro_scale, scale: [0.01, -0.01, 0.005]}"]);

    // The catalogue's own term: explained.
    let (_, rep) = diagnose(d.path(), &real, &d.path().join("scale"));
    assert_eq!(rep["verdict"]["explained"], true, "{}", rep["verdict"]);
    assert!(rep["findings"].as_array().unwrap().iter().any(|f| f["term"] == "gyro_scale"), "{}", rep["findings"]);

    // The gyro x gain grows by 5 % at 20 s.
    let (mut rec, _) = read_recording(&real, &RecordingTopics::default()).unwrap();
    let t0 = rec.imu[0].stamp_ns;
    for s in rec.imu.iter_mut().filter(|s| s.stamp_ns - t0 >= 20_000_000_000) {
        s.gyro.x *= 1.05;
    }
    let changed = d.path().join("changed.mcap");
    write_recording(&changed, &rec).unwrap();
    let out = d.path().join("changed");
    let (o, rep) = diagnose(d.path(), &changed, &out);
    let v = &rep["verdict"];
    assert_eq!(v["explained"], false, "{v}");
    let statement = v["statement"].as_str().unwrap();
    assert!(statement.starts_with("The catalogue does not explain this recording"), "{statement}");
    assert!(v["unexplained_channels"].as_array().unwrap().iter().any(|c| c == "gyro_x"), "{v}");
    assert!(!v["unexplained_channels"].as_array().unwrap().iter().any(|c| c.as_str().unwrap().starts_with("accel")), "{v}");
    assert!(rep["findings_are"].as_str().unwrap().contains("not a diagnosis"));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(!md.contains("Nothing left out"), "{md}");
    assert!(md.contains("The catalogue does not explain this recording"), "{md}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.lines().next().unwrap_or("").starts_with("The catalogue does not explain"), "{stdout}");
}
