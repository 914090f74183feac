#!/usr/bin/env bash
# What the codebase measures (docs/codebase.md): lines of Rust per crate, the cli's size and what
# it is made of, test binaries, the longest functions outside tests; with --cold-build DIR also
# a cold `cargo test --workspace --all-targets --no-run` into the empty folder DIR (CPU and wall
# time, size).
# Usage: scripts/codebase-measures.sh [--cold-build DIR]
set -euo pipefail
cd "$(dirname "$0")/.."

echo "== lines of Rust per crate (tracked files, fuzz/ apart)"
git ls-files '*.rs' | grep -v '^fuzz/' | xargs wc -l | grep -v ' total$' |
  awk '{split($2, p, "/"); n[p[1]] += $1; t += $1} END {for (k in n) printf "%-12s %7d\n", k, n[k]; printf "%-12s %7d\n", "total", t}' |
  sort

echo "== cli/src"
python3 - <<'PY'
import glob, re
total = args = tests = 0
for p in sorted(glob.glob('cli/src/*.rs')):
    text = open(p).read()
    lines = text.split('\n')
    total += text.count('\n')  # as wc -l counts
    i = 0
    while i < len(lines):
        if lines[i].startswith('#[cfg(test)]'):
            tests += len(lines) - i
            break
        if re.search(r'derive\(.*(clap::Args|Parser|Subcommand|ValueEnum)', lines[i]):
            j = i
            while not lines[j].startswith('}'):
                j += 1
            args += j - i + 1
            i = j
        i += 1
print(f"{total} lines: {args} in argument definitions (clap structs and their help), "
      f"{tests} in unit tests, {total - args - tests} other")
PY

echo "== test binaries (cargo metadata: library and binary unit tests, integration tests)"
cargo metadata --no-deps --format-version 1 | python3 -c '
import json, sys
m = json.load(sys.stdin)
kinds = {}
for p in m["packages"]:
    for t in p["targets"]:
        k = t["kind"][0]
        if k in ("lib", "bin") and t.get("test", True) or k == "test":
            kinds[k] = kinds.get(k, 0) + 1
print(", ".join(f"{v} {k}" for k, v in sorted(kinds.items())), "=", sum(kinds.values()))
'

echo "== longest functions outside tests (lines, file, name)"
python3 - <<'PY'
import os, re
res = []
for root, dirs, files in os.walk('.'):
    dirs[:] = [d for d in dirs if d not in ('target', '.git', 'fuzz', 'tests', 'benches', 'examples')]
    for f in files:
        if not f.endswith('.rs'):
            continue
        p = os.path.join(root, f)
        lines = open(p, errors='ignore').read().split('\n')
        cut = next((i for i, l in enumerate(lines) if l.startswith('#[cfg(test)]')), len(lines))
        for i in range(cut):
            m = re.match(r'\s*(pub(\([^)]*\))?\s+)?(async\s+)?(const\s+)?(unsafe\s+)?fn\s+(\w+)', lines[i])
            if not m:
                continue
            depth, started, j = 0, False, i
            while j < cut:
                s = re.sub(r'"(\\.|[^"\\])*"', '""', lines[j])
                s = re.sub(r"'(\\.|[^'\\])'", "''", s).split('//')[0]
                for c in s:
                    if c == '{':
                        depth += 1
                        started = True
                    elif c == '}':
                        depth -= 1
                if started and depth <= 0:
                    break
                if not started and s.rstrip().endswith(';'):
                    break
                j += 1
            if started:
                res.append((j - i + 1, p[2:], m.group(6)))
for n, p, name in sorted(res, reverse=True)[:5]:
    print(f"{n:5d}  {p}  {name}")
PY

if [ "${1:-}" = "--cold-build" ]; then
  dir=${2:?--cold-build takes an empty folder}
  mkdir -p "$dir"
  [ -z "$(ls -A "$dir")" ] || { echo "$dir is not empty" >&2; exit 1; }
  # What CI builds (`scripts/test.sh`): every target, examples and benches included.
  echo "== cold cargo test --workspace --all-targets --no-run into $dir"
  CARGO_TARGET_DIR="$dir" CARGO_INCREMENTAL=0 /usr/bin/time -f '%e s wall, %U s user, %S s system' \
    cargo test --workspace --all-targets --no-run --quiet 2>&1 | tail -n 1
  du -sh "$dir" | awk '{print $1 " in the target folder"}'
fi
