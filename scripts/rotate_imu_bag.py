#!/usr/bin/env python3
"""Rewrite a bag's /imu/data as a sensor mounted in another frame, for testing the diagnosis.

usage: rotate_imu_bag.py IN.mcap OUT.mcap ROTVEC|swapxy

ROTVEC "rx,ry,rz" (rad) is body_from_imu = Exp(rotvec): every angular velocity and linear
acceleration v becomes Rᵀ v, what `mount_rotation` with that rotation vector simulates.
`swapxy` exchanges x and y instead (a mirror image: a driver's axis-order error). Every other
message is copied as it is. Run with the project's venv ($PYTHON from scripts/env.sh).
"""
import math
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer


def rotation(rotvec):
    v = np.asarray(rotvec, float)
    th = np.linalg.norm(v)
    if th < 1e-12:
        return np.eye(3)
    k = v / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def plain(o):
    if hasattr(o, '__slots__'):
        return {k: plain(getattr(o, k)) for k in o.__slots__}
    if isinstance(o, (list, tuple)):
        return [plain(x) for x in o]
    return o


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    src, dst, kind = sys.argv[1:]
    m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1.0]]) if kind == 'swapxy' else rotation([float(x) for x in kind.split(',')]).T
    with open(src, 'rb') as f, open(dst, 'wb') as g:
        writer = Writer(g)
        schemas = {}
        for schema, channel, message, decoded in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if schema.name not in schemas:
                schemas[schema.name] = writer.register_msgdef(schema.name, schema.data.decode())
            d = plain(decoded)
            if channel.topic == '/imu/data':
                for key in ('angular_velocity', 'linear_acceleration'):
                    v = m @ np.array([d[key]['x'], d[key]['y'], d[key]['z']])
                    d[key] = {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])}
            writer.write_message(channel.topic, schemas[schema.name], d, log_time=message.log_time, publish_time=message.publish_time)
        writer.finish()


if __name__ == '__main__':
    main()
