# Sourced by the other scripts: where the shared torch venv lives and how cargo finds libtorch.
# The venv sits under the user's cache so every clone (and every CI run) reuses it.
IMU_FSDA_CACHE="${XDG_CACHE_HOME:-$HOME/.cache}/imu-fsda"
IMU_FSDA_VENV="${IMU_FSDA_VENV:-$IMU_FSDA_CACHE/torch-2.13.0}"
export IMU_FSDA_VENV
export LIBTORCH="$IMU_FSDA_VENV/lib/python3.11/site-packages/torch"
export LIBTORCH_BYPASS_VERSION_CHECK=1
export PYTHON="$IMU_FSDA_VENV/bin/python"

# The paper's test split as bags in the user cache (imported once, reused by every script):
# `paper_test_bags BIN DATA` prints one bag path per line, EuRoC then TUM-VI.
paper_test_bags() {
  local bin="$1" data="$2" bags="$IMU_FSDA_CACHE/bags" s
  mkdir -p "$bags"
  for s in MH_02_easy MH_04_difficult V1_01_easy V1_03_difficult V2_02_medium; do
    [ -f "$bags/$s.mcap" ] || "$bin" import "$data/euroc/$s" -o "$bags/$s.mcap" >&2
    echo "$bags/$s.mcap"
  done
  for s in 2 4 6; do
    [ -f "$bags/room$s.mcap" ] || "$bin" import "$data/tumvi/dataset-room${s}_512_16" -o "$bags/room$s.mcap" >&2
    echo "$bags/room$s.mcap"
  done
}

# Which IMU recorded the bags above, for models with one Ĉ_ω per IMU (`imu-fsda eval --imu`):
# EuRoC's ADIS16448, TUM-VI's BMI160, by bag name.
paper_imu_args=(--imu 'room*=tumvi' --imu 'MH_*=euroc' --imu 'V?_*=euroc')
# `paper_imu BAG`: the same, one name.
paper_imu() {
  case "$(basename "$1")" in
    room*) echo tumvi ;;
    *) echo euroc ;;
  esac
}

# `require_models MODEL.pt ...`: stop with the command that trains a missing one.
require_models() {
  local m
  for m in "$@"; do
    [ -f "$m" ] || { echo "error: $m not found (train it: imu-fsda train --config params/train/$(basename "${m%.pt}").yaml)" >&2; exit 1; }
  done
}
