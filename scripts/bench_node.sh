#!/usr/bin/env bash
# Node benchmarks over DDS, in a private network namespace (loopback only):
# end-to-end latency (play publishes → node → play receives /imu/denoised), p50/p99, at
# 200 Hz and 1 kHz input, and the node's CPU share, for the incremental model and the naive
# full-window forward, in the same run. Then the in-process figures of `imu-fsda bench`
# (throughput, memory over an hour). Prints everything; writes nothing into the repo.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
bash scripts/setup.sh >/dev/null
bin="$here/target/release/imu-fsda"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
bag="${1:-$here/test_bags/sim_quadruped.mcap}"
model="${MODEL:-}"
if [ -z "$model" ]; then
  "$bin" bench --samples 2000 --naive-samples 20 --memory-hours 0 --save-model "$work" >/dev/null
  model="$work/bench-fsda-f.pt"
fi
echo "bag: $bag"
echo "model: $model"
tck=$(getconf CLK_TCK)
for mode in incremental naive; do
  for rate in 1 5; do
    hz=$((200 * rate))
    extra=""; [ "$mode" = naive ] && extra="--naive-full-window"
    out=$(timeout 120 unshare -n bash -c "
      ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo
      '$bin' node --model '$model' $extra --idle-exit-s 3 --stats-json > '$work/stats.json' 2>/dev/null &
      pid=\$!
      sleep 1
      c0=\$(awk '{print \$14+\$15}' /proc/\$pid/stat); t0=\$(date +%s.%N)
      '$bin' play '$bag' --topic /imu/data -r /imu/data:=/imu/data_raw --rate $rate --wait-for-subscribers-s 5 --latency-topic /imu/denoised
      c1=\$(awk '{print \$14+\$15}' /proc/\$pid/stat); t1=\$(date +%s.%N)
      awk -v c0=\$c0 -v c1=\$c1 -v t0=\$t0 -v t1=\$t1 'BEGIN {print \"cpu_share\", (c1 - c0) / $tck / (t1 - t0)}'
      wait \$pid
    ")
    lat=$(echo "$out" | grep '^latency' || true)
    cpu=$(echo "$out" | awk '/^cpu_share/ {printf "%.1f%%", 100*$2}')
    node_lat=$(python3 -c "import json;d=json.load(open('$work/stats.json'));c=d['counters'];print(f\"in-node p50 {d['latency_p50_us']:.0f} µs p99 {d['latency_p99_us']:.0f} µs; received {c['received']}, published {c['processed']}, gaps {c['gaps']}\")")
    printf '%-12s %5d Hz | %s | node CPU %s (includes DDS) | %s\n' "$mode" "$hz" "${lat#latency publish → /imu/denoised: }" "$cpu" "$node_lat"
    python3 -c "
import json
d = json.load(open('$work/stats.json'))
st = d.get('latency_by_stage', {})
f = lambda k: f\"{k} p50 {st[k]['p50_us']:.0f} / p99 {st[k]['p99_us']:.0f} µs\" if k in st else ''
w = d.get('latency_by_adaptation_state', {}).get('idle', {}).get('write_to_publish')
back = f'; peer write → node publish p50 {w[\"p50_us\"]:.0f} / p99 {w[\"p99_us\"]:.0f} µs' if w and w['count'] else ''
print('    by stage: ' + ', '.join(f(k) for k in ['dds_receive', 'correct', 'publish_denoised', 'publish_correction']) + back)
"
  done
done
echo
"$bin" bench --model "$model"
