#!/usr/bin/env bash
# Interaction latency of the live view on a local cluster (docs/live-view.md): starts
# `lightfold demo --serve` (extra demo flags from the command line, e.g. --size 320x240), then
# measures with `lightfold view-probe` a drag (30 inputs/s) and single steps of the camera, of
# light 0 and of object $OBJECT (default 1), on-change and --continuous, and stops the demo with
# Ctrl-C.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${LIGHTFOLD:-target/release/lightfold}
[ -x "$bin" ] || cargo build --release -p lightfold-cli
seconds=${SECONDS_PER_RUN:-20}
port=${PORT:-18080}
for mode in on-change continuous; do
  work=$(mktemp -d)
  extra=()
  [ "$mode" = continuous ] && extra=(--continuous)
  "$bin" demo --serve "127.0.0.1:$port" "${extra[@]}" --work-dir "$work" \
    --out "$work/out.png" --exr "$work/out.exr" "$@" >"$work/demo.log" 2>&1 &
  demo=$!
  for _ in $(seq 600); do grep -q '^view: ' "$work/demo.log" && break; sleep 0.5; done
  grep -q '^view: ' "$work/demo.log" || { cat "$work/demo.log"; kill -INT $demo; exit 1; }
  pid=$(awk '$1 == "coordinator" {print $2}' "$work/pids")
  echo "== $mode ($*)"
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid"
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid" --steps
  # A light dragged instead of the camera (light 0), as a drag and one step at a time.
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid" --light 0
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid" --light 0 --steps
  # An object dragged (mesh ${OBJECT:-1}: a ball of the default scene).
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid" --object "${OBJECT:-1}"
  "$bin" view-probe --addr "127.0.0.1:$port" --seconds "$seconds" --pid "$pid" --object "${OBJECT:-1}" --steps
  kill -INT $demo
  wait $demo || { cat "$work/demo.log"; exit 1; }
  rm -rf "$work"
done
