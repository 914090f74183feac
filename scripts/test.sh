#!/usr/bin/env bash
# Runs every test. GPU tests use Mesa's lavapipe and fail (never skip) when no adapter is found.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh --test
export NODEVICE_SELECT=1
cargo test --workspace --all-targets
