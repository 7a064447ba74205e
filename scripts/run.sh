#!/usr/bin/env bash
# The main job on the bundled default: set up (idempotent), then run the denoising node's
# pipeline with the bundled model over a bundled bag (`imu-fsda replay`, the node's own code
# path) and print the orientation-error table: raw gyro, static-bias baseline, the model.
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
if [ -f "$model" ]; then
  for b in "${bags[@]}"; do
    "$bin" replay "$b" -o "$out/$(basename "$b" .mcap)-denoised.mcap" --model "$model"
  done
  echo
  "$bin" bag info "$out/$(basename "${bags[0]}" .mcap)-denoised.mcap"
  echo
  "$bin" eval "${bags[@]}" --method raw --method static-bias --model "$model"
else
  echo "note: $model is not there yet (train it: imu-fsda train --config params/train/fsda-f.yaml); evaluating the baselines only" >&2
  "$bin" eval "${bags[@]}" --method raw --method static-bias
fi
