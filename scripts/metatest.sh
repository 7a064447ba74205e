#!/usr/bin/env bash
# The paper's meta-test protocol on its test split (issue 3, docs/metatest.md): every test
# sequence is a meta-testing task whose first 60 s are the support set and the rest the query
# set. The bundled model is adapted on the support set only — the few-shot step on the first
# 45 s, accepted or refused on 45–60 s (so nothing of the scored part is seen) — and every
# method is then scored on the query set (60 s–end), beside the raw gyro, DIGDL and the bundled
# model run as deployed.
#
#   bash scripts/metatest.sh            # writes docs/metatest.md and docs/metatest.json
#
# MODEL (default models/fsda-f.pt), DIGDL (default models/digdl-euroc.pt). Bags and adapted
# models go to the user cache ($IMU_FSDA_CACHE/metatest), never into the repository.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD="${IMU_FSDA_BIN:+1}" "$here/scripts/setup.sh"
data="${IMU_FSDA_DATA:-$here/../shared/data}"
[ -d "$data/euroc" ] || { echo "error: datasets not found at $data (set IMU_FSDA_DATA)" >&2; exit 1; }
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
model="${MODEL:-$here/models/fsda-f.pt}"
digdl="${DIGDL:-$here/models/digdl-euroc.pt}"
support_s=60
adapt_s=45 # of the support set: the rest of it (15 s) judges the adaptation
require_models "$model" "$digdl"
work="$IMU_FSDA_CACHE/metatest"
mkdir -p "$work"
rm -f "$work"/*.json "$work"/*.log
mapfile -t bag_list < <(paper_test_bags "$bin" "$data")
[ ${#bag_list[@]} -eq 8 ] || { echo "error: importing the test split failed" >&2; exit 1; }
mstem="$(basename "${model%.pt}")"
# A model that knows IMUs by name (one Ĉ_ω or a correction gain per IMU) adapts from, and is
# judged against, itself as deployed on the test IMU.
per_imu=0
grep -q -e '"imu_gyro_calibrations"' -e '"imu_correction_gains"' "${model%.pt}.json" && per_imu=1
for bag in "${bag_list[@]}"; do
  s="$(basename "${bag%.mcap}")"
  models=(--model "$model" --model "$digdl")
  imu_flag=()
  [ "$per_imu" = 1 ] && imu_flag=(--imu "$(paper_imu "$bag")")
  for variant in adapted embedding-only; do
    flag=()
    [ "$variant" = embedding-only ] && flag=(--embedding-only)
    out="$work/$mstem-$s-$variant.pt"
    rm -f "$out" "${out%.pt}".{ot,json,adapt.json}
    start=$(date +%s.%N)
    if "$bin" adapt --keep-power-on-bias --model "$model" --bag "$bag" "${imu_flag[@]}" --support-seconds "$adapt_s" --query-seconds "$((support_s - adapt_s))" \
      "${flag[@]}" -o "$out" --json >"$work/$s.$variant.adapt.json" 2>"$work/$s.$variant.log"; then
      status=accepted
      models+=(--model "$out")
    else
      status=rejected
    fi
    end=$(date +%s.%N)
    echo "{\"sequence\": \"$s\", \"variant\": \"$variant\", \"status\": \"$status\", \"wall_seconds\": $(echo "$end - $start" | bc)}" >"$work/$s.$variant.status.json"
  done
  "$bin" eval "$bag" --start-s "$support_s" --method raw "${models[@]}" "${paper_imu_args[@]}" --json "$work/$s.query.json" >/dev/null
done
"$PYTHON" "$here/scripts/metatest_table.py" "$work" "$mstem" "$here/docs/metatest.md" "$here/docs/metatest.json"
echo "wrote docs/metatest.md"
