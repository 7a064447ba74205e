//! `imu-fsda train`: the CI profile (params/train/ci-small.yaml, FSDA-F with second-order MAML
//! on two short EuRoC tasks) learns — the loss falls and the held-out AOE beats the raw gyro —,
//! its export loads as TorchScript, a checkpoint resumes, and bad inputs are refused with a
//! clear message before any training starts.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use imu_fsda::bag::write_recording;
use imu_fsda::core::{ImuSample, PoseSample, Recording};
use imu_fsda::model::export::{load_metadata, load_torchscript};
use nalgebra::{UnitQuaternion, Vector3};

mod common;
use common::bin;

fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shared_data() -> Option<PathBuf> {
    let p = manifest().join("../shared/data");
    if p.join("euroc").is_dir() {
        Some(p)
    } else {
        common::skip_or_fail("the training test", "../shared/data not found: it needs EuRoC");
        None
    }
}

fn run(cmd: &mut Command) -> Output {
    cmd.env("RUST_LOG", "info").output().expect("spawn imu-fsda")
}

fn ok(cmd: &mut Command) -> String {
    let out = run(cmd);
    assert!(out.status.success(), "{cmd:?} failed:\n{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn ci_small_learns_exports_and_resumes() {
    let Some(_) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let t0 = std::time::Instant::now();
    let printed = ok(Command::new(bin())
        .args(["train", "--config"])
        .arg(manifest().join("params/train/ci-small.yaml"))
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--name", "ci", "--no-progress"]));
    eprintln!("{printed}(trained in {:.1} s)", t0.elapsed().as_secs_f64());

    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("ci.train.json")).unwrap()).unwrap();
    let (first, last) = (summary["loss_first"].as_f64().unwrap(), summary["loss_last"].as_f64().unwrap());
    assert!(last < 0.8 * first, "loss did not fall: {first} → {last}");

    assert!(printed.contains("curves: "), "{printed}");
    let png = std::fs::read(dir.path().join("ci.curves.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 10_000, "curves: {} bytes", png.len());
    let meta = load_metadata(&dir.path().join("ci.json")).unwrap();
    let raw = meta.metrics["val.mean_raw_aoe_deg"];
    let model = meta.metrics["val.mean_aoe_deg"];
    assert!(model < 0.7 * raw, "held-out AOE {model}° did not improve over raw {raw}°");
    // One validation recording: the weighted score is its AOE, with the correction gain the
    // run fitted on it (`train.correction_gains`); gain 1 is among the candidates, so it can
    // only be as good or better than the model without it.
    let gain = meta.imu_correction_gains["euroc"];
    assert!((0.0..=1.0).contains(&gain), "gain {gain}");
    assert_eq!(meta.metrics["correction_gain.euroc"], gain);
    let without = meta.metrics["val.score_without_gain_deg"];
    assert!((without - model).abs() < 1e-12);
    let with = meta.metrics["val.score_deg"];
    assert!((with - meta.metrics["val.V1_01_easy@0-40s.aoe_with_gain_deg"]).abs() < 1e-12, "{:?}", meta.metrics);
    assert!(with <= without + 1e-9, "gained score {with} above the ungained {without}");
    assert!(meta.training_data.iter().any(|s| s.contains("MH_01_easy")), "{:?}", meta.training_data);
    assert_eq!(meta.trained_imus, ["euroc"], "the IMU of its training recordings, once");
    assert!(meta.metrics.contains_key("test.MH_04_difficult@0-40s.aoe_deg"), "{:?}", meta.metrics.keys());
    // The monitor (the test crop itself) is evaluated with the validation set, at the same epochs.
    let epochs_of = |v: &serde_json::Value| -> Vec<u64> { v["evals"].as_array().unwrap().iter().map(|e| e[0].as_u64().unwrap()).collect() };
    assert_eq!(epochs_of(&summary["monitor"][0]), vec![20, 40, 60]);
    assert_eq!(epochs_of(&summary["monitor"][0]), epochs_of(&summary["validation"][0]));
    // Its last entry is the exported model (without the gain, fitted after training), so it
    // equals the test figure without the gain.
    let monitored_last = summary["monitor"][0]["evals"][2][1]["aoe_deg"].as_f64().unwrap();
    let tested = meta
        .metrics
        .get("test.MH_04_difficult@0-40s.aoe_without_gain_deg")
        .copied()
        .unwrap_or(meta.metrics["test.MH_04_difficult@0-40s.aoe_deg"]);
    assert!((monitored_last - tested).abs() < 1e-9, "monitor {monitored_last} vs test {tested}");

    let ts = load_torchscript(&dir.path().join("ci.json")).unwrap();
    let u = tch::Tensor::zeros([1, 700, 6], (tch::Kind::Float, tch::Device::Cpu));
    assert_eq!(ts.forward(&u).unwrap().size(), vec![1, 700, 3]);
    // The profile learns one Ĉ_ω for `euroc` and fits its correction gain: `eval --imu` applies
    // both, an unknown IMU is refused.
    assert!(meta.imu_gyro_calibrations.contains_key("euroc"), "{:?}", meta.imu_gyro_calibrations);
    let bag = dir.path().join("MH_04_difficult.mcap");
    ok(Command::new(bin()).arg("import").arg(manifest().join("../shared/data/euroc/MH_04_difficult")).arg("-o").arg(&bag));
    let eval = |imu: &str| {
        run(Command::new(bin())
            .arg("eval")
            .arg(&bag)
            .args(["--end-s", "40", "--method", "raw", "--imu", imu, "--model"])
            .arg(dir.path().join("ci.pt")))
    };
    let table = eval("MH_*=euroc");
    assert!(table.status.success(), "{}", String::from_utf8_lossy(&table.stderr));
    let printed_table = String::from_utf8_lossy(&table.stdout);
    assert!(printed_table.contains(&format!("as on IMU euroc (correction gain {gain:.3})")), "{printed_table}");
    let refused = eval("bmi088");
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success() && err.contains("bmi088") && err.contains("euroc"), "{err}");

    // Resume the finished run for two more epochs: history continues, the model re-exports.
    let printed = ok(Command::new(bin())
        .args(["train", "--config"])
        .arg(manifest().join("params/train/ci-small.yaml"))
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--name", "ci", "--no-progress", "--epochs", "62", "--resume"])
        .arg(dir.path().join("ci.ckpt.json")));
    assert!(printed.contains("62 epochs"), "{printed}");
    let resumed: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("ci.train.json")).unwrap()).unwrap();
    assert_eq!(resumed["resumed_from_epoch"].as_u64(), Some(60));
    assert_eq!(resumed["history"].as_array().unwrap().len(), 62);
    assert_eq!(resumed["history"][59]["loss"], summary["history"][59]["loss"]);
    assert_eq!(epochs_of(&resumed["monitor"][0]), vec![20, 40, 60, 62], "the monitor survives the resume");

    // The wall-time budget is the whole run's: resumed under half the seconds already spent,
    // the run stops after its first new epoch and exports it (three more epochs take a few
    // seconds, far under that half, so a budget counting only this process would not stop it).
    let spent = resumed["train_seconds"].as_f64().unwrap();
    let config = std::fs::read_to_string(manifest().join("params/train/ci-small.yaml")).unwrap();
    assert!(config.trim_end().lines().last().unwrap().starts_with("  "), "ci-small.yaml must end inside `train:`");
    let data = manifest().join("../shared/data");
    let budgeted: String = config
        .lines()
        .map(|l| if l.trim_start().starts_with("root:") { format!("  root: {}", data.display()) } else { l.to_string() })
        .chain([format!("  max_train_seconds: {}", spent / 2.0)])
        .collect::<Vec<_>>()
        .join("\n");
    let budgeted_cfg = dir.path().join("ci-budget.yaml");
    std::fs::write(&budgeted_cfg, &budgeted).unwrap();
    let printed = ok(Command::new(bin())
        .args(["train", "--config"])
        .arg(&budgeted_cfg)
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--name", "ci", "--no-progress", "--epochs", "65", "--resume"])
        .arg(dir.path().join("ci.ckpt.json")));
    assert!(printed.contains("after epoch 63 of 65") && !printed.contains("lowest validation score"), "{printed}");
    let stopped: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("ci.train.json")).unwrap()).unwrap();
    assert_eq!(stopped["history"].as_array().unwrap().len(), 63, "stops after the first epoch past the budget");
    // Said as such: it reported "65 epochs" and, with select_best off, "lowest validation score".
    assert_eq!((stopped["epochs"].as_u64(), stopped["epochs_planned"].as_u64()), (Some(63), Some(65)));
    assert_eq!(load_metadata(&dir.path().join("ci.json")).unwrap().metrics["stopped_at_budget"], 63.0);

    // A run of other length than the config's does not replace an existing model of its name
    // (timing `params/train/fsda-f.yaml --epochs 3` from the repo root replaced the bundled one).
    let model_json = std::fs::read(dir.path().join("ci.json")).unwrap();
    let out = run(Command::new(bin()).args(["train", "--config"]).arg(&budgeted_cfg).arg("--out-dir").arg(dir.path()).args([
        "--name",
        "ci",
        "--no-progress",
        "--epochs",
        "3",
    ]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--epochs 3 (the config trains 60) would replace"), "{err}");
    assert_eq!(std::fs::read(dir.path().join("ci.json")).unwrap(), model_json);

    // A resume continues the same run: fewer epochs than done, or another learning rate, are
    // refused before anything is written (the checkpoint stays as it is).
    let ckpt = std::fs::read(dir.path().join("ci.ckpt.json")).unwrap();
    let other_lr = dir.path().join("ci-lr.yaml");
    std::fs::write(&other_lr, budgeted.replace("  lr: 0.01", "  lr: 0.02")).unwrap();
    for (cfg, epochs, needle) in [(&budgeted_cfg, "10", "cannot be shortened"), (&other_lr, "70", "differs in train.lr")] {
        let out = run(Command::new(bin())
            .args(["train", "--config"])
            .arg(cfg)
            .arg("--out-dir")
            .arg(dir.path())
            .args(["--name", "ci", "--no-progress", "--epochs", epochs, "--resume"])
            .arg(dir.path().join("ci.ckpt.json")));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(needle), "{err}");
    }
    assert_eq!(std::fs::read(dir.path().join("ci.ckpt.json")).unwrap(), ckpt);
    // Nor under another seed (its windows would be another run's, recorded as this one).
    let out = run(Command::new(bin())
        .args(["train", "--config"])
        .arg(&budgeted_cfg)
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--name", "ci", "--no-progress", "--epochs", "70", "--seed", "5", "--resume"])
        .arg(dir.path().join("ci.ckpt.json")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("trained with seed 0, not 5"), "{err}");
    // A second run writing `ci` while one is alive (its lock holds a live pid: this test's) is
    // refused; the files stay as they are.
    std::fs::write(dir.path().join("ci.lock"), format!("{}\n", std::process::id())).unwrap();
    let out = run(Command::new(bin()).args(["train", "--config"]).arg(&budgeted_cfg).arg("--out-dir").arg(dir.path()).args([
        "--name",
        "ci",
        "--no-progress",
    ]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("another run (pid"), "{err}");
    std::fs::remove_file(dir.path().join("ci.lock")).unwrap();
    assert_eq!(std::fs::read(dir.path().join("ci.ckpt.json")).unwrap(), ckpt);

    // A fine-tune from the exported model (`init_from`) starts where that model is, not from
    // scratch.
    let fine_tune = |same_model: bool| {
        let text: String = budgeted
            .lines()
            .filter(|l| !l.contains("max_train_seconds") && !l.contains("checkpoint_every") && !l.contains("eval_every"))
            .filter(|l| same_model || !l.contains("imu_calibrations"))
            .map(|l| l.replace("first_order: false", "first_order: true\n    batch_tasks: true"))
            .collect::<Vec<_>>()
            .join("\n");
        let cfg = dir.path().join("ft.yaml");
        std::fs::write(&cfg, format!("{text}\n  init_from: ci.json\n  lr: 1.0e-4\n").replace("  lr: 0.01\n", "")).unwrap();
        run(Command::new(bin()).args(["train", "--config"]).arg(&cfg).arg("--out-dir").arg(dir.path()).args([
            "--name",
            if same_model { "ft" } else { "ft-other" },
            "--no-progress",
            "--epochs",
            "3",
        ]))
    };
    let out = fine_tune(true);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let ft: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("ft.train.json")).unwrap()).unwrap();
    let first_ft = ft["history"][0]["loss"].as_f64().unwrap();
    assert!(first_ft < 0.5 * first, "the fine-tune's first loss {first_ft} is not below the fresh run's {first}");
    let vars = |name: &str| -> std::collections::BTreeMap<String, tch::Tensor> {
        tch::Tensor::load_multi(dir.path().join(name)).unwrap().into_iter().collect()
    };
    let (start, end) = (vars("ci.ot"), vars("ft.ot"));
    assert!(!start["generator.conv0.weight"].equal(&end["generator.conv0.weight"]), "the fine-tune did not train");
    // A start whose config is not this one is refused, naming the file.
    let out = fine_tune(false);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("init_from") && err.contains("ci.json"), "{err}");
}

/// `train.seeds`: one run per seed (two at once), the lowest validation score is exported as
/// `<name>` with every candidate recorded; a second call reuses the finished runs; `--resume`
/// without `--seed` is refused.
#[test]
fn seed_restarts_export_the_best_validated_run() {
    let Some(data) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(manifest().join("params/train/ci-small.yaml")).unwrap();
    let text = text.replace("root: ../../../shared/data", &format!("root: {}", data.display())).replace("  seed: 0\n", "  seeds: [3, 1]\n");
    assert!(text.contains("seeds: [3, 1]"), "{text}");
    let config = dir.path().join("restarts.yaml");
    std::fs::write(&config, text).unwrap();
    let train = |extra: &[&str]| {
        run(Command::new(bin())
            .args(["train", "--config"])
            .arg(&config)
            .arg("--out-dir")
            .arg(dir.path())
            .args(["--no-progress", "--epochs", "4", "--jobs", "2"])
            .args(extra))
    };
    let out = train(&[]);
    let printed = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{printed}\n{}", String::from_utf8_lossy(&out.stderr));

    // Recompute the choice from the two runs' own summaries.
    let score = |run: &str| -> f64 {
        let s: imu_fsda::train::report::TrainSummary =
            serde_json::from_str(&std::fs::read_to_string(dir.path().join("restarts.runs").join(format!("{run}.train.json"))).unwrap())
                .unwrap();
        let scored = if s.validation_with_gain.is_empty() { &s.validation } else { &s.validation_with_gain };
        imu_fsda::train::fit::validation_score(scored, Some(s.exported_epoch), s.config.train.task_weighting).unwrap()
    };
    let (s3, s1) = (score("restarts-s3"), score("restarts-s1"));
    let expected = if s1 < s3 { 1 } else { 3 };
    let sel: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.path().join("restarts.seeds.json")).unwrap()).unwrap();
    assert_eq!(sel["chosen_seed"].as_u64(), Some(expected), "scores s3 {s3} s1 {s1}: {sel}");
    assert_eq!(sel["candidates"].as_array().unwrap().len(), 2);
    assert!(printed.contains("<- exported"), "{printed}");

    // The promoted model is the chosen run's, under the new name.
    let meta = load_metadata(&dir.path().join("restarts.json")).unwrap();
    assert_eq!(meta.name, "restarts");
    assert_eq!(meta.files.torchscript, "restarts.pt");
    assert_eq!(meta.metrics["seed"], expected as f64);
    assert_eq!(meta.metrics["seed_selection.candidates"], 2.0);
    let u = tch::Tensor::randn([1, 700, 6], (tch::Kind::Float, tch::Device::Cpu));
    let promoted = load_torchscript(&dir.path().join("restarts.json")).unwrap().forward(&u).unwrap();
    let chosen = load_torchscript(&dir.path().join(format!("restarts.runs/restarts-s{expected}.json"))).unwrap().forward(&u).unwrap();
    assert_eq!(f64::try_from((promoted - chosen).abs().max()).unwrap(), 0.0);

    // Both runs are complete: a second call trains nothing and chooses the same.
    let again = train(&[]);
    let printed = String::from_utf8_lossy(&again.stdout).into_owned();
    assert!(again.status.success() && printed.matches("already trained").count() == 2, "{printed}");
    let resume = train(&["--resume", "x.ckpt.json"]);
    assert!(!resume.status.success() && String::from_utf8_lossy(&resume.stderr).contains("--seed"));
    // One seed under the chosen export's name would replace it (and leave the selection stale).
    let one = train(&["--seed", "1"]);
    let err = String::from_utf8_lossy(&one.stderr);
    assert!(!one.status.success() && err.contains("was chosen among seeds"), "{err}");
    // Finished runs under another config are neither reused nor overwritten.
    let changed = dir.path().join("changed.yaml");
    std::fs::write(&changed, std::fs::read_to_string(&config).unwrap().replace("  lr: 0.01", "  lr: 0.02")).unwrap();
    let out = run(Command::new(bin()).args(["train", "--config"]).arg(&changed).arg("--out-dir").arg(dir.path()).args([
        "--name",
        "restarts",
        "--no-progress",
        "--epochs",
        "4",
    ]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("differs in train.lr") && !err.contains("training failed"), "{err}");
    // A bad override is refused once, before any child starts (no child's "training failed").
    let zero = run(Command::new(bin()).args(["train", "--config"]).arg(&config).arg("--out-dir").arg(dir.path()).args([
        "--no-progress",
        "--epochs",
        "0",
    ]));
    let err = String::from_utf8_lossy(&zero.stderr);
    assert!(!zero.status.success() && err.contains("train.epochs must be") && !err.contains("training failed"), "{err}");

    // A run that cannot start (a training sequence that is not there) fails the command with
    // the child's own error, and nothing is promoted.
    let broken = dir.path().join("broken.yaml");
    let text = std::fs::read_to_string(&config).unwrap().replace("euroc/V1_02_medium", "euroc/V9_99_missing");
    std::fs::write(&broken, text).unwrap();
    let out = run(Command::new(bin()).args(["train", "--config"]).arg(&broken).arg("--out-dir").arg(dir.path()).args([
        "--no-progress",
        "--epochs",
        "2",
        "--jobs",
        "2",
    ]));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("training failed") && err.contains("V9_99_missing"), "{err}");
    assert!(!dir.path().join("broken.json").exists());
}

fn imu(n: usize, t0_ns: i64) -> Vec<ImuSample> {
    (0..n)
        .map(|i| ImuSample {
            stamp_ns: t0_ns + i as i64 * 5_000_000,
            gyro: Vector3::new(0.01, 0.0, 0.0),
            accel: Vector3::new(0.0, 0.0, 9.81),
        })
        .collect()
}

fn poses(n: usize, t0_ns: i64) -> Vec<PoseSample> {
    (0..n)
        .map(|i| PoseSample {
            stamp_ns: t0_ns + i as i64 * 5_000_000,
            position_in_world: Vector3::zeros(),
            world_from_body: UnitQuaternion::identity(),
        })
        .collect()
}

/// Trains on one bag with a small FSDA config (`train` adds to its train section); returns
/// stderr of the (expected) failure.
fn train_fails_on(dir: &Path, rec: &Recording, tag: &str, train: &str) -> String {
    let bag = dir.join(format!("{tag}.mcap"));
    write_recording(&bag, rec).unwrap();
    let cfg = dir.join(format!("{tag}.yaml"));
    std::fs::write(
        &cfg,
        format!(
            "model: {{mode: fsda}}\ndataset:\n  train: [{{bag: {}}}]\ntrain: {{epochs: 2, window_samples: 2000, threads: 1{train}}}\n",
            bag.display()
        ),
    )
    .unwrap();
    let t = std::time::Instant::now();
    let out = run(Command::new(bin()).args(["train", "--no-progress", "--config"]).arg(&cfg).arg("--out-dir").arg(dir.join("out")));
    assert!(!out.status.success(), "{tag}: training should have been refused");
    assert!(!dir.join("out").join(format!("{tag}.ckpt.json")).exists(), "{tag}: trained anyway");
    assert!(t.elapsed().as_secs_f64() < 30.0);
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn bad_inputs_are_refused_before_training() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let no_gt = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: vec![], temperature: vec![] };
    let err = train_fails_on(d, &no_gt, "no_gt", "");
    assert!(err.contains("no ground truth"), "{err}");

    // A driver stamping bursts on arrival: 3 of 4 samples repeat a stamp (eval refuses it too).
    let mut bursts = imu(8000, 0);
    bursts.iter_mut().enumerate().for_each(|(i, s)| s.stamp_ns = (i / 4) as i64 * 20_000_000);
    let bursty = Recording { name: "x".into(), imu: bursts, ground_truth: poses(8000, 0), temperature: vec![] };
    let err = train_fails_on(d, &bursty, "bursts", "");
    assert!(err.contains("repeat or go back from an earlier header stamp"), "{err}");
    // The same bursts 10 µs apart: nothing repeats, but the stamps are still the arrival's
    // (read as 100 kHz before).
    let mut arrivals = imu(8000, 0);
    arrivals.iter_mut().enumerate().for_each(|(i, s)| s.stamp_ns = (i / 4) as i64 * 20_000_000 + (i % 4) as i64 * 10_000);
    let arrived = Recording { name: "x".into(), imu: arrivals, ground_truth: poses(8000, 0), temperature: vec![] };
    let err = train_fails_on(d, &arrived, "arrivals", "");
    assert!(err.contains("header.stamp is the arrival time of a batch"), "{err}");

    // Two recordings of one name in a list: their results would be filed under one key.
    let ok_rec = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(5000, 0), temperature: vec![] };
    for sub in ["day0", "day1", "day2"] {
        std::fs::create_dir_all(d.join(sub)).unwrap();
        write_recording(d.join(sub).join("run_0.mcap"), &ok_rec).unwrap();
    }
    let cfg = d.join("same_names.yaml");
    std::fs::write(
        &cfg,
        format!(
            "model: {{mode: fsda}}\ndataset:\n  root: {}\n  train: [{{bag: day0/run_0.mcap}}]\n  test: [{{bag: day1/run_0.mcap}}, {{bag: day2/run_0.mcap}}]\ntrain: {{epochs: 2, window_samples: 2000, threads: 1}}\n",
            d.display()
        ),
    )
    .unwrap();
    let out = run(Command::new(bin()).args(["train", "--no-progress", "--config"]).arg(&cfg).arg("--out-dir").arg(d.join("out")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("dataset.test: two recordings are named run_0"), "{err}");
    // A validation crop shorter than the model's window scores only its warm-up (near 0°) and
    // would steer the choice of seed.
    let cfg = d.join("short_validation.yaml");
    std::fs::write(
        &cfg,
        format!(
            "model: {{mode: fsda}}\ndataset:\n  root: {}\n  train: [{{bag: day0/run_0.mcap}}]\n  validation: [{{bag: day1/run_0.mcap, end_s: 0.1}}]\ntrain: {{epochs: 2, window_samples: 2000, threads: 1}}\n",
            d.display()
        ),
    )
    .unwrap();
    let out = run(Command::new(bin()).args(["train", "--no-progress", "--config"]).arg(&cfg).arg("--out-dir").arg(d.join("out")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("dataset.validation: run_0") && err.contains("shorter than the model's window"), "{err}");
    assert!(!d.join("out/short_validation.pt").exists());

    let short = Recording { name: "x".into(), imu: imu(1000, 0), ground_truth: poses(1000, 0), temperature: vec![] };
    let err = train_fails_on(d, &short, "short", "");
    assert!(err.contains("shorter than the training window (2000 samples)"), "{err}");

    // A simulated flight whose ground truth is stamped 80 ms late: a clock error, refused.
    let sim = imu_fsda::sim::SimConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("params/sim/aerial_adis16448.yaml")).unwrap();
    let mut late = imu_fsda::sim::simulate(&sim).unwrap().recording;
    late.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 80_000_000);
    let err = train_fails_on(d, &late, "late", "");
    assert!(err.contains("lags the IMU by 80.") && err.contains("correct the stamps"), "{err}");

    // Ground truth that is not this IMU's rotation: trained on without a word before.
    let flight = imu_fsda::sim::simulate(&sim).unwrap().recording;
    let mut degrees = flight.clone();
    degrees.imu.iter_mut().for_each(|s| s.gyro *= 180.0 / std::f64::consts::PI);
    let err = train_fails_on(d, &degrees, "gyro_in_degrees", "");
    assert!(err.contains("the gyro is not in rad/s"), "{err}");
    let mut other_frame = flight.clone();
    let quarter = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(std::f64::consts::FRAC_PI_2, 0.0, 0.0));
    other_frame.ground_truth.iter_mut().for_each(|p| p.world_from_body *= quarter);
    let err = train_fails_on(d, &other_frame, "gt_other_frame", "");
    assert!(err.contains("the ground truth is in another frame: a constant rotation of 90.0°"), "{err}");
    let mut inverted = flight.clone();
    inverted.ground_truth.iter_mut().for_each(|p| p.world_from_body = p.world_from_body.inverse());
    let err = train_fails_on(d, &inverted, "gt_inverted", "");
    assert!(err.contains("quaternions are inverted"), "{err}");
    // A driver that flips the z axis: a mirror image, which no rotation fixes (it was reported
    // as "another frame" of 123.8°, and `adapt --frame apply` accepted it).
    let mut flipped = flight.clone();
    flipped.imu.iter_mut().for_each(|s| s.gyro.z = -s.gyro.z);
    let err = train_fails_on(d, &flipped, "gyro_z_flipped", "");
    assert!(err.contains("mirror image of the ground truth's (x→x, y→y, z→−z"), "{err}");

    let far = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(5000, 3_600_000_000_000), temperature: vec![] };
    let err = train_fails_on(d, &far, "no_overlap", "");
    assert!(err.contains("does not overlap the IMU"), "{err}");

    let mut nan = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(5000, 0), temperature: vec![] };
    nan.imu[100].gyro.y = f64::NAN;
    let err = train_fails_on(d, &nan, "nan", "");
    assert!(err.contains("non-finite"), "{err}");

    // Poses at 25 Hz under a 10-ms nearest-pose rule: no 17 consecutive samples qualify, so no
    // increment could be scored and the run trained the reconstruction alone (L_D = 0) before.
    let mut sparse = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(5000, 0), temperature: vec![] };
    sparse.ground_truth.retain(|p| p.stamp_ns % 40_000_000 == 0);
    let err = train_fails_on(d, &sparse, "sparse_gt", "");
    assert!(err.contains("no 16-sample increment of the loss can be scored") && err.contains("is 5 samples"), "{err}");

    // A 100-Hz IMU under a 200-Hz model: the window would span twice the time, and the exported
    // rate (what the node checks its input against) would be wrong for it.
    let mut slow = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(10000, 0), temperature: vec![] };
    slow.imu.iter_mut().enumerate().for_each(|(i, s)| s.stamp_ns = i as i64 * 10_000_000);
    let err = train_fails_on(d, &slow, "slow_imu", "");
    assert!(err.contains("the model is for a 200 Hz IMU and this one runs at 100.0 Hz"), "{err}");

    // A key no recipe has (an experiment's, removed): refused by name, not ignored.
    let fine = Recording { name: "x".into(), imu: imu(5000, 0), ground_truth: poses(5000, 0), temperature: vec![] };
    let err = train_fails_on(d, &fine, "removed_key", ", augment_per_imu: {euroc: {gyro_noise_std: 8.0e-4}}");
    assert!(err.contains("unknown field") && err.contains("augment_per_imu"), "{err}");

    // A sequence shorter than the FSDA-F support set (60 s) plus a query set.
    let bag = d.join("support.mcap");
    write_recording(&bag, &Recording { name: "x".into(), imu: imu(8000, 0), ground_truth: poses(8000, 0), temperature: vec![] }).unwrap();
    let cfg = d.join("support.yaml");
    std::fs::write(
        &cfg,
        format!("model: {{mode: fsda_f}}\ndataset:\n  train: [{{bag: {}}}]\ntrain: {{epochs: 2, threads: 1}}\n", bag.display()),
    )
    .unwrap();
    let out = run(Command::new(bin()).args(["train", "--no-progress", "--config"]).arg(&cfg).arg("--out-dir").arg(d.join("out")));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("shorter than the support set (60 s) plus a query window"), "{err}");
    assert!(!err.contains("8001 samples"), "the needed length is the support set's and a query window's: {err}");

    // A name is a file stem: an empty one wrote dotfiles (.pt, .json) before.
    for name in ["", "../x", ".hidden"] {
        let out = run(Command::new(bin())
            .args(["train", "--no-progress", "--config"])
            .arg(&cfg)
            .arg("--out-dir")
            .arg(d.join("out"))
            .args(["--name", name]));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("a model name is a file stem"), "{name:?}: {err}");
    }
}

/// The ground-truth checks accept every real recording of the benchmarks (raw, uncalibrated
/// gyro included): the rotation each 0.25 s agrees in size and axis with the gyro's.
#[test]
fn real_recordings_pass_the_ground_truth_checks() {
    let Some(data) = shared_data() else { return };
    for set in ["euroc", "tumvi"] {
        for entry in std::fs::read_dir(data.join(set)).unwrap() {
            let path = entry.unwrap().path();
            let (_, rec, _) = imu_fsda::dataset::load_sequence(&path).unwrap();
            let (ratio, n, frame, inverted) = imu_fsda::train::data::rotation_agreement(&rec).unwrap();
            let f = frame.unwrap();
            eprintln!(
                "{}: ratio {:.3} over {n}; frame {:.2}°, residual {:.2}° (identity {:.2}°), bias {:?} rad/s",
                rec.name,
                ratio.unwrap_or(f64::NAN),
                f.angle_deg,
                f.residual_deg,
                f.residual_identity_deg,
                f.gyro_bias_rad_s
            );
            assert!(!inverted, "{}", rec.name);
            imu_fsda::train::data::check_ground_truth_follows_gyro(&rec, true).unwrap();
        }
    }
}

/// A `train.seeds` parent stopped by SIGTERM (timeout, systemd, Ctrl-C) takes its children with
/// it, each at its checkpoint: before, they went on training, and a restarted parent started
/// second writers on their runs.
#[test]
fn seed_children_stop_with_their_parent() {
    let Some(data) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(manifest().join("params/train/ci-small.yaml")).unwrap();
    let text = text.replace("root: ../../../shared/data", &format!("root: {}", data.display())).replace("  seed: 0\n", "  seeds: [0, 1]\n");
    let config = dir.path().join("orphans.yaml");
    std::fs::write(&config, text).unwrap();
    let mut parent = Command::new(bin())
        .args(["train", "--config"])
        .arg(&config)
        .arg("--out-dir")
        .arg(dir.path())
        .args(["--no-progress", "--epochs", "100000", "--jobs", "2"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let logs: Vec<PathBuf> = ["orphans-s0.log", "orphans-s1.log"].iter().map(|l| dir.path().join("orphans.runs").join(l)).collect();
    let size = |p: &PathBuf| std::fs::metadata(p).map_or(0, |m| m.len());
    let started = std::time::Instant::now();
    // Wait until both children are training (their logs grow past the data loading).
    while logs.iter().any(|l| size(l) < 2000) {
        assert!(started.elapsed().as_secs() < 120, "the children did not start");
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    unsafe { libc::kill(parent.id() as i32, libc::SIGTERM) };
    // The parent stops its children at their next epoch, each writing its checkpoint, and
    // says so with the exit status of an interrupted command.
    assert_eq!(parent.wait().unwrap().code(), Some(130));
    for run in ["orphans-s0", "orphans-s1"] {
        let ckpt = dir.path().join("orphans.runs").join(format!("{run}.ckpt.json"));
        let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&ckpt).unwrap()).unwrap();
        assert!(meta["epoch"].as_u64().is_some_and(|e| e >= 1), "{run}: {}", meta["epoch"]);
    }
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let before: Vec<u64> = logs.iter().map(size).collect();
    std::thread::sleep(std::time::Duration::from_secs(3));
    let after: Vec<u64> = logs.iter().map(size).collect();
    assert_eq!(before, after, "a child went on training after its parent stopped");
}

/// A resume continues on the data its checkpoint trained on: a training bag rewritten under
/// the same path (a re-export, another crop of the same drive) is refused by name; the
/// untouched bag resumes.
#[test]
fn a_resume_refuses_recordings_that_changed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sim = imu_fsda::sim::SimConfig::load(&manifest().join("params/sim/aerial_adis16448.yaml")).unwrap();
    let flight = imu_fsda::sim::simulate(&sim).unwrap().recording;
    let bag = d.join("flight.mcap");
    write_recording(&bag, &flight).unwrap();
    let cfg = d.join("c.yaml");
    std::fs::write(
        &cfg,
        "model: {mode: fsda}\ndataset:\n  train: [{bag: flight.mcap}]\ntrain: {epochs: 2, window_samples: 2000, threads: 1}\n",
    )
    .unwrap();
    let train = |epochs: &str, resume: bool| {
        let mut cmd = Command::new(bin());
        cmd.args(["train", "--no-progress", "--config"])
            .arg(&cfg)
            .arg("--out-dir")
            .arg(d.join("out"))
            .args(["--name", "m", "--epochs", epochs]);
        if resume {
            cmd.arg("--resume").arg(d.join("out/m.ckpt.json"));
        }
        run(&mut cmd)
    };
    assert!(train("2", false).status.success());
    let mut edited = flight.clone();
    edited.imu[100].gyro.x += 1e-3;
    write_recording(&bag, &edited).unwrap();
    let out = train("3", true);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("the data of train.flight changed since the checkpoint"), "{err}");
    write_recording(&bag, &flight).unwrap();
    let out = train("3", true);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    // Stopped with epochs left, the same command without --resume is refused (it started again
    // from epoch 0 over the checkpoint); the checkpoint stays as it was.
    let mut long = Command::new(bin())
        .args(["train", "--no-progress", "--config"])
        .arg(&cfg)
        .arg("--out-dir")
        .arg(d.join("out"))
        .args(["--name", "long", "--epochs", "100000"])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let ckpt = d.join("out/long.ckpt.json");
    // Its first checkpoint (the stop writes one too, but waiting for it keeps the test honest
    // about a run that has started training).
    let t = std::time::Instant::now();
    while !d.join("out/long.lock").exists() && t.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    std::thread::sleep(std::time::Duration::from_millis(1500));
    // SAFETY: a signal to the child this test started.
    unsafe { libc::kill(long.id() as i32, libc::SIGINT) };
    assert_eq!(long.wait().unwrap().code(), Some(130));
    let saved = std::fs::read(&ckpt).unwrap();
    let again = run(Command::new(bin())
        .args(["train", "--no-progress", "--config"])
        .arg(&cfg)
        .arg("--out-dir")
        .arg(d.join("out"))
        .args(["--name", "long", "--epochs", "100000"]));
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(!again.status.success() && err.contains("holds an unfinished run of long") && err.contains("--resume"), "{err}");
    assert_eq!(std::fs::read(&ckpt).unwrap(), saved);
}

/// The trainer's test rows say, as `eval`'s do, how much of a recording its ground-truth gaps
/// left unscored.
#[test]
fn test_rows_name_the_ground_truth_gaps() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sim = imu_fsda::sim::SimConfig::load(&manifest().join("params/sim/aerial_adis16448.yaml")).unwrap();
    let flight = imu_fsda::sim::simulate(&sim).unwrap().recording;
    write_recording(d.join("flight.mcap"), &flight).unwrap();
    let mut gappy = flight.clone();
    let t0 = gappy.ground_truth[0].stamp_ns;
    gappy.ground_truth.retain(|p| !(5_000_000_000..9_000_000_000).contains(&(p.stamp_ns - t0)));
    write_recording(d.join("gappy.mcap"), &gappy).unwrap();
    let cfg = d.join("c.yaml");
    std::fs::write(
        &cfg,
        "model: {mode: fsda}\ndataset:\n  train: [{bag: flight.mcap}]\n  test: [{bag: gappy.mcap, end_s: 1000}]\ntrain: {epochs: 2, window_samples: 2000, threads: 1}\n",
    )
    .unwrap();
    let out = run(Command::new(bin()).args(["train", "--no-progress", "--config"]).arg(&cfg).arg("--out-dir").arg(d.join("out")));
    let (printed, err) = (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success() && err.contains("end_s 1000 s is past its ground-truth-covered data"), "{err}");
    let row = printed.lines().find(|l| l.starts_with("test gappy")).unwrap_or_else(|| panic!("{printed}"));
    let share: f64 =
        row.split("; ").nth(1).and_then(|n| n.split(' ').next()).and_then(|x| x.parse().ok()).unwrap_or_else(|| panic!("{row}"));
    let span = (flight.imu.last().unwrap().stamp_ns - flight.imu[0].stamp_ns) as f64 * 1e-9;
    assert!(row.contains("% of the span in ground-truth gaps, not scored") && (share - 400.0 / span).abs() < 1.0, "{row} ({span} s)");
}

/// A lock whose pid now belongs to a process started after the lock was written (the pid was
/// reused: after a reboot, or months later) is taken over; a lock held by a live run is not.
#[test]
fn a_lock_whose_pid_was_reused_is_taken_over() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sim = imu_fsda::sim::SimConfig::load(&manifest().join("params/sim/aerial_adis16448.yaml")).unwrap();
    write_recording(d.join("flight.mcap"), &imu_fsda::sim::simulate(&sim).unwrap().recording).unwrap();
    let cfg = d.join("c.yaml");
    std::fs::write(
        &cfg,
        "model: {mode: fsda}\ndataset:\n  train: [{bag: flight.mcap}]\ntrain: {epochs: 1, window_samples: 2000, threads: 1}\n",
    )
    .unwrap();
    std::fs::create_dir_all(d.join("out")).unwrap();
    let lock = d.join("out/m.lock");
    let train = || {
        run(Command::new(bin()).args(["train", "--no-progress", "--name", "m", "--config"]).arg(&cfg).arg("--out-dir").arg(d.join("out")))
    };
    // This test's own pid, written now: a live run's lock.
    std::fs::write(&lock, format!("{}\n", std::process::id())).unwrap();
    let out = train();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("another run (pid"));
    // The same pid in a lock written a day before this process started.
    assert!(Command::new("touch").args(["-d", "1 day ago"]).arg(&lock).status().unwrap().success());
    let out = train();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("since given to a process started after the lock was written"), "{err}");
    // Written a few seconds before this process started, as a file system whose clock runs
    // behind stamps a live run's lock: still that run's, not taken.
    std::fs::write(&lock, format!("{}\n", std::process::id())).unwrap();
    assert!(Command::new("touch").args(["-d", "-5 seconds"]).arg(&lock).status().unwrap().success());
    let out = train();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("another run (pid"));
    std::fs::remove_file(&lock).unwrap();
    assert!(!lock.exists(), "the lock is removed at the end of the run");
    // An adapted model of the name (`adapt -o out/m.pt` writes m.adapt.json beside it) is not
    // replaced by a training run.
    std::fs::write(d.join("out/m.adapt.json"), "{}").unwrap();
    let model = std::fs::read(d.join("out/m.json")).unwrap();
    let out = train();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("is an adapted model"), "{err}");
    assert_eq!(std::fs::read(d.join("out/m.json")).unwrap(), model);
}

/// A resume may change the validation list: each recording's evaluations stay under its own
/// name (they were paired by position, and a new recording's figures were filed under the
/// old one's name, beside the old one's raw AOE).
#[test]
fn a_resume_with_another_validation_list_keeps_each_recordings_figures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut sim = imu_fsda::sim::SimConfig::load(&manifest().join("params/sim/aerial_adis16448.yaml")).unwrap();
    for (name, seed) in [("a", 1), ("b", 2), ("c", 3)] {
        sim.seed = seed;
        write_recording(d.join(format!("{name}.mcap")), &imu_fsda::sim::simulate(&sim).unwrap().recording).unwrap();
    }
    let config = |validation: &str| {
        let cfg = d.join(format!("v{}.yaml", validation.len()));
        std::fs::write(
            &cfg,
            format!(
                "model: {{mode: fsda}}\ndataset:\n  train: [{{bag: a.mcap}}]\n  validation: [{validation}]\ntrain: {{epochs: 4, window_samples: 2000, threads: 1, eval_every: 1, select_best: true}}\n"
            ),
        )
        .unwrap();
        cfg
    };
    let train = |cfg: &Path, epochs: &str, resume: bool| {
        let mut cmd = Command::new(bin());
        cmd.args(["train", "--no-progress", "--name", "m", "--epochs", epochs, "--config"]).arg(cfg).arg("--out-dir").arg(d.join("out"));
        if resume {
            cmd.arg("--resume").arg(d.join("out/m.ckpt.json"));
        }
        run(&mut cmd)
    };
    let out = train(&config("{bag: b.mcap}"), "2", false);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = train(&config("{bag: c.mcap}, {bag: b.mcap}"), "4", true);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && err.contains("the validation set is not the checkpoint's"), "{err}");
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join("out/m.train.json")).unwrap()).unwrap();
    let epochs = |name: &str| -> Vec<u64> {
        let v = summary["validation"].as_array().unwrap().iter().find(|v| v["name"] == name).unwrap_or_else(|| panic!("{summary}"));
        v["evals"].as_array().unwrap().iter().map(|e| e[0].as_u64().unwrap()).collect()
    };
    assert_eq!((epochs("b"), epochs("c")), (vec![1, 2, 3, 4], vec![3, 4]));
    assert!(summary["exported_epoch"].as_u64().unwrap() >= 3, "chosen on the new set only");
}
