"""Independent computation of `imu-fsda attitude`'s figures from a replayed bag.

Written apart from the Rust code: the bag is read with rosbags (its own CDR decoder and the ROS 2
Humble types), rotations are matrices, the ground truth is interpolated by normalised linear
interpolation of quaternions (within 1e-7 rad of a slerp between poses 10 ms apart), tilt and
heading come from the error matrix's z column and its remaining turn about z.
Usage: independent_attitude.py BAG [--topic /imu/denoised] [--ground-truth-topic /ground_truth/pose]
→ JSON on stdout.
"""
import argparse
import json
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

MAX_GAP_NS = 50_000_000
CHI2_2DOF_95 = 5.991


def quat_to_mat(w, x, y, z):
    q = np.array([w, x, y, z], dtype=float)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def stamp_ns(header):
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def read(path, topic, gt_topic):
    gt, published, first = [], [], None
    with AnyReader([Path(path)]) as reader:
        conns = [c for c in reader.connections if c.topic in (topic, gt_topic)]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == gt_topic:
                o = msg.pose.orientation
                gt.append((stamp_ns(msg.header), np.array([o.w, o.x, o.y, o.z])))
            else:
                t = stamp_ns(msg.header)
                first = t if first is None else first
                cov = np.asarray(msg.orientation_covariance, dtype=float).reshape(3, 3)
                if cov[0, 0] != -1.0:
                    o = msg.orientation
                    published.append((t, quat_to_mat(o.w, o.x, o.y, o.z), cov))
    return gt, published, first


def gt_at(gt, t):
    stamps = [g[0] for g in gt]
    i = np.searchsorted(stamps, t)
    if i < len(gt) and stamps[i] == t:
        return quat_to_mat(*gt[i][1])
    if i == 0 or i == len(gt) or stamps[i] - stamps[i - 1] > MAX_GAP_NS:
        return None
    a, b = gt[i - 1][1], gt[i][1]
    if np.dot(a, b) < 0:
        b = -b
    s = (t - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
    return quat_to_mat(*((1 - s) * a + s * b))


def tilt_heading(E):
    """Swing off z (as a rotation vector) and the turn about z left once it is taken off."""
    z = np.array([0.0, 0.0, 1.0])
    ez = E[:, 2]
    angle = np.arccos(np.clip(ez @ z, -1.0, 1.0))
    axis = np.cross(z, ez)
    n = np.linalg.norm(axis)
    swing = axis / n * angle if n > 1e-15 else np.zeros(3)
    th = np.linalg.norm(swing)
    if th > 1e-15:
        K = np.array([[0, -swing[2], swing[1]], [swing[2], 0, -swing[0]], [-swing[1], swing[0], 0]]) / th
        S = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    else:
        S = np.eye(3)
    T = S.T @ E
    return swing, np.arctan2(T[1, 0], T[0, 0])


def main():
    p = argparse.ArgumentParser()
    p.add_argument("bag")
    p.add_argument("--topic", default="/imu/denoised")
    p.add_argument("--ground-truth-topic", default="/ground_truth/pose")
    args = p.parse_args()
    gt, published, first = read(args.bag, args.topic, args.ground_truth_topic)
    rows = [(t, R, P, gt_at(gt, t)) for t, R, P in published]
    covered = [r for r in rows if r[3] is not None]
    t0, R0, _, G0 = covered[0]
    _, h0 = tilt_heading(R0 @ G0.T)
    A = rot_z(-h0)
    tilts, headings, angles, nees = [], [], [], []
    for t, R, P, G in covered:
        E = A @ R @ G.T
        swing, heading = tilt_heading(E)
        angles.append(np.arccos(np.clip((np.trace(E) - 1.0) / 2.0, -1.0, 1.0)))
        tilts.append(np.linalg.norm(swing))
        headings.append(heading)
        Pa = (A @ P @ A.T)[:2, :2]
        e = swing[:2]
        nees.append(float(e @ np.linalg.solve(Pa, e)))
    tilts, headings, nees = np.degrees(tilts), np.degrees(np.abs(headings)), np.array(nees)
    out = {
        "first_attitude_s": (published[0][0] - first) * 1e-9,
        "evaluated": len(covered),
        "seconds": (covered[-1][0] - t0) * 1e-9,
        "tilt_initial_deg": float(tilts[0]),
        "tilt_rmse_deg": float(np.sqrt(np.mean(tilts**2))),
        "tilt_max_deg": float(tilts.max()),
        "heading_rmse_deg": float(np.sqrt(np.mean(headings**2))),
        "heading_final_deg": float(headings[-1]),
        "aoe_deg": float(np.degrees(np.sqrt(np.mean(np.square(angles))))),
        "tilt_nees_mean": float(nees.mean()),
        "tilt_within_95": float(np.mean(nees <= CHI2_2DOF_95)),
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
