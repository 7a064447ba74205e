#!/usr/bin/env bash
# The few-shot claim on domains the model never saw (issue 5, docs/adaptation.md):
# a model meta-trained on EuRoC only is adapted with the first 60 s of each unseen domain and
# judged on the rest of it (the query set), beside training from scratch on the same 60 s and
# DIGDL trained on EuRoC. Domains: the six TUM-VI rooms (another IMU, hand-held), and two
# simulated robots (a car with an MTi-600-like IMU, a quadruped with an MPU-9250-like IMU,
# datasheet errors on). Rooms: the adapted model is also run on the other rooms (same IMU).
#
#   bash scripts/fewshot.sh            # writes docs/fewshot.md and docs/fewshot.json
#   MODEL=models/fsda-f.pt OUT=docs/fewshot-bundled bash scripts/fewshot.sh
#                                      # the same from the bundled model (the rooms are not
#                                      # unseen for it; the simulated robots are)
#
# Models (defaults): MODEL=models/fsda-f-euroc.pt (params/train/fsda-f-euroc.yaml),
# DIGDL=models/digdl-euroc.pt (params/train/digdl-euroc.yaml). Bags and adapted models go to
# the user cache ($IMU_FSDA_CACHE/fewshot, the adaptations and evaluations under runs/<model>-<sha256>/,
# so two starting models never mix), never into the repository; OUT (default docs/fewshot,
# relative to the repository) names the page and its JSON.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
IMU_FSDA_NO_BUILD="${IMU_FSDA_BIN:+1}" "$here/scripts/setup.sh"
data="${IMU_FSDA_DATA:-$here/../shared/data}"
[ -d "$data/tumvi" ] || { echo "error: datasets not found at $data (set IMU_FSDA_DATA)" >&2; exit 1; }
bin="${IMU_FSDA_BIN:-$here/target/release/imu-fsda}"
model="${MODEL:-$here/models/fsda-f-euroc.pt}"
digdl="${DIGDL:-$here/models/digdl-euroc.pt}"
support_s="${SUPPORT_S:-60}"
scratch_epochs="${SCRATCH_EPOCHS:-300}"
require_models "$model" "$digdl"
work="$IMU_FSDA_CACHE/fewshot"
mstem="$(basename "${model%.pt}")"
run="$work/runs/$mstem-$(sha256sum "$model" | cut -c1-12)"   # keyed by the file's content
mkdir -p "$work/bags" "$work/scratch" "$run/adapted" "$run/eval"

# Domains: TUM-VI rooms and two simulated robots (3 min each, seeded, byte-identical reruns).
domains=()
for r in 1 2 3 4 5 6; do
  b="$work/bags/room$r.mcap"
  [ -f "$b" ] || "$bin" import "$data/tumvi/dataset-room${r}_512_16" -o "$b" >/dev/null
  domains+=("room$r")
done
[ -f "$work/bags/sim_car_mti600.mcap" ] ||
  "$bin" simulate --profile car --grade mti-600 --seconds 180 --seed 11 --datasheet-errors -o "$work/bags/sim_car_mti600.mcap" >/dev/null
[ -f "$work/bags/sim_quadruped_mpu9250.mcap" ] ||
  "$bin" simulate --profile quadruped --grade mpu-9250 --seconds 180 --seed 12 --datasheet-errors -o "$work/bags/sim_quadruped_mpu9250.mcap" >/dev/null
domains+=(sim_car_mti600 sim_quadruped_mpu9250)

for d in "${domains[@]}"; do
  bag="$work/bags/$d.mcap"
  # 1. The paper's few-shot step (Embedding only) on the support set, judged on the query set.
  out="$run/adapted/$mstem-$d.pt"
  start=$(date +%s.%N)
  if "$bin" adapt --keep-power-on-bias --model "$model" --bag "$bag" --support-seconds "$support_s" --embedding-only -o "$out" --json >"$run/adapted/$d.adapt.json" 2>"$run/adapted/$d.adapt.log"; then
    status=accepted
  else
    status=rejected
  fi
  end=$(date +%s.%N)
  echo "{\"domain\": \"$d\", \"status\": \"$status\", \"wall_seconds\": $(echo "$end - $start" | bc)}" >"$run/adapted/$d.status.json"
  # 1b. The default: also the calibration head (Ĉ_ω and the output bias; beyond the paper).
  out_cal="$run/adapted/$mstem-$d-cal.pt"
  start=$(date +%s.%N)
  if "$bin" adapt --keep-power-on-bias --model "$model" --bag "$bag" --support-seconds "$support_s" -o "$out_cal" --json >"$run/adapted/$d.cal.adapt.json" 2>"$run/adapted/$d.cal.adapt.log"; then
    status_cal=accepted
  else
    status_cal=rejected
  fi
  end=$(date +%s.%N)
  echo "{\"domain\": \"$d\", \"status\": \"$status_cal\", \"wall_seconds\": $(echo "$end - $start" | bc)}" >"$run/adapted/$d.cal.status.json"
  # 2. From scratch on the same support set (the FSDA framework, no meta-learning), judged on the query set.
  cfg="$work/scratch/$d.yaml"
  cat >"$cfg" <<YAML
model: {mode: fsda}
dataset:
  root: $work/bags
  train: [{bag: $d.mcap, end_s: $support_s, name: ${d}_support}]
  test: [{bag: $d.mcap, start_s: $support_s, name: ${d}_query}]
train:
  seed: 0
  epochs: $scratch_epochs
  schedule: {kind: cosine_warm_restarts, t0: $scratch_epochs, t_mult: 1}
  windows_per_sequence: 4
  window_samples: 3000
  augment: {gyro_noise_std: 8.0e-5, accel_noise_std: 1.0e-3, gyro_offset: 1.0e-3}
  zero_init_correction: true
  threads: 1
YAML
  [ -f "$work/scratch/$d.train.json" ] || "$bin" train --config "$cfg" --out-dir "$work/scratch" --name "$d" --no-progress >"$work/scratch/$d.log" 2>&1 ||
    echo "scratch training on $d failed: see $work/scratch/$d.log" >&2
  # 3. Every model on the same query set, scored the same way.
  models=(--model "$model" --model "$digdl")
  [ "$status" = accepted ] && models+=(--model "$out")
  [ "$status_cal" = accepted ] && models+=(--model "$out_cal")
  [ -f "$work/scratch/$d.pt" ] && models+=(--model "$work/scratch/$d.pt")
  "$bin" eval "$bag" --start-s "$support_s" --method raw "${models[@]}" --json "$run/eval/$d.query.json" >/dev/null
done
# 4. Rooms: the model adapted on one room, on the other rooms (whole recordings).
for d in "${domains[@]}"; do
  case "$d" in room*) ;; *) continue ;; esac
  adapted_models=()
  for a in "$run/adapted/$mstem-$d.pt" "$run/adapted/$mstem-$d-cal.pt"; do [ -f "$a" ] && adapted_models+=(--model "$a"); done
  [ ${#adapted_models[@]} -gt 0 ] || continue
  others=()
  for o in "${domains[@]}"; do case "$o" in room*) [ "$o" != "$d" ] && others+=("$work/bags/$o.mcap") ;; esac; done
  "$bin" eval "${others[@]}" --method raw --model "$model" "${adapted_models[@]}" --json "$run/eval/$d.others.json" >/dev/null
done

out_page="${OUT:-docs/fewshot}"
if [ -z "${MODEL:-}" ]; then
  args=()
else
  args=("${model%.pt}.json" "MODEL=${MODEL#"$here"/} OUT=$out_page bash scripts/fewshot.sh")
fi
"$PYTHON" "$here/scripts/fewshot_table.py" "$run" "$mstem" "$support_s" "$here/$out_page.md" "$here/$out_page.json" "${args[@]}"
echo "wrote $out_page.md"
