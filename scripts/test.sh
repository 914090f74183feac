#!/usr/bin/env bash
# Runs every test. GPU tests use Mesa's lavapipe and fail (never skip) when no adapter is found.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh --test
# The lightfold binary turns off Mesa's device-select layer itself; the GPU tests of the library
# crates open devices from their own test binaries, which do not.
export NODEVICE_SELECT=1
cargo test --workspace --all-targets
