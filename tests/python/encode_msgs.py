#!/usr/bin/env python3
"""Encode messages with two independent CDR encoders, without any bag.

usage: encode_msgs.py SPEC.json

SPEC.json: {"messages": [{"type": "sensor_msgs/msg/Imu", "msg": {...}}, ...]} with floats
tagged as "f64:<bits>". For each message prints the hex of
  * rosbags `Typestore.serialize_cdr` (built-in ROS 2 Humble types, little endian), and
  * mcap_ros2's encoder driven by the definition text rosbags generates for the type,
after checking that both agree and that decoding the bytes gives back the input values.
Prints {"messages": [{"type", "rosbags_hex", "mcap_ros2_hex"}]}; exits 1 on any mismatch.
"""

from __future__ import annotations

import json
import sys

from interop_common import Mismatch, dump, plain_to_rosbags, rosbags_to_plain, run_main, slots_to_plain, tagged, untagged


def main() -> None:
    if len(sys.argv) != 2:
        raise Mismatch('usage: encode_msgs.py SPEC.json')
    from mcap_ros2._dynamic import generate_dynamic, serialize_dynamic
    from rosbags.typesys import Stores, get_typestore

    with open(sys.argv[1], encoding='utf-8') as f:
        spec = json.load(f)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    encoders: dict[str, object] = {}
    decoders: dict[str, object] = {}
    out = []
    for i, item in enumerate(spec['messages']):
        typename = item['type']
        value = untagged(item['msg'])
        if typename not in encoders:
            msgdef, _ = ts.generate_msgdef(typename, ros_version=2)
            encoders[typename] = serialize_dynamic(typename, msgdef)[typename]
            decoders[typename] = generate_dynamic(typename, msgdef)[typename]
        rb = bytes(ts.serialize_cdr(plain_to_rosbags(value, ts, typename), typename, little_endian=True))
        mr = bytes(encoders[typename](value))
        if rb != mr:
            raise Mismatch(f'message {i} ({typename}): rosbags {rb.hex()} != mcap_ros2 {mr.hex()}')
        back_rb = tagged(rosbags_to_plain(ts.deserialize_cdr(rb, typename), ts, typename))
        back_mr = tagged(slots_to_plain(decoders[typename](mr)))
        if back_rb != item['msg'] or back_mr != item['msg']:
            raise Mismatch(f'message {i} ({typename}): decoding does not give back the input:\n  in        {item["msg"]}\n  rosbags   {back_rb}\n  mcap_ros2 {back_mr}')
        out.append({'type': typename, 'rosbags_hex': rb.hex(), 'mcap_ros2_hex': mr.hex()})
    dump({'messages': out})


if __name__ == '__main__':
    run_main(main)
