//! Peers on the node's topics that cannot work with it (src/node/peer_check.rs): a writer of
//! another message type on the input (laid out as sensor_msgs/Imu, so its samples would
//! decode) and a reader whose QoS the output cannot serve, made by an independent Cyclone DDS
//! peer (tests/python/mismatch_peer.py) in a private network namespace. The node must name
//! both on /diagnostics, log each once and keep running. Cyclone DDS does not match its writer
//! with a reader of another type name, so none of its samples reaches the node: /diagnostics is
//! where the user learns why nothing arrives. (A writer that matches by topic name alone, as
//! RustDDS does, has its samples dropped by their writer's type: `peer_check`'s unit tests.)

mod common;

use std::ffi::OsStr;
use std::time::Duration;

use common::{manifest_dir, prerequisites, run_in_namespace, tail};
use serde_json::Value;

#[test]
fn peers_that_cannot_match_are_named_on_diagnostics() {
    let pre = match prerequisites() {
        Ok(p) => p,
        Err(why) => return common::skip_or_fail("dds_peers", &why),
    };
    let dir = tempfile::tempdir().unwrap();
    let peer_py = manifest_dir().join("tests/python/mismatch_peer.py");
    let script = r#"
timeout -k 2 40 "$IMU_FSDA_BIN" node --node-name imu_fsda --model "$MODEL" --idle-exit-s 30 --stats-json \
    >"$OUT/node.out" 2>"$OUT/node.err" </dev/null &
NODE=$!
timeout -k 2 30 "$PEER_PY" "$PEER" --out "$OUT/peer.json" >"$OUT/peer.out" 2>"$OUT/peer.err" </dev/null
echo $? >"$OUT/peer.rc"
kill -INT "$NODE" 2>/dev/null
wait "$NODE"
echo $? >"$OUT/node.rc"
"#;
    // The bundled model: its status is "ok", so the level and message are the peers' own.
    let model = manifest_dir().join("models/fsda-f.pt");
    let envs: [(&str, &OsStr); 4] =
        [("PEER_PY", pre.python.as_os_str()), ("PEER", peer_py.as_os_str()), ("OUT", dir.path().as_os_str()), ("MODEL", model.as_os_str())];
    let (st, _) = run_in_namespace(script, &[], &envs, Duration::from_secs(60));
    let read = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap_or_default();
    let logs = format!("--- node stderr\n{}\n--- peer stderr\n{}", tail(&read("node.err"), 30), tail(&read("peer.err"), 30));
    assert!(st.is_some_and(|s| s.success()), "the namespace run failed or timed out\n{logs}");
    assert_eq!(read("peer.rc").trim(), "0", "peer failed\n{logs}");
    assert_eq!(read("node.rc").trim(), "0", "the node did not end cleanly on SIGINT\n{logs}");
    let peer: Value = serde_json::from_str(&read("peer.json")).unwrap_or_else(|e| panic!("peer.json: {e}\n{logs}"));
    let status = &peer["status"];
    assert_eq!(status["incompatible_peers"], "2", "both peers named on /diagnostics: {status}\n{logs}");
    let list = status["incompatible_peer_list"].as_str().unwrap_or_default();
    assert!(
        list.contains("a writer on /imu/data_raw of type my_msgs::msg::dds_::Imu_, not the node's sensor_msgs::msg::dds_::Imu_"),
        "{list}"
    );
    assert!(list.contains("a reader on /imu/denoised whose durability QoS cannot match what the node offers"), "{list}");
    assert_eq!(status["_level"], 1, "WARN while they are there: {status}");
    let message = status["_message"].as_str().unwrap_or_default();
    assert!(message.starts_with("2 peer(s) on its topics cannot work with it: a "), "{message}");
    assert_eq!(peer["denoised_received"], 0, "a transient-local reader of a volatile writer gets nothing");
    // Each said once in the log, however many ticks saw them.
    let node_err = read("node.err");
    for what in ["writer on /imu/data_raw", "reader on /imu/denoised"] {
        assert_eq!(node_err.matches(what).count(), 1, "{what} logged once\n{logs}");
    }
    let stats = common::last_json_line(&read("node.out")).unwrap_or_else(|| panic!("no --stats-json line\n{logs}"));
    assert_eq!(stats["incompatible_peers"]["said"], 2, "{stats}");
    // Nothing of the wrong type reached the pipeline, decoded or not.
    assert!(peer["wrong_type_written"].as_u64().unwrap_or(0) >= 20, "{peer}");
    for key in ["decode_errors", "dropped_wrong_type"] {
        assert_eq!(stats[key], 0, "{key}: {stats}");
    }
    assert_eq!((stats["counters"]["received"].as_u64(), stats["counters"]["processed"].as_u64()), (Some(0), Some(0)), "{stats}");
}
