#!/usr/bin/env bash
# The node's per-sample latency while it adapts (`~/adapt`) against while it is idle, in the
# same run, over DDS in a private network namespace (loopback only).
#
# The node runs a model (default: the bundled models/fsda-f.pt) with a ground-truth topic;
# tests/python/adapt_peer.py streams EuRoC MH_02_easy at its recorded 200 Hz (IMU, and the
# ground truth as geometry_msgs/PoseStamped) and calls `~/adapt` at the data times in
# REQUESTS (default three calls, each once the previous one is answered), then streams
# AFTER_S more seconds. The node files every sample's latency under "idle" or "adapting"
# (whether an adaptation job was running when the sample was processed) and prints them at
# exit (`--stats-json`):
#   in-node         input taken from the subscription → /imu/denoised and the correction published
#   write→publish   the input's DDS source timestamp (the peer's write) → published: adds DDS
#                   delivery and any wait for a free tokio worker, i.e. starvation shows here.
# Usage: scripts/bench_adapt.sh            (env: MODEL, NICE=10, STEPS=100, LR=0.001,
#        SUPPORT_S=30, REQUESTS=45,60,75, AFTER_S=10, IMU_FSDA_BIN)
# Prints everything; writes nothing into the repo. Needs root (unshare) and the venv.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
if [ -z "${IMU_FSDA_BIN:-}" ]; then
  bash scripts/setup.sh >/dev/null
  IMU_FSDA_BIN="${CARGO_TARGET_DIR:-$here/target}/release/imu-fsda"
fi
model="$(realpath "${MODEL:-$here/models/fsda-f.pt}")"
seq="$here/../shared/data/euroc/MH_02_easy/mav0"
[ -f "$seq/imu0/data.csv" ] || { echo "bench_adapt: $seq not found (../shared/data)" >&2; exit 2; }
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/adapted"
cat >"$work/params.yaml" <<EOF
imu_fsda:
  ros__parameters:
    adapt_enabled: true
    ground_truth_topic: /ground_truth/pose
    adapt_support_seconds: ${SUPPORT_S:-30}
    adapted_model_dir: $work/adapted
    adapt_thread_nice: ${NICE:-10}
    adapt:
      power_on_bias: false   # MH_02 starts in flight: no standstill to measure
      steps: ${STEPS:-100}
      inner_lr: ${LR:-0.001}
EOF
echo "model: $model; data: MH_02_easy at 200 Hz; adaptation: ${STEPS:-100} steps, lr ${LR:-0.001}, support ${SUPPORT_S:-30} s, thread nice ${NICE:-10}"
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg) ($(nproc) cores)"
timeout 300 unshare --net --pid --fork --kill-child bash -c "
  ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo || exit 90
  '$IMU_FSDA_BIN' node --params '$work/params.yaml' --model '$model' --stats-json >'$work/node.out' 2>'$work/node.err' </dev/null &
  node=\$!
  '$PYTHON' tests/python/adapt_peer.py --csv '$seq/imu0/data.csv' --gt-csv '$seq/state_groundtruth_estimate0/data.csv' \
      --requests '${REQUESTS:-45,60,75}' --after-s '${AFTER_S:-10}' --rate-fast 200 --rate-busy 200 \
      --reply-timeout-s 120 --out '$work/peer.json' 2>'$work/peer.err' </dev/null
  kill -TERM \$node; wait \$node
" || { echo "bench_adapt: the namespace run failed; node stderr:" >&2; tail -20 "$work/node.err" >&2; tail -20 "$work/peer.err" >&2; exit 1; }
echo "load average after:  $(cut -d' ' -f1-3 /proc/loadavg)"
"$PYTHON" - "$work/node.out" "$work/peer.json" <<'EOF'
import json, sys
stats = [json.loads(l) for l in open(sys.argv[1]) if l.startswith("{")][-1]
peer = json.load(open(sys.argv[2]))
for r in peer["replies"]:
    print(f"reply at {r['t']:.1f} s: success={r['success']}: {r['message']}")
c = stats["counters"]
print(f"inputs sent {len(peer['sent'])}, received {c['received']}, published {c['processed']}, outputs at the peer "
      f"{len(peer['denoised'])}; adaptation time (last) {stats['adapt_seconds']:.1f} s")
s = stats["latency_by_adaptation_state"]
print(f"{'':10} {'samples':>8} | {'in-node p50 / p99 / max (µs)':>30} | {'write→publish p50 / p99 / max (µs)':>36}")
for state in ("idle", "adapting"):
    a, b = s[state]["in_node"], s[state]["write_to_publish"]
    print(f"{state:10} {a['count']:>8} | {a['p50_us']:>8.0f} / {a['p99_us']:>7.0f} / {a['max_us']:>8.0f} | "
          f"{b['p50_us']:>10.0f} / {b['p99_us']:>8.0f} / {b['max_us']:>9.0f}")
for kind in ("in_node", "write_to_publish"):
    i, a = s["idle"][kind]["p99_us"], s["adapting"][kind]["p99_us"]
    ratio = a / i if i else float("nan")
    print(f"{kind}: p99 adapting / idle = {ratio:.2f} (target ≤ 2: {'met' if ratio <= 2 else 'NOT met'})")
EOF
