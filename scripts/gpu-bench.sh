#!/usr/bin/env bash
# On a machine with a GPU: lightfold's equivalent of the paper's Fig. 2 and the local cluster,
# measured in one go (docs/gpu.md says how to read the tables).
#
#   scripts/gpu-bench.sh [OUT_DIR]        (default: gpu-bench-out)
#
# On a machine without a Rust toolchain, point LIGHTFOLD_BIN at a release binary built elsewhere
# (same architecture) and GPU_TEST_BINS at a folder of prebuilt test executables
# (`cargo test --release --no-run -p lightfold-node -p lightfold-harness --test it`: one test
# executable per crate); each is run with the filters in GPU_TEST_FILTERS.
#
# Builds the release binary, refuses to go on unless the adapter is a hardware one, then measures,
# most important first:
# 1. the local cluster's frame rate for balls (32 lights, -K 4) at 800x600 and 1920x1080,
#    walkthrough and moving lights, before (CPU pack, one frame at a time, 8 nodes + 8
#    compositors), apart (device pack and render-ahead, still 8 nodes) and after (the defaults:
#    the nodes sharing the GPU merged) in the same run: cluster.md, with the paper's 93 Hz beside
#    each figure;
# 2. `lightfold bench node` for balls at both sizes, device and CPU pack in the same rounds, two
#    requests in flight (device ms, CPU ms outside the device, interval ÷ device, bytes read back
#    a pixel);
# 3. `bench node` for animal, plant and box, the city at 1 M and 4 M triangles, shadow LOD off
#    and on (the city at 4 M), occlusion culling (the city at 4 M, own camera and street level),
#    and the GPU tests, as time allows.
# Every table goes to a file under OUT_DIR. Each step checks the clock: the whole run stays under
# about 9 minutes, and a step that would not fit is skipped with a line saying so (never
# silently).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-gpu-bench-out}"
mkdir -p "$out"
budget=${GPU_BENCH_SECONDS:-540}
start=$SECONDS
left() { echo $((budget - (SECONDS - start))); }
step() { echo "== $* ($(left) s left)" | tee -a "$out/log.txt"; }
skip_unless() {
  # skip_unless SECONDS WHAT: true when at least SECONDS remain; otherwise logs the skip.
  if [ "$(left)" -lt "$1" ]; then
    echo "skipped: $2 (needs ${1} s, $(left) s left)" | tee -a "$out/log.txt"
    return 1
  fi
}

if [ -n "${LIGHTFOLD_BIN:-}" ]; then
  bin=$LIGHTFOLD_BIN
  step "prebuilt binary $bin"
else
  step "build (release)"
  cargo build --release -p lightfold-cli 2>&1 | tail -n 3
  bin=target/release/lightfold
fi

step "adapter"
"$bin" render --scene box --size 64x48 --timings --out "$out/probe.exr" >"$out/adapter.txt" 2>&1 || {
  cat "$out/adapter.txt"
  echo "gpu-bench: cannot render at all (see $out/adapter.txt)" >&2
  exit 1
}
adapter=$(grep -m1 '^adapter ' "$out/adapter.txt" || true)
echo "$adapter" | tee -a "$out/log.txt"
if [ -z "$adapter" ] || echo "$adapter" | grep -Eqi 'llvmpipe|lavapipe|swiftshader|softpipe|basic render'; then
  echo "gpu-bench: no hardware adapter (${adapter:-none reported}); this script measures a GPU" >&2
  exit 1
fi

cluster() {
  # cluster SIZE MODE SETUP: one demo run; appends a row to cluster.md. SETUP: `before` (nodes
  # pack on the CPU, one frame at a time, one process per light group), `apart` (device pack and
  # render-ahead, but one process per light group: --no-device-merge) or `after` (the defaults).
  local size=$1 mode=$2 setup=$3 flags="" pack=auto ahead=true
  [ "$mode" = walkthrough ] && flags="--walkthrough"
  case $setup in
    before) pack=cpu ahead=false flags="$flags --no-device-merge" ;;
    apart) flags="$flags --no-device-merge" ;;
  esac
  local log="$out/cluster-$size-$mode-$setup.txt"
  # shellcheck disable=SC2086
  LIGHTFOLD_PACK=$pack LIGHTFOLD_RENDER_AHEAD=$ahead timeout 150 "$bin" demo --scene balls \
    --size "$size" -K 4 --frames 60 --orbit 2 $flags --no-frame-files \
    --out "$out/cluster.png" --exr "$out/cluster.exr" >"$log" 2>&1 \
    || echo "cluster $size $mode $setup failed: see $log" | tee -a "$out/log.txt"
  local fps interval psnr nodes
  fps=$(grep -o '([0-9.]* frames/s' "$log" | tr -d '(' | cut -d' ' -f1 | tail -n 1)
  interval=$(grep -o 'frame interval mean [0-9.]* ms' "$log" | awk '{print $4}' | tail -n 1)
  psnr=$(grep -m1 '^whole ' "$log" | grep -o 'psnr *[0-9.]*' | awk '{print $2}')
  nodes=$(grep -o 'rendered on [0-9]* render node' "$log" | awk '{print $3}' | tail -n 1)
  echo "| $size | $mode | $setup | ${nodes:-—} | ${interval:-—} | ${fps:-—} | 93 | ${psnr:-—} |" >>"$out/cluster.md"
  # A node whose device packs differently from the CPU says so and packs on the CPU.
  if grep -q "pack failed its check" "$log"; then
    echo "device pack refused by a node's start-up check: see $log" | tee -a "$out/log.txt"
  fi
}
{
  echo "### Local cluster on one GPU, balls, 32 lights, -K 4, 60 frames"
  echo
  echo "before: CPU pack, one frame at a time, one node per light group; apart: device pack and"
  echo "render-ahead, one node per light group; after: the defaults (the nodes sharing the GPU merged)."
  echo
  echo "| size | mode | setup | render nodes | frame interval ms | frames/s | paper Hz | PSNR dB |"
  echo "|---|---|---|---:|---:|---:|---:|---:|"
} >"$out/cluster.md"
# `after` first: if time runs short, the figures that matter most are already in.
for setup in after before apart; do
  for size in 800x600 1920x1080; do
    for mode in walkthrough moving; do
      if skip_unless 40 "cluster $size $mode $setup"; then
        step "cluster $size $mode, $setup"
        cluster "$size" "$mode" "$setup"
      fi
    done
  done
done
cat "$out/cluster.md"

bench() {
  # bench SCENE SIZE KS MODES PACKS
  local scene=$1 size=$2 ks=$3 modes=$4 packs=$5
  "$bin" bench node --scene "$scene" --size "$size" --ks "$ks" --modes "$modes" --pack "$packs" \
    --in-flight 2 --rounds 1 --frames 6 --warmup 2 2>"$out/bench-$scene-$size.log" | tee "$out/bench-$scene-$size.md"
}
for size in 800x600 1920x1080; do
  if skip_unless 60 "bench node balls $size"; then
    step "bench node balls $size (device and CPU pack)"
    bench balls "$size" 1,4,16,32 moving,walkthrough device,cpu \
      || echo "bench node balls $size failed: see $out/bench-balls-$size.log" | tee -a "$out/log.txt"
  fi
done
for scene in animal plant box; do
  if skip_unless 60 "bench node $scene 800x600"; then
    step "bench node $scene 800x600"
    bench "$scene" 800x600 1,4,16,32 moving,walkthrough,noshadows device \
      || echo "bench node $scene 800x600 failed: see $out/bench-$scene-800x600.log" | tee -a "$out/log.txt"
  fi
done

# The city (docs/scaling.md § Triangles) at 1 M and 4 M triangles: what a node pays as scenes
# grow, with per-view culling of meshes and chunks, on a GPU.
for scene in city:1M city:4M; do
  if skip_unless 90 "bench node $scene 800x600"; then
    step "bench node $scene 800x600"
    bench "$scene" 800x600 4 moving,walkthrough device \
      || echo "bench node $scene 800x600 failed: see $out/bench-$scene-800x600.log" | tee -a "$out/log.txt"
  fi
done

# Simplified shadow casters (docs/scaling.md § Level of detail): the city at 4 M triangles with
# every map drawn each frame, full detail against the levels, alternating in one run.
if skip_unless 90 "shadow LOD city:4M"; then
  step "shadow LOD city:4M 800x600"
  if command -v cargo >/dev/null; then
    timeout 150 cargo run --release -q -p lightfold-node --example shadow_lod -- \
      --scene city:4M --size 800x600 --frames 3 2>&1 | grep -v INFO | tee "$out/shadow-lod.txt" \
      || echo "shadow LOD: see $out/shadow-lod.txt" | tee -a "$out/log.txt"
  else
    echo "skipped: shadow LOD (no cargo here)" | tee -a "$out/log.txt"
  fi
fi

# Occlusion culling (docs/scaling.md § Occlusion culling): the city at 4 M triangles from its
# own camera and at street level, frustum culling alone, occlusion every frame and the default,
# taking turns in one run.
if skip_unless 90 "occlusion culling city:4M"; then
  step "occlusion culling city:4M 1920x1080"
  if command -v cargo >/dev/null; then
    timeout 150 cargo run --release -q -p lightfold-node --example occlusion_cull -- \
      --scene city:4M --size 1920x1080 --frames 5 2>&1 | grep -v INFO | tee "$out/occlusion.txt" \
      || echo "occlusion culling: see $out/occlusion.txt" | tee -a "$out/log.txt"
  else
    echo "skipped: occlusion culling (no cargo here)" | tee -a "$out/log.txt"
  fi
fi

# gpu_device first: the device pack's bit-for-bit differential tests on this GPU's driver.
GPU_TEST_FILTERS="gpu_device:: daemon_frame:: gpu_correctness:: gpu_modes:: cluster:: animation::"
if skip_unless 90 "GPU tests"; then
  step "GPU tests"
  if [ -n "${GPU_TEST_BINS:-}" ]; then
    for t in "$GPU_TEST_BINS"/*; do
      [ -x "$t" ] || continue
      limit=$(( $(left) > 130 ? 120 : $(left) - 10 ))
      if [ "$limit" -lt 20 ]; then
        echo "skipped: $(basename "$t") ($(left) s left)" | tee -a "$out/log.txt"
        continue
      fi
      echo "== $(basename "$t")" >>"$out/gpu-tests.txt"
      timeout "$limit" "$t" $GPU_TEST_FILTERS 2>&1 | grep -E '^test |test result|panicked' | tee -a "$out/gpu-tests.txt" \
        || echo "GPU tests: $(basename "$t") failed, see $out/gpu-tests.txt"
    done
  elif command -v cargo >/dev/null; then
    timeout 150 cargo test --release -p lightfold-node -p lightfold-harness --test it -- \
      $GPU_TEST_FILTERS 2>&1 | grep -E '^test |test result' | tee "$out/gpu-tests.txt" || echo "GPU tests: see $out/gpu-tests.txt"
  else
    echo "skipped: GPU tests (no cargo here and no GPU_TEST_BINS)" | tee -a "$out/log.txt"
  fi
fi

step "done in $((SECONDS - start)) s; tables in $out/"
