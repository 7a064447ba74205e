#!/usr/bin/env python3
"""VQF's 6D orientation of a bag's raw IMU, as a bag `imu-fsda attitude` scores.

usage: vqf_attitude.py IN.mcap OUT.mcap [--bias-clip DEG_PER_S]

VQF (Laidig & Seel 2023, the `vqf` package, its defaults but --bias-clip, °/s) runs causally on
IN's /imu/data (the raw gyro and accelerometer, dt = the median interval of the header stamps).
OUT gets every message of IN, and on /imu/denoised one sensor_msgs/Imu per IMU sample: the
same stamp and frame, the raw rates, and VQF's 6D quaternion (world from body, heading from
where it started) right after that sample's update. VQF states no covariance: the one written
is 1 rad² on each axis, so `attitude`'s NEES columns say nothing for these rows (its tilt and
heading figures do). Run with the project's venv ($PYTHON from scripts/env.sh).
"""
import argparse
import os
import sys

import numpy as np
import vqf
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from rotate_imu_bag import plain
from vqf_bias import IMU, fail, read_imu

OUT_TOPIC = '/imu/denoised'


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('src', metavar='IN.mcap')
    p.add_argument('dst', metavar='OUT.mcap')
    p.add_argument('--bias-clip', type=float, default=2.0, metavar='DEG_PER_S', help="VQF's biasClip in °/s (default 2)")
    a = p.parse_args()
    if not os.path.isfile(a.src):
        fail(f'{a.src}: no such file')
    if os.path.realpath(a.src) == os.path.realpath(a.dst):
        fail('the output must not be the input')
    stamps, gyr, acc = read_imu(a.src)
    if len(stamps) < 2:
        fail(f'{a.src}: fewer than two {IMU} messages')
    dt = float(np.median(np.diff(stamps))) * 1e-9
    f = vqf.VQF(dt, dt, biasClip=a.bias_clip)
    quats = np.empty((len(gyr), 4))
    for i in range(len(gyr)):
        f.update(np.ascontiguousarray(gyr[i]), np.ascontiguousarray(acc[i]))
        quats[i] = f.getQuat6D()
    part = a.dst + '.part'
    try:
        with open(a.src, 'rb') as fi, open(part, 'wb') as g:
            writer = Writer(g)
            schemas = {}
            i = 0
            for schema, channel, message, decoded in make_reader(fi, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                if schema.name not in schemas:
                    schemas[schema.name] = writer.register_msgdef(schema.name, schema.data.decode())
                d = plain(decoded)
                writer.write_message(channel.topic, schemas[schema.name], d, log_time=message.log_time, publish_time=message.publish_time)
                if channel.topic == IMU:
                    w, x, y, z = map(float, quats[i])
                    d['orientation'] = {'x': x, 'y': y, 'z': z, 'w': w}
                    d['orientation_covariance'] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
                    writer.write_message(OUT_TOPIC, schemas[schema.name], d, log_time=message.log_time, publish_time=message.publish_time)
                    i += 1
            writer.finish()
        os.replace(part, a.dst)
    except BaseException as e:
        if os.path.exists(part):
            os.remove(part)
        if isinstance(e, OSError):
            fail(f'cannot write {a.dst}: {e}')
        raise
    print(f'vqf_attitude: {len(gyr)} samples, dt {dt:.6g} s', file=sys.stderr)


if __name__ == '__main__':
    main()
