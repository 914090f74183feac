#!/usr/bin/env bash
# Builds the lightfold container image from this repository, tagged lightfold:<version> (the
# workspace version in Cargo.toml) and lightfold:latest, with docker (BuildKit) or podman.
#
#   scripts/build-image.sh [docker|podman] [extra build arguments...]
#
# ENGINE=docker|podman does the same as the first argument; without either, docker when it is
# installed, else podman. IMAGE=name replaces `lightfold`. The build stage keeps cargo's registry
# and target directory in BuildKit cache mounts (deploy/container/Containerfile), so a second
# build compiles only what changed: docker needs BuildKit (the default builder since Docker 23;
# DOCKER_BUILDKIT=1 before that, or docker buildx), podman and buildah support them as they are.
# The image is not published anywhere: load it where it runs (docker save | ssh host docker load,
# kind load docker-image, k3s ctr images import, or push it to your registry).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
engine=${ENGINE:-}
if [[ "${1:-}" == docker || "${1:-}" == podman ]]; then engine=$1; shift; fi
if [[ -z "$engine" ]]; then
  if command -v docker > /dev/null; then engine=docker
  elif command -v podman > /dev/null; then engine=podman
  else echo "neither docker nor podman is installed" >&2; exit 2
  fi
fi
command -v "$engine" > /dev/null || { echo "$engine is not installed" >&2; exit 2; }
version=$(sed -n '/^\[workspace.package\]/,/^\[/s/^version *= *"\(.*\)"/\1/p' "$repo/Cargo.toml")
[[ -n "$version" ]] || { echo "no version in $repo/Cargo.toml [workspace.package]" >&2; exit 2; }
image=${IMAGE:-lightfold}
args=(build -f deploy/container/Containerfile -t "$image:$version" -t "$image:latest")
case $engine in
  # BuildKit finds the ignore file by the Containerfile's name; podman is told.
  docker) export DOCKER_BUILDKIT=1 ;;
  podman) args+=(--ignorefile deploy/container/Containerfile.dockerignore) ;;
esac
cd "$repo"
echo "+ $engine ${args[*]} $* ." >&2
"$engine" "${args[@]}" "$@" .
echo "built $image:$version (also $image:latest)" >&2
