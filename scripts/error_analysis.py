#!/usr/bin/env python3
"""Where a gyro's open-loop orientation error comes from, on bags with ground truth.

Run with the project's venv (scripts/env.sh: $PYTHON has numpy, torch and mcap):

  error_analysis.py floors BAG...      per recording, the AOE of the raw gyro after the constant
                                       bias, and after the bias and a 3x3 matrix, fitted to that
                                       very recording (an oracle: it reads the ground truth)
  error_analysis.py decompose BAG...   for bags written by `imu-fsda replay` (/imu/data and
                                       /imu/denoised): the model's correction c = denoised - raw
                                       split into its recording mean and the rest, scored as
                                       raw + mean(c) + a (c - mean(c)) and raw + a c for a few a
  error_analysis.py postfilter BAG...  for bags written by `imu-fsda replay`: causal filters a node could
                                       run after the model, scored beside the model alone: the
                                       correction c low-passed (raw + EMA_tau(c)), a gravity-aided
                                       bias observer on the denoised rate (Mahony-style: the
                                       accelerometer's direction against the integrated attitude's
                                       gravity, integral gain ki, proportional gain kp; only the
                                       bias estimate reaches the scored rate), and the model's own
                                       output over the initial rest subtracted (a zero-rate update)
  error_analysis.py insobserver BAG... for bags written by `imu-fsda replay`: the denoised rate minus the
                                       gyro bias of an error-state INS filter (attitude, velocity,
                                       gyro and accelerometer biases) whose only measurement is a
                                       bounded-motion prior, velocity 0 +- SIGMA_V every PERIOD s:
                                       a platform that stays in a room cannot keep accelerating,
                                       so a tilt error shows as velocity drift. Heading is not
                                       observable from gravity: neither the heading error nor the
                                       bias along the body's up axis is updated. Only the bias
                                       estimate reaches the scored rate. --raw BAG... filters
                                       imported bags' raw gyro minus --offset instead
  error_analysis.py ensemble DIR...    for folders of bags written by `imu-fsda replay` with different models
                                       (same file names): each model's AOE and that of the mean of their
                                       /imu/denoised (an output ensemble), per recording
  error_analysis.py supportbias BAG... for bags written by `imu-fsda replay`: the model's constant error fitted
                                       on the first S s (the paper's support set, ground truth read there
                                       only) and removed; AOE over the whole recording and over the query
                                       (after S, from the ground truth at S) before and after, and a
                                       two-fold check on the support alone (fit on one half, score the other)
  error_analysis.py transfer --train BAG... --test BAG...
                                       how far a constant learned from other recordings goes: each
                                       bag's constant fitted as in `floors`, and each --test bag
                                       scored after the mean constant of the --train bags of its
                                       session (the file name before its first '_', or without its
                                       trailing digits: MH_02_easy -> MH, room2 -> room) and after
                                       its own constant (give one IMU's bags per run). The
                                       session mean is the most a model could know that identifies
                                       the session from the data but not the recording
  error_analysis.py longmean BAG...    whether a long running mean of the raw gyro could carry a
                                       recording's constant bias into a model: per bag, its own
                                       constant (fitted as in `floors`) and the mean true body
                                       rate over the first S s and the whole recording (the
                                       raw mean's error as a bias estimate), mrad/s
  error_analysis.py gtbias SEQ_DIR...  EuRoC sequence folders whose ground-truth file carries the
                                       estimator's gyro bias (b_w_RS_S_*, read by header name):
                                       its mean over the first, middle and last S s and its
                                       spread inside the recording, mrad/s (how constant a
                                       recording's bias is, and how far apart recordings are)
  error_analysis.py probe --positive PATTERN --train BAG... --test BAG...
                                       whether a window of raw IMU tells which recordings it
                                       comes from: a logistic regression on the log band powers
                                       of 512-sample windows (and their mean accelerometer),
                                       trained to tell the --train bags whose file name contains
                                       PATTERN from the others; prints each --test bag's mean
                                       probability of being one of them

The fits minimise the squared SO(3) residual Log(dR_gt^T dR) over non-overlapping increments
of J samples (default 1024, 5.1 s at 200 Hz), the quantity whose drift the AOE integrates;
least squares on the rate (`imu-fsda eval --oracle-bias`) is not AOE-optimal on mocap ground
truth. AOE here is the project's metric (docs/results.md): open loop from the ground-truth
attitude at the first covered IMU sample, real dt, ground truth slerped at the IMU stamps and
never across a gap longer than 50 ms. Degrees.
"""
import argparse
import os
import sys

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


def static_rest(w, a, max_gyro_span=0.02, max_acc_span=0.2, max_samples=2000):
    """Samples of the initial rest by `eval`'s static-bias rule (200 Hz): consecutive 0.5-s
    windows from the start whose 0.1-s block means span < 0.02 rad/s (gyro) and < 0.2 m/s²
    (accelerometer) with |mean a| within 0.5 m/s² of 9.81, up to 10 s."""
    k = 0
    while k + 100 <= min(len(w), max_samples):
        bw, ba = w[k : k + 100].reshape(5, 20, 3).mean(1), a[k : k + 100].reshape(5, 20, 3).mean(1)
        if (np.ptp(bw, 0).max() < max_gyro_span and np.ptp(ba, 0).max() < max_acc_span
                and abs(np.linalg.norm(ba.mean(0)) - 9.81) < 0.5):
            k += 100
        else:
            break
    return k


def restshift(args):
    """Each recording's flight constant (least squares on J-sample increments) against its
    initial rest mean; the test recordings scored after their rest mean plus the training
    recordings' mean flight-minus-rest shift."""
    def load(paths):
        out = {}
        for path in paths:
            d = read_bag(path, ("/imu/data", "/ground_truth/pose"))
            imu, gt = d["/imu/data"], d["/ground_truth/pose"]
            t, w, a = imu[:, 0], imu[:, 1:4], imu[:, 4:7]
            flight = -fit_calibration(Increments(t, w, gt, args.increment), False)[1]
            k = static_rest(w, a)
            rest = w[:k].mean(0) if k >= 100 else None
            out[os.path.splitext(os.path.basename(path))[0]] = (t, w, gt, flight, rest, k)
        return out

    train, test = load(args.train), load(args.test)
    print("| bag | rest, s | flight − rest, mrad/s |")
    print("|---|---|---|")
    for name, (_, _, _, flight, rest, k) in {**train, **test}.items():
        shift = "–" if rest is None else str(np.round((flight - rest) * 1e3, 2).tolist())
        print(f"| {name} | {k / 200:.1f} | {shift} |")
    shifts = [f - r for (_, _, _, f, r, _) in train.values() if r is not None]
    if not shifts:
        print("no training recording has an initial rest")
        return
    mean = np.mean(shifts, 0)
    print(f"\ntraining mean shift {np.round(mean * 1e3, 2).tolist()} mrad/s over {len(shifts)} recordings "
          f"(std {np.round(np.std(shifts, 0) * 1e3, 2).tolist()})\n")
    print("| test | raw − rest mean | raw − (rest mean + shift) | raw − own constant (oracle) |")
    print("|---|---|---|---|")
    for name, (t, w, gt, flight, rest, _) in test.items():
        if rest is None:
            print(f"| {name} | no initial rest | | |")
            continue
        row = [aoe_deg(t, w - rest, gt), aoe_deg(t, w - rest - mean, gt), aoe_deg(t, w - flight, gt)]
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in row) + " |", flush=True)


def read_replayed(path):
    """Raw IMU, denoised IMU and poses of a bag written by `imu-fsda replay`, the two IMU topics
    checked to be stamp for stamp the same samples (the analyses pair them row by row)."""
    d = read_bag(path)
    for topic in ("/imu/data", "/imu/denoised", "/ground_truth/pose"):
        if topic not in d:
            sys.exit(f"{path}: no {topic} (write the bag with `imu-fsda replay` from an imported one)")
    raw, den = d["/imu/data"], d["/imu/denoised"]
    if raw.shape != den.shape or not np.array_equal(raw[:, 0], den[:, 0]):
        sys.exit(f"{path}: /imu/denoised ({len(den)} samples) is not stamp for stamp /imu/data ({len(raw)}): samples dropped in the replay?")
    return raw, den, d["/ground_truth/pose"]


def decompose(args):
    alphas = [float(a) for a in args.alphas.split(",")]
    head = " | ".join(f"mean + {a:g}·rest" for a in alphas) + " | " + " | ".join(f"{a:g}·c" for a in alphas)
    print(f"| bag | raw | model | {head} |")
    print("|---|---|---|" + "---|" * (2 * len(alphas)))
    for path in args.bags:
        raw, den, gt = read_replayed(path)
        t, w = raw[:, 0], raw[:, 1:4]
        c = den[:, 1:4] - w
        mean = c.mean(0)
        cells = [aoe_deg(t, w + mean + a * (c - mean), gt) for a in alphas] + [aoe_deg(t, w + a * c, gt) for a in alphas]
        name = os.path.splitext(os.path.basename(path))[0]
        print(f"| {name} | {aoe_deg(t, w, gt):.2f} | {aoe_deg(t, w + c, gt):.2f} | " + " | ".join(f"{x:.2f}" for x in cells) + " |", flush=True)


def ema(x, t, tau):
    """Causal exponential moving average of the rows of x, time constant tau seconds."""
    out = np.empty_like(x)
    acc = x[0].copy()
    dt = np.diff(t, prepend=t[0]) * 1e-9
    for k in range(len(x)):
        acc += min(dt[k] / tau, 1.0) * (x[k] - acc)
        out[k] = acc
    return out


def rodrigues(v):
    """Exp of one rotation vector (numpy; the per-sample loop below is too slow in torch)."""
    th = np.linalg.norm(v)
    kx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + kx
    return np.eye(3) + np.sin(th) / th * kx + (1 - np.cos(th)) / th**2 * (kx @ kx)


def gravity_observer(t, gyro, accel, r0, kp, ki, accel_tau=0.0):
    """The rate minus a Mahony-style bias estimate: the integrated attitude's 'up' in the body
    frame against the (optionally low-passed) accelerometer's direction; the integral gain
    drives the bias, the proportional one only the observer's own attitude."""
    b, r, out = np.zeros(3), r0.copy(), np.empty_like(gyro)
    af = accel[0].copy()
    up = np.array([0.0, 0.0, 1.0])
    for k in range(len(t)):
        out[k] = gyro[k] - b
        if k + 1 == len(t):
            break
        dt = (t[k + 1] - t[k]) * 1e-9
        af += (min(dt / accel_tau, 1.0) if accel_tau > 0 else 1.0) * (accel[k] - af)
        e = np.cross(af / np.linalg.norm(af), r.T @ up)
        b -= ki * e * dt
        r = r @ rodrigues((gyro[k] - b + kp * e) * dt)
    return out


def initial_rest(gyro, n=100, max_std=0.01):
    """Samples of the initial rest: from the start while every n-sample block's gyro std per
    axis stays below max_std rad/s (rotors off; none if the recording starts moving)."""
    k = 0
    while k + n <= len(gyro) and gyro[k : k + n].std(0).max() < max_std:
        k += n
    return k


def postfilter(args):
    taus = [float(x) for x in args.taus.split(",")]
    observers = [tuple(float(v) for v in o.split(":")) for o in args.observers.split(",")]
    head = [f"EMA {tau:g} s" for tau in taus] + [f"observer kp {o[0]:g} ki {o[1]:g}" + (f" LPF {o[2]:g} s" if len(o) > 2 else "") for o in observers]
    print("| bag | raw | model | " + " | ".join(head) + " | − model's rest mean |")
    print("|---|---|---|" + "---|" * (len(head) + 1))
    for path in args.bags:
        raw, den, gt = read_replayed(path)
        rg, covered, _ = gt_at_imu(raw[:, 0], gt)
        first = int(np.argmax(covered))
        t, w, a, wd = raw[first:, 0], raw[first:, 1:4], raw[first:, 4:7], den[first:, 1:4]
        cells = [aoe_deg(t, w + ema(wd - w, t, tau), gt) for tau in taus]
        cells += [aoe_deg(t, gravity_observer(t, wd, a, rg[first], *o), gt) for o in observers]
        rest = initial_rest(w)
        rest_cell = f"{aoe_deg(t, wd - wd[:rest].mean(0), gt):.2f} ({(t[rest - 1] - t[0]) * 1e-9:.1f} s)" if rest else "no rest"
        name = os.path.splitext(os.path.basename(path))[0]
        print(f"| {name} | {aoe_deg(t, w, gt):.2f} | {aoe_deg(t, wd, gt):.2f} | " + " | ".join(f"{x:.2f}" for x in cells) + f" | {rest_cell} |", flush=True)


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def ins_bias_observer(t, gyro, accel, sigma_v, period_s, sigma_bg0=3e-3, sigma_ba0=0.3, init_s=0.5):
    """The rate minus the gyro bias of a 12-state error-state INS filter (world-frame attitude
    error, velocity, gyro bias, accelerometer bias; z up) updated with v = 0 +- sigma_v every
    period_s seconds. Noise: the ADIS16448's order (ARW 2e-4 rad/s/sqrt(Hz), VRW 2e-3), biases
    nearly constant."""
    arw, vrw, bg_rw, ba_rw = 2e-4, 2e-3, 1e-6, 1e-4
    f0 = accel[: max(1, int(init_s * 200))].mean(0)
    zb = f0 / np.linalg.norm(f0)  # world up in the body frame (at rest or hovering)
    xb = np.cross([0.0, 1.0, 0.0], zb) if abs(zb[1]) < 0.9 else np.cross([1.0, 0.0, 0.0], zb)
    xb /= np.linalg.norm(xb)
    r = np.vstack([xb, np.cross(zb, xb), zb])  # body -> world, yaw arbitrary
    v, bg, ba = np.zeros(3), np.zeros(3), np.zeros(3)
    p = np.diag([2e-2**2] * 2 + [1.0] + [0.1**2] * 3 + [sigma_bg0**2] * 3 + [sigma_ba0**2] * 3)
    eye = np.eye(12)
    h = np.zeros((3, 12))
    h[:, 3:6] = np.eye(3)
    rm = np.eye(3) * sigma_v**2
    q_diag = np.array([arw**2] * 3 + [vrw**2] * 3 + [bg_rw**2] * 3 + [ba_rw**2] * 3)
    out = np.empty_like(gyro)
    next_update = t[0] + period_s * 1e9
    for k in range(len(t)):
        out[k] = gyro[k] - bg
        if k + 1 == len(t):
            break
        dt = (t[k + 1] - t[k]) * 1e-9
        fw = r @ (accel[k] - ba)
        f = np.zeros((12, 12))
        f[0:3, 6:9] = -r
        f[3:6, 0:3] = -skew(fw)
        f[3:6, 9:12] = -r
        phi = eye + f * dt
        p = phi @ p @ phi.T + np.diag(q_diag * dt)
        v = v + (fw - np.array([0.0, 0.0, 9.81])) * dt
        r = r @ rodrigues((gyro[k] - bg) * dt)
        if t[k + 1] >= next_update:
            next_update += period_s * 1e9
            gain = p @ h.T @ np.linalg.inv(h @ p @ h.T + rm)
            up = r.T @ np.array([0.0, 0.0, 1.0])
            gain[2, :] = 0.0  # heading: gravity says nothing about it
            gain[6:9, :] = (np.eye(3) - np.outer(up, up)) @ gain[6:9, :]
            dx = gain @ -v
            ikh = eye - gain @ h
            p = ikh @ p @ ikh.T + gain @ rm @ gain.T  # Joseph form: valid for the edited gain
            r = rodrigues(dx[0:3]) @ r
            v, bg, ba = v + dx[3:6], bg + dx[6:9], ba + dx[9:12]
    return out


def insobserver(args):
    print(f"| bag | input | input − INS bias (sigma_v {args.sigma_v:g} m/s every {args.period:g} s) | final bias, mrad/s |")
    print("|---|---|---|---|")
    before, after = [], []
    for path in args.bags:
        if args.raw:
            d = read_bag(path, ("/imu/data", "/ground_truth/pose"))
            imu, gt = d["/imu/data"], d["/ground_truth/pose"]
            rate = imu[:, 1:4] - np.array(args.offset)
        else:
            imu, den, gt = read_replayed(path)
            rate = den[:, 1:4]
        _, covered, _ = gt_at_imu(imu[:, 0], gt)
        first = int(np.argmax(covered))
        t, w, a = imu[first:, 0], rate[first:], imu[first:, 4:7]
        out = ins_bias_observer(t, w, a, args.sigma_v, args.period)
        before.append(aoe_deg(t, w, gt))
        after.append(aoe_deg(t, out, gt))
        name = os.path.splitext(os.path.basename(path))[0]
        print(f"| {name} | {before[-1]:.2f} | {after[-1]:.2f} | {np.round((w[-1] - out[-1]) * 1e3, 2).tolist()} |", flush=True)
    print(f"| mean | {np.mean(before):.2f} | {np.mean(after):.2f} | |")


def ensemble(args):
    names = sorted(set.intersection(*(set(f for f in os.listdir(d) if f.endswith(".mcap")) for d in args.dirs)))
    if not names:
        sys.exit("no bag file name is in every folder")
    members = [os.path.basename(os.path.normpath(d)) for d in args.dirs]
    print("| bag | " + " | ".join(members) + " | mean of the outputs |")
    print("|---|" + "---|" * (len(members) + 1))
    for name in names:
        runs = [read_replayed(os.path.join(d, name)) for d in args.dirs]
        raw, _, gt = runs[0]
        for other, _, _ in runs[1:]:
            if not np.array_equal(other[:, 0], raw[:, 0]):
                sys.exit(f"{name}: the replays do not hold the same samples")
        t = raw[:, 0]
        alone = [aoe_deg(t, den[:, 1:4], gt) for _, den, _ in runs]
        mean = aoe_deg(t, np.mean([den[:, 1:4] for _, den, _ in runs], axis=0), gt)
        print(f"| {os.path.splitext(name)[0]} | " + " | ".join(f"{x:.2f}" for x in alone) + f" | {mean:.2f} |", flush=True)


def supportbias(args):
    s = args.support_seconds
    print(f"| bag | whole: model → − support constant | query (after {s:g} s) | two-fold check on the support (fit one half, score the other) | constant, mrad/s |")
    print("|---|---|---|---|---|")
    for path in args.bags:
        raw, den, gt = read_replayed(path)
        t, w = raw[:, 0], den[:, 1:4]
        _, covered, _ = gt_at_imu(t, gt)
        t0 = t[int(np.argmax(covered))]

        def span(a, z):
            return (t >= t0 + a * 1e9) & (t < t0 + z * 1e9)

        def fit(m):
            inc = Increments(t[m], w[m], gt, args.increment)
            if int(inc.valid.sum()) < 3:
                sys.exit(f"{path}: {int(inc.valid.sum())} ground-truth-covered {args.increment}-sample increments in a span to fit, at least 3 needed (shorter --increment?)")
            return fit_calibration(inc, False)[1]

        support = span(-np.inf, s)
        query = ~support
        if query.sum() < 2:
            sys.exit(f"{path}: nothing after the first {s:g} s")
        b = fit(support)
        first, second = span(0, s / 2), span(s / 2, s)
        folds = [(second, fit(first)), (first, fit(second))]
        checks = [(aoe_deg(t[m], w[m], gt), aoe_deg(t[m], w[m] + bf, gt)) for m, bf in folds]
        passed = all(after < before for before, after in checks)
        name = os.path.splitext(os.path.basename(path))[0]
        print(
            f"| {name} | {aoe_deg(t, w, gt):.2f} → {aoe_deg(t, w + b, gt):.2f} | {aoe_deg(t[query], w[query], gt):.2f} → "
            f"{aoe_deg(t[query], w[query] + b, gt):.2f} | " + " ; ".join(f"{x:.2f} → {y:.2f}" for x, y in checks)
            + f" ({'passed' if passed else 'failed'}) | {np.round(b * 1e3, 2).tolist()} |",
            flush=True,
        )


def window_features(imu, n=512, bands=16):
    """Log band powers of every channel and the mean accelerometer, per n-sample window."""
    x = imu[:, 1:7]
    rows = []
    for start in range(0, len(x) - n, n):
        seg = x[start : start + n]
        p = np.abs(np.fft.rfft((seg - seg.mean(0)) * np.hanning(n)[:, None], axis=0)) ** 2
        power = np.stack([p[b].mean(0) for b in np.array_split(np.arange(1, p.shape[0]), bands)])
        rows.append(np.r_[np.log(power.ravel() + 1e-12), seg[:, 3:6].mean(0)])
    return np.array(rows)


def probe(args):
    def load(paths):
        feats, labels, names = [], [], []
        for path in paths:
            f = window_features(read_bag(path, ("/imu/data",))["/imu/data"])
            name = os.path.splitext(os.path.basename(path))[0]
            feats.append(f)
            labels += [float(args.positive in name)] * len(f)
            names += [name] * len(f)
        return np.vstack(feats), np.array(labels), np.array(names)

    x, y, _ = load(args.train)
    if y.min() == y.max():
        sys.exit(f"--train needs bags with and without {args.positive!r} in their name")
    mean, std = x.mean(0), x.std(0) + 1e-9
    x = (x - mean) / std
    w, b = np.zeros(x.shape[1]), 0.0
    for _ in range(3000):  # ridge-regularised logistic regression, plain gradient descent
        p = 1 / (1 + np.exp(-(x @ w + b)))
        w -= 0.5 * (x.T @ (p - y) / len(y) + 1e-2 * w)
        b -= 0.5 * (p - y).mean()
    xt, _, names = load(args.test)
    pt = 1 / (1 + np.exp(-(((xt - mean) / std) @ w + b)))
    print(f"| test bag | windows | mean P({args.positive}) |")
    print("|---|---|---|")
    for name in dict.fromkeys(names):
        print(f"| {name} | {(names == name).sum()} | {pt[names == name].mean():.2f} |")


def longmean(args):
    print("| bag | s | own constant b (ω + b), mrad/s | mean true rate, first "
          f"{args.seconds:.0f} s, mrad/s | mean true rate, whole recording, mrad/s |")
    print("|---|---|---|---|---|")
    for path in args.bags:
        d = read_bag(path, ("/imu/data", "/ground_truth/pose"))
        imu, gt = d["/imu/data"], d["/ground_truth/pose"]
        t, w = imu[:, 0], imu[:, 1:4]
        _, b = fit_calibration(Increments(t, w, gt, args.increment), False)
        # The raw mean minus the bias it would estimate: the net rotation the robot itself made.
        first = w[: np.searchsorted(t, t[0] + args.seconds * 1e9)].mean(0) + b
        whole = w.mean(0) + b
        name = os.path.splitext(os.path.basename(path))[0]
        fmt = lambda v: "[" + ", ".join(f"{x * 1e3:.2f}" for x in v) + "]"
        print(f"| {name} | {(t[-1] - t[0]) * 1e-9:.0f} | {fmt(b)} | {fmt(first)} | {fmt(whole)} |", flush=True)


def gtbias(args):
    """The ground-truth estimator's own gyro bias per recording (EuRoC's 17-column files)."""
    print(f"| sequence | s | first {args.seconds:g} s | middle {args.seconds:g} s | last {args.seconds:g} s | max - min inside, per axis |")
    print("|---|---|---|---|---|---|")
    fmt = lambda v: "[" + ", ".join(f"{x * 1e3:.2f}" for x in v) + "]"
    for seq in args.seqs:
        path = os.path.join(seq, "mav0", "state_groundtruth_estimate0", "data.csv")
        with open(path) as fh:
            header = [h.strip() for h in fh.readline().lstrip("#").split(",")]
        cols = [i for i, h in enumerate(header) if h.startswith("b_w_RS_S_")]
        name = os.path.basename(os.path.normpath(seq))
        if len(cols) != 3:
            print(f"| {name} | – | no gyro bias columns in {path} | | | |", flush=True)
            continue
        data = np.loadtxt(path, delimiter=",", comments="#")
        t, b = data[:, 0], data[:, cols]
        n = max(1, int(round(args.seconds / (np.median(np.diff(t)) * 1e-9))))
        mid = len(b) // 2
        spans = [b[:n], b[max(0, mid - n // 2):mid + (n + 1) // 2], b[-n:]]
        spread = b.max(axis=0) - b.min(axis=0)
        print(f"| {name} | {(t[-1] - t[0]) * 1e-9:.0f} | " + " | ".join(fmt(x.mean(axis=0)) for x in spans) + f" | {fmt(spread)} |", flush=True)


def main():
    torch.set_num_threads(1)
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("floors")
    f.add_argument("bags", nargs="+")
    f.add_argument("--increment", type=int, default=1024, help="J, samples")
    f.set_defaults(run=floors)
    d = sub.add_parser("decompose")
    d.add_argument("bags", nargs="+")
    d.add_argument("--alphas", default="0,0.25,0.5,1")
    d.set_defaults(run=decompose)
    o = sub.add_parser("postfilter")
    o.add_argument("bags", nargs="+")
    o.add_argument("--taus", default="0.5,2,10,30", help="EMA time constants, s")
    o.add_argument("--observers", default="0.05:1e-3,0.02:2e-4,0.05:1e-3:1,0.01:1e-4:1", help="kp:ki[:accel LPF s],...")
    o.set_defaults(run=postfilter)
    i = sub.add_parser("insobserver")
    i.add_argument("bags", nargs="+")
    i.add_argument("--sigma-v", type=float, default=2.0, help="m/s, the bounded-motion prior")
    i.add_argument("--period", type=float, default=2.0, help="s between prior updates")
    i.add_argument("--raw", action="store_true", help="imported bags: filter the raw gyro minus --offset")
    i.add_argument("--offset", type=float, nargs=3, default=[0.0, 0.0, 0.0], help="rad/s, with --raw")
    i.set_defaults(run=insobserver)
    e = sub.add_parser("ensemble")
    e.add_argument("dirs", nargs="+", help="folders of replayed bags, one per model")
    e.set_defaults(run=ensemble)
    b = sub.add_parser("supportbias")
    b.add_argument("bags", nargs="+")
    b.add_argument("--support-seconds", type=float, default=60.0)
    b.add_argument("--increment", type=int, default=200, help="J, samples (1 s at 200 Hz)")
    b.set_defaults(run=supportbias)
    t = sub.add_parser("transfer")
    t.add_argument("--train", nargs="+", required=True)
    t.add_argument("--test", nargs="+", required=True)
    t.add_argument("--increment", type=int, default=1024, help="J, samples")
    t.set_defaults(run=transfer)
    r = sub.add_parser("restshift")
    r.add_argument("--train", nargs="+", required=True)
    r.add_argument("--test", nargs="+", required=True)
    r.add_argument("--increment", type=int, default=1024, help="J, samples")
    r.set_defaults(run=restshift)
    m = sub.add_parser("longmean")
    m.add_argument("bags", nargs="+")
    m.add_argument("--seconds", type=float, default=60.0, help="the first span, s")
    m.add_argument("--increment", type=int, default=1024, help="J, samples")
    m.set_defaults(run=longmean)
    g = sub.add_parser("gtbias")
    g.add_argument("seqs", nargs="+", help="EuRoC sequence folders (…/MH_04_difficult)")
    g.add_argument("--seconds", type=float, default=1.0, help="the span of each mean, s")
    g.set_defaults(run=gtbias)
    q = sub.add_parser("probe")
    q.add_argument("--positive", required=True, help="a file-name substring, e.g. V2_")
    q.add_argument("--train", nargs="+", required=True)
    q.add_argument("--test", nargs="+", required=True)
    q.set_defaults(run=probe)
    args = p.parse_args()
    args.run(args)


if __name__ == "__main__":
    main()
