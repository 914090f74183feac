#!/usr/bin/env python3
"""Runs the deployment files where no engine is at hand: a test harness, not a launcher.

  deploy/emulate.py image BASE ROOTFS [--bin B]   copies BASE, a Debian bookworm root made with
                                                   `debootstrap --variant=minbase bookworm BASE`, to
                                                   ROOTFS and applies the Containerfile's runtime
                                                   stage to it (B stands for the build stage's binary)
  deploy/emulate.py run compose|kubernetes|systemd ROOTFS [--out PNG] [--keep]
                                                   starts every service / pod / unit as the engine
                                                   would run it from that image: a network namespace
                                                   and hostname per container (per machine for
                                                   systemd), names resolving as the engine's DNS
                                                   would, the image's user, working directory and
                                                   environment, the file's secrets and volumes (for
                                                   systemd: instances 0 and 1 of each template on two
                                                   hosts, DynamicUser= as the image's user,
                                                   credentials and cache directories, and an
                                                   operator's coordinator on a third host); waits for
                                                   the coordinator and prints its output

Needs root, iproute2 and util-linux (unshare, nsenter, setpriv), Python 3.11 with PyYAML.
"""

import argparse
import json
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time

import yaml

from lint import COMPOSE, CONTAINERFILE, KUBE, REPO, UNITS, expand, read, unit_exec, write


def sh(*argv, **kw):
    return subprocess.run(list(argv), check=True, **kw)


def image(args):
    """Applies the Containerfile's last stage to a copy of BASE; records ENV/WORKDIR/USER in ROOTFS.json."""
    root = os.path.abspath(args.rootfs)
    if os.path.exists(root):
        shutil.rmtree(root)
    sh("cp", "-a", args.base, root)
    stages = re.split(r"^FROM .*$", read(CONTAINERFILE), flags=re.MULTILINE)
    body = re.sub(r"\\\n", " ", stages[-1])
    config = {"env": {}, "workdir": "/", "user": "0:0", "entrypoint": []}
    for line in body.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        op, rest = line.split(None, 1)
        if op == "RUN":
            print("RUN", rest, flush=True)
            sh(
                "unshare",
                "--mount",
                "--propagation",
                "private",
                "sh",
                "-c",
                'mount -t proc proc "$0/proc" && mount --rbind /dev "$0/dev" && exec chroot "$0" sh -c "$1"',
                root,
                rest,
            )
        elif op == "COPY":
            src, dst = rest.split()[-2:]
            if src != "/lightfold":
                sys.exit(f"COPY {src}: only the build stage's binary is known here")
            print("COPY", args.bin, "->", dst, flush=True)
            shutil.copy2(args.bin, root + dst)
        elif op == "ENV":
            for word in shlex.split(rest):  # ENV A=1 B=2 (continuation lines already joined)
                k, v = word.split("=", 1)
                config["env"][k] = v
        elif op == "WORKDIR":
            config["workdir"] = rest
        elif op == "USER":
            config["user"] = rest
        elif op == "ENTRYPOINT":
            config["entrypoint"] = json.loads(rest)
    write(root + ".json", json.dumps(config, indent=1))
    print("image config:", config)
    return 0


class Container:
    def __init__(self, name, argv, env, hostname, dns, mounts, coordinator=False):
        self.name, self.argv, self.env, self.hostname = name, argv, env, hostname
        self.dns, self.mounts, self.coordinator = dns, mounts, coordinator


def token_text():
    """As the files' headers say: head -c 32 /dev/urandom | base64."""
    import base64

    return base64.b64encode(os.urandom(32)).decode() + "\n"


def compose_containers(work, config):
    """compose.yaml in a copy of its directory prepared as its header says (token, out/)."""
    d = os.path.join(work, "compose")
    shutil.copytree(os.path.dirname(COMPOSE), d)
    write(os.path.join(d, "token"), token_text())
    os.makedirs(os.path.join(d, "out"), exist_ok=True)
    os.chmod(os.path.join(d, "out"), 0o777)
    doc = yaml.safe_load(read(os.path.join(d, "compose.yaml")))
    out = []
    for name, svc in doc["services"].items():
        mounts = [
            (os.path.join(d, doc["secrets"][s]["file"]), f"/run/secrets/{s}", True) for s in svc.get("secrets", [])
        ]
        for v in svc.get("volumes", []):
            parts = v.split(":")
            mounts.append((os.path.normpath(os.path.join(d, parts[0])), parts[1], len(parts) > 2 and "ro" in parts[2]))
        env = dict(config["env"], **dict(e.split("=", 1) for e in svc.get("environment", [])))
        out.append(
            Container(
                name,
                config["entrypoint"] + svc["command"],
                env,
                name,
                [name],
                mounts,
                coordinator=svc["command"][0] == "coordinator",
            )
        )
    return out, os.path.join(d, "out")


def secret(work, name):
    """The secret `name` (key `token`) as made by the header's kubectl line; its text."""
    path = os.path.join(work, "volumes", "secret-" + name)
    if not os.path.exists(path):
        os.makedirs(path)
        write(os.path.join(path, "token"), token_text())  # the kubelet writes 0644
    return read(os.path.join(path, "token"))


def kubernetes_containers(work, config):
    docs = [x for x in yaml.safe_load_all(read(KUBE)) if x]
    out, outdir = [], None
    for d in docs:
        if d["kind"] not in ("StatefulSet", "Job"):
            continue
        spec = d["spec"]["template"]["spec"]
        fsgroup = spec.get("securityContext", {}).get("fsGroup")
        if d["kind"] == "StatefulSet":
            pods = [
                (f"{d['metadata']['name']}-{i}", f"{d['metadata']['name']}-{i}.{d['spec']['serviceName']}")
                for i in range(d["spec"]["replicas"])
            ]
        else:
            pods = [(spec["hostname"], f"{spec['hostname']}.{spec['subdomain']}")]
        for pod, dns in pods:
            vols = {}
            for v in spec.get("volumes", []):
                path = os.path.join(work, "volumes", pod, v["name"])
                if "secret" in v:
                    secret(work, v["secret"]["secretName"])
                    vols[v["name"]] = os.path.join(work, "volumes", "secret-" + v["secret"]["secretName"])
                    continue
                os.makedirs(path)
                if "configMap" in v:
                    cm = next(
                        x for x in docs if x["kind"] == "ConfigMap" and x["metadata"]["name"] == v["configMap"]["name"]
                    )
                    for k, text in cm["data"].items():
                        write(os.path.join(path, k), text)
                elif "emptyDir" in v:
                    os.chmod(path, 0o777)  # as the kubelet makes it
                elif "persistentVolumeClaim" in v:
                    if fsgroup is not None:  # the kubelet makes the volume group-owned and writable
                        os.chown(path, 0, fsgroup)
                        os.chmod(path, 0o2775)
                vols[v["name"]] = path
            for c in spec["containers"]:
                env = dict(config["env"])
                for e in c.get("env", []):
                    ref = e.get("valueFrom", {})
                    if ref.get("fieldRef", {}).get("fieldPath") == "metadata.name":
                        env[e["name"]] = pod
                    elif "secretKeyRef" in ref:
                        env[e["name"]] = secret(work, ref["secretKeyRef"]["name"]).strip()
                    else:
                        env[e["name"]] = e.get("value", "")
                argv = [expand(a, env) for a in c.get("args", [])]
                mounts = [
                    (vols[m["name"]], m["mountPath"], m.get("readOnly", False)) for m in c.get("volumeMounts", [])
                ]
                if argv[0] == "coordinator":
                    outdir = next((src for src, dst, _ in mounts if dst == "/out"), None)
                out.append(
                    Container(
                        pod, config["entrypoint"] + argv, env, pod, [dns], mounts, coordinator=argv[0] == "coordinator"
                    )
                )
    return out, outdir


LAUNCH = r"""set -e
root=$1 hosts=$2 name=$3 user=$4 workdir=$5; shift 5
hostname "$name"
mount --bind "$hosts" "$root/etc/hosts"
mount -t proc proc "$root/proc"
mount -t sysfs -o ro sysfs "$root/sys"
mount --rbind /dev "$root/dev"
while [ "$1" != -- ]; do
  mount --bind "$1" "$root$2"
  [ "$3" = ro ] && mount -o remount,bind,ro "$root$2"
  shift 3
done
shift
exec chroot "$root" setpriv --reuid="${user%:*}" --regid="${user#*:}" --clear-groups \
  sh -c 'cd "$0" && exec "$@"' "$workdir" "$@"
"""


def systemd_containers(work, config, hosts=2):
    """Each unit as systemd would start instances 0 and 1 of it on HOSTS machines (DynamicUser=
    as the image's unprivileged user, LoadCredential= and CacheDirectory= as mounted directories),
    and an operator's coordinator on a host of its own with a cluster file listing them."""
    token = os.path.join(work, "token")
    write(token, token_text())
    os.chmod(token, 0o600)
    out, cluster = [], {"node": [], "compositor": []}
    for h in range(1, hosts + 1):
        host = f"render{h}"
        for path in UNITS:
            for i in (0, 1):
                argv, creds, text = unit_exec(path, i, host)
                unit = os.path.basename(path).replace("@", f"@{i}")
                mounts = []
                cred_dir = os.path.join(work, "credentials", host, unit)
                os.makedirs(cred_dir)
                for name, src in creds.items():
                    if src != "/etc/lightfold/token":
                        sys.exit(f"{unit}: credential from {src}: only /etc/lightfold/token is known here")
                    shutil.copy(token, os.path.join(cred_dir, name))
                    os.chown(os.path.join(cred_dir, name), 65534, 65534)
                mounts.append((cred_dir, f"/run/credentials/{unit}", True))
                subst = {"CREDENTIALS_DIRECTORY": f"/run/credentials/{unit}"}
                cache = re.search(r"^CacheDirectory=(.*)$", text, re.MULTILINE)
                if cache:
                    rel = cache.group(1).replace("%i", str(i))
                    src = os.path.join(work, "cache", host, rel)
                    os.makedirs(src)
                    os.chown(src, 65534, 65534)
                    mounts.append((src, f"/var/cache/{rel}", False))
                    subst["CACHE_DIRECTORY"] = f"/var/cache/{rel}"
                env = {}
                for line in re.findall(r"^Environment=(.*)$", text, re.MULTILINE):
                    k, v = line.replace("%i", str(i)).replace("%C", "/var/cache").split("=", 1)
                    env[k] = v
                argv = [re.sub(r"\$\{(\w+)\}", lambda m, subst=subst: subst[m.group(1)], x) for x in argv]
                role = argv[1]
                cluster[role].append(argv[argv.index("--advertise") + 1])
                c = Container(f"{host}-{unit}", argv, env, host, [host], mounts)
                c.workdir = "/"  # systemd's default WorkingDirectory=
                out.append(c)
    text = 'version = 1\nsink_listen = "0.0.0.0:7400"\nsink_advertise = "operator:7400"\n'
    for role in ("node", "compositor"):
        text += "".join(f'[[{role}]]\naddress = "{a}"\n' for a in cluster[role])
    os.makedirs(os.path.join(work, "etc"))
    write(os.path.join(work, "etc", "cluster.toml"), text)
    shutil.copy(token, os.path.join(work, "etc", "token"))
    os.chown(os.path.join(work, "etc", "token"), 65534, 65534)
    outdir = os.path.join(work, "out")
    os.makedirs(outdir)
    os.chmod(outdir, 0o777)
    argv = config["entrypoint"] + [
        "coordinator",
        "--cluster",
        "/etc/lightfold/cluster.toml",
        "--token-file",
        "/etc/lightfold/token",
        "--connect-timeout",
        "60",
        "--out",
        "/out/out.png",
        "--exr",
        "/out/out.exr",
        "--shutdown",
    ]
    out.append(
        Container(
            "operator",
            argv,
            dict(config["env"]),
            "operator",
            ["operator"],
            [(os.path.join(work, "etc"), "/etc/lightfold", True), (outdir, "/out", False)],
            coordinator=True,
        )
    )
    return out, outdir


def run(args):
    root = os.path.abspath(args.rootfs)
    config = json.loads(read(root + ".json"))
    work = tempfile.mkdtemp(prefix="lightfold-deploy-")
    os.chmod(work, 0o755)
    make = {"compose": compose_containers, "kubernetes": kubernetes_containers, "systemd": systemd_containers}
    containers, outdir = make[args.engine](work, config)
    prefix, procs, made = f"lfd{os.getpid() % 100000}", [], []
    bridge = prefix + "br"
    # One network namespace per host: a container, a pod, or a machine running several units.
    hostnames = list(dict.fromkeys(c.hostname for c in containers))
    try:
        sh("ip", "link", "add", bridge, "type", "bridge")
        sh("ip", "link", "set", bridge, "up")
        names = {h: [h] for h in hostnames}
        for c in containers:
            names[c.hostname] += c.dns
        hosts = ["127.0.0.1 localhost"]
        hosts += [f"10.79.0.{2 + k} {' '.join(dict.fromkeys(names[h]))}" for k, h in enumerate(hostnames)]
        write(os.path.join(work, "hosts"), "\n".join(hosts) + "\n")
        pathlib.Path(os.path.join(root, "etc", "hosts")).touch()  # engines provide it; debootstrap does not
        for k, h in enumerate(hostnames):
            ns, v, p = f"{prefix}-{k}", f"v{prefix}{k}", f"p{prefix}{k}"
            sh("ip", "netns", "add", ns)
            made.append(ns)
            sh("ip", "link", "add", v, "type", "veth", "peer", "name", p)
            sh("ip", "link", "set", p, "netns", ns)
            sh("ip", "-n", ns, "link", "set", p, "name", "eth0")
            sh("ip", "link", "set", v, "master", bridge, "up")
            sh("ip", "-n", ns, "addr", "add", f"10.79.0.{2 + k}/24", "dev", "eth0")
            sh("ip", "-n", ns, "link", "set", "eth0", "up")
            sh("ip", "-n", ns, "link", "set", "lo", "up")
        for c in containers:
            for src, dst, ro in c.mounts:  # mount points, as the runtime creates them
                target = root + dst
                if os.path.isdir(src):
                    os.makedirs(target, exist_ok=True)
                else:
                    os.makedirs(os.path.dirname(target), exist_ok=True)
                    pathlib.Path(target).touch()
        start = time.time()
        for c in sorted(containers, key=lambda c: c.coordinator):
            spec = [x for src, dst, ro in c.mounts for x in (src, dst, "ro" if ro else "rw")]
            env = [
                "env",
                "-i",
                "PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
                "HOME=/nonexistent",
            ]
            env += [f"{k2}={v}" for k2, v in c.env.items()]
            ns = f"{prefix}-{hostnames.index(c.hostname)}"
            argv = [
                "nsenter",
                f"--net=/run/netns/{ns}",
                "unshare",
                "--mount",
                "--uts",
                "--propagation",
                "private",
                "sh",
                "-c",
                LAUNCH,
                "launch",
                root,
                os.path.join(work, "hosts"),
                c.hostname,
                config["user"],
                getattr(c, "workdir", config["workdir"]),
                *spec,
                "--",
                *env,
                *c.argv,
            ]
            with open(os.path.join(work, f"{c.name}.log"), "w") as log:  # the child keeps its own copy
                procs.append((c, subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)))
        coord_c, coord = next((c, p) for c, p in procs if c.coordinator)
        try:
            status = coord.wait(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            status = "timeout"
        took = time.time() - start
        print(read(os.path.join(work, f"{coord_c.name}.log")))
        time.sleep(1)  # let daemons told to shut down finish
        for c, p in procs:
            if not c.coordinator and p.poll() is not None and p.returncode != 0:
                print(f"--- {c.name} exited with {p.returncode}:")
                print(read(os.path.join(work, f"{c.name}.log"))[-2000:])
        listing = sorted(os.listdir(outdir)) if outdir else "(no /out volume)"
        print(f"{args.engine}: coordinator exit status {status} after {took:.1f} s; outputs in {outdir}: {listing}")
        if args.out and outdir and os.path.exists(os.path.join(outdir, "out.png")):
            shutil.copy(os.path.join(outdir, "out.png"), args.out)
        return 0 if status == 0 else 1
    finally:
        for _, p in procs:
            if p.poll() is None:
                p.terminate()
        for _, p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], check=False)
        subprocess.run(["ip", "link", "del", bridge], check=False, stderr=subprocess.DEVNULL)
        if args.keep:
            print("kept", work)
        else:
            shutil.rmtree(work)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    default_bin = os.path.join(REPO, "target", "release", "lightfold")
    p = sub.add_parser("image")
    p.add_argument("base")
    p.add_argument("rootfs")
    p.add_argument("--bin", default=default_bin)
    p = sub.add_parser("run")
    p.add_argument("engine", choices=["compose", "kubernetes", "systemd"])
    p.add_argument("rootfs")
    p.add_argument("--timeout", type=float, default=300)
    p.add_argument("--out", help="copy the coordinator's PNG here")
    p.add_argument("--keep", action="store_true", help="keep the work dir (logs, volumes)")
    args = ap.parse_args()
    return {"image": image, "run": run}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
