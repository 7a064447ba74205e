//! MCAP bags as rosbag2 writes them: profile `ros2`, `ros2msg` schemas with full
//! definitions, `cdr` messages, Zstd chunks, a summary with Statistics.
//!
//! Reading streams record by record (memory does not grow with the bag); writing keeps only
//! the open chunk in memory. [`read_recording`] turns a bag into a [`Recording`](crate::core::Recording) with the
//! repairs it made counted in a [`LoadReport`].

use std::path::{Path, PathBuf};

use crate::msg::MsgError;

mod attitudes;
mod reader;
mod recording;
mod writer;

pub use attitudes::*;
pub use reader::*;
pub use recording::*;
pub use writer::*;

/// Default topic names written by `import` and `simulate` and read by `eval`.
pub const IMU_TOPIC: &str = "/imu/data";
pub const GROUND_TRUTH_TOPIC: &str = "/ground_truth/pose";
pub const TEMPERATURE_TOPIC: &str = "/imu/temperature";
pub const IMU_FRAME: &str = "imu_link";
pub const WORLD_FRAME: &str = "world";

#[derive(Debug, thiserror::Error)]
pub enum BagError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a readable MCAP bag (after {messages} messages): {source}")]
    Mcap {
        path: PathBuf,
        messages: u64,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: writing the bag failed (after {messages} messages): {source}")]
    McapWrite {
        path: PathBuf,
        messages: u64,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path}: message {index} on {topic} (log time {log_time_ns} ns): {source}")]
    Decode {
        path: PathBuf,
        topic: String,
        index: u64,
        log_time_ns: u64,
        #[source]
        source: MsgError,
    },
    #[error("{path}: topic {topic} has type {found}, expected {expected}")]
    WrongType { path: PathBuf, topic: String, found: String, expected: String },
    #[error("{path}: no messages on topic {topic} (topics present: {present})")]
    MissingTopic { path: PathBuf, topic: String, present: String },
    #[error("{path}: {what}")]
    NotMcap { path: PathBuf, what: String },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BagError + '_ {
    move |source| BagError::Io { path: path.to_path_buf(), source }
}

#[cfg(test)]
mod tests {
    use std::fs::File;

    use super::recording::*;
    use super::*;
    use crate::core::{ImuSample, PoseSample, Recording, TemperatureSample};
    use crate::msg::Imu;
    use nalgebra::{UnitQuaternion, Vector3};

    /// What `ros2 bag record` leaves that is not an MCAP file is named, with what to do.
    #[test]
    fn rosbag2_folders_sqlite_and_compressed_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let says = |p: &Path| match BagReader::open(p) {
            Err(e @ BagError::NotMcap { .. }) => e.to_string(),
            Err(e) => panic!("{}: {e}", p.display()),
            Ok(_) => panic!("{}: opened", p.display()),
        };
        let rosbag2 = dir.path().join("rec");
        std::fs::create_dir_all(&rosbag2).unwrap();
        std::fs::write(rosbag2.join("metadata.yaml"), "rosbag2_bagfile_information: {}\n").unwrap();
        std::fs::write(rosbag2.join("rec_0.mcap"), b"").unwrap();
        assert!(says(&rosbag2).contains("rec_0.mcap"), "{}", says(&rosbag2));
        std::fs::remove_file(rosbag2.join("rec_0.mcap")).unwrap();
        std::fs::write(rosbag2.join("rec_0.db3"), b"SQLite format 3\0").unwrap();
        assert!(says(&rosbag2).contains("ros2 bag convert"));
        assert!(says(&rosbag2.join("rec_0.db3")).contains("SQLite3"));
        let zst = dir.path().join("rec_0.mcap.zstd");
        std::fs::write(&zst, [0x28, 0xb5, 0x2f, 0xfd, 0, 0, 0, 0]).unwrap();
        assert!(says(&zst).contains("zstd -d"));
    }

    /// The attitudes a node published: messages without an orientation pass, unusable ones
    /// (a NaN covariance, a zero quaternion) and repeated stamps are counted as skipped.
    #[test]
    fn published_attitudes_are_read_in_stamp_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.mcap");
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>("/imu/denoised").unwrap();
        let sample = |k: i64| ImuSample { stamp_ns: 1_000_000_000 + k * 5_000_000, gyro: Vector3::zeros(), accel: Vector3::zeros() };
        let with = |k: i64, q: crate::msg::Quaternion, cov0: f64| {
            let mut m = Imu::from_sample(&sample(k), "imu_link");
            m.orientation = q;
            m.orientation_covariance.0 = [cov0, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1.0];
            m
        };
        let turned: crate::msg::Quaternion = UnitQuaternion::from_euler_angles(0.1, 0.0, 0.0).into();
        let zero = crate::msg::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 0.0 };
        let msgs = [
            Imu::from_sample(&sample(0), "imu_link"),
            with(1, turned, 1e-4),
            with(2, turned, f64::NAN),
            with(3, zero, 1e-4),
            with(1, turned, 1e-4),
            with(4, turned, 2e-4),
        ];
        for (i, m) in msgs.iter().enumerate() {
            w.write(ch, 1_000 + i as i64, m).unwrap();
        }
        w.finish().unwrap();
        let p = read_published_attitudes(&path, "/imu/denoised").unwrap();
        assert_eq!((p.messages, p.attitudes.len(), p.skipped), (6, 2, 3));
        assert_eq!(p.first_stamp_ns, Some(sample(0).stamp_ns));
        assert_eq!(p.attitudes[1].stamp_ns, sample(4).stamp_ns);
        assert!((p.attitudes[1].covariance[(0, 0)] - 2e-4).abs() < 1e-18 && (p.attitudes[0].world_from_body.angle() - 0.1).abs() < 1e-12);
        assert!(matches!(read_published_attitudes(&path, "/imu/none"), Err(BagError::MissingTopic { .. })));
    }

    fn recording() -> Recording {
        let imu = (0..500)
            .map(|k| ImuSample {
                stamp_ns: 1_000_000_000 + k * 5_000_000,
                gyro: Vector3::new(0.01 * k as f64, -0.2, 0.3),
                accel: Vector3::new(0.0, 0.1, 9.81),
            })
            .collect();
        let ground_truth = (0..250)
            .map(|k| PoseSample {
                stamp_ns: 1_000_000_000 + k * 10_000_000,
                position_in_world: Vector3::new(k as f64, 0.0, 1.0),
                world_from_body: UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001 * k as f64),
            })
            .collect();
        let temperature =
            (0..25).map(|k| TemperatureSample { stamp_ns: 1_000_000_000 + k * 100_000_000, celsius: 25.0 + k as f64 * 0.01 }).collect();
        Recording { name: "t".into(), imu, ground_truth, temperature }
    }

    #[test]
    fn recording_round_trips_through_a_bag() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let rec = recording();
        write_recording(&path, &rec).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!(report.skipped(), 0);
        assert_eq!(back.imu, rec.imu);
        assert_eq!(back.temperature, rec.temperature);
        assert_eq!(back.ground_truth.len(), rec.ground_truth.len());
        for (a, b) in back.ground_truth.iter().zip(&rec.ground_truth) {
            assert_eq!(a.stamp_ns, b.stamp_ns);
            assert!(a.world_from_body.angle_to(&b.world_from_body) < 1e-12);
        }
        let (info, err) = bag_info(&path);
        assert!(err.is_none());
        let imu = info.iter().find(|t| t.topic == IMU_TOPIC).unwrap();
        assert_eq!(imu.count, 500);
        assert!((imu.rate_hz() - 200.0).abs() < 1e-6);
    }

    /// A first sample stamped 0 before the driver's clock was set is left out and counted, not
    /// integrated as a gap of decades; a simulator's clock, which starts at 0, keeps it.
    #[test]
    fn an_unset_stamp_beside_clock_times_is_left_out() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let mut rec = recording();
        rec.imu.iter_mut().for_each(|s| s.stamp_ns += 1_700_000_000_000_000_000);
        rec.ground_truth.iter_mut().for_each(|p| p.stamp_ns += 1_700_000_000_000_000_000);
        rec.temperature.clear();
        rec.imu[0].stamp_ns = 0;
        write_recording(&path, &rec).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.imu_unset_stamp, report.skipped(), back.imu.len()), (1, 1, 499));
        assert_eq!(back.imu[..], rec.imu[1..]);
        assert!(report.to_string().contains("1 unset (0) stamps"), "{report}");
        let mut sim = recording();
        sim.imu.iter_mut().for_each(|s| s.stamp_ns -= 1_000_000_000);
        write_recording(&path, &sim).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.skipped(), back.imu.len(), back.imu[0].stamp_ns), (0, 500, 0));
        // … however long it runs (here past an hour).
        sim.imu.last_mut().unwrap().stamp_ns = 2 * UNSET_STAMP_BESIDE_NS;
        write_recording(&path, &sim).unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.skipped(), back.imu.len(), back.imu[0].stamp_ns), (0, 500, 0));
    }

    /// A bag is written beside its path and renamed when finished: an unfinished writer leaves
    /// the earlier bag as it was and its own readable `.partial`, which a later writer of this
    /// process replaces without touching the file another reader may hold.
    #[test]
    fn a_bag_appears_whole_or_not_at_all() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.mcap");
        write_recording(&path, &recording()).unwrap();
        let earlier = std::fs::read(&path).unwrap();
        {
            let mut w = BagWriter::create(&path).unwrap();
            let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
            w.write(ch, 1, &Imu::from_sample(&recording().imu[0], IMU_FRAME)).unwrap();
        }
        assert!(std::fs::read(&path).unwrap() == earlier);
        let partial = partial_path(&path, std::process::id());
        let held = File::open(&partial).unwrap();
        assert_eq!(BagReader::open(&partial).unwrap().count(), 1);
        let rec = Recording { imu: recording().imu[..10].to_vec(), ..Default::default() };
        write_recording(&path, &rec).unwrap();
        assert!(!partial.exists());
        assert_eq!(read_recording(&path, &RecordingTopics::default()).unwrap().0.imu.len(), 10);
        assert!(held.metadata().unwrap().len() > 0, "the old .partial was unlinked, not truncated");
        assert!(matches!(BagWriter::create(dir.path()), Err(BagError::NotMcap { .. })));
    }

    /// Messages written out of log-time order (allowed by MCAP) are read in log-time order,
    /// not dropped as backwards stamps.
    #[test]
    fn a_bag_out_of_log_time_order_is_read_in_log_time_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shuffled.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        let mut order: Vec<usize> = (0..rec.imu.len()).collect();
        for pair in order.chunks_mut(7) {
            pair.reverse();
        }
        for k in order {
            let s = &rec.imu[k];
            w.write(ch, s.stamp_ns, &Imu::from_sample(s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) =
            read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        assert_eq!(back.imu, rec.imu);
        assert_eq!(report.skipped(), 0);
        assert!(report.out_of_log_time_order > 400, "{}", report.out_of_log_time_order);
        // What replay and play publish: every message, in log-time order.
        let (topics, damage) = bag_info(&path);
        assert!(damage.is_none() && topics[0].out_of_log_time_order > 400);
        let times: Vec<u64> = messages_in_log_time_order(&path, &topics).unwrap().map(|m| m.unwrap().log_time_ns).collect();
        assert_eq!(times.len(), rec.imu.len());
        assert!(times.windows(2).all(|w| w[0] <= w[1]), "not in log-time order");
    }

    /// Two messages whose receive (log) times a recorder swapped, their header stamps in order
    /// as written: kept in the file's order, not one dropped as a backwards stamp.
    #[test]
    fn swapped_log_times_with_ordered_stamps_lose_no_sample() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("swapped.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let log = match k {
                100 => rec.imu[101].stamp_ns,
                101 => rec.imu[100].stamp_ns,
                _ => s.stamp_ns,
            };
            w.write(ch, log, &Imu::from_sample(s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) =
            read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        assert_eq!((report.skipped(), report.out_of_log_time_order), (0, 1), "{report}");
        assert_eq!(back.imu, rec.imu);
    }

    /// A driver restart steps the IMU's clock back: said as such, not as stamps taken on
    /// arrival or left at zero.
    #[test]
    fn a_clock_stepping_back_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("restart.mcap");
        let rec = recording();
        let n = rec.imu.len();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            s.stamp_ns += 100_000_000_000;
            if k >= n / 4 {
                s.stamp_ns -= 30_000_000_000;
            }
            // Received in order: the recorder's clock did not step.
            w.write(ch, 1_000_000_000 + k as i64 * 5_000_000, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (_, report) = read_recording(&path, &RecordingTopics { ground_truth: None, temperature: None, ..Default::default() }).unwrap();
        let why = report.stamp_problem_above(0.1).unwrap();
        assert!(why.contains("the IMU's clock steps back by 29.995 s at 0.620 s") && why.contains("a driver restart?"), "{why}");
    }

    #[test]
    fn bad_samples_are_skipped_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.mcap");
        let mut rec = recording();
        rec.imu[10].gyro.x = f64::NAN;
        rec.imu[20].stamp_ns = rec.imu[19].stamp_ns; // duplicate
        rec.imu[30].accel.z = f64::INFINITY;
        // The writer interleaves by stamp, so write the raw stream by hand to keep a backwards
        // header stamp (received in order: its log time is in order).
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            let received = s.stamp_ns;
            if k == 40 {
                s.stamp_ns -= 1_000_000_000;
            }
            w.write(ch, received, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!(report.imu_non_finite, 2);
        assert_eq!(report.imu_duplicate_stamp, 1);
        assert_eq!(report.imu_backwards_stamp, 1);
        assert_eq!(back.imu.len(), 496);
        assert!(back.imu.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
    }

    #[test]
    fn jittered_stamps_are_put_back_in_order_and_a_clock_step_is_not() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("jitter.mcap");
        let rec = recording();
        let mut w = BagWriter::create(&path).unwrap();
        let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
        for (k, s) in rec.imu.iter().enumerate() {
            let mut s = *s;
            let received = s.stamp_ns;
            // Stamped 7 ms late, so the next one (5 ms on) is 2 ms before it; sample 300
            // repeats sample 298's stamp; sample 400 is stamped 30 ms back (past the limit).
            match k {
                k if k % 50 == 7 => s.stamp_ns += 7_000_000,
                300 => s.stamp_ns -= 10_000_000,
                400 => s.stamp_ns -= 30_000_000,
                // A clock stepped back 32.5 ms: the 6 samples until it passes the last kept
                // stamp are dropped, none put among the older ones.
                k if k >= 460 => s.stamp_ns -= 32_500_000,
                _ => {}
            }
            w.write(ch, received, &Imu::from_sample(&s, IMU_FRAME)).unwrap();
        }
        w.finish().unwrap();
        let (back, report) = read_recording(&path, &RecordingTopics::default()).unwrap();
        assert_eq!((report.imu_reordered, report.imu_duplicate_stamp, report.imu_backwards_stamp), (10, 1, 7), "{report}");
        assert_eq!(back.imu.len(), 492);
        assert!(back.imu.windows(2).all(|w| w[1].stamp_ns > w[0].stamp_ns));
        // The late-stamped sample sits after the one received behind it, with its own rates.
        let late = back.imu.iter().position(|s| s.stamp_ns == rec.imu[7].stamp_ns + 7_000_000).unwrap();
        assert_eq!((back.imu[late - 1].stamp_ns, back.imu[late].gyro), (rec.imu[8].stamp_ns, rec.imu[7].gyro));
        let note = report.imu_stream_note().unwrap();
        assert!(note.contains("10 IMU samples stamped up to 20 ms before") && note.contains("put back in stamp order"), "{note}");
    }

    #[test]
    fn a_second_sensor_on_the_imu_topic_is_left_out_and_said() {
        let dir = tempfile::tempdir().unwrap();
        let rec = recording();
        let write = |name: &str, frame_of: &dyn Fn(usize) -> &'static str| {
            let path = dir.path().join(name);
            let mut w = BagWriter::create(&path).unwrap();
            let ch = w.channel::<Imu>(IMU_TOPIC).unwrap();
            for (k, s) in rec.imu.iter().enumerate() {
                let mut s = *s;
                if frame_of(k) == "imu2_link" {
                    // The other sensor: its own axes and a clock 1 ms behind.
                    s.gyro = -s.gyro;
                    s.stamp_ns -= 1_000_000;
                }
                w.write(ch, s.stamp_ns, &Imu::from_sample(&s, frame_of(k))).unwrap();
            }
            w.finish().unwrap();
            read_recording(&path, &RecordingTopics::default()).unwrap()
        };
        let (back, report) = write("two.mcap", &|k| if k % 2 == 1 { "imu2_link" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.imu_reordered), (250, 250, 0), "{report}");
        assert!(back.imu.iter().all(|s| s.gyro.y == -0.2));
        assert_eq!(report.interleaved_frames, Some((IMU_FRAME.to_string(), "imu2_link".to_string())));
        assert!(report.imu_stream_note().unwrap().contains("interleaves two sensors"));
        assert!(report.to_string().contains("250 of another sensor (frame_id \"imu2_link\")"), "{report}");
        // One rename mid-recording is one sensor: every sample is read.
        let (back, report) = write("renamed.mcap", &|k| if k >= 250 { "imu2_link" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
        // One driver alternating two frame_ids on one continuous signal: all read.
        let (back, report) = write("alternate.mcap", &|k| if k % 2 == 1 { "" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
        // Glitched frame_ids on one sensor, the first message among them: all read.
        let (back, report) = write("glitch.mcap", &|k| if k % 40 == 0 { "imu_glitch" } else { IMU_FRAME });
        assert_eq!((back.imu.len(), report.imu_other_sensor, report.interleaved_frames), (500, 0, None));
    }

    #[test]
    fn truncated_bag_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        write_recording(&path, &recording()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.path().join("cut.mcap");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let err = read_recording(&cut, &RecordingTopics::default()).unwrap_err();
        assert!(err.to_string().contains("cut.mcap"), "{err}");
        let (_, err) = bag_info(&cut);
        assert!(err.is_some());
        let garbage = dir.path().join("garbage.mcap");
        std::fs::write(&garbage, b"not an mcap file at all").unwrap();
        assert!(read_recording(&garbage, &RecordingTopics::default()).is_err());
    }

    #[test]
    fn missing_topic_names_what_is_there() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        write_recording(&path, &recording()).unwrap();
        let topics = RecordingTopics { imu: "/imu/data_raw".into(), ..Default::default() };
        let err = read_recording(&path, &topics).unwrap_err().to_string();
        assert!(err.contains("/imu/data_raw") && err.contains("/imu/data [sensor_msgs/msg/Imu]"), "{err}");
    }
}
