//! The live node against a Fast DDS peer: tests/fastdds/imu_peer.cpp on Debian's libfastrtps
//! 2.9 (rmw_fastrtps's middleware, the default of ROS 2 Humble and Jazzy), with ROS 2's topic
//! and type names and a driver's sensor-data QoS, in a private network namespace (only `lo`).
//! See docs/interop.md.
//!
//! The peer is built here from its source with the system's g++ and Fast DDS headers
//! (scripts/setup.sh installs `libfastrtps-dev`); a machine without them skips loudly, a
//! failure under `CI`.

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::Duration;

use common::replay_reference::{euroc_csv, imu_fields, reference, slice_sequence, Reference};
use common::{manifest_dir, prerequisites, run_in_namespace, tail};
use serde_json::Value;

static SERIAL: Mutex<()> = Mutex::new(());

const NODE_NAME: &str = "imu_fsda";
const COUNT: usize = 2000;
/// Bound of one namespace run (node + peer); a passing run takes ~10 s.
const RUN_TIMEOUT: Duration = Duration::from_secs(60);

fn skip_or_fail(why: &str) {
    common::skip_or_fail("dds_fastdds", why);
}

/// The peer's executable, compiled when missing or older than its source.
fn fastdds_peer() -> Result<PathBuf, String> {
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
struct Run {
    summary: std::collections::BTreeMap<String, String>,
    /// (stamp ns, frame_id, the 37 doubles' bits)
    denoised: Vec<(i64, String, Vec<u64>)>,
    node_stats: Value,
    rc: Vec<i32>,
    logs: String,
}

impl Run {
    fn summary(&self, key: &str) -> u64 {
        self.summary.get(key).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("peer summary has no {key}\n{}", self.logs))
    }
    fn node(&self, key: &str) -> u64 {
        self.node_stats[key].as_u64().unwrap_or_else(|| panic!("node stats have no {key}: {}", self.node_stats))
    }
}

/// Who starts first.
#[derive(Clone, Copy)]
enum Order {
    /// The node, then the peer, which publishes a second after its writer and reader matched.
    NodeFirst,
    /// The peer (a driver already up), then the node a second later; the peer publishes the
    /// moment its writer matched.
    PeerFirst,
}

fn run(peer: &Path, dir: &Path, tag: &str, csv: &Path, order: Order) -> Run {
    let out = dir.join(tag);
    std::fs::create_dir_all(&out).unwrap();
    // `~/adapt` offered (it answers "no model is loaded" at once: the call's mapping is what is tested).
    std::fs::write(out.join("params.yaml"), format!("{NODE_NAME}:\n  ros__parameters:\n    adapt_enabled: true\n")).unwrap();
    let node = r#"timeout -k 2 40 "$IMU_FSDA_BIN" node --node-name "$NODE_NAME" --params "$OUT/params.yaml" --model '' --idle-exit-s 3 --stats-json >"$OUT/node.out" 2>"$OUT/node.err" </dev/null"#;
    let peer_cmd = r#"timeout -k 2 40 "$PEER" "$@" --out "$OUT/peer.txt" >"$OUT/peer.out" 2>"$OUT/peer.err" </dev/null"#;
    let script = match order {
        Order::NodeFirst => format!(
            "{node} &\nNODE=$!\n{peer_cmd}\nPEER_RC=$?\n[ \"$PEER_RC\" -ne 0 ] && kill -TERM \"$NODE\" 2>/dev/null\nwait \"$NODE\"\necho \"$PEER_RC $?\" >\"$OUT/rc\"\n"
        ),
        Order::PeerFirst => format!(
            "{peer_cmd} &\nPEER=$!\nsleep 1\n{node}\nNODE_RC=$?\nwait \"$PEER\"\necho \"$? $NODE_RC\" >\"$OUT/rc\"\n"
        ),
    };
    let count = COUNT.to_string();
    let (after, wait_for) = match order {
        Order::NodeFirst => ("1", "both"),
        Order::PeerFirst => ("0", "writer"),
    };
    let mut args =
        vec!["--csv", csv.to_str().unwrap(), "--count", &count, "--rate", "400", "--after-match-s", after, "--wait-for", wait_for];
    if matches!(order, Order::NodeFirst) {
        args.extend(["--adapt-node", NODE_NAME, "--adapt-at", "1000"]);
    }
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
    let text = read("peer.txt");
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
    let node_stats = common::last_json_line(&read("node.out")).unwrap_or(Value::Null);
    Run { summary, denoised, node_stats, rc, logs }
}

/// Prerequisites, the peer, a slice of MH_04 and its replay. `None`: skipped.
fn prepare() -> Option<(PathBuf, tempfile::TempDir, PathBuf, Reference)> {
    if let Err(why) = prerequisites() {
        skip_or_fail(&why);
        return None;
    }
    let peer = match fastdds_peer() {
        Ok(p) => p,
        Err(why) => {
            skip_or_fail(&why);
            return None;
        }
    };
    let csv = match euroc_csv("MH_04_difficult") {
        Ok(c) => c,
        Err(why) => {
            skip_or_fail(&why);
            return None;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let slice = slice_sequence(&csv, 0, COUNT, dir.path());
    let reference = reference(&dir.path().join("seq"), dir.path());
    assert_eq!(reference.inputs.len(), COUNT);
    Some((peer, dir, slice, reference))
}

/// A Fast DDS driver that starts publishing a second after it matched the node: all 2000
/// samples come back on /imu/denoised, every float equal to the offline replay's bits, and the
/// node's sequence-number counters show nothing lost; a `~/adapt` call made as rmw_fastrtps
/// makes it (request id in the related sample identity) is answered and matched to the call.
#[test]
fn a_fast_dds_peer_gets_every_sample_back_as_replay_computes_it() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((peer, dir, slice, reference)) = prepare() else { return };
    let r = run(&peer, dir.path(), "node_first", &slice, Order::NodeFirst);
    let logs = &r.logs;
    assert_eq!(r.rc, vec![0, 0], "peer / node exit codes\n{logs}");
    assert_eq!(r.summary("matched"), 1, "{logs}");
    assert_eq!(r.summary("sent"), COUNT as u64, "{logs}");
    assert_eq!(r.denoised.len(), COUNT, "/imu/denoised messages the Fast DDS reader got\n{logs}");
    for (i, ((stamp, frame, bits), want)) in r.denoised.iter().zip(&reference.denoised).enumerate() {
        assert_eq!(*stamp, want.header.stamp.to_ns(), "#{i}: stamp");
        assert_eq!(frame, "imu_link", "#{i}: frame_id");
        let want: Vec<u64> = imu_fields(want).iter().flat_map(|(_, v)| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>()).collect();
        assert_eq!(bits, &want, "#{i} (stamp {stamp}): over Fast DDS != replay");
    }
    assert_eq!(r.node_stats["counters"]["received"].as_u64(), Some(COUNT as u64), "{}", r.node_stats);
    assert_eq!((r.node("input_writers"), r.node("input_published_before_first"), r.node("input_lost")), (1, 0, 0), "{}", r.node_stats);
    // `~/adapt` called as rmw_fastrtps calls a service, answered and matched to the call.
    assert_eq!((r.summary("called"), r.summary("replied"), r.summary("reply_success")), (1, 1, 0), "{logs}");
    let message = &r.summary["reply_message"];
    assert!(message.starts_with("cannot adapt: no model is loaded"), "{message}");
    let caller = r.node_stats["adapt_requested_by"].as_str().unwrap_or_default();
    assert!(caller.starts_with("client "), "the node names its caller: {}", r.node_stats);
    eprintln!(
        "dds_fastdds: {COUNT}/{COUNT} through the node from Fast DDS, bit-equal to replay (peer matched after {} s)",
        r.summary["match_s"]
    );
}

/// A Fast DDS driver already publishing-ready when the node starts (a robot stack brings its
/// IMU driver up first) publishes the moment its writer matched: RustDDS can drop Fast DDS's
/// first discovery data (it arrives before Fast DDS's participant announcement is processed)
/// and match the writer only a second later (docs/interop.md), so the samples of that second
/// never reach the node. Whatever the race does, every sample is accounted for: what the node
/// received, plus what the writer's sequence numbers say it published before its first sample
/// arrived, plus the gaps after it, is what the peer sent; every sample received is answered,
/// but for answers the node published before its writer had matched the peer's reader (it
/// counts them: `denoised_published_before_a_reader`).
#[test]
fn samples_a_fast_dds_peer_published_before_the_match_are_counted() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((peer, dir, slice, _)) = prepare() else { return };
    let mut before = Vec::new();
    for k in 0..3 {
        let r = run(&peer, dir.path(), &format!("peer_first_{k}"), &slice, Order::PeerFirst);
        let logs = &r.logs;
        assert_eq!(r.rc, vec![0, 0], "run {k}: peer / node exit codes\n{logs}");
        assert_eq!(r.summary("sent"), COUNT as u64, "{logs}");
        let received = r.node_stats["counters"]["received"].as_u64().unwrap_or_else(|| panic!("{}", r.node_stats));
        let (b, lost) = (r.node("input_published_before_first"), r.node("input_lost"));
        assert_eq!(received + b + lost, COUNT as u64, "run {k}: received {received} + before the first {b} + lost {lost}\n{logs}");
        // Every sample received is answered; an answer published before the node's writer had
        // matched the peer's reader (counted by the node) is, by volatile durability, for
        // nobody. The count is taken from the node's graph, which hears of a match just after
        // the writer makes it: it can count an answer that did arrive, never miss one that did not.
        let (answered, unheard) = (r.denoised.len() as u64, r.node("denoised_published_before_a_reader"));
        assert!(
            answered <= received && answered + unheard >= received,
            "run {k}: {answered} answers for {received} samples received, {unheard} published before a reader\n{logs}"
        );
        before.push(b);
    }
    eprintln!("dds_fastdds: the driver up first, samples it published before the first reached the node: {before:?} of {COUNT}");
}
