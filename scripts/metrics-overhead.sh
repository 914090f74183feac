#!/usr/bin/env bash
# What metrics cost the frame interval: `lightfold demo` alternately without and with `--metrics`
# (every daemon and the coordinator record and serve /metrics), the latter scraped every second
# (15 times Prometheus' usual rate), REPS times each; prints each run's mean frame interval and the
# ratio of the medians. Usage: scripts/metrics-overhead.sh [REPS] [FRAMES] [-- demo flags...]
# (docs/operations.md). Set LIGHTFOLD to the binary (default target/release/lightfold).
set -euo pipefail
cd "$(dirname "$0")/.."
reps=${1:-3}
frames=${2:-40}
shift $(( $# >= 2 ? 2 : $# ))
[ "${1:-}" = -- ] && shift
bin=${LIGHTFOLD:-target/release/lightfold}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
# Mean interval (ms) of a --stats file, leaving out the first two frames (devices warming up).
mean_interval() {
  python3 -c '
import json, sys
v = [json.loads(l)["interval_ms"] for l in open(sys.argv[1])][2:]
v = [x for x in v if x is not None]
print(f"{sum(v) / len(v):.1f}")' "$1"
}
run() { # arm rep [demo flags]
  local arm=$1 rep=$2 flags=()
  shift 2
  local stats="$out/$arm-$rep.jsonl" log="$out/$arm-$rep.log"
  [ "$arm" = metrics ] && flags=(--metrics)
  "$bin" demo --frames "$frames" --orbit 2 --no-frame-files --no-compare --stats "$stats" \
    --out "$out/out.png" --exr "$out/out.exr" "${flags[@]}" "$@" >"$log" 2>&1 &
  local demo=$!
  if [ "$arm" = metrics ]; then
    # Scrape every address the demo prints, once a second, until it ends.
    while kill -0 "$demo" 2>/dev/null; do
      grep -ho 'http://[0-9.:]*/metrics\|^metrics [0-9.:]*' "$log" 2>/dev/null \
        | sed 's/^metrics \(.*\)/http:\/\/\1\/metrics/' | sort -u \
        | while read -r url; do curl -s -m 2 -o /dev/null "$url" || true; done
      sleep 1
    done
  fi
  wait "$demo" || { cat "$log" >&2; exit 1; }
  echo "$arm $rep $(mean_interval "$stats")"
}
results=()
for rep in $(seq 1 "$reps"); do
  results+=("$(run plain "$rep" "$@")")
  echo "${results[-1]}"
  results+=("$(run metrics "$rep" "$@")")
  echo "${results[-1]}"
done
printf '%s\n' "${results[@]}" | python3 -c '
import statistics, sys
by = {}
for line in sys.stdin:
    arm, _, ms = line.split()
    by.setdefault(arm, []).append(float(ms))
p, m = statistics.median(by["plain"]), statistics.median(by["metrics"])
print(f"median interval: plain {p:.1f} ms, metrics {m:.1f} ms, ratio {m / p:.3f}")'
