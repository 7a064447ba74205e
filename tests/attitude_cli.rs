//! `imu-fsda attitude` on bags the node's pipeline wrote (`imu-fsda replay`): its figures
//! against an independent reader (tests/python/independent_attitude.py: rosbags, rotation
//! matrices), whether the covariance the node states covers its tilt error on the bundled
//! bags, and clear errors for bags it cannot score.

use std::path::Path;
use std::process::Command;

mod common;

use common::{bin, manifest_dir as repo, venv_python as python};

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().expect("run");
    assert!(out.status.success(), "{cmd:?} failed: {}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

/// `imu-fsda replay BAG MODEL_ARGS [--params P] -o DIR/TAG.mcap`, then `imu-fsda attitude` on
/// it: the row's errors.
fn replay_and_score(bag: &Path, model_args: &[String], params: Option<&Path>, dir: &Path, tag: &str) -> serde_json::Value {
    let out = dir.join(format!("{tag}.mcap"));
    let mut cmd = Command::new(bin());
    cmd.arg("replay").arg(bag).arg("-o").arg(&out).args(model_args);
    if let Some(p) = params {
        cmd.arg("--params").arg(p);
    }
    run(&mut cmd);
    let json = dir.join(format!("{tag}.json"));
    run(Command::new(bin()).arg("attitude").arg(&out).arg("--json").arg(&json));
    let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    doc["rows"][0]["errors"].clone()
}

/// The bundled bags through the node's pipeline (pass-through: the orientation is the raw
/// gyro's from the gravity start-up), scored by `attitude` and by the independent reader.
#[test]
fn published_attitude_matches_an_independent_reader_and_its_covariance_covers_it() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let params = repo().join("params/imu_fsda.yaml");
    for name in ["sim_aerial", "sim_car", "sim_handheld", "sim_quadruped"] {
        let input = repo().join(format!("test_bags/{name}.mcap"));
        let out = dir.path().join(format!("{name}-denoised.mcap"));
        run(Command::new(bin()).arg("replay").arg(&input).arg("-o").arg(&out).arg("--params").arg(&params).args(["--model", ""]));
        let json = dir.path().join(format!("{name}.json"));
        let table = run(Command::new(bin()).arg("attitude").arg(&out).arg("--json").arg(&json));
        assert!(table.contains("| AOE° |") && table.contains("| tilt NEES (2: consistent) |"), "{table}");
        let cells = |line: &str| line.matches('|').count();
        let lines: Vec<&str> = table.lines().collect();
        assert!(lines.iter().all(|l| cells(l) == cells(lines[0])), "every row has the header's cells:\n{table}");
        let doc: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let ours = &doc["rows"][0]["errors"];
        let theirs: serde_json::Value =
            serde_json::from_str(&run(Command::new(&py).arg(repo().join("tests/python/independent_attitude.py")).arg(&out))).unwrap();
        for key in [
            "first_attitude_s",
            "seconds",
            "tilt_initial_deg",
            "tilt_rmse_deg",
            "tilt_max_deg",
            "heading_rmse_deg",
            "heading_final_deg",
            "aoe_deg",
            "tilt_nees_mean",
            "tilt_within_95",
        ] {
            let (a, b) = (ours[key].as_f64().unwrap(), theirs[key].as_f64().unwrap());
            assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{name} {key}: ours {a}, independent {b}");
        }
        assert_eq!(ours["evaluated"], theirs["evaluated"], "{name}");
        // The stated tilt σ covers the error (before the start-up turned the samples' gravity
        // with the body, sim_aerial's tilt was 19.7° off and 27 % of it within the bound).
        let within = ours["tilt_within_95"].as_f64().unwrap();
        assert!(within >= 0.95, "{name}: {:.0} % of the tilt errors within the stated 95 % bound\n{table}", 100.0 * within);
    }
}

#[test]
fn bags_it_cannot_score_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let input = repo().join("test_bags/sim_car.mcap");
    let fail = |args: &[&str]| {
        let out = Command::new(bin()).args(args).output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{args:?}: {}", String::from_utf8_lossy(&out.stdout));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let bag = input.to_str().unwrap();
    // The raw IMU carries no orientation (REP 145: covariance[0] = -1).
    let err = fail(&["attitude", bag, "--topic", "/imu/data"]);
    assert!(err.contains("none of the 4000 messages on /imu/data carries an orientation"), "{err}");
    // No node output in the bag at all: the topics that are there are named.
    let err = fail(&["attitude", bag]);
    assert!(err.contains("/imu/denoised") && err.contains("/imu/data [sensor_msgs/msg/Imu]"), "{err}");
    // Another type on the topic, and the ground truth's own topic.
    let err = fail(&["attitude", bag, "--topic", "/imu/temperature"]);
    assert!(err.contains("sensor_msgs/msg/Temperature") && err.contains("sensor_msgs/msg/Imu"), "{err}");
    let err = fail(&["attitude", bag, "--topic", "/ground_truth/pose"]);
    assert!(err.contains("both /ground_truth/pose"), "{err}");
    // --json over the input is refused before anything is written.
    let copy = dir.path().join("in.mcap");
    std::fs::copy(&input, &copy).unwrap();
    let before = std::fs::read(&copy).unwrap();
    let out = Command::new(bin()).args(["attitude", copy.to_str().unwrap(), "--json", copy.to_str().unwrap()]).output().unwrap();
    assert!(!out.status.success());
    assert_eq!(std::fs::read(&copy).unwrap(), before, "the input was overwritten");
}

/// `pipeline.orientation: gravity_aided` (the default) against the open loop on what the node meets: a
/// 10-minute simulated hand-held consumer IMU with no model (the open loop drifts by tens of
/// degrees), and EuRoC V1_03 with the bundled model as trained on it. The tilt is held by
/// gravity, the stated covariance still covers it, and the heading stays the gyro's.
#[test]
fn gravity_aided_orientation_holds_the_tilt_and_states_its_error() {
    let Some(data) = common::shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let open_loop = d.join("open.yaml");
    std::fs::write(&open_loop, "imu_fsda:\n  ros__parameters:\n    pipeline:\n      orientation: open_loop\n").unwrap();
    let sim = d.join("handheld.mcap");
    run(Command::new(bin())
        .args(["simulate", "--profile", "handheld", "--grade", "mpu-9250", "--datasheet-errors"])
        .args(["--seconds", "600", "--seed", "5", "-o"])
        .arg(&sim));
    let euroc = d.join("V1_03.mcap");
    run(Command::new(bin()).arg("import").arg(data.join("euroc/V1_03_difficult")).arg("-o").arg(&euroc));
    let model = repo().join("models/fsda-f.pt");
    for (bag, model_args) in [
        (&sim, vec!["--model".to_string(), String::new()]),
        (&euroc, vec!["--model".into(), model.display().to_string(), "--imu".into(), "euroc".into()]),
    ] {
        let score = |params: Option<&Path>, tag: &str| replay_and_score(bag, &model_args, params, d, tag);
        let name = bag.file_stem().unwrap().to_string_lossy().to_string();
        // Gravity aided is the default.
        let (open, fused) = (score(Some(&open_loop), &format!("{name}-open")), score(None, &format!("{name}-aided")));
        let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
        eprintln!(
            "{name}: tilt RMS open loop {:.2}°, gravity aided {:.2}° (within 95 %: {:.0} %, NEES {:.2}); heading drift RMS {:.2}° / {:.2}°",
            f(&open, "tilt_rmse_deg"),
            f(&fused, "tilt_rmse_deg"),
            100.0 * f(&fused, "tilt_within_95"),
            f(&fused, "tilt_nees_mean"),
            f(&open, "heading_rmse_deg"),
            f(&fused, "heading_rmse_deg")
        );
        assert!(f(&fused, "tilt_rmse_deg") < 0.7 * f(&open, "tilt_rmse_deg"), "{name}: {fused} against {open}");
        assert!(f(&fused, "tilt_within_95") >= 0.95, "{name}: the stated tilt covariance does not cover the error: {fused}");
        // Gravity says nothing of heading; the bias the filter finds about tilted axes moves it
        // a little either way (measured: +11 % on this simulation, −2 % on V1_03), never far.
        assert!(f(&fused, "heading_rmse_deg") < 1.25 * f(&open, "heading_rmse_deg").max(1.0), "{name}: heading {fused} against {open}");
    }
}

/// `pipeline.platform: car`: simulated cars (a consumer IMU, 5 minutes, a rest of 5 s, bends
/// of up to 5 m/s² and brakings; three seeds) whose published tilt, gravity aided, takes their
/// bends for tilts when their accelerations are noise, and follows the truth when the forward
/// speed predicts them; the stated σ covering it either way. (Over seeds 7 and 11–15 declared
/// is 0.41–0.64 × any platform's tilt; until 2026-12-07 this test took seed 7 alone, at 0.48.)
#[test]
fn a_car_declared_as_one_holds_its_tilt_through_its_bends() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let car = d.join("car.yaml");
    std::fs::write(&car, "imu_fsda:\n  ros__parameters:\n    pipeline:\n      platform: car\n").unwrap();
    let no_model = ["--model".to_string(), String::new()];
    let (mut any_sum, mut declared_sum) = (0.0, 0.0);
    for seed in ["7", "11", "12"] {
        let bag = d.join(format!("car{seed}.mcap"));
        run(Command::new(bin())
            .args(["simulate", "--profile", "car", "--grade", "mpu-9250", "--datasheet-errors", "--seconds", "300", "--seed", seed])
            .args(["--rest-s", "5", "-o"])
            .arg(&bag));
        let tilt = |params: Option<&Path>, name: &str| {
            let e = replay_and_score(&bag, &no_model, params, d, name);
            (e["tilt_rmse_deg"].as_f64().unwrap(), e["tilt_within_95"].as_f64().unwrap())
        };
        let (any, any_within) = tilt(None, &format!("any{seed}"));
        let (declared, declared_within) = tilt(Some(&car), &format!("declared{seed}"));
        // /diagnostics says which attitude runs, and the speed it carries.
        let said =
            run(Command::new(bin()).arg("bag").arg("echo").arg(d.join(format!("declared{seed}.mcap"))).args(["--topic", "/diagnostics"]));
        let last = said.lines().last().expect("/diagnostics was written");
        assert!(last.contains("gravity aided: ") && last.contains("a car, forward speed"), "{last}");
        eprintln!("car seed {seed}, 5 min: tilt RMS {any:.2}° as any platform, {declared:.2}° declared a car");
        assert!(declared < any, "seed {seed}: {declared}° declared a car against {any}° as any platform");
        assert!(any_within >= 0.95 && declared_within >= 0.95, "seed {seed}, within the stated 95 %: {any_within}, {declared_within}");
        (any_sum, declared_sum) = (any_sum + any, declared_sum + declared);
    }
    assert!(
        declared_sum < 0.7 * any_sum,
        "mean tilt {:.2}° declared a car against {:.2}° as any platform",
        declared_sum / 3.0,
        any_sum / 3.0
    );
}
