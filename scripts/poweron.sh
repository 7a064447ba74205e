#!/usr/bin/env bash
# The power-on protocol on simulated IMUs: for every profile × a consumer (MPU-9250) and an
# industrial (ADIS16448) grade, POWER_ONS power-ons of one IMU (the same lasting errors: scale,
# cross-axis, g-sensitivity; a new turn-on bias, noise and motion each; a rest at start of
# varying length, none on one). Scored per power-on: raw, static-bias, the pipeline's
# power-on bias, the bundled model on this new IMU (alone, and as the node deploys it), and
# the model adapted on power-on 1 (`adapt --judge` on the others, and alone as the node's
# ~/adapt, no other power-on to judge on), and on power-on 2 judged on 1 and scored on 3–N
# (held out). Writes docs/poweron.json and
# the table in docs/poweron.md between its markers.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD=${IMU_FSDA_NO_BUILD:-} bash "$here/scripts/setup.sh"
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
model="${MODEL:-$here/models/fsda-f.pt}"
require_models "$model"
power_ons="${POWER_ONS:-5}"
seconds="${SECONDS_PER_POWER_ON:-120}"
rests=(3 5 1.5 2 0 4 0.8 6)
work="$IMU_FSDA_CACHE/poweron"
rm -rf "$work"; mkdir -p "$work"
source "$here/scripts/poweron_units.sh"
for profile in aerial handheld car quadruped; do
  for grade in mpu-9250 adis16448; do
    imu="$profile-$grade"
    IFS='|' read -ra terms <<< "$(lasting "$grade")"
    term_args=(); for t in "${terms[@]}"; do term_args+=(--term "$t"); done
    bags=()
    for k in $(seq 1 "$power_ons"); do
      bag="$work/$imu-$k.mcap"
      "$bin" simulate --profile "$profile" --grade "$grade" --datasheet-errors --seconds "$seconds" --seed 11 \
        --power-on "$k" --rest-s "${rests[$(( (k - 1) % ${#rests[@]} ))]}" "${term_args[@]}" -o "$bag" >/dev/null
      bags+=("$bag")
    done
    judges=(); for b in "${bags[@]:1}"; do judges+=(--judge "$b"); done
    # Adapted on power-on 1 (written only if accepted on the others).
    adapted=()
    if "$bin" adapt --model "$model" --bag "${bags[0]}" "${judges[@]}" -o "$work/$imu-adapted.pt" --json > "$work/$imu.adapt.json" 2> "$work/$imu.adapt.log"; then
      adapted=(--model "$work/$imu-adapted.pt")
    fi
    # Adapted on power-on 1 alone (no --judge, as the node's ~/adapt): only what lasts is kept.
    if "$bin" adapt --model "$model" --bag "${bags[0]}" -o "$work/$imu-alone.pt" --json > "$work/$imu.alone.adapt.json" 2> "$work/$imu.alone.adapt.log"; then
      adapted+=(--model "$work/$imu-alone.pt")
    fi
    # Judged on the past, scored on the future: adapted on power-on 2 and judged on power-on 1
    # (as the node's adapt_support_archive on the second power-on), run on 3–N, which neither
    # fitted nor judged it.
    if "$bin" adapt --model "$model" --bag "${bags[1]}" --judge "${bags[0]}" -o "$work/$imu-past.pt" --json > "$work/$imu.past.adapt.json" 2> "$work/$imu.past.adapt.log"; then
      adapted+=(--model "$work/$imu-past.pt")
    fi
    "$bin" eval "${bags[@]}" --method raw --method static-bias --method power-on-bias --model "$model" "${adapted[@]}" --json "$work/$imu.eval.json" >/dev/null
    echo "[poweron] $imu: $(tail -1 "$work/$imu.adapt.log"); without --judge: $(tail -1 "$work/$imu.alone.adapt.log"); on power-on 2 judged on 1: $(tail -1 "$work/$imu.past.adapt.log")" >&2
  done
done
"$PYTHON" "$here/scripts/poweron_table.py" "$work" "$here/docs/poweron.json" "$here/docs/poweron.md"
