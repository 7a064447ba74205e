#!/usr/bin/env bash
# The main job on the bundled default: set up (idempotent), then evaluate the raw and
# static-bias gyro on the bundled test bags and print the orientation-error table.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup.sh
shopt -s nullglob
bags=(test_bags/*.mcap)
[ ${#bags[@]} -gt 0 ] || { echo "error: no bags in test_bags/ (regenerate: bash scripts/make_test_bags.sh)" >&2; exit 1; }
for b in "${bags[@]}"; do ./target/release/imu-fsda bag info "$b"; echo; done
./target/release/imu-fsda eval "${bags[@]}" --method raw --method static-bias
