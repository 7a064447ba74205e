#!/usr/bin/env bash
# The power-on protocol on real recordings: EuRoC's eleven recordings are eleven power-ons of
# one ADIS16448. Each in turn is the support (`adapt` on its first 60 s, the bundled model run
# as on a new IMU); the other ten are judged (`--judge`). Twice: as recorded, and with a
# consumer part's lasting scale and cross-axis errors injected into every recording
# (`imu-fsda inject`, the same terms as scripts/poweron.sh's MPU-9250 unit). Each support is
# also adapted on alone (no `--judge`, as the node's ~/adapt) and what that wrote is run on
# the others. Then the order a robot meets them in (EuRoC's numbering): each recording adapted
# on and judged on the JUDGE_POWER_ONS (3) before it, as the node's adapt_support_archive
# judges, and what it kept scored on the ones after it, which neither fitted nor judged it.
# Writes docs/poweron-euroc.json and the tables in docs/poweron.md between their markers.
# RATE_HZ=100: the same on each recording's samples averaged in pairs (scripts/rate_variants.py,
# real data at a wheeled robot's 100 Hz); writes docs/poweron-euroc-100.json and the `-100` tables.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD=${IMU_FSDA_NO_BUILD:-} bash "$here/scripts/setup.sh"
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
model="${MODEL:-$here/models/fsda-f.pt}"
require_models "$model"
data="${DATA:-$here/../shared/data}"
rate="${RATE_HZ:-}"
case "$rate" in "" | 100) ;; *) echo "RATE_HZ: 100 or unset (as recorded, 200 Hz)" >&2; exit 2 ;; esac
suffix="${rate:+-$rate}"
work="$IMU_FSDA_CACHE/poweron-euroc$suffix"
judge_power_ons="${JUDGE_POWER_ONS:-3}"
rm -rf "$work"; mkdir -p "$work/recorded" "$work/injected" "$work/rate" "$IMU_FSDA_CACHE/bags"
for dir in "$data"/euroc/*/; do
  s="$(basename "$dir")"
  [ -f "$IMU_FSDA_CACHE/bags/$s.mcap" ] || "$bin" import "$dir" -o "$IMU_FSDA_CACHE/bags/$s.mcap" >&2
  if [ -n "$rate" ]; then
    "$PYTHON" "$here/scripts/rate_variants.py" --only "$rate" -o "$work/rate" "$IMU_FSDA_CACHE/bags/$s.mcap" >/dev/null
    mv "$work/rate/${s}_$rate.mcap" "$work/recorded/$s.mcap"
  else
    cp "$IMU_FSDA_CACHE/bags/$s.mcap" "$work/recorded/$s.mcap"
  fi
  "$bin" inject "$work/recorded/$s.mcap" \
    --term "{term: gyro_scale, scale: [0.021, -0.027, 0.014]}" \
    --term "{term: gyro_misalignment, matrix: [[0, 0.012, -0.008], [-0.015, 0, 0.010], [0.006, -0.011, 0]]}" \
    -o "$work/injected/$s.mcap" 2>/dev/null
done
for set in recorded injected; do
  bags=("$work/$set"/*.mcap)
  "$bin" eval "${bags[@]}" --method raw --method static-bias --method power-on-bias --json "$work/$set.eval.json" >/dev/null
  for support in "${bags[@]}"; do
    s="$(basename "$support" .mcap)"
    judges=(); for b in "${bags[@]}"; do [ "$b" = "$support" ] || judges+=(--judge "$b"); done
    "$bin" adapt --model "$model" --bag "$support" "${judges[@]}" -o "$work/$set/$s-adapted.pt" --json \
      > "$work/$set/$s.adapt.json" 2> "$work/$set/$s.adapt.log" || true
    echo "[poweron-euroc] $set $s: $(tail -1 "$work/$set/$s.adapt.log")" >&2
    # The user's protocol with no other power-on at hand (as the node's ~/adapt): adapt on
    # the support alone, then run what was written on the others as deployed.
    others=(); for b in "${bags[@]}"; do [ "$b" = "$support" ] || others+=("$b"); done
    if "$bin" adapt --model "$model" --bag "$support" -o "$work/$set/$s-alone.pt" --json \
      > "$work/$set/$s.alone.adapt.json" 2> "$work/$set/$s.alone.adapt.log"; then
      "$bin" eval "${others[@]}" --model "$work/$set/$s-alone.pt" --json "$work/$set/$s.alone.eval.json" >/dev/null
    fi
    echo "[poweron-euroc] $set $s without --judge: $(tail -1 "$work/$set/$s.alone.adapt.log")" >&2
  done
  # Judged on the past, scored on the future.
  for ((i = 1; i < ${#bags[@]} - 1; i++)); do
    s="$(basename "${bags[i]}" .mcap)"
    past=(); for ((j = i > judge_power_ons ? i - judge_power_ons : 0; j < i; j++)); do past+=(--judge "${bags[j]}"); done
    if "$bin" adapt --model "$model" --bag "${bags[i]}" "${past[@]}" -o "$work/$set/$s-past.pt" --json \
      > "$work/$set/$s.past.adapt.json" 2> "$work/$set/$s.past.adapt.log"; then
      "$bin" eval "${bags[@]:i+1}" --model "$work/$set/$s-past.pt" --json "$work/$set/$s.past.eval.json" >/dev/null
    fi
    echo "[poweron-euroc] $set $s judged on the $(( ${#past[@]} / 2 )) before it: $(tail -1 "$work/$set/$s.past.adapt.log")" >&2
  done
done
JUDGE_POWER_ONS="$judge_power_ons" MARKER_SUFFIX="$suffix" "$PYTHON" "$here/scripts/poweron_euroc_table.py" "$work" \
  "$here/docs/poweron-euroc$suffix.json" "$here/docs/poweron.md"
