#!/usr/bin/env bash
# deploy/systemd/*.service under a real systemd, on a machine whose PID 1 is not systemd (a
# container, a VM with another init): boots the machine's own systemd (/lib/systemd/systemd) as
# PID 1 of new pid, mount, UTS, IPC, network and cgroup namespaces, over an overlay of this
# machine's root with fresh /dev, /run and /tmp and a read-only /sys and /proc/sys, so nothing it
# does reaches the machine's files, devices or kernel settings. In it: the units as they are in
# deploy/systemd/, the binary at /usr/local/bin/lightfold, /etc/lightfold/token (0600), the host
# name render1. It starts lightfold-node@{0,1,12} and lightfold-compositor@{0,1,12}, checks that
# @100 and @x are refused with status 64 and not restarted, that an environment file moves the
# metrics listener, runs a coordinator against instances 0 and 1 with --shutdown, checks that
# Restart=always brought the daemons back, and prints systemd-analyze security for the units.
#
#   deploy/systemd-local.sh                 # LIGHTFOLD_BIN, default target/release/lightfold
#   deploy/systemd-local.sh --stand-in      # a Python stand-in instead of the binary: it reports
#                                           # what the sandbox lets it do, speaks sd_notify
#
# Needs root, util-linux (unshare, nsenter), systemd (not running) and, for --stand-in, python3.
# KEEP=1 leaves the namespaces running and prints how to enter them; kill the PID it prints.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
standin=""
[[ "${1:-}" == --stand-in ]] && standin=1
bin=${LIGHTFOLD_BIN:-$repo/target/release/lightfold}
[[ "$(id -u)" == 0 ]] || { echo "needs root (namespaces, mounts)" >&2; exit 2; }
for tool in unshare nsenter pivot_root /lib/systemd/systemd; do
  command -v "$tool" > /dev/null || { echo "missing $tool" >&2; exit 2; }
done
if [[ -n "$standin" ]]; then command -v python3 > /dev/null || { echo "--stand-in needs python3" >&2; exit 2; }
else [[ -x "$bin" ]] || { echo "no binary at $bin (cargo build --release -p lightfold-cli, or --stand-in)" >&2; exit 2; }
fi

work=$(mktemp -d /var/tmp/lightfold-systemd.XXXXXX)
cg=lightfold-systemd-$$
mkdir "$work/layers" "$work/root" "$work/units"
cp "$repo"/deploy/systemd/lightfold-*@.service "$work/units/"
cat > "$work/units/lightfold-test.target" << 'EOF'
[Unit]
Description=lightfold units under test
Wants=lightfold-node@0.service lightfold-node@1.service lightfold-node@12.service
Wants=lightfold-compositor@0.service lightfold-compositor@1.service lightfold-compositor@12.service
Wants=lightfold-node@100.service lightfold-compositor@x.service
EOF
if [[ -n "$standin" ]]; then
  cat > "$work/lightfold" << 'EOF'
#!/usr/bin/python3
# Stands for /usr/local/bin/lightfold: reports what the sandbox lets it do, binds its ports and
# speaks sd_notify (READY=1, WATCHDOG=1, STOPPING=1) as the daemon does.
import ctypes, json, os, signal, socket, sys, time
argv, opts = sys.argv[1:], {}
for i, a in enumerate(argv):
    if a.startswith("--"):
        opts[a] = argv[i + 1] if i + 1 < len(argv) and not argv[i + 1].startswith("--") else True
def notify(msg):
    addr = os.environ["NOTIFY_SOCKET"].replace("@", "\0", 1)
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM); s.connect(addr); s.send(msg.encode()); s.close()
def attempt(f):
    try:
        r = f(); return "ok" if r is None else r
    except OSError as e:
        return os.strerror(e.errno) if e.errno else str(e)
libc = ctypes.CDLL(None, use_errno=True)
libc.mmap.restype, libc.mmap.argtypes = ctypes.c_void_p, [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long]
r = {"uid": os.getuid(), "groups": os.getgroups(), "umask": oct(os.umask(0o77))}
r["token"] = attempt(lambda: f"{len(open(opts['--token-file']).read())} bytes, mode {oct(os.stat(opts['--token-file']).st_mode & 0o777)}")
if "--cache-dir" in opts:
    r["write cache"] = attempt(lambda: open(os.path.join(opts["--cache-dir"], "probe"), "w").close())
r["write /etc"] = attempt(lambda: open("/etc/probe", "w").close())
r["list /root"] = attempt(lambda: os.listdir("/root") and None)
r["/proc/cpuinfo"] = attempt(lambda: open("/proc/cpuinfo").close())
r["sched_setaffinity"] = attempt(lambda: os.sched_setaffinity(0, os.sched_getaffinity(0)))
p = libc.mmap(None, 4096, 7, 0x22, -1, 0)
r["W+X memory"] = "ok" if p not in (None, ctypes.c_void_p(-1).value) else os.strerror(ctypes.get_errno())
r["AF_NETLINK"] = attempt(lambda: socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, 0).close())
r["user namespace"] = "ok" if libc.unshare(0x10000000) == 0 else os.strerror(ctypes.get_errno())
socks = []
for flag in ("--listen", "--metrics-listen"):
    host, port = opts[flag].rsplit(":", 1)
    s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1); s.bind((host, int(port))); s.listen()
    socks.append(s)
print("stand-in", " ".join(argv[:1] + [f"{k} {v}" for k, v in opts.items() if k in ("--listen", "--metrics-listen")]), json.dumps(r), flush=True)
notify("READY=1")
signal.signal(signal.SIGTERM, lambda *a: (notify("STOPPING=1"), sys.exit(0)))
while True:
    notify("WATCHDOG=1"); time.sleep(5)
EOF
  chmod 755 "$work/lightfold"
else
  cp "$bin" "$work/lightfold"
fi

# Inside the new namespaces: the root, then systemd as PID 1.
cat > "$work/inner.sh" << EOF
#!/bin/bash
set -euo pipefail
W=$work M=$work/root
mount --make-rprivate /
mount -t tmpfs tmpfs \$W/layers
mkdir \$W/layers/up \$W/layers/work
mount -t overlay overlay -o lowerdir=/,upperdir=\$W/layers/up,workdir=\$W/layers/work \$M
mount -t proc proc \$M/proc
mount --bind \$M/proc/sys \$M/proc/sys
mount -o remount,bind,ro \$M/proc/sys
mount -t sysfs -o ro sysfs \$M/sys
mount -t tmpfs -o mode=755 tmpfs \$M/sys/fs/cgroup
for c in \$(awk '\$4 == 1 && \$1 != "rdma" && \$1 != "misc" { print \$1 }' /proc/cgroups); do
  mkdir \$M/sys/fs/cgroup/\$c
  mount -t cgroup -o \$c cgroup \$M/sys/fs/cgroup/\$c 2> /dev/null || rmdir \$M/sys/fs/cgroup/\$c
done
mkdir \$M/sys/fs/cgroup/systemd \$M/sys/fs/cgroup/unified
mount -t cgroup -o none,name=systemd cgroup \$M/sys/fs/cgroup/systemd
mount -t cgroup2 cgroup2 \$M/sys/fs/cgroup/unified
mount -t tmpfs -o mode=755,nosuid tmpfs \$M/dev
for n in null:1:3 zero:1:5 full:1:7 random:1:8 urandom:1:9 tty:5:0; do
  IFS=: read -r name major minor <<< "\$n"
  mknod -m 666 \$M/dev/\$name c \$major \$minor
done
mkdir \$M/dev/pts \$M/dev/shm
mount -t devpts -o newinstance,ptmxmode=666 devpts \$M/dev/pts
ln -s pts/ptmx \$M/dev/ptmx
mount -t tmpfs -o mode=1777 tmpfs \$M/dev/shm
mount -t tmpfs -o mode=1777 tmpfs \$M/tmp
mount -t tmpfs -o mode=755 tmpfs \$M/run
ip link set lo up 2> /dev/null || true
mkdir -p \$M/etc/lightfold
(umask 077 && head -c 32 /dev/urandom | base64 > \$M/etc/lightfold/token)
cp \$W/units/* \$M/etc/systemd/system/
cp \$W/lightfold \$M/usr/local/bin/lightfold
echo render1 > \$M/etc/hostname
echo "127.0.0.1 localhost render1" > \$M/etc/hosts
hostname render1
# A GPU machine has the render group (udev creates it); the units name it.
grep -q '^render:' \$M/etc/group || echo 'render:x:989:' >> \$M/etc/group
# pivot_root, not chroot: a chrooted process may not create user namespaces (PrivateUsers=).
mkdir -p \$M/.oldroot
cd \$M
pivot_root . .oldroot
umount -l /.oldroot
# What systemd does itself when the kernel starts it, and a container manager does for it: the
# credentials it mounts for a service (LoadCredential=) propagate into the service's namespace.
mount --make-rshared /
exec /usr/bin/env -i container=lightfold-test /lib/systemd/systemd --system --unit=lightfold-test.target --show-status=no
EOF
chmod +x "$work/inner.sh"

sd=""
# shellcheck disable=SC2317 # called by the trap
cleanup() {
  set +e
  if [[ -n "${KEEP:-}" && -n "$sd" ]]; then
    echo "kept: nsenter -t $sd -m -p -u -n -- systemctl status 'lightfold-*'; kill -KILL $sd when done, then rm -rf $work and rmdir /sys/fs/cgroup/*/$cg (deepest first)" >&2
    return
  fi
  [[ -n "$sd" ]] && kill -KILL "$sd" 2> /dev/null && sleep 1
  for h in /sys/fs/cgroup/*/"$cg"; do [[ -d "$h" ]] && find "$h" -depth -type d -exec rmdir {} + 2> /dev/null; done
  rm -rf "$work"
}
trap cleanup EXIT

# Its own cgroup in every hierarchy it may write, which the cgroup namespace makes its root.
(
  for h in /sys/fs/cgroup/*/; do
    if mkdir -p "$h$cg" 2> /dev/null; then echo "$BASHPID" > "$h$cg/cgroup.procs" 2> /dev/null || true; fi
  done
  exec setsid unshare --pid --fork --mount --uts --ipc --net --cgroup "$work/inner.sh"
) > "$work/boot.log" 2>&1 &
launcher=$!
for _ in $(seq 100); do
  sd=$(pgrep -P "$(pgrep -P "$launcher" -x unshare || echo "$launcher")" -x systemd || true)
  [[ -n "$sd" ]] && break
  sleep 0.1
done
[[ -n "$sd" ]] || { echo "systemd did not start:" >&2; cat "$work/boot.log" >&2; exit 1; }
in_ns() { nsenter -t "$sd" -m -p -u -n -- "$@"; }
ctl() { in_ns systemctl --no-pager "$@"; }

failures=0
check() { # message command...
  if "${@:2}"; then echo "ok: $1"; else echo "FAILED: $1"; failures=$((failures + 1)); fi
}
good=(lightfold-node@0 lightfold-node@1 lightfold-node@12 lightfold-compositor@0 lightfold-compositor@1 lightfold-compositor@12)
for _ in $(seq 300); do
  states=$(ctl show -p ActiveState --value "${good[@]}" 2> /dev/null | grep . | sort -u | tr '\n' ' ' || true)
  [[ "$states" == "active " || "$states" == *failed* ]] && break
  sleep 0.5
done
ctl list-units --all 'lightfold-*'
check "instances 0, 1 and 12 of both units started (Type=notify: READY=1 reached systemd)" test "$states" = "active "
listening=$(in_ns ss -Hltn | awk '{print $4}' | sort | tr '\n' ' ')
echo "listening: $listening"
for a in 0.0.0.0:7300 0.0.0.0:7301 0.0.0.0:7312 0.0.0.0:7500 0.0.0.0:7501 0.0.0.0:7512 127.0.0.1:9300 127.0.0.1:9312 127.0.0.1:9500 127.0.0.1:9512; do
  check "something listens on $a" grep -qF " $a " <<< " $listening"
done
for u in lightfold-node@100 lightfold-compositor@x; do
  check "$u refused with status 64 and not restarted" \
    test "$(ctl show -p ExecMainStatus --value "$u") $(ctl show -p NRestarts --value "$u")" = "64 0"
  ctl status "$u" 2>&1 | grep 'must be a number' | tail -1 || true
done
in_ns sh -c 'echo LIGHTFOLD_METRICS_LISTEN=0.0.0.0:9412 > /etc/lightfold/node-12.env'
ctl restart lightfold-node@12
sleep 1
check "/etc/lightfold/node-12.env moves node 12's metrics to 0.0.0.0:9412" in_ns sh -c 'ss -Hltn | grep -q "0.0.0.0:9412 "'
if [[ -n "$standin" ]]; then
  echo "--- the sandbox as each daemon sees it"
  in_ns journalctl --no-pager -o cat -u 'lightfold-*' | grep '^stand-in' | sort -u || true
else
  in_ns sh -c 'cat > /etc/lightfold/cluster.toml' << 'EOF'
version = 1
sink_listen = "0.0.0.0:7400"
sink_advertise = "render1:7400"
[[node]]
address = "render1:7300"
[[node]]
address = "render1:7301"
[[compositor]]
address = "render1:7500"
[[compositor]]
address = "render1:7501"
EOF
  before=$(ctl show -p NRestarts --value lightfold-node@0)
  echo "--- coordinator (as root, beside the units) against nodes 0 and 1, compositors 0 and 1"
  set +e
  in_ns sh -c 'cd /tmp && timeout 300 lightfold coordinator --cluster /etc/lightfold/cluster.toml \
    --token-file /etc/lightfold/token --connect-timeout 60 --shutdown --out /tmp/out.png --exr /tmp/out.exr'
  status=$?
  set -e
  check "the coordinator rendered through the units' daemons (status $status)" test "$status" = 0
  check "it wrote out.png and out.exr" in_ns test -s /tmp/out.exr
  for _ in $(seq 60); do
    [[ "$(ctl show -p ActiveState --value lightfold-node@0 lightfold-compositor@0 | grep . | sort -u)" == active ]] \
      && (( $(ctl show -p NRestarts --value lightfold-node@0) > before )) && break
    sleep 0.5
  done
  check "--shutdown stopped node 0 with status 0 and Restart=always started it again" \
    test "$(ctl show -p NRestarts --value lightfold-node@0)" -gt "$before"
  in_ns journalctl --no-pager -o cat -u lightfold-node@0 -u lightfold-compositor@0 -p warning | tail -20 || true
fi
echo "--- systemd-analyze security (this systemd, these units running)"
in_ns systemd-analyze security --no-pager lightfold-node@0.service lightfold-compositor@0.service | tail -3
echo "systemd-local: $failures failed"
exit $(( failures > 0 ))
