//! `imu-fsda simulate` end to end: the built binary writes bags that read back, the same
//! seed gives the same bytes, and bad input is a clear error, never a panic.

use std::path::Path;
use std::process::{Command, Output};

use imu_fsda::bag::{read_recording, RecordingTopics};

fn simulate(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_imu-fsda")).arg("simulate").args(args).output().expect("run imu-fsda")
}

fn ok(out: &Output) -> String {
    assert!(out.status.success(), "failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn fails_cleanly(out: &Output, expect: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "should fail: {stderr}");
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    for e in expect {
        assert!(stderr.contains(e), "`{e}` not in: {stderr}");
    }
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).display().to_string()
}

#[test]
fn every_profile_writes_a_bag_that_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    for profile in ["aerial", "handheld", "car", "quadruped", "mav"] {
        let out = path(dir.path(), &format!("{profile}.mcap"));
        let stdout =
            ok(&simulate(&["--profile", profile, "--grade", "bmi160", "--rate", "200", "--seconds", "3", "--seed", "1", "-o", &out]));
        assert!(stdout.contains("600 IMU") && stdout.contains("300 pose"), "{stdout}");
        let (rec, report) = read_recording(&out, &RecordingTopics::default()).unwrap();
        assert_eq!(report.skipped(), 0);
        assert_eq!(rec.imu.len(), 600);
        assert_eq!(rec.ground_truth.len(), 300);
        assert!(rec.temperature.is_empty());
        assert!((rec.imu_rate_hz() - 200.0).abs() < 1e-6);
        let mean_f: f64 = rec.imu.iter().map(|s| s.accel.norm()).sum::<f64>() / 600.0;
        assert!(mean_f > 8.0 && mean_f < 12.0, "{profile}: |f| mean {mean_f}");
    }
}

#[test]
fn same_seed_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (path(dir.path(), "a.mcap"), path(dir.path(), "b.mcap"), path(dir.path(), "c.mcap"));
    let args = |o: &str, seed: &str| {
        let o = o.to_owned();
        let seed = seed.to_owned();
        move || {
            simulate(&[
                "--profile",
                "quadruped",
                "--grade",
                "mpu-9250",
                "--rate",
                "400",
                "--seconds",
                "2",
                "--seed",
                &seed,
                "--datasheet-errors",
                "-o",
                &o,
            ])
        }
    };
    ok(&args(&a, "5")());
    ok(&args(&b, "5")());
    ok(&args(&c, "6")());
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&c).unwrap());
}

#[test]
fn config_file_terms_flags_and_truth() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("sim.yaml");
    std::fs::write(
        &cfg,
        "profile: car\ngrade: adis16448\nrate_hz: 100\nseconds: 4\nseed: 2\nterms:\n  - {term: gyro_bias_temperature, coefficient: [1.0e-4, 0, 0], reference_c: 25}\n",
    )
    .unwrap();
    let (out, truth) = (path(dir.path(), "o.mcap"), path(dir.path(), "truth.yaml"));
    let cfg_s = cfg.display().to_string();
    let stdout = ok(&simulate(&[
        "--config",
        &cfg_s,
        "--seconds",
        "2",
        "--term",
        "{term: gyro_bias, bias: [0.01, 0, 0]}",
        "--truth",
        &truth,
        "-o",
        &out,
    ]));
    assert!(stdout.contains("car / adis16448") && stdout.contains("gyro_bias_temperature") && stdout.contains("gyro_bias,"), "{stdout}");
    let (rec, _) = read_recording(&out, &RecordingTopics::default()).unwrap();
    assert_eq!(rec.imu.len(), 200);
    assert_eq!(rec.temperature.len(), 200, "a temperature term brings the temperature topic");
    assert_eq!(rec.ground_truth.len(), 200, "ground truth at the IMU rate when it is below 100 Hz");
    let truth = std::fs::read_to_string(&truth).unwrap();
    for want in ["term: gyro_bias", "term: white_noise", "gyro_noise_density: 0.00016968", "seconds: 2"] {
        assert!(truth.contains(want), "`{want}` not in {truth}");
    }
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let o = path(dir.path(), "x.mcap");
    fails_cleanly(&simulate(&["--profile", "boat", "-o", &o]), &["boat", "handheld"]);
    fails_cleanly(&simulate(&["--grade", "mpu6050", "-o", &o]), &["mpu6050", "mpu-9250"]);
    fails_cleanly(&simulate(&["--rate", "0", "-o", &o]), &["rate_hz"]);
    fails_cleanly(&simulate(&["--rate", "NaN", "-o", &o]), &["rate_hz"]);
    fails_cleanly(&simulate(&["--seconds=-3", "-o", &o]), &["seconds"]);
    fails_cleanly(&simulate(&["--term", "{term: gyro_wobble, x: 1}", "-o", &o]), &["gyro_wobble", "gyro_bias"]);
    fails_cleanly(&simulate(&["--term", "{term: gyro_scale, scale: [.nan, 0, 0]}", "-o", &o]), &["gyro_scale", "scale"]);
    fails_cleanly(&simulate(&["--config", &path(dir.path(), "missing.yaml"), "-o", &o]), &["missing.yaml"]);
    // Parameters no sensor has: a bag of NaN before.
    fails_cleanly(&simulate(&["--term", "{term: mount_rotation, rotvec: [1.0e300, 0, 0]}", "-o", &o]), &["non-finite", "physical range"]);
    fails_cleanly(&simulate(&["--term", "{term: gyro_bias, bias: [1.0e10, 0, 0]}", "-o", &o]), &["|ω| = 1.000e10"]);
    // A first stamp ROS 2 cannot hold (its seconds are 32-bit): a wrapped header stamp before.
    let late = dir.path().join("late.yaml");
    std::fs::write(&late, "start_time_ns: 2200000000000000000\n").unwrap();
    fails_cleanly(&simulate(&["--config", &late.display().to_string(), "-o", &o]), &["ROS 2 stamp"]);
    std::fs::write(&late, "start_time_ns: -5\n").unwrap();
    fails_cleanly(&simulate(&["--config", &late.display().to_string(), "-o", &o]), &["ROS 2 stamp"]);
    // The bag and its truth at one path: the YAML replaced the bag before.
    fails_cleanly(&simulate(&["--seconds", "1", "--truth", &o, "-o", &o]), &["--output and --truth are the same file"]);
    assert!(!Path::new(&o).exists());
    // A config that sets only terms takes the flags and the defaults for the rest.
    let terms_only = dir.path().join("terms.yaml");
    std::fs::write(&terms_only, "terms:\n  - {term: gyro_bias, bias: [0.01, 0, 0]}\n").unwrap();
    let stdout = ok(&simulate(&["--config", &terms_only.display().to_string(), "--profile", "car", "--seconds", "1", "-o", &o]));
    assert!(stdout.contains("car / mpu-9250") && stdout.contains("gyro_bias"), "{stdout}");
}
