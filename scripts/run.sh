#!/usr/bin/env bash
# The main job on the bundled default: set up (idempotent), then
#  1. run the denoising node's pipeline with the bundled model over the bundled bags
#     (`imu-fsda replay`, the node's own code path) and print the orientation-error table:
#     raw gyro, static-bias baseline, the model;
#  2. a new IMU, as a user meets one: a 3-minute recording of the bundled quadruped
#     (params/sim/quadruped_mpu9250.yaml, an MPU-9250 the model never saw) with ground truth;
#     few-shot adaptation on its first 60 s (`imu-fsda adapt`), the rest held back and scored
#     (raw, the bundled model, the adapted one), then the adapted model replayed over it and
#     the attitude it published scored (`imu-fsda attitude`).
# Everything it writes goes to the user cache, never into the repository.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup.sh
bin=./target/release/imu-fsda
shopt -s nullglob
bags=(test_bags/*.mcap)
[ ${#bags[@]} -gt 0 ] || { echo "error: no bags in test_bags/ (regenerate: bash scripts/make_test_bags.sh)" >&2; exit 1; }
model=models/fsda-f.pt
out="${XDG_CACHE_HOME:-$HOME/.cache}/imu-fsda/run"
mkdir -p "$out"
if [ ! -f "$model" ]; then
  echo "note: $model is not there yet (train it: imu-fsda train --config params/train/fsda-f.yaml); evaluating the baselines only" >&2
  "$bin" eval "${bags[@]}" --method raw --method static-bias
  exit 0
fi

echo "== 1. The bundled model over the bundled bags (20-s simulated IMUs it was not trained on)"
for b in "${bags[@]}"; do
  "$bin" replay "$b" -o "$out/$(basename "$b" .mcap)-denoised.mcap" --model "$model"
done
echo
"$bin" bag info "$out/$(basename "${bags[0]}" .mcap)-denoised.mcap"
echo
"$bin" eval "${bags[@]}" --method raw --method static-bias --model "$model"

echo
echo "== 2. A new IMU: few-shot adaptation on 60 s with ground truth, judged on the next 120 s"
quad="$out/quadruped_mpu9250_180s.mcap"
adapted="$out/fsda-f-quadruped.pt"
"$bin" simulate --config params/sim/quadruped_mpu9250.yaml --seconds 180 -o "$quad" --truth "$out/quadruped_mpu9250_180s.truth.yaml"
# An adaptation that does not beat the starting model on the held-back part is refused (exit 1)
# and no model is written: then the table shows the starting model alone.
rm -f "$adapted"
"$bin" adapt --model "$model" --bag "$quad" --support-seconds 60 -o "$adapted" || echo "adaptation refused: the bundled model is kept"
models=(--model "$model")
[ -f "$adapted" ] && models+=(--model "$adapted")
echo
echo "AOE on the held-back 120 s (after the support set):"
"$bin" eval "$quad" --start-s 60 --method raw "${models[@]}"
if [ -f "$adapted" ]; then
  echo
  "$bin" replay "$quad" -o "$out/quadruped_mpu9250_180s-denoised.mcap" --model "$adapted"
  # The first samples carry no orientation (covariance[0] = -1) until gravity gives the tilt.
  echo "the /imu/denoised message at 120 s (corrected angular velocity, integrated orientation, covariances):"
  "$bin" bag echo "$out/quadruped_mpu9250_180s-denoised.mcap" --topic /imu/denoised --limit 24001 | tail -n 1
  echo
  echo "the attitude it published against the ground truth, and whether its stated covariance covers it:"
  "$bin" attitude "$out/quadruped_mpu9250_180s-denoised.mcap"
  echo
  echo "the adapted model: $adapted (run it: imu-fsda node --params params/imu_fsda.yaml --model $adapted)"
fi
