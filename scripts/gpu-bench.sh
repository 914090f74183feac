#!/usr/bin/env bash
# On a machine with a GPU: lightfold's equivalent of the paper's Fig. 2 and the local cluster,
# measured in one go (docs/gpu.md says how to read the tables).
#
#   scripts/gpu-bench.sh [OUT_DIR]        (default: gpu-bench-out)
#
# Builds the release binary, refuses to go on unless the adapter is a hardware one, runs the test
# suite's GPU tests on it, then `lightfold bench node` for balls, animal, plant and box with
# K = 1, 2, 3, 4, 8, 16, 32 in moving, walkthrough and no-shadows modes at 800x600 (and a subset at
# 1920x1080), and a local cluster (demo --frames 60 --orbit 2, K = 4). Every table goes to a file
# under OUT_DIR. Each step checks the clock: the whole run stays under about 9 minutes, and a step
# that would not fit is skipped with a line saying so (never silently).
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

step "build (release)"
cargo build --release -p lightfold-cli 2>&1 | tail -n 3
bin=target/release/lightfold

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

if skip_unless 400 "GPU tests"; then
  step "GPU tests"
  timeout 150 cargo test --release -p lightfold-node -p lightfold-tests --test cluster --test animation \
    2>&1 | grep -E '^test |test result' | tee "$out/gpu-tests.txt" || echo "GPU tests: see $out/gpu-tests.txt"
fi

bench() {
  # bench SCENE SIZE KS
  local scene=$1 size=$2 ks=$3
  "$bin" bench node --scene "$scene" --size "$size" --ks "$ks" --modes moving,walkthrough,noshadows \
    --rounds 1 --frames 4 --warmup 2 2>"$out/bench-$scene-$size.log" | tee "$out/bench-$scene-$size.md"
}
for scene in balls animal plant box; do
  if skip_unless 60 "bench node $scene 800x600"; then
    step "bench node $scene 800x600"
    bench "$scene" 800x600 1,2,3,4,8,16,32
  fi
done
for scene in balls animal plant box; do
  if skip_unless 60 "bench node $scene 1920x1080"; then
    step "bench node $scene 1920x1080"
    bench "$scene" 1920x1080 1,4,16,32
  fi
done

if skip_unless 60 "local cluster"; then
  step "local cluster: demo --frames 60 --orbit 2 -K 4"
  "$bin" demo --frames 60 --orbit 2 -K 4 --no-frame-files --verbose --stats "$out/demo-stats.jsonl" \
    2>&1 | tee "$out/demo.txt"
fi
step "done in $((SECONDS - start)) s; tables in $out/"
