#!/usr/bin/env bash
# On a machine with a GPU: lightfold's equivalent of the paper's Fig. 2 and the local cluster,
# measured in one go (docs/gpu.md says how to read the tables).
#
#   scripts/gpu-bench.sh [OUT_DIR]        (default: gpu-bench-out)
#
# On a machine without a Rust toolchain, point LIGHTFOLD_BIN at a release binary built elsewhere
# (same architecture) and GPU_TEST_BINS at a folder of prebuilt test executables
# (`cargo test --release --no-run -p lightfold-node --test gpu_correctness --test gpu_modes
# --test gpu_device`); each is run with its default arguments.
#
# Builds the release binary, refuses to go on unless the adapter is a hardware one, then runs
# `lightfold bench node` for balls, animal, plant and box with
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

bench() {
  # bench SCENE SIZE KS
  local scene=$1 size=$2 ks=$3
  "$bin" bench node --scene "$scene" --size "$size" --ks "$ks" --modes moving,walkthrough,noshadows \
    --rounds 1 --frames 4 --warmup 2 2>"$out/bench-$scene-$size.log" | tee "$out/bench-$scene-$size.md"
}
for scene in balls animal plant box; do
  if skip_unless 60 "bench node $scene 800x600"; then
    step "bench node $scene 800x600"
    bench "$scene" 800x600 1,2,3,4,8,16,32 || echo "bench node $scene 800x600 failed: see $out/bench-$scene-800x600.log" | tee -a "$out/log.txt"
  fi
done
for scene in balls animal plant box; do
  if skip_unless 60 "bench node $scene 1920x1080"; then
    step "bench node $scene 1920x1080"
    bench "$scene" 1920x1080 1,4,16,32 || echo "bench node $scene 1920x1080 failed: see $out/bench-$scene-1920x1080.log" | tee -a "$out/log.txt"
  fi
done

if skip_unless 60 "local cluster"; then
  step "local cluster: demo --frames 60 --orbit 2 -K 4"
  "$bin" demo --frames 60 --orbit 2 -K 4 --no-frame-files --verbose --stats "$out/demo-stats.jsonl" \
    2>&1 | tee "$out/demo.txt" || echo "local cluster failed: see $out/demo.txt" | tee -a "$out/log.txt"
fi
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
      timeout "$limit" "$t" 2>&1 | grep -E '^test |test result|panicked' | tee -a "$out/gpu-tests.txt" \
        || echo "GPU tests: $(basename "$t") failed, see $out/gpu-tests.txt"
    done
  elif command -v cargo >/dev/null; then
    timeout 150 cargo test --release -p lightfold-node -p lightfold-tests --test cluster --test animation \
      2>&1 | grep -E '^test |test result' | tee "$out/gpu-tests.txt" || echo "GPU tests: see $out/gpu-tests.txt"
  else
    echo "skipped: GPU tests (no cargo here and no GPU_TEST_BINS)" | tee -a "$out/log.txt"
  fi
fi

step "done in $((SECONDS - start)) s; tables in $out/"
