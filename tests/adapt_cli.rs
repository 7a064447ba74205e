//! `imu-fsda adapt` end to end: a model that does not fit a new domain (a seeded random
//! FSDA-F model exported through the library, on a simulated car with an MPU-9250-like IMU)
//! is adapted on the first 60 s and judged on the rest; the written model loads, replays and
//! is not worse. Bad inputs give clear errors and write nothing.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use imu_fsda::bag::{read_recording, write_recording, RecordingTopics};
use imu_fsda::core::Recording;
use imu_fsda::model::export::{export_model, load_metadata, load_torchscript, ExportInfo};
use imu_fsda::model::{Config, Mode, Net};
use nalgebra::UnitQuaternion;

mod common;
use common::bin;

fn run(args: &[&str]) -> Output {
    Command::new(bin()).args(args).output().expect("run imu-fsda")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn random_model(dir: &Path, rec: &Recording) -> PathBuf {
    tch::manual_seed(7);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = Net::new(&Config::for_mode(Mode::FsdaF), &vs.root()).unwrap();
    let mut mean = [0.0; 6];
    let mut std = [0.0; 6];
    for c in 0..6 {
        let v: Vec<f64> = rec.imu.iter().map(|s| if c < 3 { s.gyro[c] } else { s.accel[c - 3] }).collect();
        mean[c] = v.iter().sum::<f64>() / v.len() as f64;
        std[c] = (v.iter().map(|x| (x - mean[c]).powi(2)).sum::<f64>() / v.len() as f64).sqrt().max(1e-3);
    }
    net.set_normalization(&mean, &std).unwrap();
    let info = ExportInfo { training_data: vec!["seeded random (tests/adapt_cli.rs)".into()], ..Default::default() };
    export_model(dir, "random", &vs, &net, &info).unwrap().torchscript
}

#[test]
fn adapts_on_a_new_domain_and_refuses_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let car = d.join("car.mcap");
    let o = run(&["simulate", "--profile", "car", "--grade", "mpu-9250", "--seconds", "150", "--output", car.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (rec, _) = read_recording(&car, &RecordingTopics::default()).unwrap();
    let model = random_model(d, &rec);
    let m = model.to_str().unwrap();
    let c = car.to_str().unwrap();

    // The good case.
    let out = d.join("adapted/car-adapted.pt");
    let o = run(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", out.to_str().unwrap(), "--steps", "40", "--json"]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let before = report["query_before"]["aoe_deg"].as_f64().unwrap();
    let after = report["query_after"]["aoe_deg"].as_f64().unwrap();
    eprintln!("car / random model: query AOE {before:.3}° → {after:.3}° in {:.1} s", report["step_seconds"].as_f64().unwrap());
    assert!(after <= before, "{err}");
    assert!(report["accepted"].as_bool().unwrap());
    let meta = load_metadata(&out.with_extension("json")).unwrap();
    assert!(meta.training_data.iter().any(|t| t.contains("few-shot adapted")), "{:?}", meta.training_data);
    assert!((meta.metrics["adapt.query_aoe_after_deg"] - after).abs() < 1e-9);
    load_torchscript(&out.with_extension("json")).unwrap();
    assert!(out.with_extension("adapt.json").is_file());
    // It replays (the node's pipeline, incl. its TorchScript-vs-streaming start-up check).
    let replayed = d.join("replayed.mcap");
    let o = run(&["replay", c, "--model", out.to_str().unwrap(), "-o", replayed.to_str().unwrap()]);
    assert!(o.status.success(), "replay: {}", stderr(&o));

    // Two models of one internal name (a renamed copy) are told apart by file in eval's table.
    for ext in ["pt", "ot", "json"] {
        std::fs::copy(out.with_extension(ext), d.join(format!("copy.{ext}"))).unwrap();
    }
    let o = run(&["eval", c, "-m", "raw", "--model", out.to_str().unwrap(), "--model", d.join("copy.pt").to_str().unwrap()]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success() && table.contains("| car-adapted |") && table.contains("| copy |"), "{table}{}", stderr(&o));
    // Same name and same file stem (two folders): the paths.
    std::fs::create_dir_all(d.join("twin")).unwrap();
    for ext in ["pt", "ot", "json"] {
        std::fs::copy(out.with_extension(ext), d.join(format!("twin/car-adapted.{ext}"))).unwrap();
    }
    let twin = d.join("twin/car-adapted.pt");
    let o = run(&["eval", c, "-m", "raw", "--model", out.to_str().unwrap(), "--model", twin.to_str().unwrap()]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains(&format!("| {} |", twin.display())) && table.contains(&format!("| {} |", out.display())), "{table}");

    // Bad input: each a clear error, nothing written.
    let bad_out = d.join("bad/x.pt");
    let bo = bad_out.to_str().unwrap();
    let expect_err = |args: &[&str], needle: &str| {
        let o = run(args);
        let e = stderr(&o);
        assert!(!o.status.success(), "{args:?} should fail");
        assert!(e.contains(needle), "{args:?}: expected {needle:?} in: {e}");
        assert!(!bad_out.exists(), "{args:?} wrote a model");
    };
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--support-seconds", "8"], "at least 20 s needed");
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--support-seconds", "400"], "nothing left after");
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--ground-truth-topic", "/nope"], "no ground truth");
    expect_err(&["adapt", "--keep-power-on-bias", "--model", "/nonexistent.pt", "--bag", c, "-o", bo], "missing");
    // A model that is not better is rejected with the figures (no step: the same model).
    expect_err(
        &["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--steps", "0", "--embedding-only"],
        "rejected: the adapted model is not better",
    );

    // An -o whose .json is some other record (the model's training summary): replaced before.
    let summary = d.join("bad/x.json");
    std::fs::create_dir_all(d.join("bad")).unwrap();
    std::fs::write(&summary, "{\"epochs\": 3}").unwrap();
    let o = run(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo]);
    assert!(!o.status.success() && stderr(&o).contains("is not a model's metadata"), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&summary).unwrap(), "{\"epochs\": 3}");
    std::fs::remove_file(&summary).unwrap();

    // Outputs that are not this command's to replace, refused before any work: a trained model,
    // a folder in the way of one file, a model whose metadata is `<name>.adapt.json`.
    let trained = d.join("bad/trained.pt");
    std::fs::create_dir_all(d.join("bad/folder.ot")).unwrap();
    for ext in ["pt", "ot", "json"] {
        std::fs::copy(model.with_extension(ext), trained.with_extension(ext)).unwrap();
        std::fs::copy(model.with_extension(ext), d.join(format!("bad/robot.adapt.{ext}"))).unwrap();
    }
    let trained_json = std::fs::read(trained.with_extension("json")).unwrap();
    // A deployed TorchScript file alone (no `.json` to say what it is).
    std::fs::copy(model.with_extension("pt"), d.join("bad/solo.pt")).unwrap();
    for (o, needle) in [
        (trained.clone(), "is a trained model"),
        (d.join("bad/folder.pt"), "is a folder"),
        (d.join("bad/robot.pt"), "the metadata of a model named robot.adapt"),
        (d.join("bad/"), "a folder; name the model file"),
        (d.join("bad/x.mcap"), "<name>.pt (not .mcap)"),
        (d.join("bad/solo.pt"), "says it is an earlier adaptation"),
    ] {
        let out = run(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", o.to_str().unwrap(), "--steps", "1"]);
        assert!(!out.status.success() && stderr(&out).contains(needle), "-o {}: {}", o.display(), stderr(&out));
    }
    assert_eq!(std::fs::read(trained.with_extension("json")).unwrap(), trained_json);
    assert!(!d.join("bad/folder.pt").exists() && !d.join("bad/robot.json").exists());
    expect_err(
        &["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--ground-truth-topic", "/imu/data"],
        "is the IMU topic",
    );

    // Settings the inner loop cannot run with: a panic inside tch before.
    let cfg = d.join("adapt.yaml");
    for (yaml, needle) in [
        ("window_samples: 10\n", "adapt.window_samples = 10"),
        ("loss: {increments: []}\n", "adapt.loss.increments"),
        ("loss: {increments: [{samples: 0, weight: 1.0}]}\n", "adapt.loss.increments"),
        ("windows: 0\n", "adapt.windows"),
        ("max_interpolation_gap_ms: 0\n", "adapt.max_interpolation_gap_ms"),
    ] {
        std::fs::write(&cfg, yaml).unwrap();
        expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", c, "-o", bo, "--config", cfg.to_str().unwrap()], needle);
    }

    // Ground truth not overlapping the IMU in time.
    let mut shifted = rec.clone();
    for p in &mut shifted.ground_truth {
        p.stamp_ns += 10_000_000_000_000;
    }
    let b = d.join("shifted.mcap");
    write_recording(&b, &shifted).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "does not overlap");
    // One pose inside the support's span (between two samples) overlaps it in time but covers no sample.
    let mut one_pose = rec.clone();
    let t30 = one_pose.imu[0].stamp_ns + 30_000_000_000;
    one_pose.ground_truth.retain(|p| p.stamp_ns >= t30);
    one_pose.ground_truth.truncate(1);
    one_pose.ground_truth[0].stamp_ns += 1_000_000; // off the IMU's stamps
    let b = d.join("one_pose.mcap");
    write_recording(&b, &one_pose).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "1 pose(s)");

    // A support set of 60 s whose ground truth covers 10 s of it: too little.
    let mut holed = rec.clone();
    let (t10, t60) = (holed.imu[0].stamp_ns + 10_000_000_000, holed.imu[0].stamp_ns + 60_000_000_000);
    holed.ground_truth.retain(|p| p.stamp_ns < t10 || p.stamp_ns > t60);
    let b = d.join("holed.mcap");
    write_recording(&b, &holed).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "support: 9.99");

    // Quaternions stored inverted (world in body): named as such, not as another frame.
    let mut inverted = rec.clone();
    inverted.ground_truth.iter_mut().for_each(|p| p.world_from_body = p.world_from_body.inverse());
    let b = d.join("inverted.mcap");
    write_recording(&b, &inverted).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "quaternions are inverted");

    // Ground truth stamped 60 ms late: a clock error, refused before any step.
    let mut late = rec.clone();
    late.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 60_000_000);
    let b = d.join("late.mcap");
    write_recording(&b, &late).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "lags the IMU by 60.");

    // Gyro samples no IMU measures (a corrupt driver value) in the support set: named as the
    // data's fault, not the learning rate's.
    let mut corrupt = rec.clone();
    corrupt.imu.iter_mut().take(10_000).step_by(400).for_each(|s| s.gyro.x = 1e30);
    let b = d.join("corrupt.mcap");
    write_recording(&b, &corrupt).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "beyond what any IMU measures");

    // Ground truth of another body frame (rotated 30° about x): detected and reported …
    let rx = UnitQuaternion::from_euler_angles(0.5, 0.0, 0.0);
    let mut rotated = rec.clone();
    for p in &mut rotated.ground_truth {
        p.world_from_body *= rx.inverse();
    }
    let b = d.join("rotated.mcap");
    write_recording(&b, &rotated).unwrap();
    expect_err(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo], "another frame");
    // … or re-expressed on request.
    let o =
        run(&["adapt", "--keep-power-on-bias", "--model", m, "--bag", b.to_str().unwrap(), "-o", bo, "--frame", "apply", "--steps", "3"]);
    let e = stderr(&o);
    assert!(e.contains("re-expressed"), "{e}");
}

/// A model whose correction is exactly zero (the Generator's last conv zeroed, as the trainer's
/// `zero_init_correction`) on a gyro with a bias it never saw: the Embedding alone cannot move
/// the output (its gradient passes through the zero layer), so the paper's θ_e step
/// (`--embedding-only`) is rejected; the default also adapts the output bias and Ĉ_ω.
#[test]
fn calibration_head_learns_a_bias_the_embedding_cannot() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let car = d.join("car.mcap");
    let o =
        run(&["simulate", "--profile", "car", "--grade", "mpu-9250", "--seconds", "100", "--seed", "3", "--output", car.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let biased = biased_by(&car, d.join("biased.mcap"));
    let model = zero_correction_model(d);
    let (m, b) = (model.to_str().unwrap(), biased.to_str().unwrap());

    let o = run(&[
        "adapt",
        "--keep-power-on-bias",
        "--model",
        m,
        "--bag",
        b,
        "-o",
        d.join("e.pt").to_str().unwrap(),
        "--steps",
        "60",
        "--embedding-only",
        "--json",
    ]);
    assert!(!o.status.success(), "the Embedding alone changed a zeroed output: {}", stderr(&o));
    assert!(stderr(&o).contains("rejected"), "{}", stderr(&o));

    let o = run(&[
        "adapt",
        "--keep-power-on-bias",
        "--model",
        m,
        "--bag",
        b,
        "-o",
        d.join("c.pt").to_str().unwrap(),
        "--steps",
        "60",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let before = report["query_before"]["aoe_deg"].as_f64().unwrap();
    let after = report["query_after"]["aoe_deg"].as_f64().unwrap();
    eprintln!("biased car / zero-correction model, calibration head: query AOE {before:.3}° → {after:.3}°");
    assert!(after < 0.3 * before, "{before} → {after}");
}

/// `rec` at `car` with 0.02 rad/s added to the vertical gyro (1.15 °/s: a heading drift of 69°
/// a minute), written to `out`.
fn biased_by(car: &Path, out: PathBuf) -> PathBuf {
    let (mut rec, _) = read_recording(car, &RecordingTopics::default()).unwrap();
    for s in &mut rec.imu {
        s.gyro.z += 0.02;
    }
    write_recording(&out, &rec).unwrap();
    out
}

/// An FSDA-F model for 200 Hz whose Generator's last layer is zero: no correction.
fn zero_correction_model(d: &Path) -> PathBuf {
    tch::manual_seed(11);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let cfg = Config::for_mode(Mode::FsdaF);
    let net = Net::new(&cfg, &vs.root()).unwrap();
    net.set_normalization(&[0.0, 0.0, 0.0, 0.0, 0.0, 9.81], &[0.5, 0.5, 0.5, 2.0, 2.0, 2.0]).unwrap();
    let last = cfg.generator.kernel_sizes.len() - 1;
    let vars = vs.variables();
    tch::no_grad(|| {
        for leaf in ["weight", "bias"] {
            let _ = vars[&format!("generator.conv{last}.{leaf}")].shallow_clone().zero_();
        }
    });
    export_model(d, "zero", &vs, &net, &ExportInfo::default()).unwrap().torchscript
}

/// The same on a 1-kHz IMU: the 200-Hz model adapts in its 5-ms periods, learns the bias as
/// well, and the adapted model replays on the 1-kHz bag in its periods.
#[test]
fn a_faster_imu_adapts_in_the_models_periods() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let car = d.join("car1k.mcap");
    let o = run(&[
        "simulate",
        "--profile",
        "car",
        "--grade",
        "mpu-9250",
        "--rate",
        "1000",
        "--seconds",
        "100",
        "--seed",
        "3",
        "--output",
        car.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let biased = biased_by(&car, d.join("biased1k.mcap"));
    let model = zero_correction_model(d);
    let out = d.join("c1k.pt");
    let o = run(&[
        "-v",
        "adapt",
        "--keep-power-on-bias",
        "--model",
        model.to_str().unwrap(),
        "--bag",
        biased.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--steps",
        "60",
        "--json",
    ]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("Hz IMU is adapted on in the model's 200 Hz periods"), "{e}");
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let before = report["query_before"]["aoe_deg"].as_f64().unwrap();
    let after = report["query_after"]["aoe_deg"].as_f64().unwrap();
    eprintln!("biased 1-kHz car / zero-correction 200-Hz model: query AOE {before:.3}° → {after:.3}°");
    assert!(after < 0.3 * before, "{before} → {after}");
    let replayed = d.join("replayed1k.mcap");
    let o = run(&["-v", "replay", biased.to_str().unwrap(), "--model", out.to_str().unwrap(), "-o", replayed.to_str().unwrap()]);
    assert!(o.status.success() && stderr(&o).contains("in its periods"), "replay: {}", stderr(&o));
}

/// An uncalibrated consumer gyro (the simulator's datasheet biases, ~0.04–0.07 rad/s) on a car
/// that mostly yaws and on a trotting quadruped: its bias is neither a frame rotation (it was
/// read as an 18.9° tilt) nor a clock offset (a 1-s trot period was read as a 1.06-s lag).
/// The adaptation runs; a real 20° mount rotation on the same biased gyro is still found.
#[test]
fn a_consumer_gyro_bias_is_neither_another_frame_nor_a_lag() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for profile in ["car", "quadruped"] {
        let bag = d.join(format!("{profile}.mcap"));
        let o = run(&[
            "simulate",
            "--profile",
            profile,
            "--grade",
            "mpu-9250",
            "--datasheet-errors",
            "--seconds",
            "100",
            "--output",
            bag.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let (rec, _) = read_recording(&bag, &RecordingTopics::default()).unwrap();
        let model = random_model(d, &rec);
        let out = d.join(format!("{profile}-adapted.pt"));
        let o = run(&[
            "adapt",
            "--keep-power-on-bias",
            "--model",
            model.to_str().unwrap(),
            "--bag",
            bag.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--steps",
            "3",
            "--support-seconds",
            "50",
        ]);
        let e = stderr(&o);
        assert!(e.contains("adapted on 50.0 s"), "{profile}: {e}");
        let frame: f64 = e.split("frame check: ").nth(1).and_then(|r| r.split('°').next()).and_then(|v| v.parse().ok()).unwrap_or(0.0);
        assert!(frame < 2.0, "{profile}: frame check {frame}°: {e}");

        let rx = UnitQuaternion::from_euler_angles(0.35, 0.0, 0.0);
        let mut rotated = rec.clone();
        rotated.ground_truth.iter_mut().for_each(|p| p.world_from_body *= rx.inverse());
        let b = d.join(format!("{profile}-rotated.mcap"));
        write_recording(&b, &rotated).unwrap();
        let o = run(&[
            "adapt",
            "--keep-power-on-bias",
            "--model",
            model.to_str().unwrap(),
            "--bag",
            b.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
            "--support-seconds",
            "50",
        ]);
        let e = stderr(&o);
        let angle: f64 =
            e.split("a constant rotation of ").nth(1).and_then(|r| r.split('°').next()).and_then(|v| v.parse().ok()).unwrap_or(f64::NAN);
        assert!((angle - 20.05).abs() < 1.0, "{profile}: the 20° rotation read as {angle}°: {e}");
    }
}

/// The power-on rule: the support's standstill bias is removed before adapting, the model is
/// marked so the node removes each power-on's, a support without a standstill is refused, and
/// `--judge` scores other power-ons beside the power-on bias the node runs without the model.
#[test]
fn adaptation_removes_the_power_on_bias_and_is_judged_on_other_power_ons() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sim = |k: &str, rest: &str| {
        let bag = d.join(format!("car{k}.mcap"));
        let o = run(&[
            "simulate",
            "--profile",
            "car",
            "--grade",
            "mpu-9250",
            "--datasheet-errors",
            "--seconds",
            "90",
            "--power-on",
            k,
            "--rest-s",
            rest,
            "--output",
            bag.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        bag
    };
    let (first, second, moving) = (sim("1", "3"), sim("2", "2"), sim("3", "0"));
    let (rec, _) = read_recording(&first, &RecordingTopics::default()).unwrap();
    let model = random_model(d, &rec);
    let m = model.to_str().unwrap();
    // No standstill in the support: refused, with the way out said.
    let o = run(&["adapt", "--model", m, "--bag", moving.to_str().unwrap(), "-o", d.join("x.pt").to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("no standstill in the support set"), "{}", stderr(&o));
    assert!(!d.join("x.pt").exists());
    // With one: the bias is measured and removed, and the other power-on is judged.
    let out = d.join("a.pt");
    let o = run(&[
        "adapt",
        "--model",
        m,
        "--bag",
        first.to_str().unwrap(),
        "--judge",
        second.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--steps",
        "40",
        "--json",
    ]);
    let e = stderr(&o);
    assert!(e.contains("support power-on bias ["), "{e}");
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_default();
    assert!(report["query_power_on_bias"]["aoe_deg"].as_f64().is_some(), "{report}");
    match report["judged"].as_array().and_then(|j| j.first()) {
        // Judged (it passed the query rule): written exactly when it beats the power-on bias
        // on the other power-on.
        Some(j) => {
            let (after, pob) = (j["after"]["aoe_deg"].as_f64().unwrap(), j["power_on_bias"]["aoe_deg"].as_f64().unwrap());
            assert_eq!(out.exists(), after < pob, "after {after} against power-on bias {pob}\n{e}");
        }
        // Refused on the query set: nothing written, and said.
        None => assert!(!out.exists() && e.contains("rejected"), "{e}"),
    }
    if out.exists() {
        assert!(load_metadata(&out.with_extension("json")).unwrap().power_on_bias_removed);
    }
}
