#!/usr/bin/env bash
# A real Slurm cluster on one machine, to run deploy/slurm/lightfold.sbatch unchanged: munged,
# slurmctld and one slurmd per Slurm node, each node a "host" of its own (network namespace joined
# by a bridge, 10.78.0.0/24, and its own UTS namespace, so its hostname is its node name). Writes
# every config under a temp dir, starts the daemons, submits the batch script, waits for it,
# prints the job's output and stops everything. Needs root, iproute2, util-linux and Debian's
# slurm-wlm + munge (apt-get install -y slurm-wlm munge). Not part of CI: it needs root and daemons.
#
#   scripts/slurm-local.sh [NODES]        # default 9, as the batch script asks (--nodes=9)
#
# LIGHTFOLD_BIN (default target/release/lightfold) is copied into the temp dir, which stands for
# the shared file system. KEEP=1 keeps the temp dir (logs, configs, image); OUT=FILE copies the
# PNG there; TIMEOUT (seconds, default 600) bounds the wait for the job. JOB_TOKEN=1 gives the job
# no LIGHTFOLD_TOKEN_FILE, so the batch script makes its own token. After the job, the EXR is
# compared with the CPU reference (lightfold render --reference, lightfold compare).
set -euo pipefail
nodes=${1:-9}
repo=$(cd "$(dirname "$0")/.." && pwd)
bin=${LIGHTFOLD_BIN:-$repo/target/release/lightfold}
batch=$repo/deploy/slurm/lightfold.sbatch
timeout=${TIMEOUT:-600}
for tool in slurmctld slurmd munged sbatch ip unshare nsenter; do
  command -v "$tool" > /dev/null || { echo "missing $tool (apt-get install -y slurm-wlm munge iproute2)" >&2; exit 2; }
done
[ "$(id -u)" = 0 ] || { echo "needs root (network namespaces, slurmd)" >&2; exit 2; }
[ -x "$bin" ] || { echo "no binary at $bin (cargo build --release -p lightfold-cli)" >&2; exit 2; }
(( nodes >= 2 && nodes <= 200 )) || { echo "NODES must be 2..200" >&2; exit 2; }

# Leftovers of a run that was killed outright (its PID is gone): the daemons in its namespaces,
# the namespaces, its bridge, its munged and its temp dir. (A zombie counts as gone: kill -0
# would still reach it until its new parent reaps it.)
alive() { local state; state=$(sed 's/.*) //' "/proc/$1/stat" 2> /dev/null | cut -d' ' -f1) && [ -n "$state" ] && [ "$state" != Z ]; }
for ns in $(ip netns list | awk '{print $1}' | grep -E '^lfs[0-9]+-' || true); do
  owner=${ns%%-*}; owner=${owner#lfs}
  if ! alive "$owner"; then
    ip netns pids "$ns" 2> /dev/null | xargs -r kill -KILL 2> /dev/null || true
    ip netns del "$ns" 2> /dev/null || true
    ip link del "lfs${owner}br" 2> /dev/null || true
  fi
done
for dir in /tmp/lightfold-slurm.*; do
  if [ -f "$dir/owner" ] && ! alive "$(cat "$dir/owner")"; then
    if [ -f "$dir/munge/munged.pid" ]; then kill -TERM "$(cat "$dir/munge/munged.pid")" 2> /dev/null || true; fi
    rm -rf "$dir"
  fi
done

prefix=lfs$$
bridge=${prefix}br
work=$(mktemp -d /tmp/lightfold-slurm.XXXXXX)
chmod 0755 "$work"
echo $$ > "$work/owner"
pids=()
namespaces=()
cleanup() {
  set +e
  for p in "${pids[@]}"; do kill -TERM "$p" 2> /dev/null; done
  for _ in $(seq 50); do
    running=0
    for p in "${pids[@]}"; do alive "$p" && running=1; done
    [ $running = 0 ] && break
    sleep 0.1
  done
  for p in "${pids[@]}"; do kill -KILL "$p" 2> /dev/null; done
  wait 2> /dev/null # reap our children (munged daemonised itself and is not one)
  # Anything the job left behind (a slurmstepd, a daemon) lives in one of our namespaces.
  for ns in "${namespaces[@]}"; do
    ip netns pids "$ns" 2> /dev/null | xargs -r kill -KILL 2> /dev/null
    ip netns del "$ns" 2> /dev/null
  done
  ip link del "$bridge" 2> /dev/null
  if [ -n "${KEEP:-}" ]; then echo "kept $work" >&2; else rm -rf "$work"; fi
}
trap cleanup EXIT

names=(); addrs=()
for i in $(seq 0 $((nodes - 1))); do names+=("n$i"); addrs+=("10.78.0.$((10 + i))"); done

# Network: one bridge, one namespace per host ("ctl" for slurmctld, n0.. for the slurmds).
ip link add "$bridge" type bridge
ip link set "$bridge" up
hosts_file=$work/hosts
{
  echo "127.0.0.1 localhost"
  echo "10.78.0.1 ctl"
  for i in "${!names[@]}"; do echo "${addrs[$i]} ${names[$i]}"; done
} > "$hosts_file"
add_host() { # name address
  local ns=$prefix-$1 n=$((${#namespaces[@]}))
  ip netns add "$ns"
  namespaces+=("$ns")
  ip link add "v${prefix}h$n" type veth peer name "p${prefix}h$n"
  ip link set "p${prefix}h$n" netns "$ns"
  ip -n "$ns" link set "p${prefix}h$n" name eth0
  ip link set "v${prefix}h$n" master "$bridge" up
  ip -n "$ns" addr add "$2/24" dev eth0
  ip -n "$ns" link set eth0 up
  ip -n "$ns" link set lo up
}
# Run a command on a host: its network namespace, its own UTS namespace (hostname = host name) and
# a mount namespace where $hosts_file is /etc/hosts, so host names resolve as on a cluster with DNS
# without touching the machine's /etc/hosts. (Not `ip netns exec`: it remounts /sys, which hides
# the cgroup mounts slurmd insists on.)
# The daemon becomes the process itself (exec all the way), so $! of `on_host ... &` is its PID.
on_host() { # name command...
  local name=$1; shift
  # shellcheck disable=SC2016 # expanded by the inner sh
  exec nsenter --net="/run/netns/$prefix-$name" unshare --uts --mount --propagation private \
    sh -c 'mount --bind "$0" /etc/hosts && hostname "$1" && shift && exec "$@"' "$hosts_file" "$name" "$@"
}
add_host ctl 10.78.0.1
for i in "${!names[@]}"; do add_host "${names[$i]}" "${addrs[$i]}"; done

# munge: its own key and socket (the Unix socket is reachable from every network namespace).
mkdir -m 0755 "$work/munge"
head -c 1024 /dev/urandom > "$work/munge/munge.key"
chmod 0400 "$work/munge/munge.key"
munged --force --socket="$work/munge/munge.sock" --key-file="$work/munge/munge.key" \
  --pid-file="$work/munge/munged.pid" --log-file="$work/munge/munged.log" \
  --seed-file="$work/munge/munged.seed"
pids+=("$(cat "$work/munge/munged.pid")")

mkdir -p "$work/state" "$work/job"
for n in "${names[@]}"; do mkdir -p "$work/spool/$n"; done
export SLURM_CONF=$work/slurm.conf
cat > "$SLURM_CONF" << EOF
ClusterName=lightfold
SlurmctldHost=ctl(10.78.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$work/munge/munge.sock
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool/%n
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/spool/slurmd-%n.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd-%n.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
SlurmdParameters=config_overrides
NodeName=n[0-$((nodes - 1))] NodeAddr=10.78.0.[10-$((nodes + 9))] CPUs=2 RealMemory=1000 State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF

on_host ctl slurmctld -D -i > "$work/slurmctld.out" 2>&1 &
pids+=($!)
for n in "${names[@]}"; do
  on_host "$n" slurmd -D > "$work/slurmd-$n.out" 2>&1 &
  pids+=($!)
done
ctl() { (on_host ctl "$@"); }

# Wait until every node has registered and is idle.
for _ in $(seq 120); do
  idle=$(ctl sinfo -h -N -t idle -o '%N' 2> /dev/null | sort -u | wc -l || true)
  [ "$idle" = "$nodes" ] && break
  sleep 0.5
done
ctl sinfo -N
[ "$idle" = "$nodes" ] || { echo "only $idle of $nodes nodes came up; see $work/slurm*.log" >&2; KEEP=1; exit 1; }

# The shared file system: binary, token (unless the job makes its own), submit directory.
cp "$bin" "$work/lightfold"
export LIGHTFOLD_BIN=$work/lightfold
if [ -n "${JOB_TOKEN:-}" ]; then
  unset LIGHTFOLD_TOKEN_FILE
else
  head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' > "$work/token"
  chmod 0600 "$work/token"
  export LIGHTFOLD_TOKEN_FILE=$work/token
fi
start=$(date +%s.%N)
set +e
(cd "$work/job" && timeout "$timeout" nsenter --net="/run/netns/$prefix-ctl" sbatch --wait --nodes="$nodes" --parsable "$batch") > "$work/sbatch.out"
status=$?
set -e
end=$(date +%s.%N)
job=$(head -1 "$work/sbatch.out" | cut -d';' -f1)
echo "job $job: sbatch --wait returned $status after $(awk "BEGIN { printf \"%.1f\", $end - $start }") s (it polls the job state)"
ctl scontrol show job "$job" 2> /dev/null | grep -E 'JobState|RunTime|StartTime|NodeList=|ExitCode' || true
echo "--- slurm-$job.out"
cat "$work/job/slurm-$job.out" 2> /dev/null || echo "(no output file)"
ls -la "$work/job"
if [ -n "${OUT:-}" ] && [ -f "$work/job/out-$job.png" ]; then cp "$work/job/out-$job.png" "$OUT"; echo "image copied to $OUT"; fi
[ $status = 0 ] || { KEEP=1; exit $status; }
# The image against the CPU reference (ray-traced shadows, same scene and light samples).
echo "--- against the CPU reference"
"$work/lightfold" render --reference --scene balls --out "$work/reference.exr" --log warn
"$work/lightfold" compare "$work/job/out-$job.exr" "$work/reference.exr" --log warn
