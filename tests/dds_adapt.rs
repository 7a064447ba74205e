//! The node's on-demand adaptation service `~/adapt` end to end over DDS, on real data,
//! against an independent peer (tests/python/adapt_peer.py on PyPI cyclonedds, no ROS 2
//! library). See docs/adaptation.md ("In the node", "Latency while adapting").
//!
//! In a fresh network + PID namespace (only `lo`; tests/common), the node runs the bundled
//! model `models/fsda-f.pt` with a ground-truth topic and an adapted-model dir in a temp dir;
//! the peer streams EuRoC V2_02_medium (IMU, and ground truth as geometry_msgs/PoseStamped
//! from 5 s on) and calls `~/adapt` four times:
//! 1. after 3 s of data, before any ground truth → failure "no ground truth received yet";
//! 2. after 25 s (20 s of ground truth, less than the 60 s support set) → failure, nothing to
//!    judge the adaptation on;
//! 3. and 4. back to back after 90 s (60 s support + ~25 s query): one adapts (accepted, or
//!    rejected with before/after AOE — on this data and configuration it is accepted,
//!    which the saved-model and restart checks need), the other is answered "busy" at once. Deterministic:
//!    the service marks itself running before it reads the next request, and the job takes
//!    seconds (loading, two query evaluations, 60 inner steps), the second request arrives
//!    milliseconds after the first.
//!
//! While a request is outstanding the peer streams at the recorded 200 Hz (faster, 2 kHz,
//! otherwise), closed loop so nothing can be lost. Checked: every reply; one /imu/denoised
//! per input, in order, same stamps, none lost or repeated across the swap; the node kept
//! publishing while each request was outstanding; /diagnostics shows `running` and then the
//! result; the saved model files; and, in a second namespace, a node started on the saved
//! model loads it and runs.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::python_peer::{diag_values, run, value, NODE_NAME};
use common::{manifest_dir, prerequisites, Prereqs};
use serde_json::Value;

/// One DDS namespace run at a time (two cores).
static SERIAL: Mutex<()> = Mutex::new(());

/// Bound of the adaptation run (node + peer); a passing run takes ~16 s.
const ADAPT_RUN_TIMEOUT: Duration = Duration::from_secs(100);
/// Bound of the restart run.
const RESTART_RUN_TIMEOUT: Duration = Duration::from_secs(40);

fn skip_or_fail(why: &str) {
    common::skip_or_fail("dds_adapt", why);
}

/// The node's parameters: ground truth on /ground_truth/pose, 60 s support, 60 inner Adam
/// steps at lr 1e-3 (defaults: 100 at 1e-2; 60 takes ~2 s alone, long enough for the busy
/// case to be deterministic and short enough that V2_02's 117 s of data outlast the reply on
/// a loaded machine). With the bundled model (v6) on V2_02_medium this is accepted
/// (`imu-fsda adapt`, support 0–60 s, query 60–85 s: AOE 1.88° → 1.32°). On MH_02_easy,
/// where v6 is already at 1.16° over 60–95 s, every rate tried is rejected (40 steps at
/// 1e-2, 3e-3, 1e-3, 3e-4: 2.55, 2.16, 1.73, 1.32°).
fn write_params(dir: &Path, adapted_dir: &Path) -> PathBuf {
    write_params_with(dir, adapted_dir, "params.yaml", 60, 20.0)
}

fn write_params_with(dir: &Path, adapted_dir: &Path, file: &str, steps: usize, max_seconds: f64) -> PathBuf {
    let p = dir.join(file);
    let yaml = format!(
        "{NODE_NAME}:\n  ros__parameters:\n    adapt_enabled: true\n    ground_truth_topic: /ground_truth/pose\n    ground_truth_type: geometry_msgs/msg/PoseStamped\n    \
         adapt_buffer_seconds: 120.0\n    adapt_support_seconds: 60.0\n    adapted_model_dir: {}\n    adapt:\n      power_on_bias: false\n      steps: {steps}\n      inner_lr: 0.001\n      max_seconds: {max_seconds:?}\n",
        adapted_dir.display()
    );
    std::fs::write(&p, yaml).unwrap();
    p
}

/// "swapped in at sample N" in an accepted reply.
fn swap_sample(message: &str) -> Option<u64> {
    let rest = &message[message.find("swapped in at sample ")? + "swapped in at sample ".len()..];
    rest.split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

fn latency_line(stats: &Value) -> String {
    let s = &stats["latency_by_adaptation_state"];
    let h = |state: &str, kind: &str| {
        let x = &s[state][kind];
        format!(
            "p50 {:.0} / p99 {:.0} / max {:.0} µs (n {})",
            x["p50_us"].as_f64().unwrap_or(f64::NAN),
            x["p99_us"].as_f64().unwrap_or(f64::NAN),
            x["max_us"].as_f64().unwrap_or(f64::NAN),
            x["count"]
        )
    };
    format!(
        "in-node idle {}, adapting {}; write→publish idle {}, adapting {}",
        h("idle", "in_node"),
        h("adapting", "in_node"),
        h("idle", "write_to_publish"),
        h("adapting", "write_to_publish")
    )
}

/// What both tests need: the namespace prerequisites, V2_02_medium, the bundled model and a
/// temp dir with an empty `adapted/`. `None` (after skip_or_fail) when a prerequisite is missing.
struct Setup {
    pre: Prereqs,
    seq: PathBuf,
    model: PathBuf,
    dir: tempfile::TempDir,
    adapted_dir: PathBuf,
}

fn setup() -> Option<Setup> {
    let pre = prerequisites().map_err(|why| skip_or_fail(&why)).ok()?;
    let seq = common::euroc_sequence("V2_02_medium", &[]).map_err(|why| skip_or_fail(&why)).ok()?;
    let model = manifest_dir().join("models/fsda-f.pt");
    assert!(model.is_file(), "the bundled model {} is missing", model.display());
    let dir = tempfile::tempdir().unwrap();
    let adapted_dir = dir.path().join("adapted");
    std::fs::create_dir_all(&adapted_dir).unwrap();
    Some(Setup { pre, seq, model, dir, adapted_dir })
}

#[test]
fn adapt_service_over_dds() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t0 = Instant::now();
    let Some(Setup { pre, seq, model, dir, adapted_dir }) = setup() else { return };
    let params = write_params(dir.path(), &adapted_dir);
    let imu_csv = seq.join("imu0/data.csv");
    let gt_csv = seq.join("state_groundtruth_estimate0/data.csv");

    // ---- 1. adaptation run ----------------------------------------------------------------
    let o = run(
        &pre,
        dir.path(),
        "adapt",
        &["--params", params.to_str().unwrap(), "--model", model.to_str().unwrap()],
        "adapt_peer.py",
        &[
            "--csv",
            imu_csv.to_str().unwrap(),
            "--gt-csv",
            gt_csv.to_str().unwrap(),
            "--gt-from-s",
            "5",
            "--requests",
            "3,25,90x2",
            "--after-s",
            "2",
            "--rate-fast",
            "2000",
            "--rate-busy",
            "200",
        ],
        ADAPT_RUN_TIMEOUT,
    );
    let (p, logs) = (&o.peer, &o.logs);
    assert_eq!(p["matched"], true, "the peer never matched the node: {}\n{logs}", p["match_status"]);
    assert_eq!(o.rc, vec![0, 0], "peer / node exit codes\n{logs}");
    assert_eq!(p["stalled"], false, "an input or its output was lost (flow control stalled)\n{logs}");
    assert_eq!(p["data_exhausted"], false, "the data ran out before every reply came\n{logs}");

    // Replies: one per request, in the order the requests were sent.
    let requests = p["requests"].as_array().unwrap();
    let replies = p["replies"].as_array().unwrap();
    assert_eq!(requests.len(), 4, "requests sent\n{logs}");
    assert_eq!(replies.len(), 4, "replies received: {replies:?}\n{logs}");
    let msg = |r: &Value| r["message"].as_str().unwrap().to_string();
    let ok = |r: &Value| r["success"].as_bool().unwrap();
    assert!(!ok(&replies[0]) && msg(&replies[0]).contains("no ground truth received yet"), "reply 1 (no ground truth): {}", replies[0]);
    assert!(
        !ok(&replies[1]) && msg(&replies[1]).contains("nothing after the 60 s support set"),
        "reply 2 (too little data): {}",
        replies[1]
    );
    for r in &replies[..2] {
        assert!(msg(r).contains("the current model keeps running"), "a failure says the model keeps running: {r}");
    }
    // Requests 3 and 4 were sent back to back: the busy answer comes first, at once.
    let busy = &replies[2];
    let result = &replies[3];
    assert!(!ok(busy) && msg(busy).contains("already running"), "reply 3 should be 'busy': {busy}\nreply 4: {result}");
    let result_msg = msg(result);
    assert!(result_msg.contains("query AOE") && result_msg.contains('→'), "the adaptation reply gives the before/after AOE: {result_msg}");
    let accepted = ok(result);
    if accepted {
        assert!(result_msg.starts_with("adapted:"), "{result_msg}");
    } else {
        assert!(result_msg.contains("rejected"), "a failure other than a rejection: {result_msg}\n{logs}");
    }

    // The node kept publishing while each request was outstanding (the busy one is answered
    // in milliseconds, so it is not counted).
    for (i, (rq, rp)) in requests.iter().zip(replies).enumerate() {
        if i == 2 {
            continue;
        }
        let (d0, d1) = (rq["n_denoised"].as_u64().unwrap(), rp["n_denoised"].as_u64().unwrap());
        assert!(d1 > d0, "request {}: no output while it was outstanding ({d0} → {d1})", i + 1);
    }

    // Exactly one output per input, in order: the stamps are the sent ones, none lost or
    // repeated, also across the swap.
    let sent: Vec<i64> = p["sent"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    let got: Vec<i64> = p["denoised"].as_array().unwrap().iter().map(|m| m["stamp_ns"].as_i64().unwrap()).collect();
    assert!(sent.windows(2).all(|w| w[0] < w[1]), "sent stamps increase");
    if got != sent {
        let first = sent.iter().zip(&got).position(|(a, b)| a != b).unwrap_or(sent.len().min(got.len()));
        panic!("/imu/denoised: {} outputs for {} inputs; first difference at #{first}\n{logs}", got.len(), sent.len());
    }
    let c = &o.node_stats["counters"];
    for k in ["received", "processed"] {
        assert_eq!(c[k].as_u64(), Some(sent.len() as u64), "node counters.{k}: {c}");
    }
    for k in ["dropped_non_finite", "dropped_duplicate_stamp", "dropped_backwards_stamp", "gaps"] {
        assert_eq!(c[k].as_u64(), Some(0), "node counters.{k}: {c}");
    }
    let split = &o.node_stats["latency_by_adaptation_state"];
    let n_idle = split["idle"]["in_node"]["count"].as_u64().unwrap();
    let n_adapting = split["adapting"]["in_node"]["count"].as_u64().unwrap();
    assert_eq!(n_idle + n_adapting, sent.len() as u64, "every sample is filed under idle or adapting: {split}");
    assert!(n_adapting > 200, "samples processed while adapting: {n_adapting}; the adaptation's reply: {result_msg}");

    // /diagnostics: `running` during the adaptation, then the result with the figures.
    let diags = p["diagnostics"].as_array().unwrap();
    let values: Vec<&serde_json::Map<String, Value>> = diags.iter().filter_map(diag_values).collect();
    assert!(values.iter().any(|v| value(v, "adaptation") == "running"), "no /diagnostics with adaptation = running\n{logs}");
    let last = values
        .iter()
        .find(|v| value(v, "received") == sent.len().to_string())
        .unwrap_or_else(|| panic!("no /diagnostics counting every input ({})\n{logs}", sent.len()));
    let status = value(last, "adaptation");
    assert!(status.starts_with(if accepted { "accepted: " } else { "not applied: " }), "/diagnostics adaptation = {status:?}");
    assert_eq!(value(last, "adaptations"), "3", "three jobs ran (the busy answer is not one)");
    for k in ["adapt_query_aoe_before_deg", "adapt_query_aoe_after_deg", "adapt_seconds", "latency_adapting_p99_us"] {
        assert!(value(last, k).parse::<f64>().is_ok(), "/diagnostics {k} = {:?}", value(last, k));
    }
    let adapt_seconds: f64 = value(last, "adapt_seconds").parse().unwrap();

    eprintln!(
        "dds_adapt: sent {} IMU + {} poses in {:.1} s; reply: {result_msg}; adaptation {adapt_seconds:.1} s; {}; wall {:.1} s",
        sent.len(),
        p["gt_sent"],
        p["publish_s"].as_f64().unwrap_or(f64::NAN),
        latency_line(&o.node_stats),
        o.wall_s
    );

    // ---- 2. the saved model, and a node restarted on it -----------------------------------
    let saved: Vec<PathBuf> = std::fs::read_dir(&adapted_dir).unwrap().map(|e| e.unwrap().path()).collect();
    if !accepted {
        assert!(saved.is_empty(), "a rejected adaptation wrote {saved:?}");
        // A clear rejection is a valid answer, but the checks below need an accepted model:
        // with a new bundled model, pick the configuration again (see write_params).
        panic!("the adaptation was rejected on V2_02_medium ({result_msg}): the saved-model and restart checks need it accepted");
    }
    let pt = saved.iter().find(|p| p.extension().is_some_and(|e| e == "pt")).unwrap_or_else(|| panic!("no .pt in {saved:?}"));
    let name = pt.file_stem().unwrap().to_str().unwrap().to_string();
    assert!(name.starts_with("fsda-f-adapted-"), "{name}");
    for ext in ["json", "ot", "adapt.json"] {
        assert!(adapted_dir.join(format!("{name}.{ext}")).is_file(), "{name}.{ext} missing from {saved:?}");
    }
    assert!(result_msg.contains(pt.to_str().unwrap()), "the reply names the saved file: {result_msg}");
    assert_eq!(o.node_stats["model"], name.as_str(), "the running model after the swap");
    assert_eq!(value(last, "model"), name, "/diagnostics model after the swap");
    // The swap happened while the request was outstanding, between two inputs.
    let swap = swap_sample(&result_msg).unwrap_or_else(|| panic!("no swap sample in {result_msg}"));
    let (sent_at_request, sent_at_reply) = (requests[2]["n_sent"].as_u64().unwrap(), result["n_sent"].as_u64().unwrap());
    assert!(
        swap > sent_at_request && swap <= sent_at_reply + 1,
        "swap at sample {swap}, request at {sent_at_request}, reply at {sent_at_reply}"
    );

    let csv_rows = imu_csv.to_str().unwrap();
    let r = run(
        &pre,
        dir.path(),
        "restart",
        &["--params", params.to_str().unwrap(), "--model", pt.to_str().unwrap()],
        "dds_peer.py",
        &["--csv", csv_rows, "--count", "400", "--rate", "1000"],
        RESTART_RUN_TIMEOUT,
    );
    assert_eq!(r.rc, vec![0, 0], "restart: peer / node exit codes\n{}", r.logs);
    assert_eq!(r.node_stats["model"], name.as_str(), "restarted node's model\n{}", r.logs);
    assert_eq!(r.node_stats["counters"]["processed"].as_u64(), Some(400), "restarted node processed\n{}", r.logs);
    assert_eq!(r.peer["denoised"].as_array().map(Vec::len), Some(400), "restart: outputs\n{}", r.logs);
    let ok_model = r.peer["diagnostics"].as_array().unwrap().iter().filter_map(diag_values).any(|v| value(v, "model") == name);
    assert!(ok_model, "restart: /diagnostics never named the adapted model\n{}", r.logs);
    eprintln!("dds_adapt: restart on {name}: 400 in, 400 out, wall {:.1} s; total {:.1} s", r.wall_s, t0.elapsed().as_secs_f64());
}

/// `~/adapt` answers every call, also when it cannot adapt: with no model loaded (at once,
/// saying why; also to a client on rmw_cyclonedds's mapping, `service_mapping: cyclone`), and when the node is stopped while an adaptation runs (the open call is
/// answered as abandoned before the node leaves, its thread stopped and joined; nothing is
/// saved).
#[test]
fn adapt_service_answers_when_it_cannot_adapt() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(Setup { pre, seq, model, dir, adapted_dir }) = setup() else { return };
    let imu_csv = seq.join("imu0/data.csv");
    let gt_csv = seq.join("state_groundtruth_estimate0/data.csv");
    let csv_args = ["--csv", imu_csv.to_str().unwrap(), "--gt-csv", gt_csv.to_str().unwrap(), "--gt-from-s", "1"];

    // One `~/adapt` call to a node without a model: it exits cleanly and answers once, saying why.
    let call_without_model = |tag: &str, params: &Path, extra: &[&str]| {
        let mut peer_args = csv_args.to_vec();
        peer_args.extend(["--count", "2000", "--requests", "3", "--after-s", "1", "--no-ground-truth-reader"]);
        peer_args.extend_from_slice(extra);
        let o = run(
            &pre,
            dir.path(),
            tag,
            &["--params", params.to_str().unwrap(), "--model", ""],
            "adapt_peer.py",
            &peer_args,
            RESTART_RUN_TIMEOUT,
        );
        let logs = &o.logs;
        assert_eq!(o.rc, vec![0, 0], "{tag}: peer / node exit codes\n{logs}");
        let replies = o.peer["replies"].as_array().unwrap();
        assert_eq!(replies.len(), 1, "{tag}: one call, one reply that names it\n{logs}");
        let msg = replies[0]["message"].as_str().unwrap_or("").to_string();
        assert!(replies[0]["success"] == false && msg.contains("no model is loaded"), "{tag}: reply {}\n{logs}", replies[0]);
        assert_eq!(o.node_stats["adapt_calls_refused"], 1, "{tag}: the refused call counted\n{logs}");
        (o, msg)
    };

    // ---- no model: a ground-truth topic, so the service is there, and it says why it cannot.
    let (o, no_model_msg) = call_without_model("no_model", &write_params(dir.path(), &adapted_dir), &[]);
    let status = o.node_stats["adaptation"].as_str().unwrap_or("");
    assert!(status.starts_with("unavailable: no model"), "no model: stats adaptation = {status:?}");

    // ---- the same call as rmw_cyclonedds makes it (request id in a header in the payload),
    // to a node set to that mapping: answered, the header echoed (the peer takes only a reply
    // that names its call).
    let cyclone = dir.path().join("params_cyclone.yaml");
    std::fs::write(&cyclone, format!("{NODE_NAME}:\n  ros__parameters:\n    adapt_enabled: true\n    service_mapping: cyclone\n")).unwrap();
    call_without_model("cyclone_mapping", &cyclone, &["--service-mapping", "cyclone"]);

    // ---- a flood of calls: each answered and counted, the log one line a second.
    let mut peer_args = csv_args.to_vec();
    // A reply timeout well inside the run's: should replies go missing, the peer and the node
    // still end and say how many calls the node counted beside the replies that came.
    peer_args.extend(["--count", "2000", "--requests", "3x50", "--after-s", "1", "--no-ground-truth-reader", "--reply-timeout-s", "15"]);
    let params = write_params(dir.path(), &adapted_dir);
    let o = run(
        &pre,
        dir.path(),
        "flood",
        &["--params", params.to_str().unwrap(), "--model", ""],
        "adapt_peer.py",
        &peer_args,
        RESTART_RUN_TIMEOUT,
    );
    let logs = &o.logs;
    assert_eq!(o.rc, vec![0, 0], "flood: peer / node exit codes\n{logs}");
    assert_eq!(
        o.peer["replies"].as_array().unwrap().len(),
        50,
        "flood: every call answered (the node counted {} refused)\n{logs}",
        o.node_stats["adapt_calls_refused"]
    );
    assert_eq!(o.node_stats["adapt_calls_refused"], 50, "flood: every call counted\n{logs}");
    let lines = logs.matches("(refused: ").count();
    assert!((1..=5).contains(&lines), "flood: {lines} log lines for 50 calls\n{logs}");

    // ---- stopped while adapting: a long inner loop, SIGTERM 2 s after the call.
    let params = write_params_with(dir.path(), &adapted_dir, "params_long.yaml", 1_000_000, 60.0);
    let mut peer_args = csv_args.to_vec();
    peer_args.extend(["--requests", "90", "--term-node-after-s", "2", "--reply-timeout-s", "15", "--stall-timeout-s", "2"]);
    let o = run(
        &pre,
        dir.path(),
        "stopped",
        &["--params", params.to_str().unwrap(), "--model", model.to_str().unwrap()],
        "adapt_peer.py",
        &peer_args,
        ADAPT_RUN_TIMEOUT,
    );
    let logs = &o.logs;
    assert!(o.peer["node_terminated_s"].is_number(), "stopped: the peer did not stop the node\n{logs}");
    assert_eq!(o.rc[1], 0, "stopped: node exit code\n{logs}");
    let replies = o.peer["replies"].as_array().unwrap();
    assert_eq!(replies.len(), 1, "stopped: the open call got no reply\n{logs}");
    let msg = replies[0]["message"].as_str().unwrap_or("");
    assert!(replies[0]["success"] == false && msg.contains("abandoned"), "stopped: reply {}\n{logs}", replies[0]);
    let status = o.node_stats["adaptation"].as_str().unwrap_or("");
    assert!(status.starts_with("abandoned"), "stopped: stats {status}");
    // Stopped at its next step and joined: the process ends normally, nothing left inside libtorch.
    assert!(status.contains("stopped and joined"), "stopped: stats {status}\n{logs}");
    let saved: Vec<PathBuf> = std::fs::read_dir(&adapted_dir).unwrap().map(|e| e.unwrap().path()).collect();
    assert!(saved.is_empty(), "stopped: an abandoned adaptation wrote {saved:?}");
    eprintln!("dds_adapt: no model → {no_model_msg:?}; stopped while adapting → {msg:?}");
}

/// `~/retake_power_on_bias` over DDS: on EuRoC V1_03 (3.5 s at rest, then flight) with the
/// bundled model and no `imu_calibration` (a new IMU to it: the node runs the power-on bias,
/// not the model), the node measures the power-on bias at the rest; a call at 20 s is answered
/// at once, the node forgets the bias (/diagnostics: empty until a later standstill), and
/// counts the re-take. Then a flood, 50 calls at 25 s: each answered and counted, the caller
/// named, the log a line a second.
#[test]
fn power_on_bias_is_retaken_on_demand_over_dds() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Ok(pre) = prerequisites().map_err(|why| skip_or_fail(&why)) else { return };
    let Ok(seq) = common::euroc_sequence("V1_03_difficult", &[]).map_err(|why| skip_or_fail(&why)) else { return };
    let dir = tempfile::tempdir().unwrap();
    let (imu_csv, gt_csv) = (seq.join("imu0/data.csv"), seq.join("state_groundtruth_estimate0/data.csv"));
    let o = run(
        &pre,
        dir.path(),
        "retake",
        &["--model", manifest_dir().join("models/fsda-f.pt").to_str().unwrap()],
        "adapt_peer.py",
        &[
            "--csv",
            imu_csv.to_str().unwrap(),
            "--gt-csv",
            gt_csv.to_str().unwrap(),
            "--gt-from-s",
            "1000",
            "--count",
            "6000",
            "--no-ground-truth-reader",
            "--service",
            "retake_power_on_bias",
            "--requests",
            "20,25x50",
            "--after-s",
            "2",
            "--reply-timeout-s",
            "15",
        ],
        RESTART_RUN_TIMEOUT,
    );
    let (p, logs) = (&o.peer, &o.logs);
    assert_eq!(p["matched"], true, "the peer never matched the node: {}\n{logs}", p["match_status"]);
    assert_eq!(o.rc, vec![0, 0], "peer / node exit codes\n{logs}");
    let replies = p["replies"].as_array().unwrap();
    assert_eq!(replies.len(), 51, "51 calls, 51 replies (the node counted {} calls)\n{logs}", o.node_stats["power_on_bias_retake_calls"]);
    assert!(replies[0]["success"] == true && replies[0]["message"].as_str().unwrap().contains("power-on bias forgotten"), "{}", replies[0]);
    assert_eq!(o.node_stats["power_on_bias_retake_calls"].as_u64(), Some(51), "stats: {}\n{logs}", o.node_stats);
    // The calls that reach the node between two samples are one re-take: the flood is at least one more.
    let retakes = o.node_stats["power_on_bias_retakes"].as_u64().unwrap_or(0);
    assert!((2..=51).contains(&retakes), "re-takes {retakes}: stats {}\n{logs}", o.node_stats);
    assert!(o.node_stats["retake_requested_by"].as_str().unwrap_or("").starts_with("client "), "stats: {}", o.node_stats);
    let lines = logs.matches("~/retake_power_on_bias called by client").count();
    assert!((1..=6).contains(&lines), "{lines} log lines for 51 calls\n{logs}");
    eprintln!("retake flood: 51 calls answered, {retakes} re-takes, {lines} log lines");
    // Measured at the rest before the call; forgotten after it (V1_03 has no standstill in
    // the 2 s after it).
    let values: Vec<&serde_json::Map<String, Value>> = p["diagnostics"].as_array().unwrap().iter().filter_map(diag_values).collect();
    let measured = values.iter().position(|v| !value(v, "power_on_bias_rad_s").is_empty());
    // The first diagnostics after the flood began: a period may hold one re-take or many.
    let retaken = values.iter().position(|v| value(v, "power_on_bias_retakes").parse::<u64>().is_ok_and(|n| n >= 1));
    let (Some(m), Some(r)) = (measured, retaken) else { panic!("diagnostics: measured {measured:?}, retaken {retaken:?}\n{logs}") };
    assert!(m < r, "the bias was measured before the re-take");
    assert!(value(values[r], "power_on_bias_rad_s").is_empty(), "after the re-take: {:?}", value(values[r], "power_on_bias_rad_s"));
    assert_eq!(value(values[r], "correction"), "power-on bias");
    assert_eq!(o.node_stats["correction"], "power-on bias", "the bundled model on a new IMU: the power-on bias runs");
}

/// `power_on_bias_memory` over DDS: the node reads what three earlier power-ons of EuRoC's
/// ADIS16448 predict (said on /diagnostics), and adds this power-on's standstill estimate to
/// the file (a relative path, taken against the parameter file's folder).
#[test]
fn a_power_on_bias_is_remembered_for_the_next_power_on_over_dds() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Ok(pre) = prerequisites().map_err(|why| skip_or_fail(&why)) else { return };
    let Ok(seq) = common::euroc_sequence("V1_03_difficult", &[]).map_err(|why| skip_or_fail(&why)) else { return };
    let Some(data) = common::shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut earlier = Vec::new();
    for s in ["V1_01_easy", "V1_02_medium", "V2_01_easy"] {
        let bag = d.join(format!("{s}.mcap"));
        let o = Command::new(common::bin()).arg("import").arg(data.join("euroc").join(s)).arg("-o").arg(&bag).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        earlier.push(bag);
    }
    let memory = d.join("config/memory/bias.json");
    let o = Command::new(common::bin()).arg("bias-memory").args(&earlier).arg("-o").arg(&memory).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let params = d.join("config/params.yaml");
    std::fs::write(&params, format!("{NODE_NAME}:\n  ros__parameters:\n    power_on_bias_memory: memory/bias.json\n")).unwrap();
    let (imu_csv, gt_csv) = (seq.join("imu0/data.csv"), seq.join("state_groundtruth_estimate0/data.csv"));
    let model = manifest_dir().join("models/fsda-f.pt");
    let o = run(
        &pre,
        d,
        "memory",
        &["--params", params.to_str().unwrap(), "--model", model.to_str().unwrap()],
        "adapt_peer.py",
        &[
            "--csv",
            imu_csv.to_str().unwrap(),
            "--gt-csv",
            gt_csv.to_str().unwrap(),
            "--gt-from-s",
            "1000",
            "--count",
            "6000",
            "--rate-fast",
            "400",
            "--no-ground-truth-reader",
        ],
        RESTART_RUN_TIMEOUT,
    );
    let (p, logs) = (&o.peer, &o.logs);
    assert_eq!(p["matched"], true, "the peer never matched the node: {}\n{logs}", p["match_status"]);
    assert_eq!(o.rc, vec![0, 0], "peer / node exit codes\n{logs}");
    let values: Vec<&serde_json::Map<String, Value>> = p["diagnostics"].as_array().unwrap().iter().filter_map(diag_values).collect();
    let first = values.first().unwrap_or_else(|| panic!("no /diagnostics\n{logs}"));
    let said = value(first, "power_on_bias_memory");
    assert!(said.starts_with("3 earlier power-ons predict") && said.contains("z 0.0"), "{said}");
    // Not turned on in this parameter file: no `~/adapt`, and /diagnostics says so.
    let adaptation = value(first, "adaptation");
    assert!(adaptation.starts_with("off: adapt_enabled is false"), "/diagnostics adaptation = {adaptation:?}");
    let file: Value = serde_json::from_str(&std::fs::read_to_string(&memory).unwrap()).unwrap();
    let power_ons = file["power_ons"].as_array().unwrap();
    assert_eq!(power_ons.len(), 4, "{file}\n{logs}");
    let this = &power_ons[3];
    assert!(this["power_on"].as_str().unwrap().starts_with("node started"), "{this}");
    // What the node saved is what it measured and said.
    let said_bias: Vec<f64> = values
        .iter()
        .rev()
        .map(|v| value(v, "power_on_bias_rad_s"))
        .find(|b| !b.is_empty())
        .unwrap_or_else(|| panic!("no power-on bias on /diagnostics\n{logs}"))
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    for (k, b) in said_bias.iter().enumerate() {
        let saved = this["bias_rad_s"][k].as_f64().unwrap();
        assert!((saved - b).abs() < 1e-3, "axis {k}: saved {saved}, said {b}\n{file}");
    }
    assert!(o.node_stats["power_on_bias_memory"].as_str().unwrap_or_default().contains("saved (4 power-ons"), "{}", o.node_stats);
}

/// A robot that reboots: the first power-on's `~/adapt` keeps its support in
/// `adapt_support_archive` (judged on itself alone: nowhere else to judge); the next power-on's
/// is judged on the earlier ones there (that support, and two bags a user imported into the
/// folder), and keeps what carries over to them. EuRoC V2_01 then V1_03, the archive also
/// holding V1_02 and V2_02: the `adapt --judge` case of tests/adapt_real_cli.rs, in the node.
#[test]
fn an_adaptation_is_judged_on_the_earlier_power_ons_the_node_kept_over_dds() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Ok(pre) = prerequisites().map_err(|why| skip_or_fail(&why)) else { return };
    let Some(data) = common::shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let archive = d.join("config/supports/imu0");
    std::fs::create_dir_all(&archive).unwrap();
    let params = d.join("config/params.yaml");
    std::fs::write(
        &params,
        format!(
            "{NODE_NAME}:\n  ros__parameters:\n    adapt_enabled: true\n    adapt_support_archive: supports/imu0\n    adapted_model_dir: adapted\n    adapt_support_seconds: 60.0\n"
        ),
    )
    .unwrap();
    let model = manifest_dir().join("models/fsda-f.pt");
    let power_on = |tag: &str, sequence: &str| {
        let seq = data.join("euroc").join(sequence).join("mav0");
        let (imu_csv, gt_csv) = (seq.join("imu0/data.csv"), seq.join("state_groundtruth_estimate0/data.csv"));
        let o = run(
            &pre,
            d,
            tag,
            &["--params", params.to_str().unwrap(), "--model", model.to_str().unwrap()],
            "adapt_peer.py",
            &[
                "--csv",
                imu_csv.to_str().unwrap(),
                "--gt-csv",
                gt_csv.to_str().unwrap(),
                "--requests",
                "100",
                "--after-s",
                "1",
                "--rate-fast",
                "2000",
                "--rate-busy",
                "200",
            ],
            ADAPT_RUN_TIMEOUT,
        );
        assert_eq!(o.peer["matched"], true, "{tag}: the peer never matched the node\n{}", o.logs);
        assert_eq!(o.rc, vec![0, 0], "{tag}: peer / node exit codes\n{}", o.logs);
        let replies = o.peer["replies"].as_array().unwrap().clone();
        assert_eq!(replies.len(), 1, "{tag}: {replies:?}\n{}", o.logs);
        (o, replies[0]["message"].as_str().unwrap().to_string(), replies[0]["success"].as_bool().unwrap())
    };
    let supports = |dir: &Path| -> Vec<PathBuf> {
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.to_string_lossy().contains("support-")).collect()
    };

    let (first, said, _) = power_on("first", "V2_01_easy");
    assert!(said.contains("no earlier power-on in") && said.contains("support kept as"), "{said}\n{}", first.logs);
    let kept = supports(&archive);
    assert_eq!(kept.len(), 1, "{kept:?}");
    // What was kept is what the node buffered: read back by `imu-fsda bag info`.
    let info = Command::new(common::bin()).args(["bag", "info"]).arg(&kept[0]).output().unwrap();
    let info = String::from_utf8_lossy(&info.stdout).to_string() + &String::from_utf8_lossy(&info.stderr);
    assert!(info.contains("/imu/data") && info.contains("/ground_truth/pose"), "{info}");
    for s in ["V1_02_medium", "V2_02_medium"] {
        let o = Command::new(common::bin())
            .arg("import")
            .arg(data.join("euroc").join(s))
            .arg("-o")
            .arg(archive.join(format!("{s}.mcap")))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }

    let (second, said, success) = power_on("second", "V1_03_difficult");
    assert!(said.contains("judged on 3 earlier power-ons"), "{said}\n{}", second.logs);
    assert_eq!(supports(&archive).len(), 2, "the second power-on's support is kept too");
    assert!(
        success && said.starts_with("adapted: the gyro calibration with the support's bias offset in motion"),
        "V1_03 judged on three other power-ons keeps its offset: {said}\n{}",
        second.logs
    );
    // The next power-on runs the saved model: /diagnostics says what runs and why.
    let adapted = d.join("config/adapted");
    let pt = std::fs::read_dir(&adapted).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|e| e == "pt"));
    let pt = pt.unwrap_or_else(|| panic!("no model saved in {}: {said}", adapted.display()));
    // Who asked for the model is in its metadata, as the node logged and said it.
    let caller = second.node_stats["adapt_requested_by"].as_str().unwrap_or_default().to_string();
    assert!(caller.starts_with("client ") && caller.contains(" request "), "{}", second.node_stats);
    let meta: Value = serde_json::from_str(&std::fs::read_to_string(pt.with_extension("json")).unwrap()).unwrap();
    let provenance = meta["training_data"].as_array().unwrap().last().and_then(Value::as_str).unwrap_or_default();
    assert!(provenance.ends_with(&format!("requested by {caller}")), "{provenance}");
    let csv = data.join("euroc/V1_02_medium/mav0/imu0/data.csv");
    let r = run(
        &pre,
        d,
        "third",
        &["--params", params.to_str().unwrap(), "--model", pt.to_str().unwrap()],
        "dds_peer.py",
        &["--csv", csv.to_str().unwrap(), "--count", "400", "--rate", "1000"],
        RESTART_RUN_TIMEOUT,
    );
    assert_eq!(r.rc, vec![0, 0], "third: peer / node exit codes\n{}", r.logs);
    let values: Vec<&serde_json::Map<String, Value>> = r.peer["diagnostics"].as_array().unwrap().iter().filter_map(diag_values).collect();
    let reason = values.iter().rev().map(|v| value(v, "correction_reason")).find(|r| !r.is_empty()).unwrap_or_default();
    assert!(reason.contains("bias offset in motion"), "/diagnostics on the next power-on: {reason:?}\n{}", r.logs);
    eprintln!("dds_adapt power-ons: first {:.1} s, second {:.1} s: {said}", first.wall_s, second.wall_s);
}
