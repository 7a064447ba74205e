#!/usr/bin/env python3
"""Independent ROS 2 peer for tests/dds_adapt.rs and scripts/bench_adapt.sh: drives the
node's on-demand adaptation service `~/adapt` (or, with `--service`, another of its
std_srvs/srv/Trigger services: `retake_power_on_bias`) over plain Cyclone DDS
(PyPI cyclonedds==11.0.1), without any ROS 2 library. The message types and helpers are
dds_peer.py's (same folder).

It
  * publishes an EuRoC sequence's IMU rows (sensor_msgs/Imu on `rt/imu/data_raw`, best
    effort) and, from `--gt-from-s` data seconds on, its ground truth interleaved in stamp
    order (geometry_msgs/PoseStamped on `rt/ground_truth/pose`, best effort, as a
    motion-capture driver does);
  * calls the service at given data times (`--requests 3,25,100x2`: one request after 3 s of
    data, one after 25 s, two back to back after 100 s), each group only once the earlier
    requests are answered. ROS 2 maps a service onto two DDS topics, `rq/<node>/adaptRequest`
    (type `std_srvs::srv::dds_::Trigger_Request_`) and `rr/<node>/adaptReply`
    (`Trigger_Response_`), both reliable. The node's ros2-client server uses the
    "Enhanced" mapping (rmw_fastrtps's): no request header in the payload, the request id
    travels as the RELATED_SAMPLE_IDENTITY inline QoS. Cyclone's API cannot set or read that
    parameter, so requests go without it (the server then takes the request's own writer
    GUID + sequence number as its id, which is what a Fast DDS client puts there) and replies
    are matched to requests by order and content — this peer has at most one group of
    requests outstanding;
  * keeps publishing while a request is outstanding, at `--rate-busy` (the recorded 200 Hz
    by default) instead of `--rate-fast`, closed loop like dds_peer.py (never more than
    `--max-in-flight` inputs ahead of the /imu/denoised outputs), so no input can be lost;
  * stops `--after-s` data seconds after the last reply, waits for every output and a
    /diagnostics message counting every input, and writes what it sent and received to
    `--out` as JSON (floats as the hex digits of their bits, as dds_peer.py).

Exit status: 0 when the run completed (the assertions are the caller's), 2 when the node
was not matched in time.
"""

import argparse
import json
import os
import signal
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Qos, Policy
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
import cyclonedds.idl.annotations as annotate
from cyclonedds.idl.types import float64, int64, uint8, uint64
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from dds_peer import (DiagnosticArray, wait_for_writers, outputs_matched, Header, Imu, InvalidSample, Quaternion, Time, fbits, header_json,
                      make_imu, read_euroc_csv, vec_json)


@annotate.final
@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@annotate.final
@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@annotate.final
@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


@annotate.final
@dataclass
class TriggerRequest(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    # rosidl gives an empty request this placeholder member.
    structure_needs_at_least_one_member: uint8


@annotate.final
@dataclass
class TriggerResponse(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    success: bool
    message: str


# rmw_cyclonedds's service mapping (`--service-mapping cyclone`): the same DDS type names, the
# payload led by a request header (rmw_cyclonedds_cpp serdata.hpp, cdds_request_header_t:
# uint64 guid, int64 seq), which the server echoes in its reply.
@annotate.final
@dataclass
class CycloneTriggerRequest(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    guid: uint64
    seq: int64
    structure_needs_at_least_one_member: uint8


@annotate.final
@dataclass
class CycloneTriggerResponse(IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    guid: uint64
    seq: int64
    success: bool
    message: str


CYCLONE_CLIENT_GUID = 0x1122334455667788


def read_ground_truth(path: str, t0: int, t1: int) -> list[tuple[int, list[float], list[float]]]:
    """EuRoC state_groundtruth_estimate0/data.csv rows in [t0, t1]: (stamp, p xyz, q wxyz),
    columns found by header name (some sequences have 8 columns, others 17)."""
    out = []
    with open(path) as f:
        header = [h.strip().lstrip("#").strip() for h in f.readline().split(",")]
        col = {h.split(" ")[0]: i for i, h in enumerate(header)}
        ip = [col["p_RS_R_x"], col["p_RS_R_y"], col["p_RS_R_z"]]
        iq = [col["q_RS_w"], col["q_RS_x"], col["q_RS_y"], col["q_RS_z"]]
        for line in f:
            p = line.strip().split(",")
            if len(p) < 8:
                continue
            t = int(p[0])
            if t0 <= t <= t1:
                out.append((t, [float(p[i]) for i in ip], [float(p[i]) for i in iq]))
    return out


def make_pose(t: int, p: list[float], q: list[float]) -> PoseStamped:
    return PoseStamped(header=Header(stamp=Time(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000), frame_id="world"),
                       pose=Pose(position=Point(*p), orientation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])))


def parse_requests(spec: str) -> list[tuple[float, int]]:
    groups = []
    for part in filter(None, spec.split(",")):
        t, _, n = part.partition("x")
        groups.append((float(t), int(n or 1)))
    return groups


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--csv", required=True, help="EuRoC mav0/imu0/data.csv")
    ap.add_argument("--gt-csv", required=True, help="EuRoC mav0/state_groundtruth_estimate0/data.csv")
    ap.add_argument("--start", type=int, default=0, help="first IMU data row")
    ap.add_argument("--count", type=int, default=29000, help="IMU rows at most")
    ap.add_argument("--gt-from-s", type=float, default=0.0, help="publish ground truth from this data time on")
    ap.add_argument("--requests", default="", help="data times of the service calls: 3,25,100x2")
    ap.add_argument("--after-s", type=float, default=2.0, help="data seconds published after the last reply")
    ap.add_argument("--rate-fast", type=float, default=2000.0, help="IMU rate with no request outstanding, Hz")
    ap.add_argument("--rate-busy", type=float, default=200.0, help="IMU rate while a request is outstanding, Hz")
    ap.add_argument("--node-name", default="imu_fsda")
    ap.add_argument("--service", default="adapt", help="the node's Trigger service to call: adapt, retake_power_on_bias")
    ap.add_argument("--frame-id", default="imu_link")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--max-in-flight", type=int, default=5)
    ap.add_argument("--stall-timeout-s", type=float, default=3.0)
    ap.add_argument("--settle-s", type=float, default=0.5)
    ap.add_argument("--match-timeout-s", type=float, default=15.0)
    ap.add_argument("--reply-timeout-s", type=float, default=60.0, help="wall time a request may stay unanswered")
    ap.add_argument("--drain-timeout-s", type=float, default=8.0)
    ap.add_argument("--service-mapping", choices=["enhanced", "cyclone"], default="enhanced",
                    help="enhanced: no header in the payload (rmw_fastrtps's, without the inline QoS Cyclone's "
                         "API cannot set); cyclone: rmw_cyclonedds's request header in the payload")
    ap.add_argument("--no-ground-truth-reader", action="store_true",
                    help="do not wait for a reader of the ground truth (a node with nothing to adapt has none)")
    ap.add_argument("--term-node-after-s", type=float, default=None,
                    help="SIGTERM to the process $NODE_PID this many wall seconds after the last group of calls")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()

    with open(args.csv) as f:
        n_rows = sum(1 for line in f if line.strip() and not line.startswith("#"))
    rows = read_euroc_csv(args.csv, args.start, min(args.count, n_rows - args.start))
    t_first = rows[0][0]
    gt = read_ground_truth(args.gt_csv, t_first + int(args.gt_from_s * 1e9), rows[-1][0])
    groups = parse_requests(args.requests)
    diag_name = f"{args.node_name}: gyro denoiser"

    t_start = time.monotonic()
    dp = DomainParticipant(args.domain)
    pub, sub = Publisher(dp), Subscriber(dp)
    sensor_qos = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(100))
    reliable_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile, Policy.History.KeepAll)
    w_imu = DataWriter(pub, Topic(dp, "rt/imu/data_raw", Imu), qos=sensor_qos)
    w_gt = DataWriter(pub, Topic(dp, "rt/ground_truth/pose", PoseStamped), qos=sensor_qos)
    cyclone = args.service_mapping == "cyclone"
    req_type, rep_type = (CycloneTriggerRequest, CycloneTriggerResponse) if cyclone else (TriggerRequest, TriggerResponse)
    w_req = DataWriter(pub, Topic(dp, f"rq/{args.node_name}/{args.service}Request", req_type), qos=reliable_qos)
    # The node's writers known before our readers exist (wait_for_writers says why); a node
    # without the service has no reply writer, so that one is waited for only with calls to make.
    reply_topic = f"rr/{args.node_name}/{args.service}Reply"
    no_writer = wait_for_writers(dp, ["rt/imu/denoised"] + ([reply_topic] if groups else []), args.match_timeout_s)
    r_rep = DataReader(sub, Topic(dp, reply_topic, rep_type), qos=reliable_qos)
    cyclone_seq = {"next": 1, "open": set()}
    r_den = DataReader(sub, Topic(dp, "rt/imu/denoised", Imu), qos=reliable_qos)
    r_diag = DataReader(sub, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=reliable_qos)

    denoised: list[dict] = []
    diagnostics: list[dict] = []
    replies: list[dict] = []
    requests: list[dict] = []
    sent: list[int] = []
    state = {"gt_sent": 0}

    def now() -> float:
        return time.monotonic() - t_start

    def drain() -> None:
        for m in r_den.take(N=10_000):
            if not isinstance(m, InvalidSample):
                denoised.append({"stamp_ns": m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                                 "angular_velocity": vec_json(m.angular_velocity)})
        for m in r_diag.take(N=1000):
            if not isinstance(m, InvalidSample):
                diagnostics.append({
                    "t": now(), "header": header_json(m.header),
                    "status": [{"level": s.level, "name": s.name, "message": s.message,
                                "values": {kv.key: kv.value for kv in s.values}} for s in m.status],
                })
        for m in r_rep.take(N=100):
            if not isinstance(m, InvalidSample):
                if cyclone:
                    # rmw_cyclonedds takes a reply only when its header names this client's call.
                    if m.guid != CYCLONE_CLIENT_GUID or m.seq not in cyclone_seq["open"]:
                        continue
                    cyclone_seq["open"].discard(m.seq)
                replies.append({"t": now(), "success": bool(m.success), "message": m.message,
                                "n_sent": len(sent), "n_denoised": len(denoised)})

    def matched() -> dict:
        return {
            "imu/data_raw": w_imu.get_publication_matched_status().current_count,
            "ground_truth/pose": w_gt.get_publication_matched_status().current_count,
            "adaptRequest": w_req.get_publication_matched_status().current_count,
            "adaptReply": r_rep.get_subscription_matched_status().current_count,
            "imu/denoised": r_den.get_subscription_matched_status().current_count,
            "diagnostics": r_diag.get_subscription_matched_status().current_count,
        }

    result = {"rate_fast_hz": args.rate_fast, "rate_busy_hz": args.rate_busy, "start": args.start,
              "gt_from_s": args.gt_from_s, "requests_spec": args.requests, "writers_not_seen": sorted(no_writer)}

    def write_out() -> None:
        drain()
        result.update({"sent": sent, "denoised": denoised, "diagnostics": diagnostics, "requests": requests,
                       "replies": replies, "gt_sent": state["gt_sent"]})
        with open(args.out, "w") as f:
            json.dump(result, f)

    while True:
        m = matched()
        if args.no_ground_truth_reader:
            m.pop("ground_truth/pose")
        if not groups:  # no call to make: a node without the service is matched all the same
            m.pop("adaptRequest")
            m.pop("adaptReply")
        if all(v >= 1 for v in m.values()):
            break
        if now() > args.match_timeout_s:
            result.update({"matched": False, "match_status": m})
            write_out()
            print(f"adapt_peer: not matched after {args.match_timeout_s} s: {m}", file=sys.stderr)
            return 2
        time.sleep(0.002)
    result.update({"matched": True, "all_matched_s": now()})
    # As in dds_peer.py: a /diagnostics counting a reader on /imu/denoised says the node's
    # writer took in ours (before it, an output is for nobody: one was lost so under load).
    while not outputs_matched(diagnostics, ["denoised_subscription_count"]) and now() < args.match_timeout_s:
        drain()
        time.sleep(0.01)
    result["node_heard_s"] = now()
    time.sleep(args.settle_s)
    drain()

    gi = 0  # next ground-truth row
    next_group = 0
    stop_after_index = None  # last IMU row to send once every reply is in
    stalled = False
    due = time.monotonic()
    slips = 0
    t_pub = time.monotonic()
    t_last_group = None
    for i, (t, g, a) in enumerate(rows):
        data_t = (t - t_first) / 1e9
        outstanding = len(requests) - len(replies)
        # A group of calls is due: send it once the earlier calls are answered.
        if next_group < len(groups) and data_t >= groups[next_group][0] and outstanding == 0:
            for _ in range(groups[next_group][1]):
                requests.append({"t": now(), "data_t": data_t, "n_sent": len(sent), "n_denoised": len(denoised)})
                if cyclone:
                    seq = cyclone_seq["next"]
                    cyclone_seq["next"] += 1
                    cyclone_seq["open"].add(seq)
                    w_req.write(CycloneTriggerRequest(guid=CYCLONE_CLIENT_GUID, seq=seq, structure_needs_at_least_one_member=0))
                else:
                    w_req.write(TriggerRequest(structure_needs_at_least_one_member=0))
            next_group += 1
            outstanding = len(requests) - len(replies)
            if next_group == len(groups):
                t_last_group = time.monotonic()
        if (args.term_node_after_s is not None and t_last_group is not None and "node_terminated_s" not in result
                and time.monotonic() - t_last_group >= args.term_node_after_s):
            os.kill(int(os.environ["NODE_PID"]), signal.SIGTERM)
            result["node_terminated_s"] = now()
        if next_group == len(groups) and outstanding == 0 and stop_after_index is None:
            stop_after_index = i + int(round(args.after_s / max(1e-9, (rows[1][0] - rows[0][0]) / 1e9)))
        if stop_after_index is not None and i >= stop_after_index:
            break
        # Closed loop: at most `max_in_flight` inputs ahead of the outputs.
        if args.max_in_flight > 0 and len(sent) - len(denoised) >= args.max_in_flight:
            t_wait = time.monotonic()
            while len(sent) - len(denoised) >= args.max_in_flight:
                drain()
                if time.monotonic() - t_wait > args.stall_timeout_s:
                    stalled = True
                    break
                time.sleep(0.0002)
            if stalled:
                break
        period = 1.0 / (args.rate_busy if outstanding else args.rate_fast)
        due += period
        tnow = time.monotonic()
        if due > tnow:
            time.sleep(due - tnow)
        elif tnow - due > 2 * period:
            due = tnow  # behind: shift the schedule rather than burst
            slips += 1
        if data_t >= args.gt_from_s:
            while gi < len(gt) and gt[gi][0] <= t:
                w_gt.write(make_pose(*gt[gi]))
                gi += 1
                state["gt_sent"] += 1
        w_imu.write(make_imu({"stamp_ns": t, "gyro": g, "accel": a}, args.frame_id))
        sent.append(t)
        if i % 8 == 0:
            drain()
    result.update({"publish_s": time.monotonic() - t_pub, "schedule_slips": slips, "stalled": stalled,
                   "data_exhausted": stop_after_index is None, "groups_sent": next_group})

    # Replies still outstanding (the data ran out first): wait for them.
    t_wait = time.monotonic()
    while len(replies) < len(requests) and time.monotonic() - t_wait < args.reply_timeout_s:
        drain()
        time.sleep(0.01)

    def diag_done() -> bool:
        return any(st["name"] == diag_name and st["values"].get("received") == str(len(sent))
                   for d in diagnostics for st in d["status"])

    t_end = time.monotonic()
    while time.monotonic() - t_end < args.drain_timeout_s:
        drain()
        if len(denoised) >= len(sent) and diag_done():
            break
        time.sleep(0.01)
    write_out()
    print(f"adapt_peer: discovery {result['all_matched_s']:.3f} s, sent {len(sent)} IMU + {state['gt_sent']} poses in "
          f"{result['publish_s']:.2f} s, {len(requests)} requests, {len(replies)} replies, {len(denoised)} denoised, "
          f"{len(diagnostics)} diagnostics", file=sys.stderr)
    for r in replies:
        print(f"adapt_peer: reply at {r['t']:.2f} s: success={r['success']} {r['message']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
