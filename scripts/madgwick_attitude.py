#!/usr/bin/env python3
"""Madgwick's IMU filter on a bag's raw IMU, as a bag `imu-fsda attitude` scores.

usage: madgwick_attitude.py IN.mcap OUT.mcap [--gain BETA]

The algorithm of ROS's imu_filter_madgwick without a magnetometer (Madgwick 2010, the IMU
update: a gradient-descent step of gain β towards the accelerometer's gravity, added to the
gyro's rate of change of the quaternion; imu_filter_madgwick's defaults: gain 0.1, zeta 0, ENU,
the start from the first specific force with heading 0), written here from the paper's
equations, run causally on IN's /imu/data (dt from the header stamps). OUT gets every message
of IN, and on /imu/denoised one sensor_msgs/Imu per IMU sample with the filter's quaternion
(world from body) after that sample. Madgwick states no covariance: 1 rad² on each axis is
written, so `attitude`'s NEES columns say nothing for these rows. Run with the project's venv.
"""
import argparse
import sys

import numpy as np
from vqf_bias import read_input, write_orientations


def quat_mul(p, q):
    w0, x0, y0, z0 = p
    w1, x1, y1, z1 = q
    return np.array([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1,
                     w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1,
                     w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])


def from_gravity(a):
    """World-from-body with heading 0 whose body z is along the specific force `a`."""
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)  # rotates body `a` onto world z
    c = float(np.dot(a, z))
    q = np.array([1.0 + c, v[0], v[1], v[2]])
    n = np.linalg.norm(q)
    return q / n if n > 1e-9 else np.array([0.0, 1.0, 0.0, 0.0])


def madgwick_step(q, w, a, beta, dt):
    """One IMU update (Madgwick 2010, eqs. 25-33): q world-from-body (w, x, y, z)."""
    q_dot = 0.5 * quat_mul(q, np.array([0.0, *w]))
    n = np.linalg.norm(a)
    if n > 0.0:
        ax, ay, az = a / n
        q0, q1, q2, q3 = q
        # f: the body-frame gravity q* (0,0,1) q minus the measured direction; J its Jacobian.
        f = np.array([2 * (q1 * q3 - q0 * q2) - ax,
                      2 * (q0 * q1 + q2 * q3) - ay,
                      2 * (0.5 - q1 * q1 - q2 * q2) - az])
        j = np.array([[-2 * q2, 2 * q3, -2 * q0, 2 * q1],
                      [2 * q1, 2 * q0, 2 * q3, 2 * q2],
                      [0.0, -4 * q1, -4 * q2, 0.0]])
        step = j.T @ f
        sn = np.linalg.norm(step)
        if sn > 0.0:
            q_dot = q_dot - beta * step / sn
    q = q + q_dot * dt
    return q / np.linalg.norm(q)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('src', metavar='IN.mcap')
    p.add_argument('dst', metavar='OUT.mcap')
    p.add_argument('--gain', type=float, default=0.1, help="β (imu_filter_madgwick's `gain`, default 0.1)")
    a = p.parse_args()
    stamps, gyr, acc = read_input(a.src, a.dst)
    quats = np.empty((len(gyr), 4))
    q = from_gravity(np.asarray(acc[0], dtype=float))
    quats[0] = q
    for i in range(1, len(gyr)):
        dt = (stamps[i] - stamps[i - 1]) * 1e-9
        if 0.0 < dt < 0.1:  # a gap is held, as the node holds it
            q = madgwick_step(q, np.asarray(gyr[i], dtype=float), np.asarray(acc[i], dtype=float), a.gain, dt)
        quats[i] = q

    write_orientations(a.src, a.dst, quats)
    print(f'madgwick_attitude: {len(gyr)} samples, gain {a.gain}', file=sys.stderr)


if __name__ == '__main__':
    main()
