#!/usr/bin/env bash
# What SROS2 (DDS Security) costs the node: end-to-end latency (play publishes → node →
# play receives /imu/denoised) and the node's CPU share, plain DDS and secured (Enforce, a
# keystore from scripts/sros2_keystore.sh with `ros2 security`'s governance), at 200 Hz and
# 1 kHz, in a private network namespace. The two are run in turn, ROUNDS times each (default
# 2), so that a machine's drift falls on both. Prints everything; writes nothing into the repo.
#
#   bash scripts/bench_security.sh [BAG] [ROUNDS]
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
bash scripts/setup.sh >/dev/null
bin="$here/target/release/imu-fsda"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
bag="${1:-$here/test_bags/sim_quadruped.mcap}"
rounds="${2:-2}"
bash scripts/sros2_keystore.sh "$work/keystore" /imu_fsda /imu_play >/dev/null
echo "bag: $bag; no model (the power-on bias path); $rounds rounds; $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
tck=$(getconf CLK_TCK)
run() { # $1 plain|secured, $2 rate factor → one line of figures
  local sec=""
  if [ "$1" = secured ]; then
    sec="export ROS_SECURITY_ENABLE=true ROS_SECURITY_STRATEGY=Enforce ROS_SECURITY_KEYSTORE='$work/keystore'"
  fi
  timeout 120 unshare -n bash -c "
    ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo
    $sec
    '$bin' node --model '' --enclave /imu_fsda --idle-exit-s 3 --stats-json > '$work/stats.json' 2>'$work/node.err' &
    pid=\$!
    sleep 1
    c0=\$(awk '{print \$14+\$15}' /proc/\$pid/stat); t0=\$(date +%s.%N)
    '$bin' play '$bag' --enclave /imu_play --topic /imu/data -r /imu/data:=/imu/data_raw --rate $2 --wait-for-subscribers-s 10 --latency-topic /imu/denoised 2>'$work/play.err'
    c1=\$(awk '{print \$14+\$15}' /proc/\$pid/stat); t1=\$(date +%s.%N)
    awk -v c0=\$c0 -v c1=\$c1 -v t0=\$t0 -v t1=\$t1 'BEGIN {print \"cpu_share\", (c1 - c0) / $tck / (t1 - t0)}'
    wait \$pid
  "
}
for rate in 1 5; do
  hz=$((200 * rate))
  for round in $(seq "$rounds"); do
    for mode in plain secured; do
      out=$(run "$mode" "$rate")
      lat=$(echo "$out" | grep '^latency' || echo "latency: none (see the node's log)")
      cpu=$(echo "$out" | awk '/^cpu_share/ {printf "%.1f%%", 100*$2}')
      sec=$(python3 -c "import json;print(json.load(open('$work/stats.json')).get('security') or 'off')" 2>/dev/null || echo "no stats")
      printf '%5d Hz round %d %-8s | %s | node CPU %s | security: %s\n' "$hz" "$round" "$mode" "${lat#latency publish → /imu/denoised: }" "$cpu" "$sec"
    done
  done
done
