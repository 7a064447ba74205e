#!/usr/bin/env bash
# Regenerate docs/figures/*.png (presented in docs/figures.md) from the bundled models and
# ../shared/data (IMU_FSDA_DATA overrides), ../shared/bench/concealed (IMU_FSDA_BENCH).
# IMU_FSDA_BIN: use this imu-fsda binary instead of building target/release/imu-fsda.
# Bags go to the user cache, never into the repository.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
data="${IMU_FSDA_DATA:-$here/../shared/data}"
bench="${IMU_FSDA_BENCH:-$here/../shared/bench/concealed}"
[ -d "$data/euroc" ] || { echo "error: datasets not found at $data (set IMU_FSDA_DATA)" >&2; exit 1; }
if [ -n "${IMU_FSDA_BIN:-}" ]; then
  bin="$IMU_FSDA_BIN"
else
  "$here/scripts/setup.sh"
  bin="$here/target/release/imu-fsda"
fi
out="$here/docs/figures"
mkdir -p "$out"
bags="$IMU_FSDA_CACHE/bags"
mkdir -p "$bags"

# Figs. 3 and 4 of the paper: attitude and its error on room4 (TUM-VI) and V1_01 (EuRoC),
# raw gyro vs DIGDL vs FSDA-F, open-loop integration over the whole sequence.
[ -f "$bags/V1_01_easy.mcap" ] || "$bin" import "$data/euroc/V1_01_easy" -o "$bags/V1_01_easy.mcap"
[ -f "$bags/room4.mcap" ] || "$bin" import "$data/tumvi/dataset-room4_512_16" -o "$bags/room4.mcap"
"$bin" eval "$bags/room4.mcap" "$bags/V1_01_easy.mcap" --method raw \
  --model "$here/models/digdl-euroc.pt" --model "$here/models/fsda-f.pt" \
  "${paper_imu_args[@]}" --plot-dir "$out" >/dev/null

# The t-SNE of FSDA-F's Embedding over the train and test sequences of both datasets.
seqs=()
for s in MH_01_easy MH_02_easy MH_03_medium MH_04_difficult MH_05_difficult \
         V1_01_easy V1_02_medium V1_03_difficult V2_01_easy V2_02_medium V2_03_difficult; do
  seqs+=("$data/euroc/$s")
done
for r in 1 2 3 4 5 6; do seqs+=("$data/tumvi/dataset-room${r}_512_16"); done
"$bin" embed --model "$here/models/fsda-f.pt" --sequence "${seqs[@]}" \
  --points-per-sequence 150 --seed 0 -o "$out/embedding_tsne.png"

# One diagnosis: a concealed case with two left-out terms, a located segment and bands.
case=misalignment_plus_bias_handheld
if [ -d "$bench/$case" ]; then
  tmp="$(mktemp -d)"
  "$bin" diagnose --sim "$bench/$case/sim.mcap" --real "$bench/$case/real.mcap" -o "$tmp"
  for f in psd allan residual; do cp "$tmp/$f.png" "$out/diagnosis_${case}_$f.png"; done
  rm -rf "$tmp"
else
  echo "warning: $bench/$case not found; the diagnosis figures were not regenerated" >&2
fi
ls -l "$out"/*.png
