#!/usr/bin/env bash
# Regenerate test_bags/*.mcap from the seeded configs in params/sim/, bit for bit, then
# regenerate them a second time into a scratch directory and check the bytes are identical.
# Usage: scripts/make_test_bags.sh
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/env.sh
cargo build --release
BIN=target/release/imu-fsda
OUT=test_bags
mkdir -p "$OUT"
SCRATCH=$(mktemp -d)
trap 'rm -rf "$SCRATCH"' EXIT

# bag name  config
BAGS=(
  "sim_aerial     params/sim/aerial_adis16448.yaml"
  "sim_handheld   params/sim/handheld_bmi160.yaml"
  "sim_car        params/sim/car_mti600.yaml"
  "sim_quadruped  params/sim/quadruped_mpu9250.yaml"
)

for entry in "${BAGS[@]}"; do
  read -r name config <<<"$entry"
  "$BIN" simulate --config "$config" -o "$OUT/$name.mcap" --truth "$OUT/$name.truth.yaml"
  "$BIN" simulate --config "$config" -o "$SCRATCH/$name.mcap" --truth "$SCRATCH/$name.truth.yaml" >/dev/null
  cmp "$OUT/$name.mcap" "$SCRATCH/$name.mcap"
  cmp "$OUT/$name.truth.yaml" "$SCRATCH/$name.truth.yaml"
done
echo "test_bags: $(du -ch "$OUT"/*.mcap | tail -1 | cut -f1) in ${#BAGS[@]} bags, regenerated identically"
