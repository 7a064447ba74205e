#!/usr/bin/env python3
"""Table of scripts/poweron_norest.sh: per simulated IMU, over its power-ons without a rest,
the bias error left by the power-on bias against the raw gyro's (the turn-on bias itself), per
axis and over time, and the AOE, tilt and heading of both.

usage: poweron_norest_table.py WORK_DIR OUT.json OUT.md  (OUT.md: the table replaces the text
between `<!-- norest:begin -->` and `<!-- norest:end -->`, or is the whole file if it has none)."""
import glob
import json
import math
import os
import re
import sys


def truth_bias(path):
    """The turn-on bias in a `simulate --truth` file (its `gyro_bias` term)."""
    text = open(path).read()
    m = re.search(r"- term: gyro_bias\n\s+bias:\n\s+- (\S+)\n\s+- (\S+)\n\s+- (\S+)", text)
    return [float(m.group(i)) for i in (1, 2, 3)]


def bias_errors(corrections, bias):
    """Mean |bias − removed| and mean |bias| per axis (rad/s), and whether an axis was left
    worse than raw by more than 10 % (+0.1 mrad/s)."""
    left, raw, n = [0.0] * 3, [abs(b) for b in bias], 0
    for line in open(corrections):
        v = json.loads(line)["msg"]["vector"]
        removed = [-v["x"], -v["y"], -v["z"]]
        for a in range(3):
            left[a] += abs(bias[a] - removed[a])
        n += 1
    left = [x / max(n, 1) for x in left]
    worse = any(left[a] > raw[a] * 1.1 + 1e-4 for a in range(3))
    return left, raw, worse


def main():
    work, out_json, out_md = sys.argv[1:4]
    rows = json.load(open(os.path.join(work, "eval.json")))["rows"]
    scores = {}
    for r in rows:
        scores.setdefault(r["bag"], {})[r["method"]] = r
    per_imu = {}
    for truth in sorted(glob.glob(os.path.join(work, "*.truth.yaml"))):
        name = os.path.basename(truth)[: -len(".truth.yaml")]
        imu = name.rsplit("-", 1)[0]
        left, raw, worse = bias_errors(os.path.join(work, name + ".correction.jsonl"), truth_bias(truth))
        s = scores[name]
        per_imu.setdefault(imu, []).append({
            "power_on": name, "bias_left_rad_s": left, "bias_raw_rad_s": raw, "an_axis_worse_than_raw": worse,
            **{f"{m}_{k}": s[m][k] for m in ("raw", "power-on-bias") for k in ("aoe_deg", "tilt_rmse_deg", "heading_rmse_deg")},
        })
    json.dump(per_imu, open(out_json, "w"), indent=1)

    def mean(v, key, a=None):
        return sum(x[key][a] if a is not None else x[key] for x in v) / len(v)

    lines = ["| IMU (profile-grade) | power-ons | bias left, x / y / z (mrad/s) | raw's (the turn-on bias) | power-ons with an axis worse than raw | AOE raw / power-on bias (°) | tilt | heading |",
             "|---|---|---|---|---|---|---|---|"]
    ratios, worse_n, total = [], 0, 0
    for imu, v in sorted(per_imu.items()):
        left = " / ".join(f"{mean(v, 'bias_left_rad_s', a) * 1e3:.2f}" for a in range(3))
        raw = " / ".join(f"{mean(v, 'bias_raw_rad_s', a) * 1e3:.2f}" for a in range(3))
        worse = sum(x["an_axis_worse_than_raw"] for x in v)
        worse_n, total = worse_n + worse, total + len(v)
        ratios += [x["power-on-bias_aoe_deg"] / x["raw_aoe_deg"] for x in v]
        lines.append(f"| {imu} | {len(v)} | {left} | {raw} | {worse} | {mean(v, 'raw_aoe_deg'):.2f} / {mean(v, 'power-on-bias_aoe_deg'):.2f} | "
                     f"{mean(v, 'raw_tilt_rmse_deg'):.2f} / {mean(v, 'power-on-bias_tilt_rmse_deg'):.2f} | "
                     f"{mean(v, 'raw_heading_rmse_deg'):.2f} / {mean(v, 'power-on-bias_heading_rmse_deg'):.2f} |")
    geo = math.exp(sum(math.log(r) for r in ratios) / len(ratios))
    lines.append("")
    lines.append(f"Over all {total} power-ons: an axis left worse than raw on {worse_n}; AOE power-on bias / raw, geometric mean {geo:.3f}.")
    real = os.path.join(work, "euroc.eval.json")
    if os.path.exists(real):
        lines += ["", "Real: EuRoC's recordings that start with a rest, from 2 s after it (AOE / tilt / heading RMSE, °):", "",
                  "| recording | raw | power-on bias | what it removed at the end |", "|---|---|---|---|"]
        by = {}
        for r in json.load(open(real))["rows"]:
            by.setdefault(r["bag"], {})[r["method"]] = r
        for bag, m in sorted(by.items()):
            f = lambda r: f"{r['aoe_deg']:.2f} / {r['tilt_rmse_deg']:.2f} / {r['heading_rmse_deg']:.2f}"
            note = (m["power-on-bias"].get("note") or "").split(";")[0]
            lines.append(f"| {bag} | {f(m['raw'])} | {f(m['power-on-bias'])} | {note} |")
    table = "\n".join(lines)
    text = open(out_md).read() if os.path.exists(out_md) else ""
    begin, end = "<!-- norest:begin -->", "<!-- norest:end -->"
    if begin in text and end in text:
        text = text[: text.index(begin) + len(begin)] + "\n" + table + "\n" + text[text.index(end):]
    else:
        text = table + "\n"
    open(out_md, "w").write(text)
    print(table)


if __name__ == "__main__":
    main()
