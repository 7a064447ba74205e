//! `imu-fsda diagnose --sensors gyro`: the accelerometer's residual and terms are left out
//! (named under not_judged), the gyro's terms are still found. On a simulated bag with a
//! gyro scale and an accelerometer bias left out, both sensors find the accelerometer bias;
//! gyro alone must not.

use std::path::Path;
use std::process::Command;

mod common;
use common::bin;

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("spawn");
    assert!(out.status.success(), "{cmd:?} failed:\n{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn report(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap()
}

fn terms(j: &serde_json::Value) -> Vec<String> {
    j["findings"].as_array().unwrap().iter().map(|f| f["term"].as_str().unwrap().to_string()).collect()
}

#[test]
fn sensors_gyro_leaves_the_accelerometer_out() {
    let d = tempfile::tempdir().unwrap();
    let bag = d.path().join("real.mcap");
    run(Command::new(bin())
        .args(["simulate", "--profile", "handheld", "--grade", "bmi160", "--seconds", "30", "--seed", "5"])
        .args(["--term", "{term: accel_bias, bias: [0.2, -0.1, 0.15]}", "--term", "{term: gyro_scale, scale: [0.01, -0.01, 0.005]}"])
        .arg("-o")
        .arg(&bag));
    // The simulator's noise model of bmi160 (params: the grade's densities).
    let model = d.path().join("noise.yaml");
    std::fs::write(
        &model,
        "gyro_noise_density: 0.00016\naccel_noise_density: 0.0028\ngyro_bias_random_walk: 0.000022\naccel_bias_random_walk: 0.00086\n",
    )
    .unwrap();
    let diagnose = |sensors: &str, out: &Path| {
        // A simulator's ground truth is noise-free: no smoothing, so only --sensors differs.
        run(Command::new(bin())
            .args(["diagnose", "--gt-smoothing", "0", "--sensors", sensors, "--noise-model"])
            .arg(&model)
            .arg("--real")
            .arg(&bag)
            .arg("-o")
            .arg(out));
        report(out)
    };

    let both = diagnose("both", &d.path().join("both"));
    let found = terms(&both);
    assert!(found.contains(&"accel_bias".to_string()) && found.contains(&"gyro_scale".to_string()), "both sensors: {found:?}");

    let gyro = diagnose("gyro", &d.path().join("gyro"));
    let found = terms(&gyro);
    assert!(found.contains(&"gyro_scale".to_string()), "gyro alone: {found:?}");
    let accel_terms = ["accel_bias", "accel_scale", "accel_misalignment", "lever_arm", "gravity_magnitude", "vibration"];
    assert!(!found.iter().any(|t| accel_terms.contains(&t.as_str())), "gyro alone found accelerometer terms: {found:?}");
    // The gyro scale is the same fit either way (the accelerometer's channels do not enter it).
    let scale = |j: &serde_json::Value| -> Vec<f64> {
        let f = j["findings"].as_array().unwrap().iter().find(|f| f["term"] == "gyro_scale").unwrap();
        f["params"]["scale"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect()
    };
    for (a, b) in scale(&both).iter().zip(scale(&gyro)) {
        assert!((a - b).abs() < 1e-3, "gyro_scale differs: {a} vs {b}");
    }
    // The report says what was left out, and why.
    let not_judged: Vec<(String, String)> = gyro["not_judged"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| (v["term"].as_str().unwrap().to_string(), v["why"].as_str().unwrap().to_string()))
        .collect();
    for t in accel_terms {
        assert!(not_judged.iter().any(|(n, why)| n == t && why.contains("--sensors gyro")), "{t} not under not_judged: {not_judged:?}");
    }
    assert!(gyro["notes"].as_array().unwrap().iter().any(|n| n.as_str().unwrap().contains("--sensors gyro")));
    let chi2 = gyro["residual_after"]["chi2_per_sample"].as_object().unwrap();
    assert!(chi2.keys().all(|k| k.starts_with("gyro")), "accelerometer χ² reported: {chi2:?}");
    assert!(gyro["located"].as_array().unwrap().iter().all(|l| l["channel"].as_str().unwrap().starts_with("gyro")));
}

/// `-o` naming an existing file (not a directory) is refused before anything is read or
/// written, and the file is left as it was.
#[test]
fn an_output_that_is_a_file_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let file = d.path().join("notes.txt");
    std::fs::write(&file, "keep me").unwrap();
    let out = Command::new(bin()).args(["diagnose", "--real", "missing.mcap", "--sim", "missing.mcap", "-o"]).arg(&file).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("exists and is not a directory"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
}

/// An input that is one of the files the report directory holds (the last run's
/// corrected_sim.mcap given back as --sim, into the same -o) is refused before anything is
/// written: before, the report replaced it.
#[test]
fn an_input_inside_the_report_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("report");
    std::fs::create_dir_all(&out).unwrap();
    let corrected = out.join("corrected_sim.mcap");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"), &corrected).unwrap();
    let before = std::fs::read(&corrected).unwrap();
    for side in ["--sim", "--real"] {
        let other = if side == "--sim" { "--real" } else { "--sim" };
        let o = Command::new(bin())
            .arg("diagnose")
            .arg(side)
            .arg(&corrected)
            .arg(other)
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"))
            .arg("-o")
            .arg(d.path().join(".").join("report"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{side}: {err}");
        assert!(err.contains("is also an input"), "{side}: {err}");
    }
    assert!(std::fs::read(&corrected).unwrap() == before, "the input was rewritten");
    assert!(!out.join("report.json").exists(), "a report was written");
}
