//! CI interop test of the live ROS 2 node (`imu-fsda node`, ros2-client/rustdds) against an
//! independent DDS peer (tests/python/dds_peer.py on PyPI cyclonedds, no ROS 2 library), on
//! real EuRoC data. See docs/interop.md.
//!
//! Each test:
//! 1. cuts a slice of an EuRoC `imu0/data.csv` into a temporary sequence folder, imports it
//!    (`imu-fsda import`) and replays it offline (`imu-fsda replay --model ''`): the reference
//!    `/imu/denoised` and `/imu/gyro_correction` messages;
//! 2. inside a fresh network + PID namespace (`unshare --net --pid --fork --kill-child`; only
//!    `lo`, multicast on) starts the node (`--model '' --idle-exit-s 3 --stats-json`) and the
//!    peer, which publishes the same CSV rows on `rt/imu/data_raw` and records what comes back
//!    on `rt/imu/denoised`, `rt/imu/gyro_correction` and `rt/diagnostics`;
//! 3. compares, bit for bit, what came over DDS with the replay, the sent inputs and the
//!    node's counters.
//!
//! Nothing touches the host's network: a machine where the namespace cannot be created skips
//! loudly (`SKIPPED: ...`), except under `CI`, where that is a failure.

mod common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::replay_reference::{euroc_csv, imu_fields, reference, slice_sequence, Reference};
use common::{fs, manifest_dir, prerequisites, run_in_namespace as ns_run, same_bits, stamp_ns, tail, Prereqs};

use serde_json::Value;

/// The two tests share two cores: one at a time keeps the timing (and so the drop-free
/// pacing) of each as measured.
static SERIAL: Mutex<()> = Mutex::new(());

const NODE_NAME: &str = "imu_fsda";
const FRAME_ID: &str = "imu_link";
/// Bound of one namespace run (node + peer); a passing run takes ~7 s.
const NAMESPACE_TIMEOUT: Duration = Duration::from_secs(40);

fn skip_or_fail(why: &str) {
    common::skip_or_fail("dds_interop", why);
}

/// One run of node + peer in a fresh namespace; everything it produced.
struct Run {
    peer: Value,
    node_stats: Value,
    node_rc: i32,
    peer_rc: i32,
    wall_s: f64,
    logs: String,
}

fn run_in_namespace(pre: &Prereqs, dir: &Path, csv: &Path, peer_args: &[&str]) -> Run {
    let peer_py = manifest_dir().join("tests/python/dds_peer.py");
    // Inside the namespace: the node in the background, the peer in the foreground; each
    // under its own `timeout`, and the node stopped if the peer fails.
    let script = r#"
timeout -k 2 30 "$IMU_FSDA_BIN" node --node-name "$NODE_NAME" --model '' --idle-exit-s 3 --stats-json \
    >"$OUT/node.out" 2>"$OUT/node.err" </dev/null &
NODE=$!
timeout -k 2 30 "$PEER_PY" "$PEER" "$@" --out "$OUT/peer.json" >"$OUT/peer.out" 2>"$OUT/peer.err" </dev/null
PEER_RC=$?
[ "$PEER_RC" -ne 0 ] && kill -TERM "$NODE" 2>/dev/null
wait "$NODE"
NODE_RC=$?
echo "$PEER_RC $NODE_RC" >"$OUT/rc"
"#;
    let mut args = vec!["--csv", csv.to_str().unwrap()];
    args.extend_from_slice(peer_args);
    let envs: [(&str, &OsStr); 4] =
        [("NODE_NAME", NODE_NAME.as_ref()), ("PEER_PY", pre.python.as_os_str()), ("PEER", peer_py.as_os_str()), ("OUT", dir.as_os_str())];
    let (st, wall_s) = ns_run(script, &args, &envs, NAMESPACE_TIMEOUT);
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    let logs = format!(
        "--- node stdout\n{}\n--- node stderr (tail)\n{}\n--- peer stderr\n{}",
        read("node.out"),
        tail(&read("node.err"), 30),
        tail(&read("peer.err"), 30)
    );
    let Some(st) = st else { panic!("node + peer did not finish within {NAMESPACE_TIMEOUT:?}\n{logs}") };
    assert!(st.success(), "namespace script failed ({st}); exit 90 = could not set up lo\n{logs}");
    let rc = read("rc");
    let rc: Vec<i32> = rc.split_whitespace().map(|s| s.parse().unwrap()).collect();
    assert_eq!(rc.len(), 2, "no exit codes from the namespace\n{logs}");
    let peer: Value = serde_json::from_str(&read("peer.json")).unwrap_or_else(|e| panic!("peer.json: {e}\n{logs}"));
    let node_stats: Value =
        common::last_json_line(&read("node.out")).unwrap_or_else(|| panic!("no --stats-json line from the node\n{logs}"));
    Run { peer, node_stats, peer_rc: rc[0], node_rc: rc[1], wall_s, logs }
}

/// The counters of the node's status in a /diagnostics message, if it is there.
fn diag_values(d: &Value) -> Option<&serde_json::Map<String, Value>> {
    let name = format!("{NODE_NAME}: gyro denoiser");
    d["status"].as_array()?.iter().find(|s| s["name"] == name.as_str())?["values"].as_object()
}

struct Expect {
    received: u64,
    published: u64,
    non_finite: u64,
    implausible: u64,
    duplicate: u64,
    backwards: u64,
}

/// Everything both tests assert about one run.
fn check_run(run: &Run, reference: &Reference, expect: &Expect) {
    let p = &run.peer;
    let logs = &run.logs;
    assert_eq!(p["matched"], true, "the peer never matched the node: {}\n{logs}", p["match_status"]);
    assert_eq!(run.peer_rc, 0, "peer failed\n{logs}");
    assert_eq!(run.node_rc, 0, "node exited with {} (124 = killed by its timeout)\n{logs}", run.node_rc);
    assert_eq!(p["stalled"], false, "an input or its output was lost (flow control stalled)\n{logs}");

    // What was sent: the valid rows are exactly the bag's /imu/data (CSV parsed twice,
    // independently, to the same bits).
    let sent = p["sent"].as_array().unwrap();
    assert_eq!(sent.len() as u64, expect.received, "inputs sent\n{logs}");
    let valid: Vec<&Value> = sent.iter().filter(|s| s["kind"] == "valid").collect();
    assert_eq!(valid.len(), reference.inputs.len(), "valid inputs sent vs rows imported");
    for (i, (s, r)) in valid.iter().zip(&reference.inputs).enumerate() {
        assert_eq!(s["stamp_ns"].as_i64().unwrap(), r.header.stamp.to_ns(), "input {i}: stamp");
        let rg = [r.angular_velocity.x, r.angular_velocity.y, r.angular_velocity.z];
        let ra = [r.linear_acceleration.x, r.linear_acceleration.y, r.linear_acceleration.z];
        assert!(same_bits(&fs(&s["gyro"]), &rg) && same_bits(&fs(&s["accel"]), &ra), "input {i}: peer's CSV values differ from the import");
    }

    // /imu/denoised: one per valid input, in order, header unchanged, every float equal to
    // the offline replay of the same input.
    let den = p["denoised"].as_array().unwrap();
    assert_eq!(
        den.len(),
        valid.len(),
        "/imu/denoised: {} messages for {} valid inputs ({} sent; the node counted {} received)\n{logs}",
        den.len(),
        valid.len(),
        sent.len(),
        run.node_stats["counters"]["received"]
    );
    assert_eq!(reference.denoised.len(), valid.len(), "replay output count");
    let mut last = i64::MIN;
    let (mut last_bias, mut bias_changes) = (vec![0.0; 3], 0usize);
    for (i, ((m, s), r)) in den.iter().zip(&valid).zip(&reference.denoised).enumerate() {
        let t = stamp_ns(&m["header"]);
        assert!(t > last, "/imu/denoised #{i}: stamp {t} not after {last}");
        last = t;
        assert_eq!(t, s["stamp_ns"].as_i64().unwrap(), "/imu/denoised #{i}: stamp differs from the sent one");
        assert_eq!(t, r.header.stamp.to_ns(), "/imu/denoised #{i}: stamp differs from replay");
        assert_eq!(m["header"]["frame_id"], FRAME_ID, "/imu/denoised #{i}: frame_id");
        for (name, want) in imu_fields(r) {
            let got = fs(&m[name]);
            assert!(same_bits(&got, &want), "/imu/denoised #{i} (stamp {t}): {name} over DDS {got:?} != replay {want:?}");
        }
        // No model: ω̂ = ω − b, this power-on's bias from the standstills (piecewise
        // constant), and the accel untouched — checked against what was sent, independently
        // of the replay.
        let (got, sent) = (fs(&m["angular_velocity"]), fs(&s["gyro"]));
        let b: Vec<f64> = sent.iter().zip(&got).map(|(a, g)| a - g).collect();
        assert!(b.iter().all(|v| v.abs() < 0.15), "/imu/denoised #{i}: ω − ω̂ = {b:?} is no bias");
        if i > 0 && b.iter().zip(&last_bias).any(|(x, y)| (x - y).abs() > 1e-12) {
            bias_changes += 1;
        }
        last_bias = b;
        assert!(same_bits(&fs(&m["linear_acceleration"]), &fs(&s["accel"])), "/imu/denoised #{i}: accel not passed through");
    }
    // The bias changes only where a standstill window ends: at most one per 0.5 s of input.
    assert!(bias_changes <= valid.len() / 100 + 1, "ω − ω̂ changed {bias_changes} times over {} samples", valid.len());
    // The replay integrates an orientation once gravity is known; so does the node.
    let with_orientation = reference.denoised.iter().filter(|m| m.has_orientation()).count();
    assert!(with_orientation > valid.len() / 2, "only {with_orientation} replayed messages carry an orientation");

    // /imu/gyro_correction: one per valid input, header and vector as replayed.
    let corr = p["corrections"].as_array().unwrap();
    assert_eq!(corr.len(), valid.len(), "/imu/gyro_correction count\n{logs}");
    for (i, (c, r)) in corr.iter().zip(&reference.corrections).enumerate() {
        assert_eq!(stamp_ns(&c["header"]), r.header.stamp.to_ns(), "/imu/gyro_correction #{i}: stamp");
        assert_eq!(c["header"]["frame_id"], FRAME_ID);
        assert!(same_bits(&fs(&c["vector"]), &[r.vector.x, r.vector.y, r.vector.z]), "/imu/gyro_correction #{i}: vector");
    }

    // The node's own counters: --stats-json at exit, and the last /diagnostics message.
    let c = &run.node_stats["counters"];
    let want = [
        ("received", expect.received),
        ("processed", expect.published),
        ("dropped_non_finite", expect.non_finite),
        ("dropped_implausible", expect.implausible),
        ("dropped_duplicate_stamp", expect.duplicate),
        ("dropped_backwards_stamp", expect.backwards),
        ("gaps", 0),
    ];
    for (k, v) in want {
        assert_eq!(c[k].as_u64(), Some(v), "--stats-json counters.{k}: {c}\n{logs}");
    }
    let diags = p["diagnostics"].as_array().unwrap();
    let final_diag = diags
        .iter()
        .filter_map(diag_values)
        .find(|v| v.get("received").and_then(Value::as_str) == Some(&expect.received.to_string()))
        .unwrap_or_else(|| {
            panic!("no /diagnostics status '{NODE_NAME}: gyro denoiser' with received = {}: {diags:?}\n{logs}", expect.received)
        });
    let want = [
        ("received", expect.received),
        ("published", expect.published),
        ("dropped_non_finite", expect.non_finite),
        ("dropped_implausible", expect.implausible),
        ("dropped_duplicate_stamp", expect.duplicate),
        ("dropped_backwards_stamp", expect.backwards),
        ("decode_errors", 0),
        ("gaps_reset", 0),
        ("frame_id_changes", 0),
    ];
    for (k, v) in want {
        assert_eq!(final_diag.get(k).and_then(Value::as_str), Some(v.to_string().as_str()), "/diagnostics {k}: {final_diag:?}");
    }
    // The last status (the first ones come before any input, when no frame is known yet).
    let status = diags.iter().rev().find_map(|d| d["status"].as_array()?.first().cloned()).unwrap();
    assert_eq!(status["hardware_id"], FRAME_ID, "/diagnostics hardware_id");

    eprintln!(
        "dds_interop: discovery {:.3} s (first match {:.3} s), sent {} ({} valid) in {:.2} s at {} Hz, \
         flow-control waits {} ({:.3} s), received {} denoised, {} corrections, {} diagnostics; node: {}; wall {:.1} s",
        p["all_matched_s"].as_f64().unwrap_or(f64::NAN),
        p["first_match_s"].as_f64().unwrap_or(f64::NAN),
        sent.len(),
        valid.len(),
        p["publish_s"].as_f64().unwrap_or(f64::NAN),
        p["rate_hz"],
        p["flow_control_waits"],
        p["flow_control_wait_s"].as_f64().unwrap_or(f64::NAN),
        den.len(),
        corr.len(),
        diags.len(),
        run.node_stats,
        run.wall_s
    );
}

/// Prepare a case: prerequisites, the slice and its reference. `None` = skipped.
fn prepare(preferred: &str, start: usize, count: usize) -> Option<(Prereqs, tempfile::TempDir, PathBuf, Reference)> {
    let pre = match prerequisites() {
        Ok(p) => p,
        Err(why) => {
            skip_or_fail(&why);
            return None;
        }
    };
    let csv = match euroc_csv(preferred) {
        Ok(c) => c,
        Err(why) => {
            skip_or_fail(&why);
            return None;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let slice = slice_sequence(&csv, start, count, dir.path());
    let reference = reference(&dir.path().join("seq"), dir.path());
    assert_eq!(reference.inputs.len(), count, "import kept {} of {count} rows", reference.inputs.len());
    Some((pre, dir, slice, reference))
}

/// 3000 consecutive MH_04_difficult samples (15 s of flight data) over DDS: every one comes
/// back once, in order, equal to the offline replay.
#[test]
fn node_over_dds_matches_replay() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t0 = Instant::now();
    const COUNT: usize = 3000;
    let Some((pre, dir, slice, reference)) = prepare("MH_04_difficult", 0, COUNT) else { return };
    let run = run_in_namespace(&pre, dir.path(), &slice, &["--count", &COUNT.to_string(), "--rate", "1000"]);
    check_run(
        &run,
        &reference,
        &Expect { received: COUNT as u64, published: COUNT as u64, non_finite: 0, implausible: 0, duplicate: 0, backwards: 0 },
    );
    eprintln!("dds_interop: node_over_dds_matches_replay took {:.1} s", t0.elapsed().as_secs_f64());
}

/// 1000 V1_01_easy samples with two NaN and one +inf sample, a duplicate and a backwards
/// stamp mixed in: exactly the valid ones come back (still equal to the replay of the valid
/// rows alone: the drops leave no trace in the state), each drop counted by reason.
#[test]
fn node_over_dds_drops_bad_input_by_reason() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t0 = Instant::now();
    const COUNT: usize = 1000;
    let Some((pre, dir, slice, reference)) = prepare("V1_01_easy", 0, COUNT) else { return };
    let run = run_in_namespace(&pre, dir.path(), &slice, &["--count", &COUNT.to_string(), "--rate", "1000", "--inject-bad"]);
    let kinds: Vec<&str> = run.peer["sent"].as_array().unwrap().iter().map(|s| s["kind"].as_str().unwrap()).collect();
    let n = |k: &str| kinds.iter().filter(|x| **x == k).count() as u64;
    assert_eq!(
        (n("non_finite"), n("implausible"), n("duplicate_stamp"), n("backwards_stamp")),
        (3, 1, 1, 1),
        "the peer's bad samples: {kinds:?}"
    );
    check_run(
        &run,
        &reference,
        &Expect { received: COUNT as u64 + 6, published: COUNT as u64, non_finite: 3, implausible: 1, duplicate: 1, backwards: 1 },
    );
    // No published message carries a bad sample's values.
    for m in run.peer["denoised"].as_array().unwrap() {
        for k in ["angular_velocity", "linear_acceleration"] {
            assert!(fs(&m[k]).iter().all(|v| v.is_finite()), "non-finite {k} published: {m}");
        }
    }
    eprintln!("dds_interop: node_over_dds_drops_bad_input_by_reason took {:.1} s", t0.elapsed().as_secs_f64());
}
