#!/usr/bin/env python3
"""Rewrite a bag's /imu/data gyro with VQF's running gyro-bias estimate subtracted, causally.

usage: vqf_bias.py IN.mcap OUT.mcap [--bias-clip DEG_PER_S] [--rest-only]

VQF (Laidig & Seel 2023, the `vqf` package) runs sample by sample at dt = the median interval of
the IMU header stamps; each angular velocity ω becomes ω − b, b being VQF's bias estimate right after
that sample's update, so `imu-fsda eval OUT.mcap --method raw` scores "raw gyro minus VQF's running
bias". VQF's defaults apply, except --bias-clip (VQF's biasClip, °/s, default 2) and --rest-only
(motionBiasEstEnabled=False: bias estimated at rest only). Stamps, frame ids, covariances and
accelerations are kept exactly; every other message is copied as it is. The output is written to
OUT.part and renamed at the end. Run with the project's venv ($PYTHON from scripts/env.sh).
"""
import argparse
import os
import sys

import numpy as np
import vqf
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from rotate_imu_bag import plain  # the decoded message as plain dicts, for the writer

IMU = '/imu/data'


def vec(v):
    return np.array([v.x, v.y, v.z], float)


def fail(msg):
    print(f'error: {msg}', file=sys.stderr)
    sys.exit(2)


def read_imu(path):
    """Header stamps (ns), gyro and accel of every /imu/data message, in the bag's order."""
    stamps, gyr, acc = [], [], []
    with open(path, 'rb') as f:
        for _, _, _, m in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=[IMU]):
            stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
            gyr.append(vec(m.angular_velocity))
            acc.append(vec(m.linear_acceleration))
    return np.array(stamps, np.int64), np.array(gyr).reshape(-1, 3), np.array(acc).reshape(-1, 3)


def read_input(src, dst):
    """The IMU of `src` for a script that writes `dst`: a clear error (and exit 2) for a missing or
    unreadable bag, fewer than two samples, or an output that would overwrite the input."""
    if not os.path.isfile(src):
        fail(f'{src}: no such file')
    if os.path.realpath(src) == os.path.realpath(dst):
        fail('the output must not be the input')
    try:
        stamps, gyr, acc = read_imu(src)
    except Exception as e:  # not an MCAP bag, or an undecodable one
        fail(f'{src}: cannot read as an MCAP ros2 bag ({type(e).__name__}: {e})')
    if len(stamps) < 2:
        fail(f'{src}: no {IMU} topic' if len(stamps) == 0 else f'{src}: only one {IMU} message')
    return stamps, gyr, acc


def write_orientations(src, dst, quats):
    """`src` to `dst` with one /imu/denoised per /imu/data message: the same sample and an
    estimator's quaternion quats[i] (w, x, y, z; world from body). The estimators compared this
    way state no covariance: 1 rad² on each axis is written (no NEES to read from it)."""
    def with_orientation(i, d):
        w, x, y, z = map(float, quats[i])
        denoised = dict(d, orientation={'x': x, 'y': y, 'z': z, 'w': w},
                        orientation_covariance=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
        return [(IMU, d), ('/imu/denoised', denoised)]

    rewrite_bag(src, dst, with_orientation, len(quats))


def rewrite_bag(src, dst, on_imu, n_imu):
    """Copies every message of `src` to `dst`, each /imu/data one (the i-th, as a plain dict)
    replaced by the (topic, message) pairs `on_imu(i, d)` returns (same schema, same times).
    Written to DST.part and renamed at the end; an error removes the part file."""
    part = dst + '.part'
    try:
        with open(src, 'rb') as fi, open(part, 'wb') as g:
            writer = Writer(g)
            schemas = {}
            i = 0
            for schema, channel, message, decoded in make_reader(fi, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                if schema.name not in schemas:
                    schemas[schema.name] = writer.register_msgdef(schema.name, schema.data.decode())
                d = plain(decoded)
                out = [(channel.topic, d)]
                if channel.topic == IMU:
                    out = on_imu(i, d)
                    i += 1
                for topic, m in out:
                    writer.write_message(topic, schemas[schema.name], m, log_time=message.log_time, publish_time=message.publish_time)
            writer.finish()
        assert i == n_imu
        os.replace(part, dst)
    except BaseException as e:
        if os.path.exists(part):
            os.remove(part)
        if isinstance(e, OSError):
            fail(f'cannot write {dst}: {e}')
        raise


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('src', metavar='IN.mcap')
    p.add_argument('dst', metavar='OUT.mcap')
    p.add_argument('--bias-clip', type=float, default=2.0, metavar='DEG_PER_S', help="VQF's biasClip in °/s (default 2)")
    p.add_argument('--rest-only', action='store_true', help='disable bias estimation during motion')
    a = p.parse_args()
    stamps, gyr, acc = read_input(a.src, a.dst)
    dt = float(np.median(np.diff(stamps))) * 1e-9
    if dt <= 0:
        fail(f'{a.src}: {IMU} stamps do not increase (median interval {dt} s)')

    f = vqf.VQF(dt, dt, biasClip=a.bias_clip, motionBiasEstEnabled=False if a.rest_only else None)
    out = np.empty_like(gyr)
    rest = np.zeros(len(gyr), bool)
    for i in range(len(gyr)):
        f.update(np.ascontiguousarray(gyr[i]), np.ascontiguousarray(acc[i]))
        bias, sigma = f.getBiasEstimate()
        out[i] = gyr[i] - bias
        rest[i] = f.getRestDetected()

    def with_bias_removed(i, d):
        st = d['header']['stamp']
        assert st['sec'] * 10**9 + st['nanosec'] == stamps[i], 'IMU messages out of step between the two passes'
        d['angular_velocity'] = dict(zip('xyz', map(float, out[i])))
        return [(IMU, d)]

    rewrite_bag(a.src, a.dst, with_bias_removed, len(stamps))

    print(f'vqf_bias: {len(gyr)} samples, dt {dt:.6g} s, final bias [{bias[0]:.6e}, {bias[1]:.6e}, {bias[2]:.6e}] rad/s, '
          f'sigma {sigma:.3e} rad/s, rest detected: {"yes" if rest.any() else "no"} ({rest.mean():.3f} of samples at rest)',
          file=sys.stderr)


if __name__ == '__main__':
    main()
