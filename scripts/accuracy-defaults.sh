#!/usr/bin/env bash
# The planner's default against the scene as it asks, on every built-in scene and every model in
# assets/, each against its area-light truth at 400×300 (docs/accuracy/defaults/README.md).
# Each scene is calibrated first when the cache has no model of it (`lightfold calibrate`).
#   scripts/accuracy-defaults.sh [CACHE_DIR] > table.md
set -euo pipefail
cd "$(dirname "$0")/.."
cache=${1:-${XDG_CACHE_HOME:-$HOME/.cache}/lightfold}
bin=${LIGHTFOLD_BIN:-target/release/lightfold}
[ -x "$bin" ] || cargo build --release -p lightfold-cli >&2
scenes=(balls box plant animal cornell carousel city
  assets/AlphaBlendModeTest/AlphaBlendModeTest.gltf assets/BoxTextured/BoxTextured.gltf
  assets/CesiumMan/CesiumMan.gltf assets/FlightHelmet/FlightHelmet.gltf assets/Fox/Fox.glb)
echo "| scene | setting | samples/light | map floor | filter | penumbra PSNR (expected) | whole PSNR | node-s | truth floor |"
echo "|---|---|---:|---:|---:|---:|---:|---:|---:|"
for s in "${scenes[@]}"; do
  start=$SECONDS
  LP_NUM_THREADS=${LP_NUM_THREADS:-2} NODEVICE_SELECT=1 "$bin" --log warn accuracy --planned \
    --scene "$s" --size 400x300 --repeats 2 --model-cache "$cache" | grep '^| [^s-]' || echo "| $s | failed |"
  echo "$s: $((SECONDS - start)) s" >&2
done
