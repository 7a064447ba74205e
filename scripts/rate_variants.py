#!/usr/bin/env python3
"""Rate variants of 200-Hz IMU bags (independent of imu-fsda's own writer).

usage: rate_variants.py [--convention fwd|bwd] [-o OUTDIR] BAG...   (docs/rates.md)

For each input X.mcap writes X_1000zoh, X_1000, X_500, X_100 .mcap. s_n = header stamps, d = s_{n+1}-s_n.
--convention picks which interval a 200-Hz sample covers:
  fwd (default): [s_n, s_{n+1}), as imu-fsda's integrator uses it (r_{n+1} = r_n exp(w_n (t_{n+1}-t_n))).
  bwd:           (s_{n-1}, s_n], the convention first specified in the brief.
  1000zoh  fwd: sample n (n <= N-2) -> 5 samples at s_n + floor(j*d_n/5), j=0..4; the LAST sample stays single.
           bwd: sample n (n >= 1) -> 5 samples at s_{n-1} + floor(j*d_{n-1}/5), j=1..5; the FIRST stays single.
           All 5 carry sample n's gyro and accel.
  1000     1000zoh + zero-sum noise per group of 5 (e ~ N(0, s^2) per axis, minus the group mean);
           gyro s = 1.7e-4*sqrt(1000) rad/s, accel s = 2.0e-3*sqrt(1000) m/s^2;
           rng = numpy default_rng(41), fresh per input bag, drawn as gyro (N-1,5,3) then accel (N-1,5,3),
           group g = the 5 samples of the g-th held interval. The single sample gets no noise.
  500      1000's samples averaged in pairs (2k, 2k+1); stamp = 2k's (fwd) or 2k+1's (bwd); odd last dropped.
  100      ORIGINAL 200-Hz samples averaged in pairs (2k, 2k+1); stamp = 2k's (fwd) or 2k+1's (bwd).

Everything else is copied: the input's schema records (name, encoding, text verbatim), channel
records (topic, encoding, metadata), and every non-IMU message's raw CDR bytes, log time and
publish time. IMU messages keep the first IMU message's frame_id, orientation and all three
covariance arrays (checked to be constant over the input); only stamp, angular_velocity and
linear_acceleration change. New IMU log_time = publish_time = header stamp (the inputs have
log_time == publish_time == header stamp for every message). Messages are written in log-time order
(stable; ties: non-IMU first), with sequence = running index over the whole file, as in the inputs.
IMU messages are CDR-encoded with mcap_ros2's dynamic serializer from the input's own schema text.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2._dynamic import serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

IMU_TYPE = 'sensor_msgs/msg/Imu'
SG = 1.7e-4 * np.sqrt(1000.0)
SA = 2.0e-3 * np.sqrt(1000.0)
SEED = 41


def read_bag(path, imu_topic):
    with open(path, 'rb') as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        summ = r.get_summary()
        header = r.get_header()
        schemas = dict(summ.schemas)
        channels = dict(summ.channels)
        others = []  # (log_time, publish_time, channel_id, data)
        imu = []  # (stamp, gx, gy, gz, ax, ay, az)
        imu_log = []
        tmpl = None
        consts = set()
        for sch, ch, raw, msg in r.iter_decoded_messages(log_time_order=False):
            if ch.topic == imu_topic:
                assert sch.name == IMU_TYPE, sch.name
                st = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                imu_log.append((raw.log_time, raw.publish_time, st))
                w, a = msg.angular_velocity, msg.linear_acceleration
                imu.append((st, w.x, w.y, w.z, a.x, a.y, a.z))
                o = msg.orientation
                key = (msg.header.frame_id, o.x, o.y, o.z, o.w, tuple(msg.orientation_covariance),
                       tuple(msg.angular_velocity_covariance), tuple(msg.linear_acceleration_covariance))
                consts.add(key)
                if tmpl is None:
                    tmpl = (ch, sch, msg, raw.data)
            else:
                others.append((raw.log_time, raw.publish_time, ch.id, raw.data))
    assert tmpl is not None, f'{path}: no messages on {imu_topic}'
    assert len(consts) == 1, f'{path}: IMU frame_id/orientation/covariances not constant: {len(consts)} variants'
    st = np.array([x[0] for x in imu], dtype=np.int64)
    val = np.array([x[1:] for x in imu], dtype=np.float64)
    lg = np.array(imu_log, dtype=np.int64)
    o = np.argsort(st, kind='stable')
    st, val, lg = st[o], val[o], lg[o]
    assert np.all(np.diff(st) > 0), f'{path}: IMU stamps not strictly increasing'
    off = lg[:, 0] - lg[:, 2]
    return dict(header=header, schemas=schemas, channels=channels, others=others, st=st, val=val,
                log_off=off, pub_off=lg[:, 1] - lg[:, 2], tmpl=tmpl)


def zoh5(st, val, conv):
    """5 samples per 200-Hz interval, each = the sample whose interval it is.

    bwd (the brief's spec): sample n (n>=1) covers (s_{n-1}, s_n] -> stamps s_{n-1} + floor(j*d/5),
        j=1..5 (j=5 is s_n); sample 0 stays single (first).
    fwd (imu-fsda's integrator, r_n = r_{n-1} exp(w_{n-1} (t_n - t_{n-1}))): sample n (n<=N-2) covers
        [s_n, s_{n+1}) -> stamps s_n + floor(j*d/5), j=0..4 (j=0 is s_n); sample N-1 stays single (last).
    Returns stamps, values, and a group id per output sample (-1 for the single one).
    """
    n = len(st)
    d = np.diff(st)
    if conv == 'bwd':
        j = np.arange(1, 6, dtype=np.int64)
        sub = st[:-1, None] + (j[None, :] * d[:, None]) // 5
        assert np.array_equal(sub[:, 4], st[1:])
        st_out = np.concatenate([st[:1], sub.reshape(-1)])
        v_out = np.concatenate([val[:1], np.repeat(val[1:], 5, axis=0)])
        grp = np.concatenate([[-1], np.repeat(np.arange(n - 1), 5)])
    else:
        j = np.arange(0, 5, dtype=np.int64)
        sub = st[:-1, None] + (j[None, :] * d[:, None]) // 5
        assert np.array_equal(sub[:, 0], st[:-1])
        st_out = np.concatenate([sub.reshape(-1), st[-1:]])
        v_out = np.concatenate([np.repeat(val[:-1], 5, axis=0), val[-1:]])
        grp = np.concatenate([np.repeat(np.arange(n - 1), 5), [-1]])
    assert len(st_out) == 1 + 5 * (n - 1) and np.all(np.diff(st_out) > 0)
    return st_out, v_out, grp


def zero_sum_noise(n_groups, rng):
    eg = SG * rng.standard_normal((n_groups, 5, 3))
    ea = SA * rng.standard_normal((n_groups, 5, 3))
    eg -= eg.mean(axis=1, keepdims=True)
    ea -= ea.mean(axis=1, keepdims=True)
    return np.concatenate([eg, ea], axis=2).reshape(-1, 6)


def pair_mean(st, val, conv):
    """Mean of samples (2k, 2k+1); stamp = 2k+1's (bwd, the brief's spec) or 2k's (fwd). Odd last dropped."""
    m = (len(st) // 2) * 2
    stamp = st[1:m:2] if conv == 'bwd' else st[0:m:2]
    return stamp.copy(), 0.5 * (val[0:m:2] + val[1:m:2])


def write_bag(path, bag, st, val):
    ch_imu, sch_imu, msg0, raw0 = bag['tmpl']
    enc = serialize_dynamic(sch_imu.name, sch_imu.data.decode())[sch_imu.name]
    # the encoder must reproduce the input's own bytes
    assert enc(msg0) == raw0, 'CDR encoder does not round-trip the input IMU message'
    frame = msg0.header.frame_id
    ori = {'x': msg0.orientation.x, 'y': msg0.orientation.y, 'z': msg0.orientation.z, 'w': msg0.orientation.w}
    oc = [float(x) for x in msg0.orientation_covariance]
    gc = [float(x) for x in msg0.angular_velocity_covariance]
    ac = [float(x) for x in msg0.linear_acceleration_covariance]

    recs = [(lt, 0, i, pt, cid, data) for i, (lt, pt, cid, data) in enumerate(bag['others'])]
    for i in range(len(st)):
        recs.append((int(st[i]), 1, i, int(st[i]), ch_imu.id, None))
    recs.sort(key=lambda r: (r[0], r[1], r[2]))

    tmp = path + '.tmp'
    with open(tmp, 'wb') as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile=bag['header'].profile, library='scripts/rate_variants.py (python mcap + mcap_ros2)')
        sid = {}
        for s in sorted(bag['schemas'].values(), key=lambda s: s.id):
            sid[s.id] = w.register_schema(s.name, s.encoding, s.data)
        cid = {}
        for c in sorted(bag['channels'].values(), key=lambda c: c.id):
            cid[c.id] = w.register_channel(c.topic, c.message_encoding, sid[c.schema_id], dict(c.metadata))
        for seq, (lt, kind, i, pt, c, data) in enumerate(recs):
            if kind == 1:
                t = int(st[i])
                v = val[i]
                data = enc({
                    'header': {'stamp': {'sec': t // 10**9, 'nanosec': t % 10**9}, 'frame_id': frame},
                    'orientation': ori, 'orientation_covariance': oc,
                    'angular_velocity': {'x': float(v[0]), 'y': float(v[1]), 'z': float(v[2])},
                    'angular_velocity_covariance': gc,
                    'linear_acceleration': {'x': float(v[3]), 'y': float(v[4]), 'z': float(v[5])},
                    'linear_acceleration_covariance': ac})
            w.add_message(channel_id=cid[c], log_time=lt, publish_time=pt, sequence=seq, data=data)
        w.finish()
    os.replace(tmp, path)
    print(f'  wrote {path}: {len(st)} IMU + {len(bag["others"])} other messages', flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('bags', nargs='+')
    ap.add_argument('-o', '--outdir', required=True)
    ap.add_argument('--imu-topic', default='/imu/data')
    ap.add_argument('--convention', choices=['fwd', 'bwd'], default='fwd',
                    help='which interval a sample covers: fwd [s_n, s_n+1) as imu-fsda integrates (default), '
                         'bwd (s_n-1, s_n] as first specified')
    ap.add_argument('--only', nargs='*', default=None, help='subset of 1000zoh 1000 500 100')
    a = ap.parse_args()
    os.makedirs(a.outdir, exist_ok=True)
    os.makedirs(a.outdir, exist_ok=True)
    for p in a.bags:
        stem = os.path.splitext(os.path.basename(p))[0]
        bag = read_bag(p, a.imu_topic)
        st, val = bag['st'], bag['val']
        print(f'{p}: {len(st)} IMU samples, median dt {np.median(np.diff(st))} ns, '
              f'IMU log-stamp offset {bag["log_off"].min()}..{bag["log_off"].max()} ns, '
              f'publish-stamp {bag["pub_off"].min()}..{bag["pub_off"].max()} ns', flush=True)
        if np.any(bag['log_off'] != 0) or np.any(bag['pub_off'] != 0):
            print('  WARNING: input IMU log/publish time != header stamp; outputs use log = publish = stamp')
        zs, zv, grp = zoh5(st, val, a.convention)
        rng = np.random.default_rng(SEED)
        noise = zero_sum_noise(len(st) - 1, rng)  # (N-1)*5 rows, group g = rows 5g..5g+4
        nz = np.zeros_like(zv)
        nz[grp >= 0] = noise
        kv = zv + nz
        # group means of the noisy stream equal the held sample exactly (up to rounding)
        held = val[1:] if a.convention == 'bwd' else val[:-1]
        assert np.allclose(kv[grp >= 0].reshape(-1, 5, 6).mean(axis=1), held, rtol=0, atol=1e-12)
        fs, fv = pair_mean(zs, kv, a.convention)
        hs, hv = pair_mean(st, val, a.convention)
        out = {'1000zoh': (zs, zv), '1000': (zs, kv), '500': (fs, fv), '100': (hs, hv)}
        for k, (s_, v_) in out.items():
            if a.only and k not in a.only:
                continue
            write_bag(os.path.join(a.outdir, f'{stem}_{k}.mcap'), bag, s_, v_)


if __name__ == '__main__':
    sys.exit(main())
