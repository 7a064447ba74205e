#!/usr/bin/env python3
"""Independent ROS 2 peer for tests/dds_parameters.rs: what `ros2 param list / get / set` does
to the node, over plain Cyclone DDS (PyPI cyclonedds==11.0.1), without any ROS 2 library.
rcl_interfaces' services are mapped as ROS 2 maps a service (`rq/<node>/set_parametersRequest`,
`rr/<node>/set_parametersReply`, types `rcl_interfaces::srv::dds_::SetParameters_Request_` …),
without the request-id inline QoS Cyclone's API cannot set (one call outstanding at a time, so a
reply is the answer to the call before it). IMU messages and helpers are dds_peer.py's.

It lists the parameters, gets three, tries to set a read-only one, publishes the first half of
`--count` EuRoC IMU rows (the node measures the power-on bias at their rest), sets
`pipeline.power_on_bias` to false, publishes the second half, gets it again, and writes every
answer, the rows sent and the /imu/denoised received to `--out` as JSON (floats as the hex
digits of their bits).

Exit status: 0 when the run completed (the assertions are the caller's), 2 when the node was
not matched in time, 3 when a call was not answered.
"""

import argparse
import json
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Qos, Policy
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
import cyclonedds.idl.annotations as annotate
from cyclonedds.idl.types import float64, int64, sequence, uint8, uint64
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from dds_peer import (DiagnosticArray, Imu, InvalidSample, fbits, make_imu, outputs_matched, read_euroc_csv, vec_json,
                      wait_for_writers)


@annotate.final
@dataclass
class ParameterValue(IdlStruct, typename="rcl_interfaces::msg::dds_::ParameterValue_"):
    type: uint8
    bool_value: bool
    integer_value: int64
    double_value: float64
    string_value: str
    byte_array_value: sequence[uint8]
    bool_array_value: sequence[bool]
    integer_array_value: sequence[int64]
    double_array_value: sequence[float64]
    string_array_value: sequence[str]


@annotate.final
@dataclass
class Parameter(IdlStruct, typename="rcl_interfaces::msg::dds_::Parameter_"):
    name: str
    value: ParameterValue


@annotate.final
@dataclass
class SetParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::SetParametersResult_"):
    successful: bool
    reason: str


@annotate.final
@dataclass
class ListParametersResult(IdlStruct, typename="rcl_interfaces::msg::dds_::ListParametersResult_"):
    names: sequence[str]
    prefixes: sequence[str]


@annotate.final
@dataclass
class SetParametersRequest(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Request_"):
    parameters: sequence[Parameter]


@annotate.final
@dataclass
class SetParametersResponse(IdlStruct, typename="rcl_interfaces::srv::dds_::SetParameters_Response_"):
    results: sequence[SetParametersResult]


@annotate.final
@dataclass
class GetParametersRequest(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Request_"):
    names: sequence[str]


@annotate.final
@dataclass
class GetParametersResponse(IdlStruct, typename="rcl_interfaces::srv::dds_::GetParameters_Response_"):
    values: sequence[ParameterValue]


@annotate.final
@dataclass
class ListParametersRequest(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Request_"):
    prefixes: sequence[str]
    depth: uint64


@annotate.final
@dataclass
class ListParametersResponse(IdlStruct, typename="rcl_interfaces::srv::dds_::ListParameters_Response_"):
    result: ListParametersResult


# rcl_interfaces/msg/ParameterType
NOT_SET, BOOL, INTEGER, DOUBLE, STRING = 0, 1, 2, 3, 4


def value(kind: int, **field) -> ParameterValue:
    v = ParameterValue(type=kind, bool_value=False, integer_value=0, double_value=0.0, string_value="",
                       byte_array_value=[], bool_array_value=[], integer_array_value=[], double_array_value=[],
                       string_array_value=[])
    for k, x in field.items():
        setattr(v, k, x)
    return v


def value_json(v: ParameterValue) -> dict:
    return {"type": v.type, "bool": bool(v.bool_value), "integer": int(v.integer_value),
            "double": fbits(v.double_value), "string": v.string_value}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--csv", required=True, help="EuRoC mav0/imu0/data.csv")
    ap.add_argument("--count", type=int, default=3000, help="IMU rows")
    ap.add_argument("--rate", type=float, default=400.0, help="IMU rate, Hz")
    ap.add_argument("--node-name", default="imu_fsda")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--match-timeout-s", type=float, default=15.0)
    ap.add_argument("--reply-timeout-s", type=float, default=10.0)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()

    rows = read_euroc_csv(args.csv, 0, args.count)
    t_start = time.monotonic()
    dp = DomainParticipant(args.domain)
    pub, sub = Publisher(dp), Subscriber(dp)
    sensor_qos = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(100))
    reliable = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile, Policy.History.KeepAll)
    w_imu = DataWriter(pub, Topic(dp, "rt/imu/data_raw", Imu), qos=sensor_qos)
    services_called = ["list_parameters", "get_parameters", "set_parameters"]
    # The node's writers known before our readers exist: wait_for_writers says why.
    no_writer = wait_for_writers(dp, ["rt/imu/denoised"] + [f"rr/{args.node_name}/{n}Reply" for n in services_called],
                                 args.match_timeout_s)
    r_den = DataReader(sub, Topic(dp, "rt/imu/denoised", Imu), qos=reliable)
    r_diag = DataReader(sub, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=reliable)
    services = {}
    for name, req, rep in [("list_parameters", ListParametersRequest, ListParametersResponse),
                           ("get_parameters", GetParametersRequest, GetParametersResponse),
                           ("set_parameters", SetParametersRequest, SetParametersResponse)]:
        services[name] = (DataWriter(pub, Topic(dp, f"rq/{args.node_name}/{name}Request", req), qos=reliable),
                          DataReader(sub, Topic(dp, f"rr/{args.node_name}/{name}Reply", rep), qos=reliable))

    denoised: list[dict] = []
    diagnostics: list[dict] = []
    result: dict = {"writers_not_seen": sorted(no_writer)}

    def now() -> float:
        return time.monotonic() - t_start

    def drain() -> None:
        for m in r_den.take(N=10_000):
            if not isinstance(m, InvalidSample):
                denoised.append({"stamp_ns": m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec,
                                 "angular_velocity": vec_json(m.angular_velocity)})
        for m in r_diag.take(N=1000):
            if not isinstance(m, InvalidSample):
                diagnostics.append({"status": [{"name": s.name, "values": {kv.key: kv.value for kv in s.values}}
                                               for s in m.status]})

    def write_out() -> None:
        drain()
        result.update({"denoised": denoised, "diagnostics": diagnostics})
        with open(args.out, "w") as f:
            json.dump(result, f)

    def call(service: str, request):
        w, r = services[service]
        w.write(request)
        t0 = time.monotonic()
        while time.monotonic() - t0 < args.reply_timeout_s:
            replies = [m for m in r.take(N=10) if not isinstance(m, InvalidSample)]
            if replies:
                return replies[0]
            drain()
            time.sleep(0.005)
        raise TimeoutError(f"{service}: no reply in {args.reply_timeout_s} s")

    def matched() -> bool:
        ends = [w_imu.get_publication_matched_status().current_count, r_den.get_subscription_matched_status().current_count,
                r_diag.get_subscription_matched_status().current_count]
        for w, r in services.values():
            ends += [w.get_publication_matched_status().current_count, r.get_subscription_matched_status().current_count]
        return all(n >= 1 for n in ends)

    while not matched():
        if now() > args.match_timeout_s:
            result["matched"] = False
            write_out()
            print(f"params_peer: not matched after {args.match_timeout_s} s", file=sys.stderr)
            return 2
        time.sleep(0.005)
    result["matched"] = True
    while not outputs_matched(diagnostics, ["denoised_subscription_count"]) and now() < args.match_timeout_s:
        drain()
        time.sleep(0.01)
    time.sleep(0.5)

    def publish(part: list) -> None:
        due = time.monotonic()
        for t, g, a in part:
            due += 1.0 / args.rate
            pause = due - time.monotonic()
            if pause > 0:
                time.sleep(pause)
            w_imu.write(make_imu({"stamp_ns": t, "gyro": g, "accel": a}, "imu_link"))
            drain()
        # Every output back before the next step.
        t0 = time.monotonic()
        while len(denoised) < len(sent) + len(part) and time.monotonic() - t0 < 3.0:
            drain()
            time.sleep(0.005)
        sent.extend(part)

    sent: list = []
    try:
        listed = call("list_parameters", ListParametersRequest(prefixes=[], depth=0))
        result["listed"] = list(listed.result.names)
        names = ["pipeline.power_on_bias", "pipeline.standstill.max_bias", "input_topic", "not_a_parameter"]
        got = call("get_parameters", GetParametersRequest(names=names))
        result["got_before"] = dict(zip(names, (value_json(v) for v in got.values)))
        refused = call("set_parameters", SetParametersRequest(parameters=[Parameter(name="model", value=value(STRING, string_value="elsewhere.pt"))]))
        result["set_read_only"] = [{"successful": bool(r.successful), "reason": r.reason} for r in refused.results]
        half = len(rows) // 2
        publish(rows[:half])
        result["outputs_before_switch"] = len(denoised)
        switched = call("set_parameters", SetParametersRequest(parameters=[Parameter(name="pipeline.power_on_bias", value=value(BOOL, bool_value=False))]))
        result["set_power_on_bias"] = [{"successful": bool(r.successful), "reason": r.reason} for r in switched.results]
        result["switched_after_rows"] = len(sent)
        publish(rows[half:])
        got = call("get_parameters", GetParametersRequest(names=["pipeline.power_on_bias"]))
        result["got_after"] = value_json(got.values[0]) if got.values else None
    except TimeoutError as e:
        result["timeout"] = str(e)
        write_out()
        print(f"params_peer: {e}", file=sys.stderr)
        return 3
    result["sent"] = [{"stamp_ns": t, "gyro": [fbits(x) for x in g]} for t, g, _ in sent]
    # A /diagnostics that counts every input, so its counters are the run's.
    t0 = time.monotonic()
    while time.monotonic() - t0 < 5.0:
        drain()
        if any(st["values"].get("received") == str(len(sent)) for d in diagnostics for st in d["status"]):
            break
        time.sleep(0.02)
    write_out()
    print(f"params_peer: {len(result['listed'])} parameters listed, sent {len(sent)}, {len(denoised)} denoised", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
