#!/usr/bin/env bash
# Idempotent set-up for a fresh machine: the torch venv (libtorch for tch, and the Python
# test peers: mcap, rosbags, cyclonedds), Debian's Fast DDS for the C++ peer, OpenSSL for DDS
# Security, then a release build of imu-fsda.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$here/scripts/env.sh"
stamp="$IMU_FSDA_VENV/.imu-fsda-ready-v2"
if [ ! -f "$stamp" ]; then
  echo "[setup] creating the torch venv at $IMU_FSDA_VENV (first run only, ~2-5 min)"
  mkdir -p "$(dirname "$IMU_FSDA_VENV")"
  [ -x "$IMU_FSDA_VENV/bin/python" ] || python3 -m venv "$IMU_FSDA_VENV"
  "$IMU_FSDA_VENV/bin/pip" install -q --disable-pip-version-check -r "$here/scripts/requirements.txt"
  touch "$stamp"
fi
if ! command -v unshare >/dev/null || ! command -v ip >/dev/null; then
  echo "[setup] installing iproute2/util-linux for the network-namespace tests"
  (apt-get update -qq && apt-get install -y -qq iproute2 util-linux) >/dev/null 2>&1 || echo "[setup] could not install iproute2; DDS tests will skip loudly"
fi
if [ ! -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ] && [ -z "${IMU_FSDA_FONT:-}" ]; then
  echo "[setup] installing fonts-dejavu-core (the text of the PNG figures)"
  (apt-get update -qq && apt-get install -y -qq fonts-dejavu-core) >/dev/null 2>&1 || echo "[setup] could not install fonts-dejavu-core; figures will fail with a clear error (set IMU_FSDA_FONT to a .ttf)"
fi
if [ ! -f /usr/include/fastdds/dds/domain/DomainParticipant.hpp ] || ! command -v g++ >/dev/null; then
  echo "[setup] installing Fast DDS 2.9 (libfastrtps-dev) and g++: the Fast DDS peer of tests/dds_fastdds.rs"
  (apt-get update -qq && apt-get install -y -qq --no-install-recommends libfastrtps-dev libfastcdr-dev g++) >/dev/null 2>&1 || echo "[setup] could not install libfastrtps-dev; the Fast DDS test will skip loudly (fail under CI)"
fi
if [ ! -f /usr/include/openssl/ssl.h ] || ! command -v pkg-config >/dev/null || ! command -v openssl >/dev/null; then
  echo "[setup] installing libssl-dev, pkg-config and openssl: DDS Security (SROS2) in the node, and scripts/sros2_keystore.sh"
  (apt-get update -qq && apt-get install -y -qq --no-install-recommends libssl-dev pkg-config openssl) >/dev/null 2>&1 || echo "[setup] could not install libssl-dev; the build needs OpenSSL's headers"
fi
cd "$here"
# IMU_FSDA_NO_BUILD=1: venv and system packages only (scripts given a prebuilt IMU_FSDA_BIN).
[ "${IMU_FSDA_NO_BUILD:-}" = 1 ] || cargo build --release --quiet
