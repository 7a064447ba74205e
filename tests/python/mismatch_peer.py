#!/usr/bin/env python3
"""Peers that cannot work with the node, for tests/dds_peers.rs, on plain Cyclone DDS (PyPI
cyclonedds, no ROS 2 library; the message types are dds_peer.py's).

On one participant it makes:
  * a writer on `rt/imu/data_raw` (the node's input is sensor_msgs/Imu) of a type laid out as
    sensor_msgs/Imu but named `my_msgs::msg::dds_::Imu_`, writing plausible samples at 10 Hz
    (they would decode as sensor_msgs/Imu; Cyclone DDS does not match a reader of another type
    name, so none should reach the node);
  * a reader of `rt/imu/denoised` asking for transient-local durability (the node offers
    volatile: no sample can flow);
  * a reader of `rt/diagnostics` (reliable, as `ros2 topic echo`), read until the node's status
    names both peers, or `--timeout-s` passes.
Writes the last status's values and what the transient-local reader got as JSON to `--out`.
"""

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402

from dds_peer import DiagnosticArray, Header, Imu, Quaternion, Time, Vector3  # noqa: E402


@annotate.final
@dataclass
class OtherImu(Imu, typename="my_msgs::msg::dds_::Imu_"):
    """sensor_msgs/Imu's fields under another type name."""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--diag-name", default="imu_fsda: gyro denoiser")
    ap.add_argument("--timeout-s", type=float, default=20.0)
    args = ap.parse_args()

    dp = DomainParticipant(0)
    best_effort = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))
    reliable = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll)
    latched = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))

    wrong = DataWriter(dp, Topic(dp, "rt/imu/data_raw", OtherImu), qos=best_effort)
    denoised = DataReader(dp, Topic(dp, "rt/imu/denoised", Imu), qos=latched)
    diagnostics = DataReader(dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=reliable)

    values, got_denoised, wrote = {}, 0, 0
    deadline = time.monotonic() + args.timeout_s
    while time.monotonic() < deadline:
        zeros = [0.0] * 9
        wrong.write(OtherImu(
            header=Header(stamp=Time(sec=1 + wrote // 10, nanosec=(wrote % 10) * 100_000_000), frame_id="imu_link"),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=[-1.0] + zeros[1:],
            angular_velocity=Vector3(x=0.01, y=-0.02, z=0.03), angular_velocity_covariance=zeros,
            linear_acceleration=Vector3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=zeros))
        wrote += 1
        got_denoised += len(denoised.take(N=100))
        for msg in diagnostics.take(N=100):
            for status in getattr(msg, "status", []):
                if status.name == args.diag_name:
                    values = {kv.key: kv.value for kv in status.values}
                    values["_level"] = int(status.level)
                    values["_message"] = status.message
        if int(values.get("incompatible_peers", "0")) >= 2 and wrote >= 20:
            break
        time.sleep(0.1)
    with open(args.out, "w") as f:
        json.dump({"status": values, "denoised_received": got_denoised, "wrong_type_written": wrote}, f)


if __name__ == "__main__":
    main()
