#!/usr/bin/env bash
# The published attitude, open loop and gravity aided, on the recordings of docs/node.md
# ("Gravity aided"): EuRoC's and TUM-VI's test recordings with the bundled model (named IMU),
# the four bundled 20-s simulated bags, and four simulated hours of an MPU-9250 without a
# model (`simulate --profile P --grade mpu-9250 --datasheet-errors --seconds 3600 --seed 5`).
# With SET=new_imu instead: all 17 real recordings (EuRoC's 11, TUM-VI's six rooms) with the
# bundled model and no IMU named, as a user with an IMU the model never saw runs it (docs/node.md,
# "On a new IMU").
# Each is replayed twice (`imu-fsda replay`, `pipeline.orientation` open_loop, then the
# default) and scored by `imu-fsda attitude` (AOE, tilt, heading drift, NEES); the table (open
# loop → gravity aided) goes to stdout and OUT/attitude.json.
#   bash scripts/attitude_table.sh [OUT]                   # OUT: default $IMU_FSDA_CACHE/attitude (SET=new_imu: …/attitude-new-imu)
#   PARAMS=P.yaml bash scripts/attitude_table.sh OUT       # the gravity-aided run with a parameter file
#   REFERENCES=1 bash scripts/attitude_table.sh            # also VQF and Madgwick on the raw IMU (minutes per hour)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD=${IMU_FSDA_NO_BUILD:-} bash "$here/scripts/setup.sh"
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
model="${MODEL:-$here/models/fsda-f.pt}"
require_models "$model"
data="${DATA:-$here/../shared/data}"
set_name="${SET:-test}"
case "$set_name" in test) out="${1:-$IMU_FSDA_CACHE/attitude}" ;; new_imu) out="${1:-$IMU_FSDA_CACHE/attitude-new-imu}" ;;
  *) echo "SET is test or new_imu, not $set_name" >&2; exit 2 ;; esac
mkdir -p "$out/open_loop" "$out/gravity_aided" "$out/vqf" "$out/madgwick" "$IMU_FSDA_CACHE/bags" "$IMU_FSDA_CACHE/hours"
open_loop="$out/open_loop.yaml"
printf 'imu_fsda:\n  ros__parameters:\n    pipeline:\n      orientation: open_loop\n' > "$open_loop"
aided=(); [[ -n "${PARAMS:-}" ]] && aided=(--params "$PARAMS")

euroc_bag() { # sequence: its imported bag, imported on first use
  local bag="$IMU_FSDA_CACHE/bags/$1.mcap"
  [ -f "$bag" ] || "$bin" import "$data/euroc/$1" -o "$bag" >&2
  echo "$bag"
}
room_bag() { # room number
  local bag="$IMU_FSDA_CACHE/bags/room$1.mcap"
  [ -f "$bag" ] || "$bin" import "$data/tumvi/dataset-room$1_512_16" -o "$bag" >&2
  echo "$bag"
}

# name|bag|model arguments
runs=()
if [[ "$set_name" == new_imu ]]; then
  for s in MH_01_easy MH_02_easy MH_03_medium MH_04_difficult MH_05_difficult V1_01_easy V1_02_medium V1_03_difficult \
           V2_01_easy V2_02_medium V2_03_difficult; do
    runs+=("$s|$(euroc_bag "$s")|--model $model")
  done
  for r in 1 2 3 4 5 6; do runs+=("room$r|$(room_bag "$r")|--model $model"); done
else
  for s in MH_02_easy MH_04_difficult V1_01_easy V1_03_difficult V2_02_medium; do
    runs+=("${s%_*}|$(euroc_bag "$s")|--model $model --imu euroc")
  done
  for r in 2 4 6; do runs+=("room$r|$(room_bag "$r")|--model $model --imu tumvi"); done
  for p in aerial car handheld quadruped; do
    runs+=("sim_$p|$here/test_bags/sim_$p.mcap|")
  done
  for p in aerial car handheld quadruped; do
    bag="$IMU_FSDA_CACHE/hours/$p.mcap"
    [ -f "$bag" ] || "$bin" simulate --profile "$p" --grade mpu-9250 --datasheet-errors --seconds 3600 --seed 5 -o "$bag" >/dev/null
    runs+=("${p}_1h|$bag|--model ''")
  done
fi

one() { # name bag model-args
  local name="$1" bag="$2" margs
  eval "margs=($3)"
  "$bin" replay "$bag" "${margs[@]}" --params "$open_loop" -o "$out/open_loop/$name.mcap" >/dev/null 2>&1
  "$bin" replay "$bag" "${margs[@]}" "${aided[@]}" -o "$out/gravity_aided/$name.mcap" >/dev/null 2>&1
  if [[ -n "${REFERENCES:-}" ]]; then
    "$PYTHON" "$here/scripts/vqf_attitude.py" "$bag" "$out/vqf/$name.mcap" --bias-clip 10 >/dev/null 2>&1
    "$PYTHON" "$here/scripts/madgwick_attitude.py" "$bag" "$out/madgwick/$name.mcap" >/dev/null 2>&1
  fi
}
n=0
for r in "${runs[@]}"; do
  IFS='|' read -r name bag margs <<< "$r"
  one "$name" "$bag" "$margs" &
  (( ++n % 2 == 0 )) && wait
done
wait
names=(); for r in "${runs[@]}"; do names+=("${r%%|*}"); done
kinds=(open_loop gravity_aided); [[ -n "${REFERENCES:-}" ]] && kinds+=(vqf madgwick)
for k in "${kinds[@]}"; do
  bags=(); for name in "${names[@]}"; do bags+=("$out/$k/$name.mcap"); done
  "$bin" attitude "${bags[@]}" --json "$out/$k.json" >/dev/null
done
"$PYTHON" - "$out" "${kinds[@]}" <<'PY'
import json, sys
out, kinds = sys.argv[1], sys.argv[2:]
rows = {k: {r["bag"]: r["errors"] for r in json.load(open(f"{out}/{k}.json"))["rows"]} for k in kinds}
def pair(bag, key, fmt="{:.2f}"):
    a, b = rows["open_loop"][bag].get(key), rows["gravity_aided"][bag].get(key)
    return f"{fmt.format(a)} → {fmt.format(b)}" if a is not None and b is not None else "–"
print("| bag | AOE | tilt RMS | tilt max | heading drift RMS | stated tilt σ (median) | tilt NEES | within 95 % |")
print("|---|---|---|---|---|---|---|---|")
table = {}
for bag in rows["gravity_aided"]:
    pct = lambda k: f"{100 * rows[k][bag]['tilt_within_95']:.0f}"
    print(f"| {bag} | {pair(bag, 'aoe_deg')} | {pair(bag, 'tilt_rmse_deg')} | {pair(bag, 'tilt_max_deg')} | {pair(bag, 'heading_rmse_deg')} | "
          f"{pair(bag, 'tilt_sigma_median_deg')} | {pair(bag, 'tilt_nees_mean')} | {pct('open_loop')} → {pct('gravity_aided')} % |")
    table[bag] = {k: rows[k][bag] for k in kinds if bag in rows[k]}
if "vqf" in kinds:
    # AOE / tilt RMS / heading drift RMS per bag, then the mean AOE of each set of bags.
    cols = ["vqf", "madgwick", "open_loop", "gravity_aided"]
    print()
    print("| bag | VQF 6D, raw IMU | Madgwick, raw IMU | ours, open loop | ours, gravity aided |")
    print("|---|---|---|---|---|")
    for bag in rows["gravity_aided"]:
        cell = lambda k: (f"{rows[k][bag]['aoe_deg']:.2f} / {rows[k][bag]['tilt_rmse_deg']:.2f} / "
                          f"{rows[k][bag]['heading_rmse_deg']:.2f}") if bag in rows[k] else "–"
        print(f"| {bag} | {' | '.join(cell(k) for k in cols)} |")
    sets = {"EuRoC": lambda b: b[:2] in ("MH", "V1", "V2"), "TUM-VI": lambda b: b.startswith("room"),
            "simulated 20 s": lambda b: b.startswith("sim_"), "simulated hours": lambda b: b.endswith("_1h")}
    for label, member in sets.items():
        bags = [b for b in rows["gravity_aided"] if member(b) and all(b in rows[k] for k in cols)]
        if bags:
            mean = lambda k: sum(rows[k][b]["aoe_deg"] for b in bags) / len(bags)
            print(f"| mean AOE, {label} ({len(bags)}) | {' | '.join(f'{mean(k):.2f}' for k in cols)} |")
json.dump(table, open(f"{out}/attitude.json", "w"), indent=1)
PY
