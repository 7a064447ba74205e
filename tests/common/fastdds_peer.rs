//! The Fast DDS peer (tests/fastdds/imu_peer.cpp on Debian's libfastrtps 2.9) and one run of
//! it beside the node in a private network namespace: tests/dds_fastdds.rs, tests/dds_security.rs.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use serde_json::Value;

use super::replay_reference::{euroc_csv, reference, slice_sequence, Reference};
use super::{manifest_dir, prerequisites, run_in_namespace, skip_or_fail, tail};

pub const NODE_NAME: &str = "imu_fsda";
/// Bound of one namespace run (node + peer); a passing run takes ~10 s.
const RUN_TIMEOUT: Duration = Duration::from_secs(60);

/// The peer's executable, compiled when missing or older than its source.
pub fn fastdds_peer() -> Result<PathBuf, String> {
    let src = manifest_dir().join("tests/fastdds/imu_peer.cpp");
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fastdds_imu_peer");
    let modified = |p: &Path| std::fs::metadata(p).and_then(|m| m.modified()).ok();
    if modified(&exe).is_some_and(|e| modified(&src).is_some_and(|s| e >= s)) {
        return Ok(exe);
    }
    if !Path::new("/usr/include/fastdds/dds/domain/DomainParticipant.hpp").is_file() {
        return Err("no Fast DDS headers (/usr/include/fastdds; scripts/setup.sh installs libfastrtps-dev)".into());
    }
    let out = Command::new("g++")
        .args(["-O2", "-std=c++17"])
        .arg(&src)
        .arg("-o")
        .arg(&exe)
        .args(["-lfastrtps", "-lfastcdr"])
        .output()
        .map_err(|e| format!("cannot run g++: {e}"))?;
    if !out.status.success() {
        // Headers present but the peer does not build: a real failure, not a skip.
        panic!("building {}:\n{}", src.display(), String::from_utf8_lossy(&out.stderr));
    }
    Ok(exe)
}

/// What one run produced: the peer's summary and the /imu/denoised it read, the node's stats.
pub struct Run {
    pub summary: std::collections::BTreeMap<String, String>,
    /// (stamp ns, frame_id, the 37 doubles' bits)
    pub denoised: Vec<(i64, String, Vec<u64>)>,
    pub node_stats: Value,
    pub rc: Vec<i32>,
    pub logs: String,
}

impl Run {
    pub fn summary(&self, key: &str) -> u64 {
        self.summary.get(key).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("peer summary has no {key}\n{}", self.logs))
    }
    pub fn node(&self, key: &str) -> u64 {
        self.node_stats[key].as_u64().unwrap_or_else(|| panic!("node stats have no {key}: {}", self.node_stats))
    }
}

/// Who starts first.
#[derive(Clone, Copy)]
pub enum Order {
    /// The node, then the peer, which publishes a second after its writer and reader matched.
    NodeFirst,
    /// The peer (a driver already up), then the node a second later; the peer publishes the
    /// moment its writer matched.
    PeerFirst,
}

/// What a run adds to the plain one: the node's environment and arguments, the peer's.
#[derive(Default)]
pub struct Setup {
    /// On top of the namespace's environment, for the node alone (e.g. `ROS_SECURITY_*`).
    pub node_env: Vec<(&'static str, String)>,
    /// More arguments of the node (e.g. `--enclave /imu_fsda`).
    pub node_args: Vec<String>,
    /// More arguments of the peer (e.g. `--security DIR`, `--match-timeout-s 8`).
    pub peer_args: Vec<String>,
}

/// A word for bash: single-quoted.
fn quoted(s: &str) -> String {
    format!("'{}'", s.replace('\'', r"'\''"))
}

/// The node (`~/adapt` offered, no model) and the peer publishing `count` rows of `csv` at
/// 400 Hz, in the order asked; the peer calls `~/adapt` after sample 1000 when the node came
/// first. Files of the run in `dir/tag`.
pub fn run(peer: &Path, dir: &Path, tag: &str, csv: &Path, count: usize, order: Order, setup: &Setup) -> Run {
    let out = dir.join(tag);
    std::fs::create_dir_all(&out).unwrap();
    // `~/adapt` offered (it answers "no model is loaded" at once: the call's mapping is what is tested).
    std::fs::write(out.join("params.yaml"), format!("{NODE_NAME}:\n  ros__parameters:\n    adapt_enabled: true\n")).unwrap();
    let node_env: String = setup.node_env.iter().map(|(k, v)| format!("{k}={} ", quoted(v))).collect();
    let node_args: String = setup.node_args.iter().map(|a| format!(" {}", quoted(a))).collect();
    let node = format!(
        r#"env {node_env}timeout -k 2 40 "$IMU_FSDA_BIN" node --node-name "$NODE_NAME" --params "$OUT/params.yaml" --model '' --idle-exit-s 3 --stats-json{node_args} >"$OUT/node.out" 2>"$OUT/node.err" </dev/null"#
    );
    let peer_cmd = r#"timeout -k 2 40 "$PEER" "$@" --out "$OUT/peer.txt" >"$OUT/peer.out" 2>"$OUT/peer.err" </dev/null"#;
    let script = match order {
        Order::NodeFirst => format!(
            "{node} &\nNODE=$!\n{peer_cmd}\nPEER_RC=$?\n[ \"$PEER_RC\" -ne 0 ] && kill -TERM \"$NODE\" 2>/dev/null\nwait \"$NODE\"\necho \"$PEER_RC $?\" >\"$OUT/rc\"\n"
        ),
        Order::PeerFirst => format!(
            "{peer_cmd} &\nPEER=$!\nsleep 1\n{node}\nNODE_RC=$?\nwait \"$PEER\"\necho \"$? $NODE_RC\" >\"$OUT/rc\"\n"
        ),
    };
    let count = count.to_string();
    let (after, wait_for) = match order {
        Order::NodeFirst => ("1", "both"),
        Order::PeerFirst => ("0", "writer"),
    };
    let mut args =
        vec!["--csv", csv.to_str().unwrap(), "--count", &count, "--rate", "400", "--after-match-s", after, "--wait-for", wait_for];
    if matches!(order, Order::NodeFirst) {
        args.extend(["--adapt-node", NODE_NAME, "--adapt-at", "1000"]);
    }
    args.extend(setup.peer_args.iter().map(String::as_str));
    let envs: [(&str, &OsStr); 3] = [("NODE_NAME", NODE_NAME.as_ref()), ("PEER", peer.as_os_str()), ("OUT", out.as_os_str())];
    let (st, _) = run_in_namespace(&script, &args, &envs, RUN_TIMEOUT);
    let read = |f: &str| std::fs::read_to_string(out.join(f)).unwrap_or_default();
    let logs = format!(
        "--- node stdout\n{}\n--- node stderr (tail)\n{}\n--- peer stderr\n{}",
        read("node.out"),
        tail(&read("node.err"), 30),
        tail(&read("peer.err"), 30)
    );
    let Some(st) = st else { panic!("{tag}: node + peer did not finish within {RUN_TIMEOUT:?}\n{logs}") };
    assert!(st.success(), "{tag}: namespace script failed ({st}); exit 90 = could not set up lo\n{logs}");
    let rc = read("rc").split_whitespace().map(|s| s.parse().unwrap()).collect();
    let (summary, denoised) = peer_file(&read("peer.txt"));
    let node_stats = super::last_json_line(&read("node.out")).unwrap_or(Value::Null);
    Run { summary, denoised, node_stats, rc, logs }
}

/// The peer's file: its summary (key=value, and the reply's message), then one /imu/denoised a line.
#[allow(clippy::type_complexity)]
fn peer_file(text: &str) -> (std::collections::BTreeMap<String, String>, Vec<(i64, String, Vec<u64>)>) {
    let mut lines = text.lines();
    let mut summary: std::collections::BTreeMap<String, String> = lines
        .next()
        .unwrap_or_default()
        .split_whitespace()
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| (k.into(), v.into()))
        .collect();
    let mut lines = lines.peekable();
    if let Some(message) = lines.peek().and_then(|l| l.strip_prefix("reply_message ")) {
        summary.insert("reply_message".into(), message.into());
        lines.next();
    }
    let denoised = lines
        .map(|l| {
            let mut w = l.split_whitespace();
            let stamp = w.next().unwrap().parse().unwrap();
            let frame = w.next().unwrap().to_string();
            (stamp, frame, w.map(|b| u64::from_str_radix(b, 16).unwrap()).collect())
        })
        .collect();
    (summary, denoised)
}

/// What a Fast DDS test runs on: the peer, `count` rows of MH_04 and their offline replay.
pub struct Prepared {
    pub peer: PathBuf,
    pub dir: tempfile::TempDir,
    pub slice: PathBuf,
    pub reference: Reference,
}

/// Prerequisites, the peer, a slice of MH_04 and its replay. `None`: skipped (loudly; a
/// failure under `CI`), `test` naming who skipped.
pub fn prepare(test: &str, count: usize) -> Option<Prepared> {
    let ready = prerequisites().and_then(|_| fastdds_peer()).and_then(|peer| euroc_csv("MH_04_difficult").map(|csv| (peer, csv)));
    let (peer, csv) = match ready {
        Ok(found) => found,
        Err(why) => {
            skip_or_fail(test, &why);
            return None;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let slice = slice_sequence(&csv, 0, count, dir.path());
    let reference = reference(&dir.path().join("seq"), dir.path());
    assert_eq!(reference.inputs.len(), count);
    Some(Prepared { peer, dir, slice, reference })
}
