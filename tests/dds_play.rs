//! `imu-fsda play` against the live node, in a network namespace the test creates: a bag whose
//! end a crashed recorder left unreadable is played up to the damage (every IMU message before
//! it reaches the node over DDS), then the damage is reported with a non-zero exit; a
//! `--topic` the bag does not have is refused, naming the topics it has.

mod common;

use std::ffi::OsStr;
use std::time::Duration;

use common::{last_json_line, manifest_dir, prerequisites, run_in_namespace, tail};
use imu_fsda::bag::bag_info;

/// A run takes ~6 s: the node's discovery, 2.1 s of playback at 1 kHz, 3 s idle exit.
const NAMESPACE_TIMEOUT: Duration = Duration::from_secs(60);

#[test]
fn a_damaged_bag_is_played_up_to_the_damage_then_reported() {
    if let Err(why) = prerequisites() {
        common::skip_or_fail("dds_play", &why);
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // The bundled car bag cut mid-record, as a recorder killed by a power loss leaves it.
    let whole = std::fs::read(manifest_dir().join("test_bags/sim_car.mcap")).unwrap();
    let damaged = dir.path().join("damaged.mcap");
    std::fs::write(&damaged, &whole[..whole.len() / 2]).unwrap();
    let (topics, damage) = bag_info(&damaged);
    assert!(damage.is_some(), "the cut bag must be damaged");
    let imu_before_damage = topics.iter().find(|t| t.topic == "/imu/data").map_or(0, |t| t.count);
    assert!(imu_before_damage > 1000, "{imu_before_damage} IMU messages before the damage");

    let script = r#"
timeout -k 2 40 "$IMU_FSDA_BIN" node --model '' --idle-exit-s 3 --stats-json >"$OUT/node.out" 2>"$OUT/node.err" </dev/null &
NODE=$!
timeout -k 2 40 "$IMU_FSDA_BIN" play "$BAG" --topic /imu/data -r /imu/data:=/imu/data_raw --rate 5 \
    --wait-for-subscribers-s 10 >"$OUT/play.out" 2>"$OUT/play.err" </dev/null
PLAY_RC=$?
timeout -k 2 20 "$IMU_FSDA_BIN" play "$BAG" --topic /no/such/topic >"$OUT/nosuch.out" 2>"$OUT/nosuch.err" </dev/null
NOSUCH_RC=$?
wait "$NODE"
echo "$PLAY_RC $NOSUCH_RC $?" >"$OUT/rc"
"#;
    let envs: [(&str, &OsStr); 2] = [("OUT", dir.path().as_os_str()), ("BAG", damaged.as_os_str())];
    let (st, wall_s) = run_in_namespace(script, &[], &envs, NAMESPACE_TIMEOUT);
    let read = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap_or_default();
    let logs = format!(
        "--- play stdout\n{}\n--- play stderr\n{}\n--- node stdout\n{}\n--- node stderr\n{}",
        read("play.out"),
        tail(&read("play.err"), 10),
        read("node.out"),
        tail(&read("node.err"), 20)
    );
    assert!(st.is_some_and(|s| s.success()), "namespace run failed or timed out ({st:?}, {wall_s:.1} s)\n{logs}");
    let rc: Vec<i32> = read("rc").split_whitespace().map(|s| s.parse().unwrap()).collect();
    assert_eq!(rc.len(), 3, "{logs}");

    // play: the readable part, then an error exit naming the damage.
    assert_eq!(rc[0], 1, "play exits with an error on a damaged bag\n{logs}");
    assert!(read("play.out").contains(&format!("played {imu_before_damage} messages")), "{logs}");
    let err = read("play.err");
    assert!(err.contains("damaged") && err.contains("not a readable MCAP bag"), "{logs}");
    assert!(!err.contains("panicked"), "{logs}");

    // The node received every IMU message that was before the damage (reliable writer, 1 kHz).
    assert_eq!(rc[2], 0, "node exit\n{logs}");
    let stats = last_json_line(&read("node.out")).unwrap_or_else(|| panic!("no stats line\n{logs}"));
    assert_eq!(stats["counters"]["received"].as_u64(), Some(imu_before_damage), "{logs}");
    assert_eq!(stats["counters"]["processed"].as_u64(), Some(imu_before_damage), "{logs}");

    // A topic the bag does not have: refused, naming the ones it has.
    assert_eq!(rc[1], 1, "--topic not in the bag\n{}", read("nosuch.err"));
    let err = read("nosuch.err");
    assert!(err.contains("/no/such/topic") && err.contains("/imu/data"), "{err}");
}
