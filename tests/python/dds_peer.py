#!/usr/bin/env python3
"""Independent ROS 2 peer for tests/dds_interop.rs, written on plain Cyclone DDS (PyPI
cyclonedds==11.0.1), without any ROS 2 library.

It declares the ROS 2 message types itself, with the DDS type names rmw gives them
(`sensor_msgs::msg::dds_::Imu_`, ...), as `@annotate.final` structs (XCDR1, as ROS 2 puts them
on the wire; `@appendable` would switch to XCDR2 and rustdds would silently get nothing), then:

  * publishes sensor_msgs/Imu on DDS topic `rt/imu/data_raw` from an EuRoC `imu0/data.csv`
    (best effort, as a sensor driver does), paced at `--rate` Hz, stamps from the CSV,
    frame_id `--frame-id`; optionally with bad samples mixed in (`--inject-bad`);
  * subscribes to `rt/imu/denoised` (sensor_msgs/Imu), `rt/imu/gyro_correction`
    (geometry_msgs/Vector3Stamped) and `rt/diagnostics` (diagnostic_msgs/DiagnosticArray),
    reliable and keep-all, i.e. what `ros2 topic echo` does;
  * waits for all four endpoints to match the node (and a settle margin) before the first
    sample, and after the last one until every expected output and a /diagnostics message
    counting every sent input have arrived (or a deadline passes);
  * writes everything it sent and received as JSON to `--out`. Every float64 is written as
    the 16 hex digits of its IEEE-754 bit pattern (big endian), so the Rust side compares
    bits exactly and NaN/inf survive JSON.

Exit status: 0 when the run completed (the assertions are the Rust test's job), 2 on a
timeout before matching (the JSON is still written, with `"matched": false`).
"""


import argparse
import json
import math
import struct
import sys
import time
from dataclasses import dataclass

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import Qos, Policy
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
import cyclonedds.idl.annotations as annotate
from cyclonedds.idl.types import array, float64, int32, sequence, uint8, uint32
from cyclonedds.internal import InvalidSample
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration


# ---- ROS 2 message types, as rosidl generates their DDS IDL -------------------------------

@annotate.final
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@annotate.final
@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@annotate.final
@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@annotate.final
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@annotate.final
@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: Header
    orientation: Quaternion
    orientation_covariance: array[float64, 9]
    angular_velocity: Vector3
    angular_velocity_covariance: array[float64, 9]
    linear_acceleration: Vector3
    linear_acceleration_covariance: array[float64, 9]


@annotate.final
@dataclass
class Vector3Stamped(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3Stamped_"):
    header: Header
    vector: Vector3


@annotate.final
@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@annotate.final
@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8  # ROS `byte`: an octet
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@annotate.final
@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


# ---- helpers ------------------------------------------------------------------------------

def wait_for_writers(dp: DomainParticipant, topics: list[str], timeout_s: float) -> set[str]:
    """Wait until a writer on each of `topics` is known to `dp`; returns the topics still
    without one at the deadline. Create the readers of the node's outputs only after this.

    Why: a reliable volatile Cyclone reader takes no data from a writer before that writer's
    first HEARTBEAT, and starts after the last sequence number that heartbeat announces.
    RustDDS sends one unprompted heartbeat when it matches a reader (then only while a reader
    has not acknowledged); Cyclone's pre-emptive ACKNACK acknowledges an empty history. So
    when the node matched our reader before we knew its writer, that heartbeat was dropped and
    the next one came with the node's first sample: that sample was lost (the first of 18,808
    /imu/denoised once in CI). A reader created after the writer is known is matched by
    Cyclone at once, before the node hears of it, so the node's heartbeat on matching is taken.
    """
    publications = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    missing = set(topics)
    deadline = time.monotonic() + timeout_s
    while missing and time.monotonic() < deadline:
        for p in publications.take(N=256):
            missing.discard(getattr(p, "topic_name", None))
        time.sleep(0.002)
    return missing


def outputs_matched(diagnostics: list[dict], keys: list[str]) -> bool:
    """A /diagnostics received says the node's output writers have each matched a reader
    (ours: the tests run one peer per node)."""
    return any(all(int(st["values"].get(k, "0")) >= 1 for k in keys) for d in diagnostics for st in d["status"])


def fbits(x: float) -> str:
    """The float64's bit pattern as 16 hex digits (exact, NaN-safe)."""
    return struct.pack(">d", x).hex()


def vec_json(v) -> list[str]:
    return [fbits(v.x), fbits(v.y), fbits(v.z)]


def header_json(h: Header) -> dict:
    return {"sec": h.stamp.sec, "nanosec": h.stamp.nanosec, "frame_id": h.frame_id}


def imu_json(m: Imu) -> dict:
    o = m.orientation
    return {
        "header": header_json(m.header),
        "orientation": [fbits(o.x), fbits(o.y), fbits(o.z), fbits(o.w)],
        "orientation_covariance": [fbits(v) for v in m.orientation_covariance],
        "angular_velocity": vec_json(m.angular_velocity),
        "angular_velocity_covariance": [fbits(v) for v in m.angular_velocity_covariance],
        "linear_acceleration": vec_json(m.linear_acceleration),
        "linear_acceleration_covariance": [fbits(v) for v in m.linear_acceleration_covariance],
    }


def read_euroc_csv(path: str, start: int, count: int) -> list[tuple[int, list[float], list[float]]]:
    """Rows `start .. start+count` of an EuRoC imu0/data.csv: (stamp_ns, gyro, accel)."""
    rows = []
    with open(path) as f:
        i = 0
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if i >= start:
                p = line.split(",")
                rows.append((int(p[0]), [float(p[1]), float(p[2]), float(p[3])], [float(p[4]), float(p[5]), float(p[6])]))
                if len(rows) == count:
                    break
            i += 1
    if len(rows) < count:
        raise SystemExit(f"{path}: only {len(rows)} rows from row {start}, {count} asked")
    return rows


def build_inputs(rows, inject_bad: bool) -> list[dict]:
    """The sequence to publish: every CSV row ("valid"), plus, with `inject_bad`, bad samples
    mixed in: two NaN and one +inf sample, a 1e30 rad/s sample (finite, but no IMU measures
    it), a duplicate stamp and a backwards stamp."""
    out = [{"kind": "valid", "stamp_ns": t, "gyro": g, "accel": a} for t, g, a in rows]
    if not inject_bad:
        return out
    n = len(rows)
    if n < 50:
        raise SystemExit("--inject-bad needs at least 50 rows")

    def between(i: int) -> int:  # a stamp between rows i and i+1 (still increasing)
        return (rows[i][0] + rows[i + 1][0]) // 2

    bad = {
        # index of the valid row the bad sample follows: the bad sample
        n * 1 // 10: {"kind": "non_finite", "stamp_ns": between(n * 1 // 10),
                      "gyro": [math.nan, rows[n // 10][1][1], rows[n // 10][1][2]], "accel": rows[n // 10][2]},
        n * 3 // 10: {"kind": "non_finite", "stamp_ns": between(n * 3 // 10),
                      "gyro": rows[n * 3 // 10][1], "accel": [0.0, 0.0, math.nan]},
        n * 5 // 10: {"kind": "non_finite", "stamp_ns": between(n * 5 // 10),
                      "gyro": [0.0, math.inf, 0.0], "accel": rows[n * 5 // 10][2]},
        # Finite but beyond any IMU's range: a corrupt driver value.
        n * 6 // 10: {"kind": "implausible", "stamp_ns": between(n * 6 // 10),
                      "gyro": [1e30, rows[n * 6 // 10][1][1], rows[n * 6 // 10][1][2]], "accel": rows[n * 6 // 10][2]},
        # Same stamp as the row before it, different values: must not be published.
        n * 7 // 10: {"kind": "duplicate_stamp", "stamp_ns": rows[n * 7 // 10][0],
                      "gyro": [v + 0.5 for v in rows[n * 7 // 10][1]], "accel": rows[n * 7 // 10][2]},
        # Between the two rows before it: older than the last accepted stamp.
        n * 9 // 10: {"kind": "backwards_stamp", "stamp_ns": (rows[n * 9 // 10 - 1][0] + rows[n * 9 // 10][0]) // 2,
                      "gyro": rows[n * 9 // 10][1], "accel": rows[n * 9 // 10][2]},
    }
    seq = []
    for i, s in enumerate(out):
        seq.append(s)
        if i in bad:
            seq.append(bad[i])
    return seq


def make_imu(s: dict, frame_id: str) -> Imu:
    # A raw IMU without orientation (REP 145: orientation_covariance[0] = -1), as a driver sends it.
    t = s["stamp_ns"]
    g, a = s["gyro"], s["accel"]
    return Imu(
        header=Header(stamp=Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000), frame_id=frame_id),
        orientation=Quaternion(0.0, 0.0, 0.0, 1.0),
        orientation_covariance=[-1.0] + [0.0] * 8,
        angular_velocity=Vector3(g[0], g[1], g[2]),
        angular_velocity_covariance=[0.0] * 9,
        linear_acceleration=Vector3(a[0], a[1], a[2]),
        linear_acceleration_covariance=[0.0] * 9,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--csv", required=True, help="EuRoC mav0/imu0/data.csv")
    ap.add_argument("--start", type=int, default=0, help="first data row")
    ap.add_argument("--count", type=int, default=3000, help="rows to publish")
    ap.add_argument("--rate", type=float, default=1000.0, help="publish rate, Hz")
    ap.add_argument("--frame-id", default="imu_link")
    ap.add_argument("--inject-bad", action="store_true")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--max-in-flight", type=int, default=5,
                    help="valid inputs sent but not yet answered on /imu/denoised (0: open loop)")
    ap.add_argument("--stall-timeout-s", type=float, default=3.0)
    ap.add_argument("--settle-s", type=float, default=0.5, help="margin after all endpoints matched")
    ap.add_argument("--match-timeout-s", type=float, default=15.0)
    ap.add_argument("--drain-timeout-s", type=float, default=8.0, help="wait for outputs after the last input")
    ap.add_argument("--diag-name", default="imu_fsda: gyro denoiser")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()

    rows = read_euroc_csv(args.csv, args.start, args.count)
    inputs = build_inputs(rows, args.inject_bad)
    n_valid = sum(1 for s in inputs if s["kind"] == "valid")

    t_start = time.monotonic()
    dp = DomainParticipant(args.domain)
    pub, sub = Publisher(dp), Subscriber(dp)
    in_qos = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(100))
    out_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile, Policy.History.KeepAll)
    writer = DataWriter(pub, Topic(dp, "rt/imu/data_raw", Imu), qos=in_qos)
    outputs = ["rt/imu/denoised", "rt/imu/gyro_correction"]
    no_writer = wait_for_writers(dp, outputs, args.match_timeout_s)
    r_denoised = DataReader(sub, Topic(dp, "rt/imu/denoised", Imu), qos=out_qos)
    r_corr = DataReader(sub, Topic(dp, "rt/imu/gyro_correction", Vector3Stamped), qos=out_qos)
    r_diag = DataReader(sub, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=out_qos)

    denoised: list[dict] = []
    corrections: list[dict] = []
    diagnostics: list[dict] = []

    invalid = {"imu/denoised": 0, "imu/gyro_correction": 0, "diagnostics": 0}

    def valid(samples, topic: str):
        # Instance-state changes (the node's writer leaving) come as InvalidSample: no data.
        for m in samples:
            if isinstance(m, InvalidSample):
                invalid[topic] += 1
            else:
                yield m

    def drain() -> None:
        for m in valid(r_denoised.take(N=10_000), "imu/denoised"):
            denoised.append(imu_json(m))
        for m in valid(r_corr.take(N=10_000), "imu/gyro_correction"):
            corrections.append({"header": header_json(m.header), "vector": vec_json(m.vector)})
        for m in valid(r_diag.take(N=1000), "diagnostics"):
            diagnostics.append({
                "header": header_json(m.header),
                "status": [{"level": s.level, "name": s.name, "message": s.message, "hardware_id": s.hardware_id,
                            "values": {kv.key: kv.value for kv in s.values}} for s in m.status],
            })

    def matched() -> dict:
        return {
            "imu/data_raw": writer.get_publication_matched_status().current_count,
            "imu/denoised": r_denoised.get_subscription_matched_status().current_count,
            "imu/gyro_correction": r_corr.get_subscription_matched_status().current_count,
            "diagnostics": r_diag.get_subscription_matched_status().current_count,
        }

    result = {"rate_hz": args.rate, "count": args.count, "start": args.start, "frame_id": args.frame_id,
              "n_valid": n_valid, "inject_bad": args.inject_bad, "writers_not_seen": sorted(no_writer)}

    def write_out() -> None:
        drain()
        result.update({
            "sent": [{"kind": s["kind"], "stamp_ns": s["stamp_ns"], "gyro": [fbits(v) for v in s["gyro"]],
                      "accel": [fbits(v) for v in s["accel"]]} for s in inputs[:result.get("n_sent", 0)]],
            "denoised": denoised, "corrections": corrections, "diagnostics": diagnostics,
            "invalid_samples": invalid,
        })
        with open(args.out, "w") as f:
            json.dump(result, f)

    # 1. Discovery: every endpoint matched with the node, then a settle margin (the remote
    #    side matches our endpoints at about the same time, but we cannot observe that).
    first_match = None
    while True:
        m = matched()
        if first_match is None and any(m.values()):
            first_match = time.monotonic() - t_start
        if all(v >= 1 for v in m.values()):
            break
        if time.monotonic() - t_start > args.match_timeout_s:
            result.update({"matched": False, "match_status": m, "n_sent": 0})
            write_out()
            print(f"dds_peer: not matched after {args.match_timeout_s} s: {m}", file=sys.stderr)
            return 2
        time.sleep(0.002)
    result["matched"] = True
    result["match_status"] = matched()
    result["first_match_s"] = first_match
    result["all_matched_s"] = time.monotonic() - t_start
    # Our readers matched the node's writers; whether the node's writers matched our readers
    # we cannot observe, except through the node: its /diagnostics (published from the start,
    # "no input yet") counts the readers each output writer has matched. A sample published
    # before that is, by DDS's volatile durability, for nobody (an early output was lost so on
    # a loaded machine, once after the first /diagnostics had come).
    while (not outputs_matched(diagnostics, ["denoised_subscription_count", "correction_subscription_count"])
           and time.monotonic() - t_start < args.match_timeout_s):
        drain()
        time.sleep(0.01)
    result["node_heard_s"] = time.monotonic() - t_start
    time.sleep(args.settle_s)
    drain()
    result["diagnostics_before_input"] = len(diagnostics)

    # 2. Publish, paced on an absolute schedule at `--rate` with no catch-up bursts, and (unless
    #    `--max-in-flight 0`) closed loop: never more than `--max-in-flight` valid inputs ahead
    #    of the /imu/denoised outputs received, so the node's best-effort input queue (keep
    #    last 10) cannot overflow even when a loaded CI machine stalls the node.
    period = 1.0 / args.rate
    t_pub = t0 = time.monotonic()
    slips = flow_waits = 0
    flow_wait_s = 0.0
    stalled = False
    valid_sent = 0
    for i, s in enumerate(inputs):
        if args.max_in_flight > 0 and valid_sent - len(denoised) >= args.max_in_flight:
            drain()
            t_wait = time.monotonic()
            waited = False
            while valid_sent - len(denoised) >= args.max_in_flight:
                if time.monotonic() - t_wait > args.stall_timeout_s:
                    stalled = True  # an input (or its output) was lost: stop waiting for it
                    break
                waited = True
                time.sleep(0.0002)
                drain()
            flow_waits += waited
            flow_wait_s += time.monotonic() - t_wait
            if stalled:
                break
        due = t0 + i * period
        now = time.monotonic()
        if due > now:
            time.sleep(due - now)
        elif now - due > 2 * period:
            t0 += now - due  # behind schedule: shift it rather than burst to catch up
            slips += 1
        writer.write(make_imu(s, args.frame_id))
        result["n_sent"] = i + 1
        valid_sent += s["kind"] == "valid"
    result["publish_s"] = time.monotonic() - t_pub
    result["schedule_slips"] = slips
    result["flow_control_waits"] = flow_waits
    result["flow_control_wait_s"] = flow_wait_s
    result["stalled"] = stalled
    n_sent = result.get("n_sent", 0)
    n_valid = result["n_valid_sent"] = sum(1 for s in inputs[:n_sent] if s["kind"] == "valid")

    # 3. Drain: every expected output, and a /diagnostics message that counted every input.
    def diag_done() -> bool:
        for d in diagnostics:
            for st in d["status"]:
                if st["name"] == args.diag_name and st["values"].get("received") == str(n_sent):
                    return True
        return False

    t_end = time.monotonic()
    while time.monotonic() - t_end < args.drain_timeout_s:
        drain()
        if len(denoised) >= n_valid and len(corrections) >= n_valid and diag_done():
            break
        time.sleep(0.01)
    result["drain_s"] = time.monotonic() - t_end
    write_out()
    print(f"dds_peer: discovery {result['all_matched_s']:.3f} s, sent {n_sent} ({n_valid} valid) in "
          f"{result['publish_s']:.3f} s, got {len(denoised)} denoised, {len(corrections)} corrections, "
          f"{len(diagnostics)} diagnostics", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
