#!/usr/bin/env bash
# Installs the system packages lightfold needs at run time (Mesa's software Vulkan and GL), if
# missing; with --test also those its tests need (Chromium, which the live view's browser test
# drives headless, and Prometheus, whose promtool checks the daemons' /metrics). No -dev packages
# are needed to build; a C++ compiler is (the `meshopt` crate compiles meshoptimizer, the shadow
# casters' simplifier).
set -euo pipefail
pkgs=(iproute2 g++ mesa-vulkan-drivers libvulkan1 libegl1 libegl-mesa0 libgl1-mesa-dri)
[ "${1:-}" = --test ] && pkgs+=(chromium prometheus)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
sudo=""
[ "$(id -u)" -ne 0 ] && sudo="sudo"
for attempt in 1 2 3 4 5; do
  if $sudo apt-get update -qq && DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
    exit 0
  fi
  echo "apt failed (attempt $attempt), retrying" >&2
  sleep $((attempt * 5))
done
exit 1
