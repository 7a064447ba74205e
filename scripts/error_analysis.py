#!/usr/bin/env python3
"""How much of a gyro's open-loop orientation error a constant bias explains, on bags with ground
truth (docs/results.md). The other analyses of docs/log/2026-11-training-experiments.md are in
this file's history (before 2026-12-06).

Run with the project's venv (scripts/env.sh: $PYTHON has numpy, torch and mcap):

  error_analysis.py floors BAG...      per recording, the AOE of the raw gyro after the constant
                                       bias, and after the bias and a 3x3 matrix, fitted to that
                                       very recording (an oracle: it reads the ground truth)
  error_analysis.py transfer --train BAG... --test BAG...
                                       how far a constant learned from other recordings goes: each
                                       bag's constant fitted as in `floors`, and each --test bag
                                       scored after the mean constant of the --train bags of its
                                       session (the file name before its first '_', or without its
                                       trailing digits: MH_02_easy -> MH, room2 -> room) and after
                                       its own constant (give one IMU's bags per run). The
                                       session mean is the most a model could know that identifies
                                       the session from the data but not the recording

The fits minimise the squared SO(3) residual Log(dR_gt^T dR) over non-overlapping increments
of J samples (default 1024, 5.1 s at 200 Hz), the quantity whose drift the AOE integrates;
least squares on the rate (`imu-fsda eval --oracle-bias`) is not AOE-optimal on mocap ground
truth. AOE here is the project's metric (docs/results.md): open loop from the ground-truth
attitude at the first covered IMU sample, real dt, ground truth slerped at the IMU stamps and
never across a gap longer than 50 ms. Degrees.
"""
import argparse
import os

import numpy as np
import torch
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

MAX_GAP_NS = 50_000_000
NEAREST_NS = 10_000_000


def read_bag(path, topics=("/imu/data", "/imu/denoised", "/ground_truth/pose")):
    """Stamped rows per topic: IMU (t, wx, wy, wz, ax, ay, az), poses (t, qw, qx, qy, qz)."""
    out = {t: [] for t in topics}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=list(topics)):
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if channel.topic == "/ground_truth/pose":
                q = msg.pose.orientation
                out[channel.topic].append((stamp, q.w, q.x, q.y, q.z))
            else:
                w, a = msg.angular_velocity, msg.linear_acceleration
                out[channel.topic].append((stamp, w.x, w.y, w.z, a.x, a.y, a.z))
    return {k: np.array(sorted(v), dtype=np.float64) for k, v in out.items() if v}


def quat_to_mat(q):
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def slerp(q0, q1, u):
    d = np.sum(q0 * q1, 1)
    q1 = np.where(d[:, None] < 0, -q1, q1)
    d = np.abs(d)
    th = np.arccos(np.clip(d, -1, 1))
    s = np.sin(th)
    small = s < 1e-9
    a = np.where(small, 1 - u, np.sin((1 - u) * th) / np.where(small, 1, s))
    b = np.where(small, u, np.sin(u * th) / np.where(small, 1, s))
    q = a[:, None] * q0 + b[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def gt_at_imu(t_imu, gt):
    """Ground-truth rotation matrices at the IMU stamps, `covered` (inside a pose gap of at most
    50 ms: scored) and `near` (covered and a pose within 10 ms: used in the fits)."""
    tg, qg = gt[:, 0], gt[:, 1:5]
    j = np.clip(np.searchsorted(tg, t_imu), 1, len(tg) - 1)
    gap = tg[j] - tg[j - 1]
    covered = (t_imu >= tg[0]) & (t_imu <= tg[-1]) & (gap <= MAX_GAP_NS)
    near = covered & (np.minimum(np.abs(t_imu - tg[j - 1]), np.abs(tg[j] - t_imu)) <= NEAREST_NS)
    u = np.clip((t_imu - tg[j - 1]) / np.maximum(gap, 1), 0, 1)
    return quat_to_mat(slerp(qg[j - 1], qg[j], u)), covered, near


def so3_exp(v):
    th = torch.linalg.norm(v, dim=-1, keepdim=True)
    k = v / th.clamp_min(1e-12)
    kx = torch.zeros(v.shape[:-1] + (3, 3), dtype=v.dtype)
    kx[..., 0, 1], kx[..., 0, 2], kx[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    kx = kx - kx.transpose(-1, -2)
    th = th[..., None]
    return torch.eye(3, dtype=v.dtype) + torch.sin(th) * kx + (1 - torch.cos(th)) * (kx @ kx)


def so3_log(r):
    c = ((r.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1 + 1e-12, 1 - 1e-12)
    th = torch.acos(c)
    v = torch.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0], r[..., 1, 0] - r[..., 0, 1]], -1)
    return v * (th / (2 * torch.sin(th)).clamp_min(1e-12))[..., None]


def aoe_deg(t_imu, gyro, gt):
    """The project's AOE of `gyro` (N x 3, rad/s) against `gt`."""
    rg, covered, _ = gt_at_imu(t_imu, gt)
    first = int(np.argmax(covered))
    steps = so3_exp(torch.tensor(gyro[first:-1] * (np.diff(t_imu[first:]) * 1e-9)[:, None])).numpy()
    # The attitude chain is sequential; the error's Log is taken once over all scored samples.
    r = np.empty((len(t_imu) - first, 3, 3))
    r[0] = rg[first]
    for k in range(1, len(r)):
        r[k] = r[k - 1] @ steps[k - 1]
    e = np.einsum("nji,njk->nik", rg[first:], r)[covered[first:]]
    errs = torch.linalg.norm(so3_log(torch.tensor(e)), dim=-1).numpy()
    return float(np.degrees(np.sqrt(np.mean(np.square(errs)))))


class Increments:
    """Non-overlapping J-sample increments of one recording with their ground truth."""

    def __init__(self, t_imu, gyro, gt, j):
        rg, _, near = gt_at_imu(t_imu, gt)
        dt = np.diff(t_imu) * 1e-9
        m = (len(t_imu) - 1) // j
        starts = np.arange(m) * j
        self.valid = torch.tensor([near[s : s + j + 1].all() for s in starts])
        self.d_gt = torch.tensor(np.einsum("nji,njk->nik", rg[starts], rg[starts + j]))
        self.gyro = torch.tensor(gyro[: m * j])
        self.dt = torch.tensor(dt[: m * j])
        self.m, self.j = m, j

    def residual(self, gyro):
        e = so3_exp(gyro * self.dt[:, None]).reshape(self.m, self.j, 3, 3)
        while e.shape[1] > 1:  # product over each increment, pairwise
            if e.shape[1] % 2:
                e = torch.cat([e, torch.eye(3, dtype=e.dtype).expand(self.m, 1, 3, 3)], 1)
            e = e[:, 0::2] @ e[:, 1::2]
        return so3_log(self.d_gt.transpose(1, 2) @ e[:, 0])[self.valid]


def fit_calibration(inc, with_matrix, steps=600):
    """Bias b (and 3x3 M) minimising the squared increment residuals of M w + b."""
    # Start from the rate-level least-squares bias, so a large bias (EuRoC: 0.08 rad/s) is not
    # left to the optimiser.
    b0 = torch.zeros(3, dtype=torch.float64)
    with torch.no_grad():
        for _ in range(3):
            r = inc.residual(inc.gyro + b0)
            b0 = b0 - r.mean(0) / float(inc.dt[: inc.j].sum())
    b = b0.clone().requires_grad_(True)
    a = torch.zeros(3, 3, dtype=torch.float64, requires_grad=with_matrix)
    opt = torch.optim.Adam([b, a] if with_matrix else [b], lr=2e-5)
    for _ in range(steps):
        opt.zero_grad()
        loss = inc.residual(inc.gyro @ (torch.eye(3, dtype=torch.float64) + a).T + b).square().sum(-1).mean()
        loss.backward()
        opt.step()
    return (torch.eye(3, dtype=torch.float64) + a).detach().numpy(), b.detach().numpy()


def floors(args):
    print("| bag | raw AOE | − fitted constant | − fitted constant and matrix | constant, rad/s |")
    print("|---|---|---|---|---|")
    for path in args.bags:
        d = read_bag(path, ("/imu/data", "/ground_truth/pose"))
        imu, gt = d["/imu/data"], d["/ground_truth/pose"]
        t, w = imu[:, 0], imu[:, 1:4]
        inc = Increments(t, w, gt, args.increment)
        _, b = fit_calibration(inc, False)
        m, bm = fit_calibration(inc, True)
        name = os.path.splitext(os.path.basename(path))[0]
        print(
            f"| {name} | {aoe_deg(t, w, gt):.2f} | {aoe_deg(t, w + b, gt):.2f} | {aoe_deg(t, w @ m.T + bm, gt):.2f} "
            f"| [{b[0]:.5f}, {b[1]:.5f}, {b[2]:.5f}] |",
            flush=True,
        )


def session_of(name):
    return name.split("_")[0] if "_" in name else name.rstrip("0123456789")


def transfer(args):
    def constants(paths):
        out = {}
        for path in paths:
            d = read_bag(path, ("/imu/data", "/ground_truth/pose"))
            imu, gt = d["/imu/data"], d["/ground_truth/pose"]
            name = os.path.splitext(os.path.basename(path))[0]
            out[name] = (imu[:, 0], imu[:, 1:4], gt, fit_calibration(Increments(imu[:, 0], imu[:, 1:4], gt, args.increment), False)[1])
        return out

    train, test = constants(args.train), constants(args.test)
    print("| bag | session | raw | − its session's training mean | − its own constant | session mean − own, mrad/s |")
    print("|---|---|---|---|---|---|")
    rows = []
    for name, (t, w, gt, own) in test.items():
        mates = [c[3] for n, c in train.items() if session_of(n) == session_of(name)]
        if not mates:
            print(f"| {name} | {session_of(name)} | no training recording of this session | | | |")
            continue
        session = np.mean(mates, 0)
        row = [aoe_deg(t, w, gt), aoe_deg(t, w + session, gt), aoe_deg(t, w + own, gt)]
        rows.append(row)
        print(
            f"| {name} | {session_of(name)} ({len(mates)}) | " + " | ".join(f"{x:.2f}" for x in row)
            + f" | {np.round((session - own) * 1e3, 2).tolist()} |",
            flush=True,
        )
    if rows:
        print("| mean | | " + " | ".join(f"{x:.2f}" for x in np.mean(rows, 0)) + " | |")


def main():
    torch.set_num_threads(1)
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("floors")
    f.add_argument("bags", nargs="+")
    f.add_argument("--increment", type=int, default=1024, help="J, samples")
    f.set_defaults(run=floors)
    t = sub.add_parser("transfer")
    t.add_argument("--train", nargs="+", required=True)
    t.add_argument("--test", nargs="+", required=True)
    t.add_argument("--increment", type=int, default=1024, help="J, samples")
    t.set_defaults(run=transfer)
    args = p.parse_args()
    args.run(args)


if __name__ == "__main__":
    main()
