#!/usr/bin/env bash
# Power-ons without a rest: what the bias seen in motion removes, against the simulation's
# truth and against the raw gyro. Every profile × a consumer (MPU-9250) and an industrial
# (ADIS16448) unit with the lasting errors of scripts/poweron.sh, POWER_ONS power-ons each
# (seeds FIRST…), 120 s each, no rest at the start. Per power-on: `imu-fsda replay` (its
# /imu/gyro_correction is minus the bias removed) scored against the truth's turn-on bias, and
# `imu-fsda eval --method raw --method power-on-bias`. Writes docs/poweron-norest.json and the
# table between `<!-- norest:begin -->` and `<!-- norest:end -->` in docs/poweron.md.
# Then real power-ons without a rest: each EuRoC recording that starts with a rest, imported
# from 2 s after its rest ended (the ADIS16448's 4.5 °/s turn-on bias unremoved until a later
# standstill), raw against power-on bias.
#   bash scripts/poweron_norest.sh            # power-ons 21-28 (a second set, 11-18, was used to choose the rule)
#   FIRST=11 PARAMS=P.yaml OUT=/tmp/x bash scripts/poweron_norest.sh   # another set or setting; OUT: no docs written
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD=${IMU_FSDA_NO_BUILD:-} bash "$here/scripts/setup.sh"
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
first="${FIRST:-21}"
power_ons="${POWER_ONS:-8}"
work="$IMU_FSDA_CACHE/poweron-norest"
rm -rf "$work"; mkdir -p "$work"
params=(); [[ -n "${PARAMS:-}" ]] && params=(--params "$PARAMS")
source "$here/scripts/poweron_units.sh"
one() { # profile grade k
  local name="$1-$2-$3" terms term_args=()
  IFS='|' read -ra terms <<< "$(lasting "$2")"
  for t in "${terms[@]}"; do term_args+=(--term "$t"); done
  "$bin" simulate --profile "$1" --grade "$2" --datasheet-errors --seconds 120 --seed 11 --power-on "$3" --rest-s 0 \
    "${term_args[@]}" -o "$work/$name.mcap" --truth "$work/$name.truth.yaml" >/dev/null
  "$bin" replay "$work/$name.mcap" -o "$work/$name.replay.mcap" "${params[@]}" >/dev/null 2>&1
  "$bin" bag echo "$work/$name.replay.mcap" --topic /imu/gyro_correction > "$work/$name.correction.jsonl"
  rm -f "$work/$name.replay.mcap"
}
bags=()
for profile in aerial handheld car quadruped; do
  for grade in mpu-9250 adis16448; do
    for k in $(seq "$first" $((first + power_ons - 1))); do
      one "$profile" "$grade" "$k" &
      bags+=("$work/$profile-$grade-$k.mcap")
      (( ${#bags[@]} % 2 == 0 )) && wait
    done
  done
done
wait
"$bin" eval "${bags[@]}" --method raw --method power-on-bias "${params[@]}" --json "$work/eval.json" >/dev/null

data="${DATA:-$here/../shared/data}"
mkdir -p "$IMU_FSDA_CACHE/bags" "$work/euroc"
full=()
for dir in "$data"/euroc/*/; do
  s="$(basename "$dir")"
  [ -f "$IMU_FSDA_CACHE/bags/$s.mcap" ] || "$bin" import "$dir" -o "$IMU_FSDA_CACHE/bags/$s.mcap" >&2
  full+=("$IMU_FSDA_CACHE/bags/$s.mcap")
done
"$bin" eval "${full[@]}" --method static-bias --json "$work/euroc/rests.json" >/dev/null
trimmed=()
while read -r s rest; do
  src="$data/euroc/$s/mav0"; dst="$work/euroc/$s/mav0"
  mkdir -p "$dst/imu0"
  cp -r "$src/state_groundtruth_estimate0" "$dst/"
  cp "$src/imu0/sensor.yaml" "$dst/imu0/"
  "$PYTHON" - "$src/imu0/data.csv" "$dst/imu0/data.csv" "$rest" <<'PY'
import sys
src, dst, rest = sys.argv[1], sys.argv[2], float(sys.argv[3])
lines = open(src).read().splitlines()
rows = [l for l in lines if l and not l.startswith("#")]
cut = int(rows[0].split(",")[0]) + int((rest + 2.0) * 1e9)
open(dst, "w").write("\n".join([l for l in lines if l.startswith("#")] + [l for l in rows if int(l.split(",")[0]) >= cut]) + "\n")
PY
  "$bin" import "$work/euroc/$s" -o "$work/euroc/$s.mcap" >/dev/null 2>&1
  trimmed+=("$work/euroc/$s.mcap")
done < <("$PYTHON" -c '
import json, re, sys
for r in json.load(open(sys.argv[1]))["rows"]:
    m = re.search(r"rest ([0-9.]+) s", r.get("note") or "")
    if m and r.get("aoe_deg") is not None:
        print(r["bag"], m.group(1))' "$work/euroc/rests.json")
"$bin" eval "${trimmed[@]}" --method raw --method power-on-bias "${params[@]}" --json "$work/euroc.eval.json" >/dev/null
if [[ -n "${OUT:-}" ]]; then
  "$PYTHON" "$here/scripts/poweron_norest_table.py" "$work" "$OUT.json" "$OUT.md"
else
  "$PYTHON" "$here/scripts/poweron_norest_table.py" "$work" "$here/docs/poweron-norest.json" "$here/docs/poweron.md"
fi
