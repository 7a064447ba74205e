# Sourced by the other scripts: where the shared torch venv lives and how cargo finds libtorch.
# The venv sits under the user's cache so every clone (and every CI run) reuses it.
IMU_FSDA_CACHE="${XDG_CACHE_HOME:-$HOME/.cache}/imu-fsda"
IMU_FSDA_VENV="${IMU_FSDA_VENV:-$IMU_FSDA_CACHE/torch-2.13.0}"
export IMU_FSDA_VENV
export LIBTORCH="$IMU_FSDA_VENV/lib/python3.11/site-packages/torch"
export LIBTORCH_BYPASS_VERSION_CHECK=1
export PYTHON="$IMU_FSDA_VENV/bin/python"
