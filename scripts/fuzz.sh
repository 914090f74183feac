#!/usr/bin/env bash
# Runs the libFuzzer targets of fuzz/ one after another, each for a given time:
#
#   scripts/fuzz.sh [TARGET...] [SECONDS]     # default: every target, 60 s each
#   scripts/fuzz.sh --check                   # exit 0 when a usable toolchain is present
#
# Targets: decode (wire codec), handshake, gltf, glb, obj, ply, usd, scene_file, scene_bytes (see
# docs/fuzzing.md). Needs cargo-fuzz (`cargo install cargo-fuzz --locked`) and a compiler that
# takes the -Z flags cargo-fuzz passes: a nightly toolchain when one is installed, else stable
# with RUSTC_BOOTSTRAP=1 (stable ships the sanitizer runtimes cargo-fuzz links). One fuzzing
# process at a time, at most 4 GiB and 120 s per input (a scene may load 1 GiB). Corpora grow in
# fuzz/corpus/TARGET (seeded from fuzz/seeds/ and the repository's models and scene files); a
# crash leaves its input in fuzz/artifacts/TARGET and makes this script fail. Prints one summary
# line per target.
set -euo pipefail
cd "$(dirname "$0")/.."

ALL=(decode handshake gltf glb obj ply usd scene_file scene_bytes)

# The cargo invocation: nightly if installed, else stable allowed to take -Z flags.
if rustup toolchain list 2>/dev/null | grep -q '^nightly'; then
  CARGO=(cargo +nightly)
else
  export RUSTC_BOOTSTRAP=1
  CARGO=(cargo)
fi

usable() {
  command -v cargo-fuzz >/dev/null 2>&1 || { echo "fuzz: cargo-fuzz is not installed" >&2; return 1; }
  local probe tc=()
  [ "${CARGO[1]:-}" = "+nightly" ] && tc=(+nightly)
  probe=$(mktemp -d)
  # What cargo-fuzz needs of the compiler: -Z flags and the address-sanitizer runtime.
  if ! echo 'fn main() {}' | rustc "${tc[@]}" -Zsanitizer=address -o "$probe/p" - >/dev/null 2>&1; then
    rm -rf "$probe"
    echo "fuzz: the compiler refuses -Zsanitizer=address (no nightly, and RUSTC_BOOTSTRAP not honoured)" >&2
    return 1
  fi
  rm -rf "$probe"
}

if [ "${1:-}" = "--check" ]; then
  usable
  exit
fi

targets=()
seconds=60
for a in "$@"; do
  if [[ "$a" =~ ^[0-9]+$ ]]; then
    seconds=$a
  else
    [[ " ${ALL[*]} " == *" $a "* ]] || { echo "fuzz: unknown target $a (targets: ${ALL[*]})" >&2; exit 2; }
    targets+=("$a")
  fi
done
[ ${#targets[@]} -eq 0 ] && targets=("${ALL[@]}")
usable || exit 1

# Seeds: the checked-in ones, plus the repository's models and scene files.
seed() {
  local t=$1 dir=fuzz/corpus/$1
  mkdir -p "$dir"
  [ -d "fuzz/seeds/$t" ] && cp -n fuzz/seeds/"$t"/* "$dir"/ 2>/dev/null || true
  case $t in
    gltf) for f in assets/*/*.gltf; do cp -n "$f" "$dir/" 2>/dev/null || true; done ;;
    glb) for f in assets/*/*.glb; do
           [ -e "$dir/raw-$(basename "$f")" ] || { printf '\001'; cat "$f"; } > "$dir/raw-$(basename "$f")"
         done ;;
    usd) for f in scene/tests/data/usd/*.usd*; do cp -n "$f" "$dir/" 2>/dev/null || true; done ;;
    scene_file) for f in scenes/*.toml scenes/hard/*.toml; do cp -n "$f" "$dir/" 2>/dev/null || true; done ;;
  esac
}

failed=0
for t in "${targets[@]}"; do
  "${CARGO[@]}" fuzz build "$t" -O 2>&1 | grep -E '^(error|warning)' -A5 >&2 || true
  seed "$t"
  mkdir -p "fuzz/artifacts/$t"
  log=$(mktemp)
  mark=$(mktemp)
  start=$(date +%s)
  set +e
  # One fuzzing process (what -jobs=1 asks for, without its log-file indirection).
  "${CARGO[@]}" fuzz run "$t" -O "fuzz/corpus/$t" -- -max_total_time="$seconds" \
    -rss_limit_mb=4096 -timeout=120 -print_final_stats=1 >"$log" 2>&1
  rc=$?
  set -e
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | tail -1 | grep -o '[0-9]*$' || true)
  cov=$(grep -oE 'cov: [0-9]+ ft: [0-9]+ corp: [0-9]+' "$log" | tail -1 || true)
  crashes=$(find "fuzz/artifacts/$t" -type f -newer "$mark" | wc -l)
  echo "fuzz $t: $(($(date +%s) - start)) s, ${runs:-?} executions, ${cov:-coverage ?}, $crashes new crash(es), rc $rc"
  if [ "$rc" -ne 0 ] || [ "$crashes" -ne 0 ]; then
    failed=1
    # The panic or sanitizer report and the input's path (not its bytes, which can be long).
    grep -E "panicked at|^thread|ERROR: |SUMMARY|Failing input|fuzz/artifacts/|assertion" -A2 "$log" |
      grep -v '^\s*\[' | head -30 >&2
  fi
  rm -f "$log" "$mark"
done
exit $failed
