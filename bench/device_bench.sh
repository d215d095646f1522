#!/usr/bin/env bash
# Network devices (issue #16), a small harness over the trocar command on localhost:
#   - latency from a pose's arrival to the control step that takes it (median, p99, max);
#   - the control loop's rate with a device flooding 10 kHz, divided by its rate with a 1 kHz
#     device (target: at least 0.95).
# Usage: bench/device_bench.sh [BUILD_DIR]   (default build)
set -euo pipefail
cd "$(dirname "$0")/.."
trocar="${1:-build}/apps/trocar"
psm=robots/davinci-classic/psm.yaml
run() {  # run RATE: prints the teleop's report for a 4 s session driven at RATE Hz
  local port=$((20000 + RANDOM % 20000))
  "$trocar" teleop --robot "$psm" --listen "127.0.0.1:$port" --duration 4 --wait 20 > "/tmp/device_bench.$$" 2>&1 &
  local teleop=$!
  "$trocar" device --connect "127.0.0.1:$port" --input circle --rate "$1" --duration 4.5 > /dev/null 2>&1 || true
  wait "$teleop"
  cat "/tmp/device_bench.$$"
  rm -f "/tmp/device_bench.$$"
}
steps() { sed -n 's/.*real time: \([0-9]*\) steps.*/\1/p'; }
echo "device at 1 kHz:"
one=$(run 1000)
echo "$one" | grep -E "latency|real time|device '"
echo "device flooding at 10 kHz:"
ten=$(run 10000)
echo "$ten" | grep -E "latency|real time|device '"
a=$(echo "$one" | steps)
b=$(echo "$ten" | steps)
echo "control steps with the flood / with 1 kHz: $b / $a = $(awk -v a="$a" -v b="$b" 'BEGIN { printf "%.3f", b / a }') (target >= 0.95)"
