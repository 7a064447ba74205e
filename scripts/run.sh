#!/usr/bin/env bash
# The main job on the bundled default: set up (idempotent), then
#  1. run the denoising node's pipeline with the bundled model over the bundled bags
#     (`imu-fsda replay`, the node's own code path) and print the orientation-error table:
#     raw gyro, static-bias baseline, the model;
#  2. a new IMU, as a robot that reboots meets one: three power-ons of one simulated MPU-9250
#     on the bundled quadruped (params/sim/quadruped_mpu9250_factory.yaml, lasting errors the
#     model never saw) with ground truth; few-shot adaptation on power-on 1's first 60 s
#     (`imu-fsda adapt`), judged on power-on 2, and scored on power-on 3, which neither fitted
#     nor judged it (raw, static-bias, the power-on bias, the bundled model, the adapted one);
#     then the adapted model replayed over power-on 3 and the attitude it published scored
#     (`imu-fsda attitude`).
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
echo "== 2. A new IMU as a robot meets it: adapted on power-on 1, judged on power-on 2, run on power-on 3"
# One MPU-9250 with its datasheet's lasting errors (scale, cross-axis, g-sensitivity); each
# power-on draws a new turn-on bias, noise and walk, and starts with a few seconds at rest.
cfg=params/sim/quadruped_mpu9250_factory.yaml
first="$out/quadruped_power_on_1.mcap"
second="$out/quadruped_power_on_2.mcap"
third="$out/quadruped_power_on_3.mcap"
adapted="$out/fsda-f-quadruped.pt"
"$bin" simulate --config "$cfg" --power-on 1 --rest-s 3 --seconds 180 -o "$first"
"$bin" simulate --config "$cfg" --power-on 2 --rest-s 2 --seconds 120 -o "$second"
"$bin" simulate --config "$cfg" --power-on 3 --rest-s 4 --seconds 120 -o "$third"
# Adapted on power-on 1 after its power-on bias (measured at its rest) is removed, and judged
# on power-on 2: refused (exit 1, nothing written) unless it beats, there, what the node runs
# without it on a new IMU: the gyro minus this power-on's bias.
rm -f "$adapted"
"$bin" adapt --model "$model" --bag "$first" --judge "$second" -o "$adapted" || echo "adaptation refused: on this IMU the node runs the power-on bias"
models=(--model "$model")
[ -f "$adapted" ] && models+=(--model "$adapted")
echo
echo "AOE on power-on 3, held out (whole recording; 'as deployed': what the node runs with the bundled model on this new IMU):"
"$bin" eval "$third" --method raw --method static-bias --method power-on-bias "${models[@]}"
use=("${models[@]: -2}")
echo
"$bin" replay "$third" -o "$out/quadruped_power_on_3-denoised.mcap" "${use[@]}"
echo "the /diagnostics the node publishes on power-on 3 (which correction runs, and why):"
"$bin" bag echo "$out/quadruped_power_on_3-denoised.mcap" --topic /diagnostics --limit 60 | tail -n 1 | grep -o '"key":"\(correction\|correction_reason\|power_on_bias_rad_s\|power_on_bias_stddev_rad_s\)","value":"[^"]*"'
echo
# The first samples carry no orientation (covariance[0] = -1) until gravity gives the tilt.
echo "the /imu/denoised message at 60 s (corrected angular velocity, integrated orientation, covariances):"
"$bin" bag echo "$out/quadruped_power_on_3-denoised.mcap" --topic /imu/denoised --limit 12001 | tail -n 1
echo
echo "the attitude it published against the ground truth, and whether its stated covariance covers it:"
"$bin" attitude "$out/quadruped_power_on_3-denoised.mcap"
[ -f "$adapted" ] && echo "the adapted model: $adapted (run it: imu-fsda node --params params/imu_fsda.yaml --model $adapted)"
exit 0
