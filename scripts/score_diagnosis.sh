#!/usr/bin/env bash
# Score `imu-fsda diagnose`:
# 1. on generated sim-vs-real cases (the project's simulator): random profiles, IMU grades,
#    rates 100–1000 Hz, durations, 0–3 left-out terms sized near the detection limit;
# 2. on real recordings with effects injected by the physics code (TUM-VI rooms 1–6, a
#    BMI160 against motion capture with dropouts; six EuRoC flights, an ADIS16448 against
#    its estimator's poses): each recording diagnosed as recorded (the control) and with
#    DRAWS random injected cases, each with its mirror (the same terms with the sign turned),
#    against the simulation of its own ground truth, gyro alone (and TUM-VI with both
#    sensors).
# Prints per case and a summary per set (recall, spurious-term rate beyond the control and how many of those the mirrored case found alike,
# parameter error by the effect-based score); writes score.json and cases.csv per set. On the
# gyro-alone sets the plain per-axis least-squares calibration is scored beside it
# (score.json `plain_calibration`, plain_cases.csv).
#   scripts/score_diagnosis.sh [CASES=40] [SEED=1] [OUT=target/diagnose-score] [DRAWS=6]
#   CASES=0 skips the generated set; DRAWS=0 the real one. Needs ../shared/data for set 2.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
export LD_LIBRARY_PATH="$LIBTORCH/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
cases="${1:-40}"
seed="${2:-1}"
out="${3:-target/diagnose-score}"
draws="${4:-6}"
cargo build --release --quiet
bin=target/release/imu-fsda
if [ "$cases" -gt 0 ]; then
  "$bin" diagnose --score-generated "$cases" --seed "$seed" -o "$out"
fi
[ "$draws" -gt 0 ] || exit 0
data="$here/../shared/data"
[ -d "$data/tumvi" ] || { echo "[score] $data not found: the real-recording set is skipped" >&2; exit 0; }
bags="$out/real-bags"
mkdir -p "$bags"
import() {  # dataset folder, bag name
  [ -s "$bags/$2.mcap" ] || "$bin" import "$1" -o "$bags/$2.mcap" >/dev/null
  echo "$bags/$2.mcap"
}
tumvi=(); for r in 1 2 3 4 5 6; do tumvi+=("$(import "$data/tumvi/dataset-room${r}_512_16" "room$r")"); done
euroc=(); for s in MH_01_easy MH_04_difficult V1_01_easy V1_03_difficult V2_01_easy V2_02_medium; do euroc+=("$(import "$data/euroc/$s" "$s")"); done
gyro_terms=gyro_bias,gyro_scale,gyro_misalignment,gyro_g_sensitivity,time_offset,low_pass
"$bin" diagnose --score-injected "${tumvi[@]}" --noise-model params/noise/bmi160_tumvi.yaml --sensors gyro \
  --score-only "$gyro_terms" --score-draws "$draws" --seed "$seed" -o "$out/tumvi-gyro"
"$bin" diagnose --score-injected "${euroc[@]}" --noise-model params/noise/adis16448_euroc.yaml --sensors gyro \
  --score-only "$gyro_terms" --score-draws "$draws" --seed "$seed" -o "$out/euroc-gyro"
"$bin" diagnose --score-injected "${tumvi[@]}" --noise-model params/noise/bmi160_tumvi.yaml \
  --score-draws "$draws" --seed "$seed" -o "$out/tumvi-both"
