#!/usr/bin/env bash
# Several "hosts" on one machine: each daemon runs in its own network namespace, joined to the
# coordinator's namespace by a bridge and veth pairs (10.77.0.0/24). Traffic crosses real
# interfaces, not loopback. Needs root (or CAP_NET_ADMIN) and iproute2.
#
#   scripts/netns-cluster.sh [NODES] [COMPOSITORS] [extra coordinator args...]
#
# Uses $LIGHTFOLD_BIN (default target/release/lightfold). Cleans up namespaces on exit.
set -euo pipefail
nodes=${1:-2}; comps=${2:-2}; shift $(( $# > 2 ? 2 : $# )) || true
bin=${LIGHTFOLD_BIN:-target/release/lightfold}
prefix=lf$$
bridge=${prefix}br
work=$(mktemp -d)
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
  sleep 0.5
  for p in "${pids[@]}"; do kill -KILL "$p" 2>/dev/null || true; done
  for ns in $(ip netns list | awk '{print $1}' | grep "^${prefix}-" || true); do ip netns del "$ns" 2>/dev/null || true; done
  ip link del "$bridge" 2>/dev/null || true
  if [ -n "${KEEP:-}" ]; then echo "logs kept in $work" >&2; else rm -rf "$work"; fi
}
trap cleanup EXIT
ip link add "$bridge" type bridge
ip addr add 10.77.0.1/24 dev "$bridge"
ip link set "$bridge" up
head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/token"
host=2
add_host() { # name -> sets $ip to the new host's address
  local ns=${prefix}-$1
  ip=10.77.0.$host
  ip netns add "$ns"
  ip link add "v${prefix}h$host" type veth peer name "p${prefix}h$host"
  ip link set "p${prefix}h$host" netns "$ns"
  ip -n "$ns" link set "p${prefix}h$host" name eth0
  ip link set "v${prefix}h$host" master "$bridge" up
  ip -n "$ns" addr add "$ip/24" dev eth0
  ip -n "$ns" link set eth0 up
  ip -n "$ns" link set lo up
  host=$((host + 1))
}
echo "version = 1" > "$work/cluster.toml"
echo 'sink_listen = "10.77.0.1:0"' >> "$work/cluster.toml"
start() { # role index
  add_host "$1$2"
  ip netns exec "${prefix}-$1$2" env NODEVICE_SELECT=1 LP_NUM_THREADS=1 "$bin" "$1" --listen "$ip:7300" \
    --id "$1-$2" --token-file "$work/token" > "$work/$1$2.out" 2> "$work/$1$2.log" &
  pids+=($!)
  printf '[[%s]]\naddress = "%s:7300"\nid = "%s-%s"\n' "$1" "$ip" "$1" "$2" >> "$work/cluster.toml"
}
for i in $(seq 0 $((nodes - 1))); do start node "$i"; done
for i in $(seq 0 $((comps - 1))); do start compositor "$i"; done
"$bin" coordinator --cluster "$work/cluster.toml" --token-file "$work/token" --connect-timeout 30 --shutdown "$@"
status=$?
for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
pids=()
exit $status
