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
import sys

import numpy as np
import vqf
from vqf_bias import read_input, write_orientations


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('src', metavar='IN.mcap')
    p.add_argument('dst', metavar='OUT.mcap')
    p.add_argument('--bias-clip', type=float, default=2.0, metavar='DEG_PER_S', help="VQF's biasClip in °/s (default 2)")
    a = p.parse_args()
    stamps, gyr, acc = read_input(a.src, a.dst)
    dt = float(np.median(np.diff(stamps))) * 1e-9
    f = vqf.VQF(dt, dt, biasClip=a.bias_clip)
    quats = np.empty((len(gyr), 4))
    for i in range(len(gyr)):
        f.update(np.ascontiguousarray(gyr[i]), np.ascontiguousarray(acc[i]))
        quats[i] = f.getQuat6D()
    write_orientations(a.src, a.dst, quats)
    print(f'vqf_attitude: {len(gyr)} samples, dt {dt:.6g} s', file=sys.stderr)


if __name__ == '__main__':
    main()
