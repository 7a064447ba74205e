//! `imu-fsda inject`: known terms applied to a recorded bag, the rest of it unchanged; bad
//! terms and an output over the input are refused before anything is written.

use std::path::Path;
use std::process::{Command, Output};

mod common;

use common::bin;
use imu_fsda::bag::{read_recording, RecordingTopics};

fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().expect("run imu-fsda")
}

fn simulate(out: &Path) {
    let o = run(&["simulate", "--profile", "car", "--seconds", "20", "-o", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn a_gyro_scale_is_applied_and_nothing_else_changes() {
    let tmp = tempfile::tempdir().unwrap();
    let (input, output) = (tmp.path().join("in.mcap"), tmp.path().join("out.mcap"));
    simulate(&input);
    let o = run(&[
        "inject",
        input.to_str().unwrap(),
        "--term",
        "{term: gyro_scale, scale: [0.02, -0.01, 0.0]}",
        "-o",
        output.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, _) = read_recording(&input, &RecordingTopics::default()).unwrap();
    let (b, _) = read_recording(&output, &RecordingTopics::default()).unwrap();
    assert_eq!(a.imu.len(), b.imu.len());
    assert_eq!(a.ground_truth.len(), b.ground_truth.len());
    for (x, y) in a.imu.iter().zip(&b.imu) {
        assert_eq!(x.stamp_ns, y.stamp_ns);
        assert_eq!(x.accel, y.accel);
        for (k, s) in [1.02, 0.99, 1.0].into_iter().enumerate() {
            assert!((y.gyro[k] - s * x.gyro[k]).abs() <= 1e-12 * (1.0 + x.gyro[k].abs()), "axis {k}: {} against {}", y.gyro[k], x.gyro[k]);
        }
    }
    for (p, q) in a.ground_truth.iter().zip(&b.ground_truth) {
        // Written and read again: the quaternion renormalised, nothing more.
        assert!(p.stamp_ns == q.stamp_ns && p.world_from_body.angle_to(&q.world_from_body) < 1e-12, "{p:?} against {q:?}");
    }
}

#[test]
fn bad_terms_and_overwriting_the_input_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (input, output) = (tmp.path().join("in.mcap"), tmp.path().join("out.mcap"));
    simulate(&input);
    let (i, out) = (input.to_str().unwrap(), output.to_str().unwrap());
    for (term, says) in [
        ("{term: gyro_wobble, x: 1}", "gyro_wobble"),
        ("{term: gyro_scale, scale: [0.01, 0]}", "--term #1"),
        ("{term: gyro_bias, bias: [.nan, 0, 0]}", "applying the terms"),
    ] {
        let o = run(&["inject", i, "--term", term, "-o", out]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(says), "{term}: {e}");
        assert!(!output.exists(), "{term}: an output was written");
    }
    let o = run(&["inject", i, "--term", "{term: gyro_bias, bias: [0.01, 0, 0]}", "-o", i]);
    assert!(!o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(read_recording(&input, &RecordingTopics::default()).is_ok(), "the input was damaged");
}
