#!/usr/bin/env bash
# Peeled translucency against D (docs/translucency.md § Peeled layers, "Measured"): the glass
# stack (three staggered panes) through the local cluster with the panes only tinting
# (`--peels off`), then 1, 2 and 3 peeled layers (3 is what `--peels auto` chooses there) and 4
# (one layer more than the scene has). One light group (K = 16: every sample on one node per
# eye layer), so D peeled layers take D + 1 nodes. Prints each run's plan lines, frame figures
# and its error against the CPU reference that sees every translucent layer in view.
#   scripts/bench-peels.sh [SIZE] [FRAMES]
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:-400x300}; frames=${2:-4}
bin=target/release/lightfold
[ -x "$bin" ] || cargo build --release -p lightfold-cli
export NODEVICE_SELECT=1
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for peels in off 1 2 3 4; do
  echo "=== --peels $peels size=$size frames=$frames"
  "$bin" demo --scene scenes/glass-stack.toml -K 16 --size "$size" --frames "$frames" \
    --tiles 1 --no-frame-files --out "$out/frame.png" --exr "$out/frame.exr" --peels "$peels" \
    2>/dev/null \
    | grep -E "^(  peels:|frame interval|node-seconds|whole|penumbra|the plan peels|demo: daemon CPU|against the reference with all)|links carry"
done
