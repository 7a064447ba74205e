#!/usr/bin/env python3
"""The comparison with the paper, computed from docs/results.json (written by `imu-fsda eval`).

Usage: paper_table.py RESULTS_JSON [METHOD=fsda-f] > markdown

Prints (1) AOE per test sequence for every evaluated method with the verdict against the raw
gyro, the EuRoC mean and the count of sequences a method makes worse than raw, and (2) the
paper's roll / pitch / yaw table (../shared/docs/anchors.md, the paper's own numbers) beside
the chosen method's, marking each cell where ours is below the paper's FSDA-F, and beside them
the raw gyro minus the constant fitted to that sequence's own ground truth (the `raw − oracle
bias` rows of `imu-fsda eval --oracle-bias`): a reference, not a method, that shows which of the
paper's cells no constant bias correction reaches in this Euler convention.
"""
import json
import sys

# The paper's table: RMSE in degrees, DIGDL / FSDA / FSDA-F per axis (anchors.md).
PAPER = {
    "MH_04_difficult": {"roll": (6.3545, 4.0661, 2.8777), "pitch": (1.4515, 0.7197, 0.5822), "yaw": (5.8232, 3.3024, 2.2552)},
    "V2_02_medium": {"roll": (15.2573, 13.5855, 14.8446), "pitch": (3.4115, 3.1405, 3.0593), "yaw": (14.6063, 12.6688, 13.9353)},
    "V1_03_difficult": {"roll": (15.5216, 13.0684, 5.8844), "pitch": (0.7688, 0.8006, 0.5490), "yaw": (15.5827, 13.0634, 6.1500)},
    "V1_01_easy": {"roll": (4.7786, 2.4963, 1.9613), "pitch": (1.3872, 0.7834, 0.7083), "yaw": (4.0019, 2.0675, 1.8942)},
    "room2": {"roll": (1.4942, 1.4272, 1.4066), "pitch": (1.4109, 1.3223, 1.3163), "yaw": (6.1720, 7.7549, 5.8225)},
    "room4": {"roll": (1.5116, 1.0619, 1.1100), "pitch": (1.6430, 1.1209, 1.1762), "yaw": (8.6927, 5.8566, 5.0745)},
    "room6": {"roll": (1.2296, 1.0577, 1.0124), "pitch": (1.5086, 1.3003, 1.2401), "yaw": (6.5248, 7.6963, 5.6873)},
}
EUROC_TEST = ["MH_02_easy", "MH_04_difficult", "V1_01_easy", "V1_03_difficult", "V2_02_medium"]


def fmt(x):
    return "–" if x is None else f"{x:.2f}"


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    # `M − oracle bias` rows read the ground truth: a bound, not a method to compare.
    all_rows = json.load(open(sys.argv[1]))["rows"]
    rows = [r for r in all_rows if not r["method"].endswith("oracle bias")]
    oracle = {r["bag"]: r for r in all_rows if r["method"] == "raw − oracle bias"}
    method = sys.argv[2] if len(sys.argv) > 2 else "fsda-f"
    by = {}
    methods = []
    bags = []
    for r in rows:
        by[(r["bag"], r["method"])] = r
        if r["method"] not in methods:
            methods.append(r["method"])
        if r["bag"] not in bags:
            bags.append(r["bag"])
    if method not in methods:
        sys.exit(f"error: method {method!r} not in {sys.argv[1]} (have {methods})")
    learned = [m for m in methods if m not in ("raw", "static-bias")]

    def aoe(bag, m):
        r = by.get((bag, m))
        return None if r is None or r.get("aoe_deg") is None else r["aoe_deg"]

    print("AOE (degrees) per test sequence; **bold** where a learned model is worse than the raw gyro:\n")
    print("| sequence | " + " | ".join(methods) + " |")
    print("|---" * (len(methods) + 1) + "|")
    for b in bags:
        cells = []
        for m in methods:
            a = aoe(b, m)
            raw = aoe(b, "raw")
            worse = m in learned and a is not None and raw is not None and a > raw
            cells.append(f"**{fmt(a)}**" if worse else fmt(a))
        print(f"| {b} | " + " | ".join(cells) + " |")
    means = []
    for m in methods:
        vals = [aoe(b, m) for b in EUROC_TEST if b in bags]
        means.append(fmt(sum(vals) / len(vals)) if vals and all(v is not None for v in vals) else "–")
    print("| **EuRoC mean (5)** | " + " | ".join(means) + " |")
    print()
    for m in learned:
        worse = [b for b in bags if aoe(b, m) is not None and aoe(b, "raw") is not None and aoe(b, m) > aoe(b, "raw")]
        print(f"- `{m}`: worse than raw on {len(worse)} of {len(bags)} sequences" + (f" ({', '.join(worse)})" if worse else ""))
    print()
    print(f"Roll / pitch / yaw RMSE (degrees; ZYX of the IMU frame, wrapped) of `{method}` against the")
    print("paper's table (its DIGDL / FSDA / FSDA-F columns); ✓ where ours is below the paper's FSDA-F;")
    print("the last column is the raw gyro minus its own constant fitted to that sequence's ground truth")
    print("(oracle, roll / pitch / yaw; † where the paper's FSDA-F is below even that):\n")
    print("| sequence | roll paper | roll ours | pitch paper | pitch ours | yaw paper | yaw ours | raw − own constant (oracle) |")
    print("|---|---|---|---|---|---|---|---|")
    beaten = total = 0
    below_oracle = []
    for seq, axes in PAPER.items():
        r = by.get((seq, method))
        o = oracle.get(seq)
        floor = []
        cells = []
        for ax in ("roll", "pitch", "yaw"):
            paper = axes[ax]
            ours = None if r is None else r.get(f"{ax}_rmse_deg")
            mark = ""
            if ours is not None:
                total += 1
                if ours < paper[2]:
                    beaten += 1
                    mark = " ✓"
            cells.append(" / ".join(f"{p:.2f}" for p in paper))
            cells.append(fmt(ours) + mark)
            o_ax = None if o is None else o.get(f"{ax}_rmse_deg")
            dagger = o_ax is not None and paper[2] < o_ax
            if dagger:
                below_oracle.append(f"{seq} {ax}")
            floor.append(fmt(o_ax) + (" †" if dagger else ""))
        cells.append(" / ".join(floor))
        print(f"| {seq} | " + " | ".join(cells) + " |")
    print(f"\n`{method}` is below the paper's FSDA-F in {beaten} of {total} cells.")
    if oracle:
        print(
            f"In {len(below_oracle)} of {total} cells the paper's FSDA-F is below the raw gyro minus the constant"
            " fitted to that very sequence's ground truth" + (f" ({', '.join(below_oracle)})" if below_oracle else "") + "."
        )


if __name__ == "__main__":
    main()
