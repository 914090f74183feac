#!/usr/bin/env bash
# The main job: installs system packages if missing, builds, and runs a local multi-process cluster
# rendering the default scene to out.png and out.exr.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
cargo build --release -p lightfold-cli
exec "${CARGO_TARGET_DIR:-target}/release/lightfold" demo "$@"
