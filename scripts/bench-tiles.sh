#!/usr/bin/env bash
# Sort-first tiles against one untiled node and sort-last partitions, through the local cluster:
# the default scene's 32 light samples on one light group (K = 32), so the grid has one node per
# tile or part; walkthrough mode with the camera orbiting (maps kept, every frame's eye pass
# rendered), the paper's case for sort-first. Prints each run's per-daemon table and summary;
# summarised in docs/scaling.md § Sort-first tiles.
#   scripts/bench-tiles.sh [SIZE] [FRAMES]
# LAYOUTS (layouts separated by '|', e.g. "--tiles 1|--tiles 2") runs only those.
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:-1920x1080}; frames=${2:-6}
bin=target/release/lightfold
[ -x "$bin" ] || cargo build --release -p lightfold-cli
export NODEVICE_SELECT=1
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
IFS='|' read -r -a layouts <<<"${LAYOUTS:---tiles 1|--tiles auto|--tiles 2|--tiles 4|--partitions 2|--partitions 4}"
for layout in "${layouts[@]}"; do
  echo "=== $layout size=$size frames=$frames"
  # shellcheck disable=SC2086 # the layout is two words
  "$bin" demo -K 32 --size "$size" --frames "$frames" --orbit 2 --walkthrough --no-compare \
    --no-frame-files --out "$out/frame.png" --exr "$out/frame.exr" $layout 2>/dev/null \
    | grep -E "^(\| (node|comp)-|frame interval|node-seconds|tiles:|partitions:|demo: daemon CPU)|decomposition:"
done
