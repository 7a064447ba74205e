//! `imu-fsda replay` on real and simulated bags: the node's pipeline against the offline
//! full-sequence evaluation of the same model (online = offline, f32 against f64 and the
//! TorchScript forward), what it copies and writes, and where its input stops or changes rate.

use std::path::Path;
use std::process::Command;

use imu_fsda::bag::{read_recording, BagReader, RecordingTopics};
use imu_fsda::model::predict::{correct_with_torchscript, correct_with_weights_f64};
use imu_fsda::model::Mode;
use imu_fsda::msg::{Imu, RosMessage, Vector3Stamped};
use imu_fsda::so3::integrate_gyro;

mod common;
use common::random_model::{car_recording, euroc_bag, export_random_model, export_random_model_with_gains};
use common::{bin, ok};

/// How far the node's f32 networks may be from the same weights run in f64: f32's rounding
/// over ~80 k multiply-adds (measured 3e-9 rad/s), far inside the 1e-5 rad/s bound against
/// the TorchScript file.
const F32_ROUNDING_RAD_S: f64 = 1e-7;

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
        let log = ok(Command::new(bin())
            .args(["-v", "replay", "--model-on-new-imu", "--imu", imu.unwrap_or(""), "--params"])
            .arg(&open_loop)
            .arg("--model")
            .arg(&model)
            .arg(&bag)
            .arg("-o")
            .arg(&out_bag));
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
    let log =
        ok(Command::new(bin()).args(["-v", "replay", "--model-on-new-imu", "--model"]).arg(&model).arg(&fast_bag).arg("-o").arg(&out_bag));
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
