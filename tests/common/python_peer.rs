//! The node beside a Python peer (tests/python/*.py on PyPI cyclonedds) in a private network
//! namespace: tests/dds_adapt.rs, tests/dds_parameters.rs.

use std::ffi::OsStr;
use std::path::Path;
use std::time::Duration;

use serde_json::Value;

use super::{last_json_line, manifest_dir, run_in_namespace, tail, Prereqs};

pub const NODE_NAME: &str = "imu_fsda";

pub struct Output {
    pub peer: Value,
    pub node_stats: Value,
    pub rc: Vec<i32>,
    pub wall_s: f64,
    pub logs: String,
}

/// Node (background, stopped by SIGTERM when the peer is done) + a peer script, in a namespace.
pub fn run(pre: &Prereqs, dir: &Path, tag: &str, node_args: &[&str], peer: &str, peer_args: &[&str], timeout: Duration) -> Output {
    let out = dir.join(tag);
    std::fs::create_dir_all(&out).unwrap();
    let script = r#"
NODE_ARGS=(); while [ "$1" != "--" ]; do NODE_ARGS+=("$1"); shift; done; shift
timeout -k 2 90 "$IMU_FSDA_BIN" node --node-name "$NODE_NAME" --stats-json "${NODE_ARGS[@]}" \
    >"$OUT/node.out" 2>"$OUT/node.err" </dev/null &
NODE=$!
NODE_PID=$NODE timeout -k 2 90 "$PEER_PY" "$PEER" "$@" --out "$OUT/peer.json" >"$OUT/peer.out" 2>"$OUT/peer.err" </dev/null
PEER_RC=$?
kill -TERM "$NODE" 2>/dev/null
wait "$NODE"
NODE_RC=$?
echo "$PEER_RC $NODE_RC" >"$OUT/rc"
"#;
    let peer_py = manifest_dir().join("tests/python").join(peer);
    let mut args: Vec<&str> = node_args.to_vec();
    args.push("--");
    args.extend_from_slice(peer_args);
    let envs: [(&str, &OsStr); 4] =
        [("NODE_NAME", NODE_NAME.as_ref()), ("PEER_PY", pre.python.as_os_str()), ("PEER", peer_py.as_os_str()), ("OUT", out.as_os_str())];
    let (st, wall_s) = run_in_namespace(script, &args, &envs, timeout);
    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap_or_default();
    let logs = format!(
        "--- node stdout\n{}\n--- node stderr (tail)\n{}\n--- peer stderr\n{}",
        read("node.out"),
        tail(&read("node.err"), 40),
        tail(&read("peer.err"), 40)
    );
    let Some(st) = st else { panic!("{tag}: node + peer did not finish within {timeout:?}\n{logs}") };
    assert!(st.success(), "{tag}: namespace script failed ({st}); exit 90 = could not set up lo\n{logs}");
    let rc: Vec<i32> = read("rc").split_whitespace().map(|s| s.parse().unwrap()).collect();
    assert_eq!(rc.len(), 2, "{tag}: no exit codes from the namespace\n{logs}");
    let peer: Value = serde_json::from_str(&read("peer.json")).unwrap_or_else(|e| panic!("{tag}: peer.json: {e}\n{logs}"));
    let node_stats = last_json_line(&read("node.out")).unwrap_or_else(|| panic!("{tag}: no --stats-json line from the node\n{logs}"));
    Output { peer, node_stats, rc, wall_s, logs }
}

/// The node's status values in a /diagnostics message as adapt_peer.py records it.
pub fn diag_values(d: &Value) -> Option<&serde_json::Map<String, Value>> {
    let name = format!("{NODE_NAME}: gyro denoiser");
    d["status"].as_array()?.iter().find(|s| s["name"] == name.as_str())?["values"].as_object()
}

pub fn value<'a>(v: &'a serde_json::Map<String, Value>, k: &str) -> &'a str {
    v.get(k).and_then(Value::as_str).unwrap_or("")
}
