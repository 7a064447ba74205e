"""Independent computation of the orientation metrics, straight from the ASL CSV files.

Written apart from the Rust code (numpy, rotation matrices instead of quaternions for the
integration) so that `imu-fsda import` + `imu-fsda eval` can be checked against it.
Usage: independent_eval.py SEQUENCE_DIR [--bias bx by bz | --oracle-bias]  → JSON on stdout.
--oracle-bias removes the mean of (gyro − ground-truth rate) over consecutive covered samples.
"""
import argparse
import json
import sys

import numpy as np


def load(path, names):
    with open(path) as f:
        header = [h.strip().lstrip("#").strip().split(" ")[0].split("[")[0] for h in f.readline().split(",")]
    data = np.loadtxt(path, delimiter=",", comments="#")
    # stamps as exact integers: float64 would round 19-digit ns stamps by ~256 ns
    stamps = np.loadtxt(path, delimiter=",", comments="#", usecols=0, dtype=np.int64)
    idx = [header.index(n) for n in names]
    return stamps, data[:, idx]


def quat_to_mat(q):  # q = [w, x, y, z], normalised here
    q = q / np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rodrigues(phi):
    th = np.linalg.norm(phi)
    K = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K


def angle(R):
    return np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))


def slerp_mat(Ra, Rb, s):
    D = Ra.T @ Rb
    th = angle(D)
    if th < 1e-12:
        return Ra
    # axis from the skew part
    axis = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / (2 * np.sin(th))
    return Ra @ rodrigues(axis * th * s)


def log_mat(D):
    th = angle(D)
    v = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / 2
    return v if th < 1e-9 else v * th / np.sin(th)


def zyx(R):
    return np.array([np.arctan2(R[2, 1], R[2, 2]), np.arcsin(np.clip(-R[2, 0], -1, 1)), np.arctan2(R[1, 0], R[0, 0])])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("seq")
    ap.add_argument("--bias", nargs=3, type=float, default=[0.0, 0.0, 0.0])
    ap.add_argument("--oracle-bias", action="store_true")
    ap.add_argument("--max-gap-ms", type=float, default=50.0)
    a = ap.parse_args()
    import os
    mav0 = os.path.join(a.seq, "mav0")
    gt_path = os.path.join(mav0, "state_groundtruth_estimate0", "data.csv")
    if not os.path.exists(gt_path):
        gt_path = os.path.join(mav0, "mocap0", "data.csv")
    t_imu, imu = load(os.path.join(mav0, "imu0", "data.csv"), ["w_RS_S_x", "w_RS_S_y", "w_RS_S_z"])
    t_gt, q = load(gt_path, ["q_RS_w", "q_RS_x", "q_RS_y", "q_RS_z"])
    max_gap = int(a.max_gap_ms * 1e6)
    # ground truth at each IMU stamp, or None inside a gap / outside the span
    j = np.searchsorted(t_gt, t_imu, side="right") - 1
    gt = []
    for k, t in enumerate(t_imu):
        jj = j[k]
        if jj < 0:
            gt.append(None)
        elif t_gt[jj] == t:
            gt.append(quat_to_mat(q[jj]))
        elif jj + 1 < len(t_gt) and t_gt[jj + 1] - t_gt[jj] <= max_gap:
            s = (t - t_gt[jj]) / (t_gt[jj + 1] - t_gt[jj])
            gt.append(slerp_mat(quat_to_mat(q[jj]), quat_to_mat(q[jj + 1]), s))
        else:
            gt.append(None)
    bias = np.array(a.bias)
    if a.oracle_bias:
        errs = [imu[k] - log_mat(gt[k].T @ gt[k + 1]) / ((t_imu[k + 1] - t_imu[k]) * 1e-9)
                for k in range(len(t_imu) - 1) if gt[k] is not None and gt[k + 1] is not None]
        bias = np.mean(errs, axis=0)
    gyro = imu - bias
    start = next(k for k, g in enumerate(gt) if g is not None)
    R = gt[start].copy()
    sq, sq_e, n = 0.0, np.zeros(3), 0
    for k in range(start, len(t_imu)):
        if gt[k] is not None:
            th = angle(gt[k].T @ R)
            d = zyx(R) - zyx(gt[k])
            d = (d + np.pi) % (2 * np.pi) - np.pi
            sq += th * th
            sq_e += d * d
            n += 1
        if k + 1 < len(t_imu):
            dt = (t_imu[k + 1] - t_imu[k]) * 1e-9
            R = R @ rodrigues(gyro[k] * dt)
            u, _, vt = np.linalg.svd(R)
            R = u @ vt
    rms = lambda s: float(np.degrees(np.sqrt(s / n)))
    json.dump({"aoe_deg": rms(sq), "roll_rmse_deg": rms(sq_e[0]), "pitch_rmse_deg": rms(sq_e[1]), "yaw_rmse_deg": rms(sq_e[2]), "evaluated_samples": n, "bias": bias.tolist()}, sys.stdout)


if __name__ == "__main__":
    main()
