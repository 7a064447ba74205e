//! `imu-fsda eval`: what it scores, and what it says of a recording's faults (implausible or
//! clipped samples, holes, frozen ground truth, another rate than the model's).

use std::path::Path;
use std::process::Command;

use imu_fsda::bag::{read_recording, BagReader, RecordingTopics};
use imu_fsda::model::predict::correct_with_torchscript;
use imu_fsda::model::Mode;
use imu_fsda::msg::RosMessage;

mod common;
use common::bin;
use common::random_model::{car_recording, euroc_bag, export_random_model};

/// `imu-fsda eval <args> --json rows.json <bag>`'s first row.
fn eval_first_row(dir: &Path, bag: &Path, args: &[&str]) -> serde_json::Value {
    let json = dir.join("rows.json");
    let out = Command::new(bin()).arg("eval").args(args).arg("--json").arg(&json).arg(bag).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["rows"][0].clone()
}

/// eval drops a value no IMU measures, as the node does, and says so in the row: one 1e30
/// rad/s sample would otherwise decide the score.
#[test]
fn eval_drops_implausible_samples_and_says_so() {
    let d = tempfile::tempdir().unwrap();
    let clean = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let mut rec = car_recording();
    let k = rec.imu.len() / 2;
    rec.imu[k].gyro = nalgebra::Vector3::new(1e30, 0.0, 0.0);
    let bad = d.path().join("implausible.mcap");
    imu_fsda::bag::write_recording(&bad, &rec).unwrap();
    let (clean_row, bad_row) =
        (eval_first_row(d.path(), &clean, &["--method", "raw"]), eval_first_row(d.path(), &bad, &["--method", "raw"]));
    let aoe = |r: &serde_json::Value| r["aoe_deg"].as_f64().unwrap();
    assert!(bad_row["note"].as_str().unwrap().contains("dropped 1 implausible IMU samples"), "{bad_row}");
    // One 5-ms sample less: the same score to a small fraction of it.
    assert!((aoe(&bad_row) - aoe(&clean_row)).abs() < 0.01 * aoe(&clean_row) + 1e-3, "{clean_row} vs {bad_row}");
}

/// A hole in the IMU stream is said on every row (the figure alone hid it), and crossed by the
/// ground truth's rotation over it, not by the last rate held.
#[test]
fn eval_says_where_the_imu_stream_has_a_hole() {
    let d = tempfile::tempdir().unwrap();
    let mut rec = car_recording();
    let t0 = rec.imu[0].stamp_ns;
    rec.imu.retain(|s| !(5_000_000_000..7_000_000_000).contains(&(s.stamp_ns - t0)));
    // 40 ms: longer than the node's gap (5 periods, 25 ms).
    rec.imu.retain(|s| !(10_000_000_000..10_035_000_000).contains(&(s.stamp_ns - t0)));
    let bag = d.path().join("hole.mcap");
    imu_fsda::bag::write_recording(&bag, &rec).unwrap();
    let row = eval_first_row(d.path(), &bag, &["--method", "raw"]);
    let note = row["note"].as_str().unwrap();
    assert!(note.contains("2 hole(s) in the IMU stream (longest 2.005 s) crossed by the ground truth's rotation"), "{row}");
    assert_eq!((row["imu_gaps"].as_u64(), row["imu_gaps_held"].as_u64()), (Some(2), Some(0)), "{row}");
}

/// A gyro held at its range is said by eval on every row and counted in replay's /diagnostics
/// (both used it silently before).
#[test]
fn clipped_samples_are_said() {
    let d = tempfile::tempdir().unwrap();
    let mut rec = car_recording();
    // A 1-Hz roll swing of 3 rad/s through a 125 °/s range (on top of the car's motion: the
    // figures are not the point).
    const RANGE: f64 = 125.0 * std::f64::consts::PI / 180.0;
    let t0 = rec.imu[0].stamp_ns;
    for s in &mut rec.imu {
        let t = (s.stamp_ns - t0) as f64 * 1e-9;
        s.gyro.x = (s.gyro.x + 3.0 * (std::f64::consts::TAU * t).sin()).clamp(-RANGE, RANGE);
    }
    let bag = d.path().join("clipped.mcap");
    imu_fsda::bag::write_recording(&bag, &rec).unwrap();
    let at_range = rec.imu.iter().filter(|s| s.gyro.x.abs() == RANGE).count();
    let row = eval_first_row(d.path(), &bag, &["--method", "raw"]);
    let note = row["note"].as_str().unwrap();
    assert!(note.contains(&format!("({at_range} gyro samples at ±2.182 rad/s)")), "{at_range}: {row}");
    let out = d.path().join("out.mcap");
    let o = Command::new(bin()).arg("replay").arg(&bag).arg("-o").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let last = BagReader::open(&out).unwrap().map(|m| m.unwrap()).filter(|m| &*m.topic == "/diagnostics").last().unwrap();
    let status = &imu_fsda::msg::DiagnosticArray::decode(&last.data).unwrap().status[0];
    let saturated: usize = status.values.iter().find(|kv| kv.key == "saturated_samples").unwrap().value.parse().unwrap();
    // Online, the first two clipped swings of each sign are not yet known as clipping.
    assert!(saturated > at_range / 4 && saturated < at_range, "{saturated} of {at_range}");
}

/// Ground truth that repeats one pose while the car turns (an INS in a tunnel) is left out as
/// a gap: scored as if those poses were missing, and said.
#[test]
fn eval_leaves_out_frozen_ground_truth() {
    let d = tempfile::tempdir().unwrap();
    let rec = car_recording();
    let g0 = rec.ground_truth[0].stamp_ns;
    let tunnel = |p: &imu_fsda::core::PoseSample| (4_000_000_000..16_000_000_000).contains(&(p.stamp_ns - g0));
    let mut frozen = rec.clone();
    let held = frozen.ground_truth.iter().rev().find(|p| p.stamp_ns - g0 < 4_000_000_000).unwrap().world_from_body;
    frozen.ground_truth.iter_mut().filter(|p| tunnel(p)).for_each(|p| p.world_from_body = held);
    let mut missing = rec.clone();
    missing.ground_truth.retain(|p| !tunnel(p));
    for (name, r) in [("frozen.mcap", &frozen), ("missing.mcap", &missing)] {
        imu_fsda::bag::write_recording(d.path().join(name), r).unwrap();
    }
    let f = eval_first_row(d.path(), &d.path().join("frozen.mcap"), &["--method", "raw"]);
    let m = eval_first_row(d.path(), &d.path().join("missing.mcap"), &["--method", "raw"]);
    assert!(f["note"].as_str().unwrap().contains("frozen ground-truth poses left out"), "{f}");
    assert_eq!((f["aoe_deg"].as_f64(), f["samples_in_gaps"].as_u64()), (m["aoe_deg"].as_f64(), m["samples_in_gaps"].as_u64()), "{f}\n{m}");
    assert!(m["samples_in_gaps"].as_u64().unwrap() > 700, "{m}");
}

/// A model on an IMU at another rate than it was trained for runs in its own periods, and
/// the row says so (before: run sample by sample, with the reason its figure was out of the
/// model's domain; a number alone before that).
#[test]
fn eval_says_when_the_imu_rate_is_not_the_models() {
    let d = tempfile::tempdir().unwrap();
    let mut rec = car_recording();
    rec.imu = rec.imu.iter().step_by(2).copied().collect();
    let bag = d.path().join("car_100hz.mcap");
    imu_fsda::bag::write_recording(&bag, &rec).unwrap();
    let model = export_random_model(d.path(), Mode::FsdaF, 31, false);
    let row = eval_first_row(d.path(), &bag, &["--model", model.to_str().unwrap()]);
    assert!(row["note"].as_str().unwrap().contains("the 100.0 Hz input run in the model's 200 Hz periods"), "{row}");
}

/// A model with one Ĉ_ω for every IMU (the DIGDL baseline, trained on EuRoC alone) runs where
/// the bag is named as the IMU it was trained on (`--imu`, a `?` in the pattern matching one
/// character as in the shell); unnamed, or named as another IMU, it is a new IMU to the model:
/// the guard scores it alone and beside it what the node runs instead.
#[test]
fn a_model_runs_on_the_imu_it_was_trained_on_when_named() {
    let d = tempfile::tempdir().unwrap();
    let bag = d.path().join("V1_01_copy.mcap");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"), &bag).unwrap();
    let digdl = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/digdl-euroc.pt");
    let rows = |imu: &[&str]| {
        let json = d.path().join("rows.json");
        let out = Command::new(bin()).arg("eval").arg("--model").arg(&digdl).args(imu).arg("--json").arg(&json).arg(&bag).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        v["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| (r["method"].as_str().unwrap().to_string(), r["note"].as_str().unwrap().to_string()))
            .collect::<Vec<_>>()
    };
    let named = rows(&["--imu", "V?_*=euroc"]);
    assert_eq!(named.len(), 1, "the model runs, nothing in its place: {named:?}");
    assert!(named[0].1.contains("as on IMU euroc (trained on it)"), "{named:?}");
    for other in [&[][..], &["--imu", "tumvi"][..], &["--imu", "V?=euroc"][..]] {
        let guarded = rows(other);
        assert_eq!(guarded.len(), 2, "{other:?}: {guarded:?}");
        assert!(guarded[0].1.contains("the model alone") && guarded[1].0 == "digdl-euroc as deployed", "{other:?}: {guarded:?}");
        assert!(guarded[1].1.contains("neither trained nor adapted on this IMU"), "{other:?}: {guarded:?}");
    }
}

/// Recordings that cannot be scored as they are (a gyro in °/s, an accelerometer in g,
/// ground truth 3 s off the IMU's clock) are scored as recorded and say why on the row (they
/// were silent before); stamps that are not set are refused; a bag that cannot be read among
/// others is a row saying why, the others' rows kept, and the command exits 1.
#[test]
fn eval_says_what_is_wrong_with_a_recording() {
    let d = tempfile::tempdir().unwrap();
    let bag_of = |name: &str, f: &dyn Fn(&mut imu_fsda::core::Recording)| {
        let mut rec = car_recording();
        f(&mut rec);
        let bag = d.path().join(name);
        imu_fsda::bag::write_recording(&bag, &rec).unwrap();
        bag
    };
    type Edit<'a> = &'a dyn Fn(&mut imu_fsda::core::Recording);
    let cases: [(&str, Edit, &str); 3] = [
        ("degps.mcap", &|r| r.imu.iter_mut().for_each(|s| s.gyro *= 180.0 / std::f64::consts::PI), "the gyro is not in rad/s"),
        ("in_g.mcap", &|r| r.imu.iter_mut().for_each(|s| s.accel /= 9.80665), "in g, not m/s²"),
        ("late.mcap", &|r| r.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 3_000_000_000), "ground truth lags the IMU by 299"),
    ];
    for (name, f, says) in cases {
        let row = eval_first_row(d.path(), &bag_of(name, f), &["--method", "raw"]);
        assert!(row["note"].as_str().unwrap().contains(says), "{name}: {row}");
    }
    let unset = bag_of("unset.mcap", &|r| r.imu.iter_mut().for_each(|s| s.stamp_ns = 0));
    let out = Command::new(bin()).arg("eval").arg(&unset).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("header.stamp is not set"), "{err}");

    let good = bag_of("good.mcap", &|_| {});
    let json = d.path().join("rows.json");
    let out = Command::new(bin()).args(["eval", "--method", "raw", "--json"]).arg(&json).arg(&good).arg(&unset).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("1 of 2 bags could not be evaluated"), "{err}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert!(rows[0]["aoe_deg"].is_number(), "{}", rows[0]);
    assert!(rows[1]["note"].as_str().unwrap().starts_with("not evaluated:"), "{}", rows[1]);
}

/// `eval --start-s` scores a span of what ran over the whole recording, as the node would have
/// run it: static-bias takes the initial rest before the span (before, it found none after
/// it), and a model's output over the span is its whole-recording output (before, it warmed up
/// again at the span's start).
#[test]
fn eval_scores_a_span_of_the_whole_run() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = euroc_bag(dir.path()) else { return };
    let model = export_random_model(dir.path(), Mode::FsdaF, 17, false);
    let args = ["--method", "static-bias", "--model", model.to_str().unwrap()];
    let whole = eval_first_row(dir.path(), &bag, &args);
    let json = dir.path().join("span.json");
    let out = Command::new(bin()).arg("eval").args(args).args(["--start-s", "60", "--json"]).arg(&json).arg(&bag).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let (bias, model_row) = (&rows["rows"][0], &rows["rows"][1]);
    assert!(bias["aoe_deg"].is_f64(), "{bias}");
    assert_eq!(bias["note"], whole["note"], "the same rest and bias");

    let (rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
    let (gyro, _) = correct_with_torchscript(&model, &rec.imu, None).unwrap();
    let span = rec.crop_after_ground_truth_start(Some(60.0), None).unwrap();
    let start = rec.imu.iter().position(|s| s.stamp_ns == span.imu[0].stamp_ns).unwrap();
    let want = imu_fsda::eval::evaluate(&span, &gyro[start..start + span.imu.len()], &Default::default()).unwrap();
    let got = model_row["aoe_deg"].as_f64().unwrap();
    assert!((got - want.aoe_deg).abs() < 1e-9, "{got} against {}", want.aoe_deg);
}
