//! What every command promises at its edges: a bad or missing model or bag is a clear error at
//! start (never a panic), outputs never overwrite inputs, options out of range are refused by
//! name, a closed stdout ends it quietly, `bench` counts what it says, security is never
//! silently dropped.

use std::path::Path;
use std::process::Command;

use imu_fsda::model::Mode;

mod common;
use common::bin;
use common::random_model::{export_random_model, export_random_model_with_gains};

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
