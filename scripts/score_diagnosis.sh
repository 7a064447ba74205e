#!/usr/bin/env bash
# Score `imu-fsda diagnose` on generated sim-vs-real cases (the project's simulator): random
# profiles, IMU grades, rates 100–1000 Hz, durations, 0–3 left-out terms sized near the
# detection limit. Prints per case and a summary (recall, spurious-term rate, parameter
# error by the effect-based score); writes score.json and cases.csv.
#   scripts/score_diagnosis.sh [CASES=40] [SEED=1] [OUT=target/diagnose-score]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
export LD_LIBRARY_PATH="$LIBTORCH/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
cases="${1:-40}"
seed="${2:-1}"
out="${3:-target/diagnose-score}"
cargo build --release --quiet
target/release/imu-fsda diagnose --score-generated "$cases" --seed "$seed" -o "$out"
