//! The node's pipeline on a real bag (`imu-fsda replay`) against the offline full-sequence
//! evaluation of the same model: online = offline. Also: bad model files are clear errors
//! at start, never panics; so are missing and damaged input bags.

use std::path::{Path, PathBuf};
use std::process::Command;

use imu_fsda::bag::{read_recording, BagReader, RecordingTopics};
use imu_fsda::model::export::{export_model, ExportInfo};
use imu_fsda::model::predict::{correct_with_torchscript, correct_with_weights_f64};
use imu_fsda::model::{Config, Mode, Net};
use imu_fsda::msg::{Imu, RosMessage, Vector3Stamped};
use imu_fsda::so3::integrate_gyro;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

mod common;
use common::bin;

/// How far the node's f32 networks may be from the same weights run in f64: f32's rounding
/// over ~80 k multiply-adds (measured 3e-9 rad/s), far inside the 1e-5 rad/s bound against
/// the TorchScript file.
const F32_ROUNDING_RAD_S: f64 = 1e-7;

/// A seeded model with random weights and EuRoC-like normalisation, exported to `dir`; with
/// `per_imu`, one random Ĉ_ω each for `euroc` and `tumvi`.
fn export_random_model(dir: &Path, mode: Mode, seed: i64, per_imu: bool) -> PathBuf {
    export_random_model_with_gains(dir, mode, seed, per_imu, Default::default())
}

/// [`export_random_model`] with per-IMU correction gains in its metadata.
fn export_random_model_with_gains(
    dir: &Path,
    mode: Mode,
    seed: i64,
    per_imu: bool,
    imu_correction_gains: std::collections::BTreeMap<String, f64>,
) -> PathBuf {
    tch::manual_seed(seed);
    let vs = VarStore::new(Device::Cpu);
    let imu_calibrations = if per_imu { vec!["euroc".into(), "tumvi".into()] } else { vec![] };
    let net = Net::new(&Config { imu_calibrations, ..Config::for_mode(mode) }, &vs.root()).unwrap();
    if let Some(per_imu) = vs.variables().get("gyro_calib.per_imu") {
        tch::no_grad(|| per_imu.shallow_clone().copy_(&(Tensor::randn([2, 3, 3], (Kind::Float, Device::Cpu)) * 0.02)));
    }
    net.set_normalization(&[0.0, 0.02, 0.08, 9.0, 0.0, -3.0], &[0.3, 0.3, 0.3, 1.0, 1.0, 1.0]).unwrap();
    for _ in 0..2 {
        let _ = net.forward_t(&(Tensor::randn([2, 600, 6], (Kind::Float, Device::Cpu)) * 0.5), true);
    }
    let paths = export_model(dir, "random", &vs, &net, &ExportInfo { imu_correction_gains, ..Default::default() }).unwrap();
    paths.torchscript
}

fn euroc_bag(dir: &Path) -> Option<PathBuf> {
    let seq = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/euroc/V1_01_easy");
    if !seq.is_dir() {
        common::skip_or_fail("the EuRoC bag", "../shared/data not found");
        return None;
    }
    let bag = dir.join("v101.mcap");
    let out = Command::new(bin()).arg("import").arg(&seq).arg("-o").arg(&bag).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    Some(bag)
}

#[test]
fn replay_equals_offline_full_sequence_evaluation() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = euroc_bag(dir.path()) else { return };
    // The open-loop orientation, checked against offline integration below (gravity aided is
    // the default: tests/attitude_cli.rs).
    let open_loop = dir.path().join("open.yaml");
    std::fs::write(&open_loop, "imu_fsda:\n  ros__parameters:\n    pipeline:\n      orientation: open_loop\n").unwrap();
    // The third: a model with one Ĉ_ω per IMU, run as `euroc`; the fourth: one shared Ĉ_ω and
    // a correction gain for `tumvi` (0.3), run as `tumvi`.
    for (mode, seed, imu) in
        [(Mode::FsdaF, 3, None), (Mode::Digdl, 4, None), (Mode::FsdaF, 7, Some("euroc")), (Mode::FsdaF, 11, Some("tumvi"))]
    {
        let model = match imu {
            Some("tumvi") => export_random_model_with_gains(dir.path(), mode, seed, false, [("tumvi".to_string(), 0.3)].into()),
            _ => export_random_model(dir.path(), mode, seed, imu.is_some()),
        };
        let out_bag = dir.path().join(format!("replayed-{mode:?}-{seed}.mcap"));
        let out = Command::new(bin())
            .args(["-v", "replay", "--model-on-new-imu", "--imu", imu.unwrap_or(""), "--params"])
            .arg(&open_loop)
            .arg("--model")
            .arg(&model)
            .arg(&bag)
            .arg("-o")
            .arg(&out_bag)
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{log}");
        if imu == Some("tumvi") {
            assert!(log.contains("its own Ĉ_ω, IMU \"tumvi\"'s correction gain 0.300"), "{log}");
        }

        let (rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
        let mut online = Vec::new();
        let mut orientation = Vec::new();
        let mut corrections = Vec::new();
        for m in BagReader::open(&out_bag).unwrap() {
            let m = m.unwrap();
            match &*m.topic {
                "/imu/denoised" => {
                    let msg = Imu::decode(&m.data).unwrap();
                    assert_eq!(msg.header.frame_id, "imu_link");
                    online.push((msg.header.stamp.to_ns(), nalgebra::Vector3::from(msg.angular_velocity)));
                    orientation.push(msg.orientation);
                }
                "/imu/gyro_correction" => corrections.push(nalgebra::Vector3::from(Vector3Stamped::decode(&m.data).unwrap().vector)),
                _ => {}
            }
        }
        assert_eq!(online.len(), rec.imu.len(), "one output per input");
        assert!(online.iter().zip(&rec.imu).all(|((t, _), s)| *t == s.stamp_ns), "stamps passed through");

        let (f32_ref, _) = correct_with_torchscript(&model, &rec.imu, imu).unwrap();
        let (f64_ref, _) = correct_with_weights_f64(&model, &rec.imu, imu).unwrap();
        if imu.is_some() {
            // Its own Ĉ_ω (I) and gain 1 give another output: the IMU's matrix or gain is applied.
            let (own, _) = correct_with_torchscript(&model, &rec.imu, None).unwrap();
            let d = own.iter().zip(&f32_ref).map(|(a, b)| (a - b).amax()).fold(0.0, f64::max);
            let correction = own.iter().zip(&rec.imu).map(|(o, s)| (o - s.gyro).amax()).fold(0.0, f64::max);
            assert!(d > 1e-3_f64.min(0.5 * correction), "{imu:?}'s Ĉ_ω or gain changes the output by only {d:.2e} rad/s");
            if imu == Some("tumvi") {
                let gained = own.iter().zip(&rec.imu).zip(&f32_ref).map(|((o, s), r)| (s.gyro + (o - s.gyro) * 0.3 - r).amax());
                assert!(gained.fold(0.0, f64::max) < 1e-5, "the gain is ω + g (ω̂ − ω)");
            }
        }
        let max_f32 = online.iter().zip(&f32_ref).map(|((_, w), r)| (w - r).amax()).fold(0.0, f64::max);
        let max_f64 = online.iter().zip(&f64_ref).map(|((_, w), r)| (w - r).amax()).fold(0.0, f64::max);
        eprintln!(
            "{mode:?} {imu:?}: online vs offline TorchScript (f32) max |Δω| = {max_f32:.2e} rad/s; vs f64 weights {max_f64:.2e} rad/s"
        );
        assert!(max_f32 < 1e-5, "{max_f32}");
        // The networks run in f32 (the f64 reference equals the f64 forward to 1e-16:
        // model::streaming's tests): within f32's rounding of the f64 weights' output.
        assert!(max_f64 < F32_ROUNDING_RAD_S, "{max_f64}");
        let max_corr = corrections.iter().zip(&online).zip(&rec.imu).map(|((c, (_, w)), s)| (c - (w - s.gyro)).amax()).fold(0.0, f64::max);
        assert!(max_corr < 1e-12);

        // The published orientation is the open-loop integral of the published gyro from the
        // node's initial attitude (gravity after 0.5 s), with the real dt.
        let k0 = orientation.iter().position(|q| q.w != 1.0 || q.x != 0.0).unwrap();
        let q0 = orientation[k0].to_unit().unwrap();
        let gyro: Vec<_> = online.iter().map(|(_, w)| *w).collect();
        let path = integrate_gyro(&rec.imu[k0..], q0, |n| gyro[k0 + n]);
        let worst = path.iter().zip(&orientation[k0..]).map(|(a, b)| a.angle_to(&b.to_unit().unwrap())).fold(0.0, f64::max);
        assert!(worst < 1e-9, "orientation differs from offline integration by {worst} rad");
    }
}

#[test]
fn bad_model_files_are_clear_errors_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("tiny.mcap");
    let rec = imu_fsda::core::Recording {
        name: "tiny".into(),
        imu: (0..50)
            .map(|k| imu_fsda::core::ImuSample {
                stamp_ns: k * 5_000_000,
                gyro: Default::default(),
                accel: nalgebra::Vector3::new(0.0, 0.0, 9.81),
            })
            .collect(),
        ..Default::default()
    };
    imu_fsda::bag::write_recording(&bag, &rec).unwrap();
    // `replay` with `model` run as IMU `imu` ("" = its own Ĉ_ω) must fail cleanly.
    let named = |model: &Path, imu: &str| {
        let out = Command::new(bin())
            .args(["replay", "--imu", imu, "--model"])
            .arg(model)
            .arg(&bag)
            .arg("-o")
            .arg(dir.path().join("o.mcap"))
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1), "an error exit, not a crash");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let run = |model: &Path| named(model, "");
    let err = run(&dir.path().join("missing.pt"));
    assert!(err.contains("missing"), "{err}");

    let model = export_random_model(dir.path(), Mode::Fsda, 5, false);
    std::fs::write(model.with_extension("ot"), b"garbage").unwrap();
    let err = run(&model);
    assert!(err.contains("random"), "{err}");

    // Weights of one architecture under the metadata of another: a shape mismatch.
    // An IMU the model has no Ĉ_ω for, and any IMU for a model with one shared Ĉ_ω.
    let per_imu = export_random_model(dir.path(), Mode::FsdaF, 8, true);
    let err = named(&per_imu, "bmi088");
    assert!(err.contains("bmi088") && err.contains("tumvi"), "{err}");
    let shared = export_random_model(dir.path(), Mode::FsdaF, 9, false);
    let err = named(&shared, "euroc");
    assert!(err.contains("shared"), "{err}");
    // A correction gain no export writes (a share of the correction is in [0, 1]): named,
    // not found later as outputs that differ by inf in the start-up check.
    let gains = [("euroc".to_string(), 1e308)].into_iter().collect();
    let damaged = export_random_model_with_gains(dir.path(), Mode::FsdaF, 10, false, gains);
    let err = named(&damaged, "euroc");
    assert!(err.contains("correction gain in the metadata is 1e308"), "{err}");

    let model = export_random_model(dir.path(), Mode::Digdl, 6, false);
    let meta_path = model.with_extension("json");
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&meta_path).unwrap()).unwrap();
    meta["config"]["digdl"]["hidden_channels"] = serde_json::json!([8, 16, 32, 64]);
    std::fs::write(&meta_path, serde_json::to_string(&meta).unwrap()).unwrap();
    let err = run(&model);
    assert!(err.contains("loading model"), "{err}");
}

/// A missing or damaged input bag is named as such (not as a bag without an IMU topic), and
/// each cause of the error is said once.
#[test]
fn missing_and_damaged_bags_are_said_so_once() {
    let dir = tempfile::tempdir().unwrap();
    let damaged = dir.path().join("damaged.mcap");
    std::fs::write(&damaged, b"not an mcap file at all").unwrap();
    for cmd in ["replay", "eval"] {
        for (bag, says) in [(dir.path().join("missing.mcap"), "No such file"), (damaged.clone(), "not a readable MCAP bag")] {
            let mut c = Command::new(bin());
            c.arg(cmd).arg(&bag);
            if cmd == "replay" {
                c.arg("-o").arg(dir.path().join("o.mcap"));
            }
            let out = c.output().unwrap();
            assert_eq!(out.status.code(), Some(1), "{cmd} {}: an error exit, not a crash", bag.display());
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(err.contains(&*bag.to_string_lossy()) && err.contains(says), "{cmd}: {err}");
            assert!(!err.contains("neither"), "{cmd}: blamed the topics: {err}");
            let last = err.lines().last().unwrap_or_default();
            assert_eq!(last.matches(says).count(), 1, "{cmd}: said once: {last}");
        }
    }
}

/// An output that is also an input, by another spelling too, is refused before anything is
/// written: the recording and the model being read stay whole.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let bag = dir.path().join("car.mcap");
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"), &bag).unwrap();
    let model = export_random_model(dir.path(), Mode::FsdaF, 12, false);
    let same_bag = dir.path().join(".").join("car.mcap");
    // A hard link is the same file under another name (the replay truncated its input before).
    let linked_bag = dir.path().join("linked.mcap");
    std::fs::hard_link(&bag, &linked_bag).unwrap();
    let model_json = model.with_extension("json");
    let before = [std::fs::read(&bag).unwrap(), std::fs::read(&model).unwrap(), std::fs::read(&model_json).unwrap()];
    for args in [
        vec!["replay".into(), bag.clone(), "-o".into(), same_bag.clone()],
        vec!["replay".into(), bag.clone(), "-o".into(), linked_bag.clone()],
        // embed writes <out>.png, .csv and .json: the model's metadata was replaced before.
        vec![
            "embed".into(),
            "--model".into(),
            model.clone(),
            "--sequence".into(),
            bag.clone(),
            "--out".into(),
            model.with_extension("png"),
        ],
        vec!["eval".into(), bag.clone(), "--json".into(), same_bag.clone()],
        vec!["adapt".into(), "--model".into(), model.clone(), "--bag".into(), bag.clone(), "-o".into(), model.clone()],
    ] {
        let out = Command::new(bin()).args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("is also an input"), "{args:?}: {err}");
    }
    assert!(
        before == [std::fs::read(&bag).unwrap(), std::fs::read(&model).unwrap(), std::fs::read(&model_json).unwrap()],
        "an input was changed"
    );
    // Two outputs at one path: the Markdown replaced the JSON before.
    let same = dir.path().join("same.txt");
    let out = Command::new(bin()).arg("eval").arg(&bag).arg("--json").arg(&same).arg("--markdown").arg(&same).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("--json and --markdown are the same file"), "{err}");
    // Two bags with one file stem get a row each under their own label.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(&bag, other.join("car.mcap")).unwrap();
    let json = dir.path().join("rows.json");
    let out =
        Command::new(bin()).args(["eval", "--method", "raw", "--json"]).arg(&json).arg(&bag).arg(other.join("car.mcap")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let labels: Vec<&str> = v["rows"].as_array().unwrap().iter().map(|r| r["bag"].as_str().unwrap()).collect();
    assert!(labels.len() == 2 && labels[0] != labels[1] && labels[1].ends_with("other_car"), "{labels:?}");
}

/// Numeric options that are NaN, infinite, negative or too large for a clock are refused when
/// the command line is read, naming the option, with a usage error (exit 2): before, an
/// infinite or huge `--idle-exit-s` / `--wait-for-subscribers-s` or a tiny `--rate` panicked
/// converting to a `Duration`, and a NaN `--rate` or `--max-gap-ms` ran silently.
#[test]
fn numeric_options_out_of_range_are_refused_by_name() {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let bag = bag.to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["node", "--idle-exit-s", "inf"], "--idle-exit-s"),
        (&["node", "--idle-exit-s", "nan"], "--idle-exit-s"),
        (&["node", "--idle-exit-s=-1"], "--idle-exit-s"),
        (&["play", bag, "--wait-for-subscribers-s", "1e30"], "--wait-for-subscribers-s"),
        (&["play", bag, "--rate", "nan"], "--rate"),
        (&["play", bag, "--rate", "1e-300"], "--rate"),
        (&["play", bag, "--rate=-2"], "--rate"),
        (&["play", bag, "--queue-depth", "0"], "--queue-depth"),
        (&["eval", bag, "--max-gap-ms", "nan"], "--max-gap-ms"),
        (&["eval", bag, "--max-gap-ms", "0"], "--max-gap-ms"),
        (&["eval", bag, "--end-s", "inf"], "--end-s"),
        (&["diagnose", "--real", bag, "-o", "unused", "--threshold", "nan"], "--threshold"),
        (&["diagnose", "--real", bag, "-o", "unused", "--gt-smoothing=-1"], "--gt-smoothing"),
        (&["bench", "--memory-hours", "inf"], "--memory-hours"),
        (&["bench", "--memory-hours", "1e300"], "--memory-hours"),
        (&["bench", "--samples", "0"], "--samples"),
        (&["adapt", "--model", "m.pt", "--bag", bag, "-o", "x.pt", "--query-seconds=-1"], "--query-seconds"),
        (&["adapt", "--model", "m.pt", "--bag", bag, "-o", "x.pt", "--support-seconds", "1e300"], "--support-seconds"),
        (&["adapt", "--model", "m.pt", "--bag", bag, "-o", "x.pt", "--lr", "nan"], "--lr"),
        (&["embed", "--model", "m.pt", "--sequence", bag, "-o", "x.png", "--perplexity", "0"], "--perplexity"),
        (&["embed", "--model", "m.pt", "--sequence", bag, "-o", "x.png", "--points-per-sequence", "0"], "--points-per-sequence"),
    ];
    for (args, option) in cases {
        let out = Command::new(bin()).args(*args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: a usage error, not a run or a crash: {err}");
        assert!(err.contains(option) && err.contains("invalid value"), "{args:?}: {err}");
    }
    // --save-model saves the seeded default model: with --model there is none to save.
    let out = Command::new(bin()).args(["bench", "--model", bag, "--save-model", "x"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(2) && err.contains("cannot be used with"), "{err}");
    // A span with one sample in it is no path to score.
    let out = Command::new(bin()).args(["eval", bag, "--method", "raw", "--end-s", "0"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("fewer than 2 IMU samples"), "{err}");
    // A start past the ground truth names the option (it read "does not overlap the IMU").
    let out = Command::new(bin()).args(["eval", bag, "--method", "raw", "--start-s", "1e6"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("--start-s 1000000 is past the ground truth"), "{err}");
}

/// A robot whose graph enforces SROS2 security: the node, which does not implement DDS
/// Security, refuses to start instead of running on plain DDS (it fails before it creates a
/// participant: nothing is sent). The Permissive strategy: `node::environment`'s unit test.
#[test]
fn a_node_under_enforced_security_refuses_to_start_on_plain_dds() {
    let out = Command::new(bin())
        .args(["node", "--params", "params/imu_fsda.yaml"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env("ROS_SECURITY_ENABLE", "true")
        .env("ROS_SECURITY_STRATEGY", "Enforce")
        .env("ROS_SECURITY_KEYSTORE", "/nonexistent/keystore")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("ROS_SECURITY_STRATEGY=Enforce") && err.contains("does not start on plain DDS"), "{err}");
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

/// The bundled simulated car, as read.
fn car_recording() -> imu_fsda::core::Recording {
    read_recording(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap"), &RecordingTopics::default()).unwrap().0
}

/// `imu-fsda eval <args> --json rows.json <bag>`'s first row.
fn eval_first_row(dir: &Path, bag: &Path, args: &[&str]) -> serde_json::Value {
    let json = dir.join("rows.json");
    let out = Command::new(bin()).arg("eval").args(args).arg("--json").arg(&json).arg(bag).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["rows"][0].clone()
}

/// Channels copied through replay keep their metadata (rosbag2's offered_qos_profiles: a
/// /tf_static without its transient-local profile is never heard by tf2's static listener).
#[test]
fn replay_keeps_the_channels_metadata() {
    let d = tempfile::tempdir().unwrap();
    let qos = "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n";
    let input = d.path().join("with_qos.mcap");
    let mut w = imu_fsda::bag::BagWriter::create(&input).unwrap();
    let mut channels = std::collections::HashMap::new();
    for m in BagReader::open(Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap")).unwrap() {
        let mut m = m.unwrap();
        let mut extras = (*m.channel).clone();
        extras.metadata.insert("offered_qos_profiles".into(), format!("{qos}# {}", m.topic));
        m.channel = std::sync::Arc::new(extras);
        let ch = *channels.entry(m.topic.clone()).or_insert_with(|| w.channel_of(&m.topic, &m).unwrap());
        w.write_raw(ch, m.log_time_ns as i64, &m.data).unwrap();
    }
    w.finish().unwrap();
    let out = d.path().join("out.mcap");
    let o = Command::new(bin()).arg("replay").arg(&input).arg("-o").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut seen = 0;
    for m in BagReader::open(&out).unwrap() {
        let m = m.unwrap();
        if !m.topic.starts_with("/imu/denoised") && !m.topic.starts_with("/imu/gyro_correction") && &*m.topic != "/diagnostics" {
            assert_eq!(m.channel.metadata.get("offered_qos_profiles"), Some(&format!("{qos}# {}", m.topic)), "{}", m.topic);
            assert_eq!(m.channel.message_encoding, "cdr");
            seen += 1;
        }
    }
    assert!(seen > 1000, "{seen}");
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

/// replay's /diagnostics tick on the bag's clock through a hole in the IMU stream, saying "no
/// input" as the live node's timer would (they waited for the next IMU sample before).
#[test]
fn replay_says_no_input_through_an_imu_dropout() {
    let d = tempfile::tempdir().unwrap();
    let mut rec = car_recording();
    let t0 = rec.imu[0].stamp_ns;
    rec.imu.retain(|s| !(5_000_000_000..8_500_000_000).contains(&(s.stamp_ns - t0)));
    let bag = d.path().join("dropout.mcap");
    imu_fsda::bag::write_recording(&bag, &rec).unwrap();
    let out = d.path().join("out.mcap");
    let o = Command::new(bin()).arg("replay").arg(&bag).arg("-o").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut silent = Vec::new();
    let mut stamps = Vec::new();
    for m in BagReader::open(&out).unwrap() {
        let m = m.unwrap();
        if &*m.topic == "/diagnostics" {
            let s = &imu_fsda::msg::DiagnosticArray::decode(&m.data).unwrap().status[0];
            let at = (m.log_time_ns as i64 - t0) as f64 * 1e-9;
            stamps.push(at);
            if s.message.starts_with("no input for") {
                assert_eq!(s.level, imu_fsda::msg::DiagnosticStatus::ERROR);
                silent.push(at);
            }
        }
    }
    // Ticks every second; the last input before the hole is at 4.995 s, so the ticks at 6.0x,
    // 7.0x and 8.0x s find it more than 1 s old.
    assert_eq!(silent.len(), 3, "{silent:?}");
    assert!(silent.iter().all(|t| (6.0..8.5).contains(t)), "{silent:?}");
    assert!(stamps.windows(2).all(|w| w[1] - w[0] <= 1.0 + 1e-6), "{stamps:?}");
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

/// A reader that closes the pipe early (`| head`) ends a command quietly: exit 0, no panic.
#[test]
fn a_closed_stdout_ends_the_command_quietly() {
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let bag = bag.to_str().unwrap();
    // echo writes far more than a pipe holds; info writes after reading the whole bag.
    for args in [&["bag", "echo", "--topic", "/imu/data", bag][..], &["bag", "info", "--json", bag][..]] {
        let mut child =
            Command::new(bin()).args(args).stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success() && !err.contains("panicked"), "{args:?}: {:?} {err}", out.status);
    }
}

/// replay refuses what would give a bag of mixed or empty streams, and its /diagnostics carry
/// the input rate in the bag's time (0.00 before: it was taken from the wall clock).
#[test]
fn replay_streams_are_its_own_and_its_rate_is_the_bags() {
    let dir = tempfile::tempdir().unwrap();
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let replay = |input: &Path, out: &str, extra: &[&str]| {
        Command::new(bin()).arg("replay").arg(input).arg("-o").arg(dir.path().join(out)).args(extra).output().unwrap()
    };
    let fails = |o: std::process::Output, needle: &str| {
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.code() == Some(1) && err.contains(needle), "expected {needle:?}: {err}");
    };
    fails(replay(&bag, "a.mcap", &["--input-topic", "/ground_truth/pose"]), "holds geometry_msgs/msg/PoseStamped, not sensor_msgs/msg/Imu");
    fails(replay(&bag, "a.mcap", &["--input-topic", "/nope"]), "no /nope holding sensor_msgs/msg/Imu");
    fails(replay(&bag, "a.mcap", &["-r", "/imu/denoised:=/imu/data"]), "already holds /imu/data");
    fails(
        replay(&bag, "a.mcap", &["-r", "/imu/gyro_correction:=/imu/denoised"]),
        "output_topic and correction_topic are both /imu/denoised",
    );

    let o = replay(&bag, "first.mcap", &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("pass-through (no model)"), "{}", String::from_utf8_lossy(&o.stdout));
    let first = dir.path().join("first.mcap");
    let mut rates = Vec::new();
    for m in BagReader::open(&first).unwrap() {
        let m = m.unwrap();
        if &*m.topic == "/diagnostics" {
            let d = imu_fsda::msg::DiagnosticArray::decode(&m.data).unwrap();
            let v = d.status[0].values.iter().find(|kv| kv.key == "input_rate_hz").unwrap().value.clone();
            rates.push(v.parse::<f64>().unwrap());
        }
    }
    // sim_car is 200 Hz: every full period says so (the last message closes a partial one).
    assert!(rates.len() >= 10 && rates[..rates.len() - 1].iter().all(|r| (r - 200.0).abs() < 1.0), "{rates:?}");
    // The replayed bag already holds the node's topics: replaying it again would mix two runs.
    fails(replay(&first, "second.mcap", &[]), "already holds /imu/denoised");
    // Both clashes in one message (one per run made a user run three times).
    fails(replay(&first, "second.mcap", &[]), "-r /imu/gyro_correction:=/imu/gyro_correction_replay");
    let o = replay(&first, "second.mcap", &["-r", "/imu/denoised:=/imu/denoised_2", "-r", "/imu/gyro_correction:=/imu/gyro_correction_2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// bench times the samples that follow its warm-up: before, it fed the stream's start again
/// after warming on it, so the timed run began with a window of samples dropped as backwards
/// stamps (free), and a short run timed almost nothing (4.5 M samples/s for 500).
#[test]
fn bench_times_the_samples_it_says() {
    let out = Command::new(bin()).args(["bench", "--samples", "300", "--naive-samples", "3", "--memory-hours", "0.0001"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("µs/sample, 300 samples)") && text.contains("µs/sample, 3 samples)"), "{text}");
    assert!(text.contains("(72 samples)"), "{text}");
    // A streaming step costs microseconds, never the tenths of one that a dropped sample does.
    let per_sample: f64 = text
        .split("incremental, f32 (node)")
        .nth(1)
        .and_then(|r| r.split('(').nth(1))
        .and_then(|r| r.split(' ').next())
        .unwrap()
        .parse()
        .unwrap();
    assert!(per_sample > 2.0, "{per_sample} µs/sample: samples were not processed\n{text}");
}

/// `bag info` of a file that holds nothing readable says only why (no table of zeros first);
/// `bag echo` of a topic the bag lacks names the topics it has (it printed nothing, exit 0).
#[test]
fn bag_commands_say_what_is_missing() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.mcap");
    let out = Command::new(bin()).args(["bag", "info"]).arg(&missing).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(out.stdout.is_empty(), "{}", String::from_utf8_lossy(&out.stdout));
    assert!(String::from_utf8_lossy(&out.stderr).contains("No such file"));
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let out = Command::new(bin()).args(["bag", "echo", "--topic", "/nope"]).arg(&bag).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("no messages on /nope") && err.contains("/imu/data"), "{err}");
}

/// A model is the three files named by the path given: renamed, it loads (its `.json` records
/// the old name); a `.pt` of another model beside the `.json` and `.ot` is refused by eval's
/// start-up check (it was scored silently before).
#[test]
fn a_model_is_the_files_its_path_names() {
    let dir = tempfile::tempdir().unwrap();
    let bag = Path::new(env!("CARGO_MANIFEST_DIR")).join("test_bags/sim_car.mcap");
    let a = export_random_model(&dir.path().join("a"), Mode::FsdaF, 21, false);
    let b = export_random_model(&dir.path().join("b"), Mode::FsdaF, 22, false);
    let renamed = dir.path().join("a/mine.pt");
    for ext in ["pt", "ot", "json"] {
        std::fs::rename(a.with_extension(ext), renamed.with_extension(ext)).unwrap();
    }
    // The old name now holds another model: it must not be the one loaded.
    std::fs::copy(&b, &a).unwrap();
    let eval = |model: &Path| Command::new(bin()).args(["eval", "--model"]).arg(model).arg(&bag).output().unwrap();
    let out = eval(&renamed);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // A .pt that is not the network of its .json and .ot.
    std::fs::copy(&b, &renamed).unwrap();
    let out = eval(&renamed);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.code() == Some(1) && err.contains("the files are not one model"), "{err}");
}

fn topic_count(bag: &Path, topic: &str) -> usize {
    BagReader::open(bag).unwrap().filter(|m| m.as_ref().unwrap().topic.as_ref() == topic).count()
}

/// A replay that ends early keeps what it did: a damaged input is replayed up to the damage
/// (exit 1, naming both); SIGTERM / Ctrl-C finishes the output at the next message (exit 130);
/// a killed replay leaves the earlier output of that name as it was and its own `.partial`.
#[test]
fn a_replay_that_ends_early_keeps_what_it_replayed() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = euroc_bag(dir.path()) else { return };
    let model = export_random_model(dir.path(), Mode::FsdaF, 5, false);
    let total = topic_count(&bag, "/imu/data");
    let replay = |input: &Path, output: &Path| {
        let mut c = Command::new(bin());
        c.arg("replay").arg(input).arg("-o").arg(output).arg("--model").arg(&model);
        c.stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::piped());
        c
    };

    let cut = dir.path().join("cut.mcap");
    let bytes = std::fs::read(&bag).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out_cut = dir.path().join("out_cut.mcap");
    let o = replay(&cut, &out_cut).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("damaged") && err.contains(&*out_cut.to_string_lossy()) && err.contains(&*cut.to_string_lossy()), "{err}");
    let kept = topic_count(&out_cut, "/imu/denoised");
    assert!(kept > total / 4 && kept < total, "{kept} of {total} denoised before the damage");

    // Stopped or killed once the output is open (its `.partial` exists), mid-loop.
    let run_until_partial = |output: &Path, signal: i32| -> std::process::Output {
        let child = replay(&bag, output).spawn().unwrap();
        let partial = imu_fsda::bag::partial_path(output, child.id());
        let t0 = std::time::Instant::now();
        while !partial.exists() {
            assert!(t0.elapsed().as_secs() < 60, "the replay never opened its output");
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        unsafe { libc::kill(child.id() as i32, signal) };
        // `timeout -s INT` signals the command, then its process group: the same request twice.
        if signal == libc::SIGINT {
            unsafe { libc::kill(child.id() as i32, signal) };
        }
        child.wait_with_output().unwrap()
    };
    let out_int = dir.path().join("out_int.mcap");
    let o = run_until_partial(&out_int, libc::SIGINT);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code() == Some(130) && err.contains("interrupted"), "two SIGINTs at once are one request: {:?} {err}", o.status);
    // Finished and readable (it may hold nothing: the signal can come before the first message).
    assert!(topic_count(&out_int, "/imu/denoised") < total);
    let out_term = dir.path().join("out_term.mcap");
    let o = run_until_partial(&out_term, libc::SIGTERM);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("interrupted") && err.contains(&*out_term.to_string_lossy()), "{err}");
    let kept = topic_count(&out_term, "/imu/denoised");
    assert!(kept < total, "{kept} of {total}: the replay was not stopped");
    let partials =
        || std::fs::read_dir(dir.path()).unwrap().filter(|e| e.as_ref().unwrap().path().to_string_lossy().ends_with(".partial")).count();
    assert_eq!(partials(), 0);

    let earlier = std::fs::read(&out_term).unwrap();
    let o = run_until_partial(&out_term, libc::SIGKILL);
    assert_eq!(std::os::unix::process::ExitStatusExt::signal(&o.status), Some(libc::SIGKILL));
    assert!(std::fs::read(&out_term).unwrap() == earlier, "a killed replay changed the earlier output");
    assert_eq!(partials(), 1);
}

/// A 1-kHz IMU into a 200-Hz model (V1_01 re-stamped on an exact 5-ms grid, each sample held
/// five times over its interval with noise that sums to zero over the five): the node feeds
/// the model the 5-ms periods, which are the 200-Hz samples again, so each 1-kHz sample is
/// corrected with what the model gives the 200-Hz recording one period before; `eval`'s
/// offline form gives the same; /diagnostics says it, at OK.
#[test]
fn a_faster_imu_runs_the_model_in_its_periods_online_as_offline() {
    let dir = tempfile::tempdir().unwrap();
    let Some(bag) = euroc_bag(dir.path()) else { return };
    let (mut slow, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
    let t0 = slow.imu[0].stamp_ns;
    for (n, s) in slow.imu.iter_mut().enumerate() {
        s.stamp_ns = t0 + n as i64 * 5_000_000;
    }
    let zero_sum = [2.0, -1.0, 0.5, -1.0, -0.5];
    let mut fast = slow.clone();
    fast.imu = slow
        .imu
        .iter()
        .flat_map(|s| {
            zero_sum.iter().enumerate().map(move |(j, e)| imu_fsda::core::ImuSample {
                stamp_ns: s.stamp_ns + j as i64 * 1_000_000,
                gyro: s.gyro + nalgebra::Vector3::new(1.0, -1.0, 0.5) * (5e-3 * e),
                accel: s.accel + nalgebra::Vector3::new(0.5, 1.0, -1.0) * (5e-2 * e),
            })
        })
        .collect();
    let fast_bag = dir.path().join("v101_1khz.mcap");
    imu_fsda::bag::write_recording(&fast_bag, &fast).unwrap();
    let model = export_random_model(dir.path(), Mode::FsdaF, 13, false);
    let out_bag = dir.path().join("replayed_1khz.mcap");
    let out = Command::new(bin())
        .args(["-v", "replay", "--model-on-new-imu", "--model"])
        .arg(&model)
        .arg(&fast_bag)
        .arg("-o")
        .arg(&out_bag)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("fed to the 200.0 Hz model in its periods"), "{log}");

    let mut corrections = Vec::new();
    let mut last_status = None;
    for m in BagReader::open(&out_bag).unwrap() {
        let m = m.unwrap();
        match &*m.topic {
            "/imu/gyro_correction" => corrections.push(nalgebra::Vector3::from(Vector3Stamped::decode(&m.data).unwrap().vector)),
            "/diagnostics" => last_status = Some(imu_fsda::msg::DiagnosticArray::decode(&m.data).unwrap().status.remove(0)),
            _ => {}
        }
    }
    assert_eq!(corrections.len(), fast.imu.len());
    let status = last_status.unwrap();
    assert_eq!(status.level, imu_fsda::msg::DiagnosticStatus::OK, "{}", status.message);
    assert!(status.values.iter().any(|kv| kv.key == "resampled_to_model_rate" && kv.value == "true"), "{:?}", status.values);

    // The node switched within the first samples and restarted its model: from a window of
    // periods after that, period n's five samples carry the 200-Hz correction of period n − 1.
    let (reference, meta) = correct_with_weights_f64(&model, &slow.imu, None).unwrap();
    let warm = 2 * meta.window_n as usize;
    let mut worst: f64 = 0.0;
    for n in warm..slow.imu.len() {
        let want = reference[n - 1] - slow.imu[n - 1].gyro;
        for c in &corrections[5 * n..5 * n + 5] {
            worst = worst.max((c - want).amax());
        }
    }
    eprintln!("1 kHz online vs the 200-Hz offline correction a period before: max |Δ| = {worst:.2e} rad/s");
    assert!(worst < F32_ROUNDING_RAD_S, "{worst}");
    // Offline, as `eval --model` runs it: the same, from the start of the recording.
    let run = imu_fsda::model::predict::correct_with_torchscript_at_model_rate(&model, &fast.imu, None).unwrap();
    assert!(run.resampled_from_hz.is_some_and(|r| (r - 1000.0).abs() < 1.0), "{:?}", run.resampled_from_hz);
    let offline = run.corrected;
    let worst = (5 * warm..fast.imu.len()).map(|k| (offline[k] - fast.imu[k].gyro - corrections[k]).amax()).fold(0.0, f64::max);
    assert!(worst < 1e-5, "{worst}");
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
