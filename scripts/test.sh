#!/usr/bin/env bash
# The whole test suite, from a fresh clone: set-up (idempotent), format, lint, tests.
# Unit, property and integration tests (CLI on bags, independent Python readers of our bags,
# DDS peers in a private network namespace) all run under `cargo test`.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
source scripts/env.sh
bash scripts/setup.sh
echo "[test] rustfmt"
cargo fmt --all -- --check
echo "[test] clippy"
cargo clippy --release --all-targets --quiet -- -D warnings
echo "[test] cargo test"
set +e
cargo test --release --no-fail-fast 2>&1 | tee "$IMU_FSDA_CACHE/last-test.log"
status=${PIPESTATUS[0]}
set -e
passed=$(grep -Eo '^test result: [a-zA-Z]+\. [0-9]+ passed' "$IMU_FSDA_CACHE/last-test.log" | awk '{s+=$4} END {print s+0}')
failed=$(grep -Eo '[0-9]+ failed' "$IMU_FSDA_CACHE/last-test.log" | awk '{s+=$1} END {print s+0}')
echo "tests: $passed passed, $failed failed"
exit "$status"
