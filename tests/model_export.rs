//! Export round trip: a seeded random model is exported, then the TorchScript file (in tch
//! and in Python's `torch.jit.load`), the reloaded `Net` and the `StreamingDenoiser` must all
//! reproduce the in-memory forward; broken files give `ModelError`s, never panics.

use std::path::{Path, PathBuf};
use std::process::Command;

use imu_fsda::model::export::{self, ExportInfo, ExportPaths};
use imu_fsda::model::{Config, Mode, ModelError, Net};
use nalgebra::Vector3;
use tch::nn::VarStore;
use tch::{Device, Kind, Tensor};

mod common;

const TOL_RAD_S: f64 = 1e-5;

/// A seeded model with non-trivial normalisation and BatchNorm statistics.
fn random_model(mode: Mode, seed: i64) -> (VarStore, Net) {
    random_model_with(&Config::for_mode(mode), seed)
}

fn random_model_with(cfg: &Config, seed: i64) -> (VarStore, Net) {
    tch::manual_seed(seed);
    let vs = VarStore::new(Device::Cpu);
    let net = Net::new(cfg, &vs.root()).unwrap();
    net.set_normalization(&[0.01, -0.02, 0.03, 9.3, 0.1, -1.0], &[0.4, 0.5, 0.3, 1.5, 1.2, 1.1]).unwrap();
    for _ in 0..3 {
        let _ = net.forward_t(&(Tensor::randn([2, 400, 6], (Kind::Float, Device::Cpu)) * 0.5 + 0.2), true);
    }
    (vs, net)
}

/// `[B, T, 6]` raw-IMU-like input: gravity on x, motion, noise.
fn imu_input(b: i64, t: i64, seed: i64) -> Tensor {
    tch::manual_seed(seed);
    let time = Tensor::arange(t, (Kind::Float, Device::Cpu)).unsqueeze(0).unsqueeze(-1) * 0.005;
    let freq = Tensor::from_slice(&[1.3f32, 0.7, 0.4, 2.0, 1.1, 0.5]).reshape([1, 1, 6]);
    let amp = Tensor::from_slice(&[0.5f32, 0.3, 0.8, 0.5, 0.4, 0.3]).reshape([1, 1, 6]);
    let offset = Tensor::from_slice(&[0.0f32, 0.0, 0.0, 9.81, 0.0, -0.2]).reshape([1, 1, 6]);
    let noise = Tensor::from_slice(&[0.05f32, 0.05, 0.05, 0.3, 0.3, 0.3]).reshape([1, 1, 6]);
    ((time * freq).sin() * amp + offset).expand([b, t, 6], false) + Tensor::randn([b, t, 6], (Kind::Float, Device::Cpu)) * noise
}

fn max_abs_diff(a: &Tensor, b: &Tensor) -> f64 {
    assert_eq!(a.size(), b.size());
    (a.to_kind(Kind::Double) - b.to_kind(Kind::Double)).abs().max().double_value(&[])
}

fn python() -> Option<PathBuf> {
    let candidate = std::env::var_os("PYTHON").map(PathBuf::from).unwrap_or_else(|| {
        let cache = std::env::var_os("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(std::env::var_os("HOME").unwrap_or_default()).join(".cache"));
        cache.join("imu-fsda/torch-2.13.0/bin/python")
    });
    candidate.is_file().then_some(candidate)
}

fn write_f32(path: &Path, t: &Tensor) {
    let v = Vec::<f32>::try_from(&t.flatten(0, -1)).unwrap();
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    std::fs::write(path, bytes).unwrap();
}

fn read_f32(path: &Path, shape: &[i64]) -> Tensor {
    let bytes = std::fs::read(path).unwrap();
    let v: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    Tensor::from_slice(&v).reshape(shape)
}

/// Runs tests/python/check_torchscript.py; None when no Python with torch is available
/// (a failure under CI).
fn run_python(model: &Path, u: &Tensor, dir: &Path) -> Option<Tensor> {
    let Some(py) = python() else {
        common::skip_or_fail("the Python TorchScript check", "no Python with torch (set PYTHON or run scripts/setup.sh)");
        return None;
    };
    let (b, t) = (u.size()[0], u.size()[1]);
    let (input, output) = (dir.join("input.bin"), dir.join("output.bin"));
    write_f32(&input, u);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check_torchscript.py");
    let status = Command::new(&py)
        .arg(&script)
        .arg(model)
        .arg(&input)
        .arg(b.to_string())
        .arg(t.to_string())
        .arg(&output)
        .status()
        .expect("run python");
    assert!(status.success(), "{} {} failed: {status}", py.display(), script.display());
    Some(read_f32(&output, &[b, t, 3]))
}

/// One sequence `[T, 6]` through the streaming denoiser, sample by sample → `[T, 3]` f32.
fn stream_sequence(stream: &mut imu_fsda::model::StreamingDenoiser, u: &Tensor) -> Tensor {
    let rows = Vec::<f32>::try_from(&u.flatten(0, -1)).unwrap();
    let out: Vec<f32> = rows
        .chunks_exact(6)
        .flat_map(|r| {
            let w = stream.step(&Vector3::new(r[0] as f64, r[1] as f64, r[2] as f64), &Vector3::new(r[3] as f64, r[4] as f64, r[5] as f64));
            [w.x as f32, w.y as f32, w.z as f32]
        })
        .collect();
    Tensor::from_slice(&out).reshape([-1, 3])
}

/// One sequence `[T, 6]` (f32) as IMU samples, 5 ms apart.
fn to_samples(u: &Tensor) -> Vec<imu_fsda::core::ImuSample> {
    let rows = Vec::<f32>::try_from(&u.flatten(0, -1)).unwrap();
    rows.chunks_exact(6)
        .enumerate()
        .map(|(k, r)| imu_fsda::core::ImuSample {
            stamp_ns: k as i64 * 5_000_000,
            gyro: Vector3::new(r[0] as f64, r[1] as f64, r[2] as f64),
            accel: Vector3::new(r[3] as f64, r[4] as f64, r[5] as f64),
        })
        .collect()
}

#[test]
fn export_round_trip_matches_in_memory_forward() {
    tch::set_num_threads(1);
    // The channel LayerNorm is kept in the inference form, not folded: it must trace too.
    let layer_norm = Config { batch_norm: false, layer_norm: true, ..Config::for_mode(Mode::FsdaF) };
    for (cfg, seed) in [(Config::for_mode(Mode::Digdl), 21), (Config::for_mode(Mode::FsdaF), 22), (layer_norm, 23)] {
        let mode = cfg.mode;
        let (vs, net) = random_model_with(&cfg, seed);
        let dir = tempfile::tempdir().unwrap();
        let info = ExportInfo { training_data: vec!["synthetic".into()], ..Default::default() };
        let paths = export::export_model(dir.path(), "model", &vs, &net, &info).unwrap();
        assert_eq!(paths, ExportPaths::new(dir.path(), "model"));
        let u = imu_input(2, 1200, seed);
        let reference = tch::no_grad(|| net.forward_t(&u, false));

        // TorchScript in tch (the trace was made at T = N, B = 1; here B = 2, T = 1200).
        let ts = export::load_torchscript(&paths.metadata).unwrap();
        assert_eq!(ts.metadata.mode, mode);
        assert_eq!(ts.metadata.window_n, net.receptive_field());
        let d_ts = max_abs_diff(&ts.forward(&u).unwrap(), &reference);
        // The weights file reloaded into a Net.
        let loaded = export::load_net(&paths.metadata, Device::Cpu).unwrap();
        let d_net = max_abs_diff(&tch::no_grad(|| loaded.net.forward_t(&u, false)), &reference);
        assert!(!loaded.vs.trainable_variables().is_empty(), "the reloaded Net must be trainable");
        // The streaming denoiser, sequence 0, against the TorchScript module.
        let (mut stream, _) = export::load_streaming(&paths.metadata, None).unwrap();
        let ts_out = ts.forward(&u).unwrap().get(0);
        let d_stream = max_abs_diff(&stream_sequence(&mut stream, &u.get(0)), &ts_out);
        // Python's torch.jit.load on the same file.
        let d_py = run_python(&paths.torchscript, &u, dir.path()).map(|y| max_abs_diff(&y, &reference));
        let py = d_py.map_or("skipped".to_string(), |d| format!("{d:.2e}"));
        println!("{mode:?}: TorchScript(tch) {d_ts:.2e}, reloaded Net {d_net:.2e}, streaming vs TorchScript {d_stream:.2e}, TorchScript(Python) {py} rad/s");
        assert!(d_ts < TOL_RAD_S, "{mode:?}: TorchScript {d_ts:e}");
        assert_eq!(d_net, 0.0, "{mode:?}: reloaded weights differ");
        assert!(d_stream < TOL_RAD_S, "{mode:?}: streaming {d_stream:e}");
        if let Some(d) = d_py {
            assert!(d < TOL_RAD_S, "{mode:?}: Python {d:e}");
        }

        let meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&paths.metadata).unwrap()).unwrap();
        for key in
            ["mode", "window_n", "rate_hz", "normalization", "config", "training_data", "code_revision", "metrics", "parameter_counts"]
        {
            assert!(meta.get(key).is_some(), "metadata lacks {key}");
        }
    }
}

#[test]
fn broken_files_give_errors_not_panics() {
    tch::set_num_threads(1);
    let (vs, net) = random_model(Mode::Fsda, 31);
    let dir = tempfile::tempdir().unwrap();
    let paths = export::export_model(dir.path(), "m", &vs, &net, &ExportInfo::default()).unwrap();
    let copy_to = |name: &str| {
        let p = ExportPaths::new(dir.path(), name);
        for (a, b) in [(&paths.torchscript, &p.torchscript), (&paths.weights, &p.weights)] {
            std::fs::copy(a, b).unwrap();
        }
        let json = std::fs::read_to_string(&paths.metadata)
            .unwrap()
            .replace("\"m.pt\"", &format!("\"{name}.pt\""))
            .replace("\"m.ot\"", &format!("\"{name}.ot\""));
        std::fs::write(&p.metadata, json).unwrap();
        p
    };

    // Missing files.
    let err = export::load_net(&dir.path().join("nope.json"), Device::Cpu).unwrap_err();
    assert!(matches!(err, ModelError::MissingFile { .. }), "{err}");
    let p = copy_to("no_weights");
    std::fs::remove_file(&p.weights).unwrap();
    assert!(matches!(export::load_streaming(&p.metadata, None).unwrap_err(), ModelError::MissingFile { .. }));

    // Corrupt files.
    let p = copy_to("bad_weights");
    std::fs::write(&p.weights, b"definitely not a tensor archive").unwrap();
    let err = export::load_net(&p.metadata, Device::Cpu).unwrap_err();
    assert!(matches!(err, ModelError::CorruptFile { .. }), "{err}");
    let weights_text = err.to_string();
    let p = copy_to("bad_pt");
    std::fs::write(&p.torchscript, b"garbage").unwrap();
    let err = export::load_torchscript(&p.metadata).unwrap_err();
    assert!(matches!(err, ModelError::CorruptFile { .. }), "{err}");
    // libtorch's own words, without the C++ stack frames it appends.
    for t in [&err.to_string(), &weights_text] {
        assert!(!t.contains("frame #") && !t.contains("Exception raised from"), "{t}");
        assert!(!t.trim_end().ends_with(':'), "a reason is kept: {t}");
    }
    let p = copy_to("bad_json");
    let json = std::fs::read_to_string(&p.metadata).unwrap();
    std::fs::write(&p.metadata, &json[..json.len() / 2]).unwrap();
    let err = export::load_net(&p.metadata, Device::Cpu).unwrap_err();
    assert!(matches!(err, ModelError::CorruptFile { .. }), "{err}");

    // Metadata that does not fit the weights: another generator width …
    let p = copy_to("other_width");
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p.metadata).unwrap()).unwrap();
    meta["config"]["generator"]["hidden_channels"] = serde_json::json!([16, 32, 64, 64]);
    std::fs::write(&p.metadata, serde_json::to_string(&meta).unwrap()).unwrap();
    let err = export::load_net(&p.metadata, Device::Cpu).unwrap_err();
    assert!(matches!(err, ModelError::Mismatch { .. }), "{err}");
    println!("{err}");
    // … another mode (DIGDL weights expected, FSDA weights found) …
    let p = copy_to("other_mode");
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p.metadata).unwrap()).unwrap();
    meta["mode"] = serde_json::json!("digdl");
    meta["config"]["mode"] = serde_json::json!("digdl");
    meta["window_n"] = serde_json::json!(511);
    std::fs::write(&p.metadata, serde_json::to_string(&meta).unwrap()).unwrap();
    let err = export::load_net(&p.metadata, Device::Cpu).unwrap_err();
    assert!(matches!(err, ModelError::Mismatch { .. }), "{err}");
    // … another normalisation, and a window that contradicts the config.
    let p = copy_to("other_norm");
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p.metadata).unwrap()).unwrap();
    meta["normalization"]["std"][0] = serde_json::json!(7.0);
    std::fs::write(&p.metadata, serde_json::to_string(&meta).unwrap()).unwrap();
    assert!(matches!(export::load_net(&p.metadata, Device::Cpu).unwrap_err(), ModelError::Mismatch { .. }));
    let p = copy_to("other_window");
    let mut meta: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p.metadata).unwrap()).unwrap();
    meta["window_n"] = serde_json::json!(512);
    std::fs::write(&p.metadata, serde_json::to_string(&meta).unwrap()).unwrap();
    assert!(matches!(export::load_streaming(&p.metadata, None).unwrap_err(), ModelError::Mismatch { .. }));

    // Input shape and kind.
    let ts = export::load_torchscript(&paths.metadata).unwrap();
    for bad in [
        Tensor::zeros([1, 10, 7], (Kind::Float, Device::Cpu)),
        Tensor::zeros([10, 6], (Kind::Float, Device::Cpu)),
        Tensor::zeros([1, 10, 6], (Kind::Double, Device::Cpu)),
    ] {
        assert!(matches!(ts.forward(&bad).unwrap_err(), ModelError::InputShape { .. }));
        assert!(matches!(net.try_forward(&bad).unwrap_err(), ModelError::InputShape { .. }));
    }
}

/// A model with one Ĉ_ω per IMU: the TorchScript file (Ĉ_ω = I traced in, the IMU's applied
/// from the metadata), the reloaded Net and the streaming denoiser agree for every IMU; an
/// unknown IMU is an error for all three; an adapted model keeps its own Ĉ_ω.
#[test]
fn per_imu_calibrations_survive_export() {
    tch::set_num_threads(1);
    tch::manual_seed(31);
    let vs = VarStore::new(Device::Cpu);
    let cfg = Config { imu_calibrations: vec!["euroc".into(), "tumvi".into()], generator_sees_imu: true, ..Config::for_mode(Mode::FsdaF) };
    let net = Net::new(&cfg, &vs.root()).unwrap();
    net.set_normalization(&[0.01, -0.02, 0.03, 9.3, 0.1, -1.0], &[0.4, 0.5, 0.3, 1.5, 1.2, 1.1]).unwrap();
    let mut per_imu = vs.variables()["gyro_calib.per_imu"].shallow_clone();
    tch::no_grad(|| per_imu.copy_(&(Tensor::randn([2, 3, 3], (Kind::Float, Device::Cpu)) * 0.05)));
    let dir = tempfile::tempdir().unwrap();
    let paths = export::export_model(dir.path(), "m", &vs, &net, &ExportInfo::default()).unwrap();
    let u = imu_input(1, 900, 31);
    let meta = export::load_metadata(&paths.metadata).unwrap();
    assert_eq!(meta.imu_gyro_calibrations.len(), 2);
    assert_eq!(meta.torchscript_gyro_calibration, Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]));
    let stream_out = |imu: Option<&str>| {
        let (mut stream, _) = export::load_streaming(&paths.metadata, imu).unwrap();
        stream_sequence(&mut stream, &u.get(0)).unsqueeze(0)
    };
    for (row, imu) in [(0, Some("euroc")), (1, Some("tumvi")), (2, None)] {
        let reference = tch::no_grad(|| net.inference_for_row(row).forward(&u));
        let mut ts = export::load_torchscript(&paths.metadata).unwrap();
        ts.select_imu(imu).unwrap();
        let loaded = export::load_net(&paths.metadata, Device::Cpu).unwrap();
        loaded.select_imu(imu).unwrap();
        let d = [
            max_abs_diff(&ts.forward(&u).unwrap(), &reference),
            max_abs_diff(&tch::no_grad(|| loaded.net.forward_t(&u, false)), &reference),
            max_abs_diff(&stream_out(imu), &reference),
        ];
        println!("{imu:?}: TorchScript {:.2e}, Net {:.2e}, streaming {:.2e} rad/s", d[0], d[1], d[2]);
        assert!(d.iter().all(|d| *d < TOL_RAD_S), "{imu:?}: {d:?}");
    }
    let euroc = tch::no_grad(|| net.inference_for_row(0).forward(&u));
    let identity = tch::no_grad(|| net.inference_for_row(2).forward(&u));
    assert!(max_abs_diff(&euroc, &identity) > 1e-3, "the IMUs' Ĉ_ω must make a difference");
    let mut ts = export::load_torchscript(&paths.metadata).unwrap();
    assert!(matches!(ts.select_imu(Some("bmi088")), Err(ModelError::UnknownImu { .. })));
    assert!(matches!(export::load_streaming(&paths.metadata, Some("bmi088")), Err(ModelError::UnknownImu { .. })));
    // An adapted model: its own Ĉ_ω whatever IMU is asked for.
    let info = ExportInfo { adapted_from: Some("m".into()), ..Default::default() };
    let adapted = export::export_model(dir.path(), "m-adapted", &vs, &net, &info).unwrap();
    let mut ts = export::load_torchscript(&adapted.metadata).unwrap();
    ts.select_imu(Some("euroc")).unwrap();
    assert!(max_abs_diff(&ts.forward(&u).unwrap(), &identity) < TOL_RAD_S);
    // A model with one shared Ĉ_ω refuses an IMU name.
    let (vs1, net1) = random_model(Mode::FsdaF, 32);
    let shared = export::export_model(dir.path(), "shared", &vs1, &net1, &ExportInfo::default()).unwrap();
    let mut ts = export::load_torchscript(&shared.metadata).unwrap();
    assert!(matches!(ts.select_imu(Some("euroc")), Err(ModelError::UnknownImu { .. })));
    // … but the IMU it was trained on: the model as it is (gain 1, its own Ĉ_ω), and the guard
    // takes it for that IMU's model; unnamed or another name, a new IMU.
    let info = ExportInfo { trained_imus: vec!["robot".into()], ..Default::default() };
    let trained = export::export_model(dir.path(), "robot-model", &vs1, &net1, &info).unwrap();
    let mut ts = export::load_torchscript(&trained.metadata).unwrap();
    let own = ts.forward(&u).unwrap();
    ts.select_imu(Some("robot")).unwrap();
    assert_eq!(max_abs_diff(&ts.forward(&u).unwrap(), &own), 0.0);
    let (_, meta) = export::load_streaming(&trained.metadata, Some("robot")).unwrap();
    let domain = |imu| imu_fsda::infer::ModelDomain::of(&meta, imu);
    assert_eq!(domain(Some("robot")), imu_fsda::infer::ModelDomain::Trained);
    assert_eq!((domain(None), domain(Some("euroc"))), (imu_fsda::infer::ModelDomain::NewImu, imu_fsda::infer::ModelDomain::NewImu));
    match ts.select_imu(Some("euroc")) {
        Err(ModelError::UnknownImu { detail, .. }) => assert!(detail.contains("trained on [\"robot\"]"), "{detail}"),
        other => panic!("{other:?}"),
    }
    // A file written before `trained_imus`: its training recordings' dataset folders.
    let mut old = meta.clone();
    old.trained_imus.clear();
    old.training_data = vec!["euroc/MH_01_easy (support 60.0 s + query 121.9 s)".into(), "euroc/V1_02_medium".into(), "robot.mcap".into()];
    assert_eq!(old.trained_imus(), ["euroc"]);
    assert!(old.knows_imu("euroc") && !old.knows_imu("robot.mcap"));
    old.adapted_from = Some("m".into());
    assert!(old.trained_imus().is_empty(), "an adapted model knows its IMU by adapted_from");
}

/// Per-IMU correction gains on a model with one shared Ĉ_ω: naming an IMU gives
/// `ω + g (ω̂ − ω)` in the TorchScript file, the reloaded model's f64 reference and the
/// streaming denoiser alike; no name (a new IMU) and a gain of 1 give the model unchanged; an
/// IMU it does not know is an error; an adapted model applies all of its own correction.
#[test]
fn correction_gains_survive_export() {
    tch::set_num_threads(1);
    let (vs, net) = random_model(Mode::FsdaF, 41);
    // A trained-size Ĉ_ω so the correction (and so the gain) is well above float noise.
    let mut delta = vs.variables()["gyro_calib.delta"].shallow_clone();
    tch::no_grad(|| delta.copy_(&(Tensor::randn([3, 3], (Kind::Float, Device::Cpu)) * 0.02)));
    let gains: std::collections::BTreeMap<String, f64> = [("euroc".to_string(), 1.0), ("tumvi".to_string(), 0.4)].into();
    let dir = tempfile::tempdir().unwrap();
    let info = ExportInfo { imu_correction_gains: gains.clone(), ..Default::default() };
    let paths = export::export_model(dir.path(), "g", &vs, &net, &info).unwrap();
    let meta = export::load_metadata(&paths.metadata).unwrap();
    assert_eq!(meta.imu_correction_gains, gains);
    assert_eq!(meta.imu_names(), ["euroc", "tumvi"]);
    let u = imu_input(1, 900, 41);
    let full = tch::no_grad(|| net.inference().forward(&u));
    let raw = u.narrow(2, 0, 3);
    for (imu, g) in [(None, 1.0), (Some("euroc"), 1.0), (Some("tumvi"), 0.4)] {
        let expected = &raw + (&full - &raw) * g;
        let mut ts = export::load_torchscript(&paths.metadata).unwrap();
        ts.select_imu(imu).unwrap();
        let (mut stream, _) = export::load_streaming(&paths.metadata, imu).unwrap();
        assert_eq!(stream.correction_gain(), g);
        let samples = to_samples(&u.get(0));
        let (f64_ref, _) = imu_fsda::model::predict::correct_with_weights_f64(&paths.torchscript, &samples, imu).unwrap();
        let f64_ref =
            Tensor::from_slice(&f64_ref.iter().flat_map(|v| [v.x as f32, v.y as f32, v.z as f32]).collect::<Vec<_>>()).reshape([1, -1, 3]);
        let d = [
            max_abs_diff(&ts.forward(&u).unwrap(), &expected),
            max_abs_diff(&stream_sequence(&mut stream, &u.get(0)).unsqueeze(0), &expected),
            max_abs_diff(&f64_ref, &expected),
        ];
        println!("{imu:?} (gain {g}): TorchScript {:.2e}, streaming {:.2e}, f64 weights {:.2e} rad/s", d[0], d[1], d[2]);
        assert!(d.iter().all(|d| *d < TOL_RAD_S), "{imu:?}: {d:?}");
    }
    assert!(max_abs_diff(&(&raw + (&full - &raw) * 0.4), &full) > 1e-3, "the gain must make a difference");
    let mut ts = export::load_torchscript(&paths.metadata).unwrap();
    assert!(matches!(ts.select_imu(Some("bmi088")), Err(ModelError::UnknownImu { .. })));
    assert!(matches!(export::load_streaming(&paths.metadata, Some("bmi088")), Err(ModelError::UnknownImu { .. })));
    let loaded = export::load_net(&paths.metadata, Device::Cpu).unwrap();
    assert!(matches!(loaded.select_imu(Some("bmi088")), Err(ModelError::UnknownImu { .. })));
    loaded.select_imu(Some("tumvi")).unwrap();
    assert_eq!(loaded.correction_gain(), 0.4);
    // An adapted model carries its own correction: the name selects nothing.
    let info = ExportInfo { adapted_from: Some("g".into()), imu_correction_gains: gains, ..Default::default() };
    let adapted = export::export_model(dir.path(), "g-adapted", &vs, &net, &info).unwrap();
    let mut ts = export::load_torchscript(&adapted.metadata).unwrap();
    ts.select_imu(Some("tumvi")).unwrap();
    assert!(max_abs_diff(&ts.forward(&u).unwrap(), &full) < TOL_RAD_S);
}

/// The model's files (and a side file) are written as one set: an export that fails half-way
/// (a folder where the metadata goes) replaces none of an earlier model's files and leaves no
/// temporaries.
#[test]
fn an_export_that_fails_leaves_the_earlier_model_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (vs, net) = random_model(Mode::FsdaF, 3);
    let info = ExportInfo { side_files: vec![("note.json".into(), "{\"first\": true}\n".into())], ..Default::default() };
    export::export_model(d, "m", &vs, &net, &info).unwrap();
    let before: Vec<Vec<u8>> = ["m.pt", "m.ot", "m.json", "m.note.json"].iter().map(|f| std::fs::read(d.join(f)).unwrap()).collect();
    // A second export of other weights, into a name whose side file is blocked by a folder.
    let (vs2, net2) = random_model(Mode::FsdaF, 4);
    std::fs::create_dir(d.join("m.other.json")).unwrap();
    let info2 = ExportInfo {
        side_files: vec![("note.json".into(), "{\"first\": false}\n".into()), ("other.json".into(), "{}".into())],
        ..Default::default()
    };
    let err = export::export_model(d, "m", &vs2, &net2, &info2).expect_err("a folder in the way");
    assert!(err.to_string().contains("m.other.json"), "{err}");
    let after: Vec<Vec<u8>> = ["m.pt", "m.ot", "m.json", "m.note.json"].iter().map(|f| std::fs::read(d.join(f)).unwrap()).collect();
    assert!(before == after, "a failed export changed the earlier model's files");
    let leftovers: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporaries left: {leftovers:?}");
    // Without the obstacle the new set replaces the old one whole.
    std::fs::remove_dir(d.join("m.other.json")).unwrap();
    export::export_model(d, "m", &vs2, &net2, &info2).unwrap();
    assert_eq!(std::fs::read_to_string(d.join("m.note.json")).unwrap(), "{\"first\": false}\n");
    assert_ne!(std::fs::read(d.join("m.ot")).unwrap(), before[1]);
}
