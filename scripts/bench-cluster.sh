#!/usr/bin/env bash
# The local cluster's frame interval, latency and node CPU for L = 32 lights at K = 1, 2, 4, 8, with
# moving lights (shadow maps re-rendered every frame) and in walkthrough mode (kept), the camera
# orbiting so every frame is rendered. Prints one block per run; summarised in docs/cluster.md.
#   scripts/bench-cluster.sh [SIZE] [FRAMES]
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:-400x300}; frames=${2:-6}
bin=target/release/lightfold
[ -x "$bin" ] || cargo build --release -p lightfold-cli
export NODEVICE_SELECT=1
for k in 8 4 2 1; do
  for mode in moving walkthrough; do
    extra=()
    [ "$mode" = walkthrough ] && extra=(--walkthrough)
    echo "=== K=$k $mode size=$size frames=$frames"
    # K = 1 needs 64 nodes and their stages: more than the default --max-processes on 2 cores.
    "$bin" demo -K "$k" --size "$size" --frames "$frames" --orbit 2 --no-compare --max-processes 80 \
      --out /tmp/lightfold-bench.png --exr /tmp/lightfold-bench.exr "${extra[@]}" 2>/dev/null \
      | grep -E "^(nodes:|[0-9]+ frame\(s\)|demo: daemon CPU|frame +[0-9]+:)"
  done
done
