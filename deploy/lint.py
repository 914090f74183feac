#!/usr/bin/env python3
"""Checks the deployment files against the lightfold binary's real flags, without any engine.

  deploy/lint.py [--bin target/release/lightfold]

Every command line in compose, Kubernetes and the systemd units uses flags the subcommand has;
listen and advertised ports agree, each daemon advertises the name the others resolve, the
cluster files list exactly the advertised daemons (and ids) with a reachable sink, tokens come from
mounted secrets or credentials, and the coordinator's images (also its default out.png/out.exr,
relative to the image's WORKDIR) land on a writable volume. Operations: Kubernetes probes ask
/healthz and /readyz on the port the daemon serves metrics on, every container has requests and
limits and a restricted securityContext, headless services publish daemons that are not ready yet
(the coordinator makes them ready); the GPU variant (kubernetes-gpu/, a kustomization over
lightfold.yaml with a strategic-merge patch) is rendered with `kubectl kustomize` where kubectl is
installed (else merged here the same way), passes the same checks, asks for a GPU and refuses a CPU
rasteriser. systemd units are Type=notify with a watchdog and an EnvironmentFile; their ExecStart
is run through its shell for instances 0-99 (ports 7300+N / 7500+N, metrics 9300+N / 9500+N, all
distinct) and must refuse any other instance with status 64, which is not restarted; they carry
the sandbox options (docs/deploy.md), and `systemd-analyze security --offline` (where installed)
scores them. The image sets no NVIDIA_VISIBLE_DEVICES (the runtime chooses a pod's GPUs), asks
NVIDIA's toolkit for `graphics`, builds with cache mounts and has a HEALTHCHECK the binary
answers. The Slurm script is run with stand-ins for srun, scontrol and the binary: ports from the
job id, GPUs when allocated, an empty array under `set -u`, a per-job token it makes (0600 in a
0700 directory, removed at the end) and a given token that others can read refused. The
Prometheus examples pass `promtool check config` (where promtool is installed; the Kubernetes
discovery file only where promtool has Kubernetes discovery, which Debian's lacks).
Needs Python 3.11 with PyYAML. Without the binary the flag checks are skipped, and it says so.
deploy/emulate.py runs the same files.
"""

import argparse
import os
import pathlib
import re
import shlex
import subprocess
import sys
import tempfile
import tomllib

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
COMPOSE = os.path.join(HERE, "compose", "compose.yaml")
KUBE = os.path.join(HERE, "kubernetes", "lightfold.yaml")
UNITS = [os.path.join(HERE, "systemd", f) for f in ("lightfold-node@.service", "lightfold-compositor@.service")]
CONTAINERFILE = os.path.join(HERE, "container", "Containerfile")
GPU_DIR = os.path.join(HERE, "kubernetes-gpu")
GPU_PATCH = os.path.join(GPU_DIR, "render-gpu.patch.yaml")
SBATCH = os.path.join(HERE, "slurm", "lightfold.sbatch")
PROMETHEUS = os.path.join(HERE, "prometheus", "prometheus.yml")
PROMETHEUS_K8S_SD = os.path.join(HERE, "prometheus", "kubernetes-sd.yml")
ROLES = ("node", "compositor", "coordinator")
errors = []


def read(path):
    return pathlib.Path(path).read_text()


def write(path, text):
    pathlib.Path(path).write_text(text)


def err(where, msg):
    errors.append(f"{where}: {msg}")


class AnyFlag(dict):
    """Stands for a subcommand's flags when there is no binary to ask: any flag is accepted, and
    it takes a value when the next word is not a flag."""

    def __contains__(self, key):
        return True


def flags_of(binary, sub):
    """{'--flag': takes_value} from `lightfold SUB --help` (AnyFlag without the binary)."""
    if not os.access(binary, os.X_OK):
        return AnyFlag()
    out = subprocess.run([binary, sub, "--help"], capture_output=True, text=True, check=True).stdout
    flags = {}
    for m in re.finditer(r"^\s+(?:-\w, )?(--[a-z][a-z-]*)( <[A-Z_]+>)?", out, re.MULTILINE):
        flags[m.group(1)] = bool(m.group(2))
    return flags


def parse_cmd(where, argv, flags):
    """Checks argv (subcommand first) against the flags; returns (role, {flag: value})."""
    if not argv or argv[0] not in ROLES:
        err(where, f"first argument {argv[:1]} is not one of {ROLES}")
        return None, {}
    role, opts, i = argv[0], {}, 1
    while i < len(argv):
        a = argv[i]
        if a not in flags[role]:
            err(where, f"`{role}` has no flag {a!r}")
            i += 1
            continue
        if isinstance(flags[role], AnyFlag):
            takes = i + 1 < len(argv) and not argv[i + 1].startswith("--")
        else:
            takes = flags[role][a]
        if takes:
            if i + 1 >= len(argv) or argv[i + 1].startswith("--"):
                err(where, f"{a} needs a value")
                i += 1
                continue
            opts[a] = argv[i + 1]
            i += 2
        else:
            opts[a] = True
            i += 1
    if role != "coordinator" and "--listen" not in opts:
        err(where, "a daemon needs --listen")
    return role, opts


def port_of(addr):
    return addr.rsplit(":", 1)[1] if addr and ":" in addr else None


def check_daemon(where, opts, name, expose=None):
    """Listen and advertise ports agree, the advertised host is the name others resolve."""
    listen, adv = opts.get("--listen"), opts.get("--advertise")
    if not adv:
        err(where, f"no --advertise: a daemon bound to {listen} advertises that, which no other host can dial")
        return None
    if port_of(listen) != port_of(adv):
        err(where, f"listens on port {port_of(listen)} but advertises {adv}")
    if name is not None and adv.rsplit(":", 1)[0] != name:
        err(where, f"advertises {adv}, but others reach it as {name}")
    if expose is not None and port_of(listen) not in expose:
        err(where, f"port {port_of(listen)} is not among the declared ports {sorted(expose)}")
    return adv


def check_cluster(where, text, advertised, sink_name, ids):
    """The cluster file lists exactly the advertised daemons by role, and a reachable sink."""
    try:
        c = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        err(where, f"cluster file does not parse: {e}")
        return
    for role, key in (("node", "node"), ("compositor", "compositor")):
        listed = {e["address"] for e in c.get(key, [])}
        if listed != advertised[role]:
            err(where, f"cluster file {key}s {sorted(listed ^ advertised[role])} differ from the advertised ones")
        for e in c.get(key, []):
            if "id" in e and ids.get(e["address"]) != e["id"]:
                err(
                    where,
                    f"cluster file expects id {e['id']} at {e['address']}, the daemon says {ids.get(e['address'])}",
                )
    sink = c.get("sink_advertise") or c.get("sink_listen", "")
    if port_of(sink) != port_of(c.get("sink_listen", "")):
        err(where, f"sink_advertise {sink} and sink_listen {c.get('sink_listen')} disagree on the port")
    if sink.rsplit(":", 1)[0] != sink_name:
        err(where, f"sink_advertise {sink}: the coordinator is reachable as {sink_name}")


def under(path, mounts):
    """The mount (target, read_only, kind) that holds path, if any."""
    best = None
    for m in mounts:
        if path == m[0] or path.startswith(m[0].rstrip("/") + "/"):
            if best is None or len(m[0]) > len(best[0]):
                best = m
    return best


def image_workdir():
    """The final stage's WORKDIR: where relative paths (the coordinator's default outputs) land."""
    last = re.split(r"^FROM .*$", read(CONTAINERFILE), flags=re.MULTILINE)[-1]
    found = re.findall(r"^WORKDIR\s+(\S+)", last, re.MULTILINE)
    return found[-1] if found else "/"


def check_files(where, opts, mounts, token_ok, role=None):
    if role == "coordinator":  # the outputs it writes when not told where
        for flag, default in (("--out", "out.png"), ("--exr", "out.exr")):
            path = opts.setdefault(flag, default)
            if not path.startswith("/"):
                opts[flag] = os.path.join(image_workdir(), path)
    tf = opts.get("--token-file")
    if tf is None and not token_ok:
        err(where, "no --token-file and no LIGHTFOLD_TOKEN")
    if tf is not None:
        m = under(tf, mounts)
        if m is None or m[2] != "secret":
            err(where, f"token file {tf} is not on a mounted secret")
    for flag in ("--out", "--exr"):
        if flag in opts:
            m = under(opts[flag], mounts)
            if m is None or m[1]:
                err(where, f"{flag} {opts[flag]} is not on a writable volume: the image is lost or not written")
    if "--cluster" in opts and under(opts["--cluster"], mounts) is None:
        err(where, f"cluster file {opts['--cluster']} is not mounted")


def lint_compose(flags):
    doc = yaml.safe_load(read(COMPOSE))
    where = "compose"
    advertised, ids, coord = {"node": set(), "compositor": set()}, {}, None
    for name, svc in doc["services"].items():
        role, opts = parse_cmd(f"{where}/{name}", svc["command"], flags)
        mounts = [(f"/run/secrets/{s}", True, "secret") for s in svc.get("secrets", [])]
        for v in svc.get("volumes", []):
            parts = v.split(":")
            mounts.append((parts[1], len(parts) > 2 and "ro" in parts[2], "bind"))
            if not os.path.exists(os.path.join(os.path.dirname(COMPOSE), parts[0])) and parts[0] != "./out":
                err(f"{where}/{name}", f"bind source {parts[0]} does not exist")
        check_files(f"{where}/{name}", opts, mounts, "LIGHTFOLD_TOKEN" in str(svc.get("environment", "")), role)
        if role in ("node", "compositor"):
            adv = check_daemon(f"{where}/{name}", opts, name)
            if adv:
                advertised[role].add(adv)
                ids[adv] = opts.get("--id")
        elif role == "coordinator":
            coord = (name, opts, svc)
    if coord is None:
        err(where, "no coordinator service")
        return
    name, opts, svc = coord
    missing = set(doc["services"]) - set(svc.get("depends_on", [])) - {name}
    if missing:
        err(f"{where}/{name}", f"does not depend on {sorted(missing)}")
    path = os.path.join(os.path.dirname(COMPOSE), "cluster.toml")
    check_cluster(f"{where}/cluster.toml", read(path), advertised, name, ids)


def expand(s, env):
    return re.sub(r"\$\((\w+)\)", lambda m: env.get(m.group(1), m.group(0)), s)


def lint_kubernetes(flags, docs=None, label="kubernetes"):
    """lightfold.yaml, or DOCS (the GPU variant as kustomize renders it) under LABEL."""
    if docs is None:
        docs = [d for d in yaml.safe_load_all(read(KUBE)) if d]
    kinds = {(d["kind"], d["metadata"]["name"]): d for d in docs}
    advertised, ids, cluster_text, sink_name = {"node": set(), "compositor": set()}, {}, None, None
    for d in docs:
        if d["kind"] not in ("StatefulSet", "Job"):
            continue
        spec = d["spec"]["template"]["spec"]
        where = f"{label}/{d['kind']}/{d['metadata']['name']}"
        vols = {v["name"]: v for v in spec.get("volumes", [])}
        pods = (
            [f"{d['metadata']['name']}-{i}" for i in range(d["spec"].get("replicas", 1))]
            if d["kind"] == "StatefulSet"
            else [None]
        )
        for c in spec["containers"]:
            mounts = []
            for vm in c.get("volumeMounts", []):
                v = vols.get(vm["name"])
                if v is None:
                    err(where, f"mount of undeclared volume {vm['name']}")
                    continue
                kind = "secret" if "secret" in v else "configMap" if "configMap" in v else "volume"
                mounts.append((vm["mountPath"], vm.get("readOnly", False) or kind in ("secret", "configMap"), kind))
                if kind == "configMap":
                    cm = kinds.get(("ConfigMap", v["configMap"]["name"]))
                    if cm is None:
                        err(where, f"no ConfigMap {v['configMap']['name']}")
                    else:
                        cluster_text = cm["data"].get("cluster.toml", cluster_text)
                if (
                    "persistentVolumeClaim" in v
                    and ("PersistentVolumeClaim", v["persistentVolumeClaim"]["claimName"]) not in kinds
                ):
                    err(where, f"no PersistentVolumeClaim {v['persistentVolumeClaim']['claimName']}")
            env_names = {e["name"] for e in c.get("env", [])}
            expose = {str(p["containerPort"]) for p in c.get("ports", [])}
            check_pod_ops(where, d, spec, c, flags)
            for pod in pods:
                env = {"POD_NAME": pod} if pod and "POD_NAME" in env_names else {}
                argv = [expand(a, env) for a in c.get("args", [])]
                role, opts = parse_cmd(where, argv, flags)
                check_files(where, opts, mounts, "LIGHTFOLD_TOKEN" in env_names, role)
                if role in ("node", "compositor"):
                    svc = d["spec"]["serviceName"]
                    if ("Service", svc) not in kinds or kinds[("Service", svc)]["spec"].get("clusterIP") != "None":
                        err(where, f"serviceName {svc} is not a headless Service")
                    elif not kinds[("Service", svc)]["spec"].get("publishNotReadyAddresses"):
                        err(
                            where,
                            f"Service {svc} does not publish addresses that are not ready: daemons are ready "
                            "only once the coordinator configured them, which it cannot do without their names",
                        )
                    adv = check_daemon(where, opts, f"{pod}.{svc}", expose)
                    if adv:
                        advertised[role].add(adv)
                        ids[adv] = opts.get("--id")
                elif role == "coordinator":
                    sink_name = f"{spec.get('hostname')}.{spec.get('subdomain')}"
                    if ("Service", spec.get("subdomain")) not in kinds:
                        err(
                            where,
                            f"subdomain {spec.get('subdomain')} has no headless Service: the sink has no DNS name",
                        )
    if cluster_text is None:
        err(label, "no cluster.toml ConfigMap mounted by the coordinator")
    else:
        check_cluster(f"{label}/ConfigMap", cluster_text, advertised, sink_name, ids)


def probe_port(c, probe):
    """The containerPort number an httpGet probe asks, and its path."""
    get = (c.get(probe) or {}).get("httpGet")
    if not get:
        return None, None
    port = get.get("port")
    for p in c.get("ports", []):
        if port in (p.get("name"), p["containerPort"]):
            return str(p["containerPort"]), get.get("path")
    return "undeclared", get.get("path")


def check_pod_ops(where, d, spec, c, flags):
    """Probes on the metrics listener, resources, and a restricted securityContext."""
    argv = c.get("args", [])
    role = argv[0] if argv else None
    metrics = argv[argv.index("--metrics-listen") + 1] if "--metrics-listen" in argv else None
    if metrics is None:
        err(where, "no --metrics-listen: no /metrics, /healthz or /readyz to probe")
        return
    want = {"livenessProbe": "/healthz"}
    if d["kind"] == "StatefulSet":
        want.update({"startupProbe": "/healthz", "readinessProbe": "/readyz"})
    for probe, path in want.items():
        port, asked = probe_port(c, probe)
        if port is None:
            err(where, f"no {probe} (httpGet {path})")
        elif port != port_of(metrics) or asked != path:
            err(where, f"{probe} asks {asked} on port {port}; the daemon serves {path} on {port_of(metrics)}")
    res = c.get("resources", {})
    for k in ("requests", "limits"):
        for r in ("cpu", "memory"):
            if r not in res.get(k, {}):
                err(where, f"no resources.{k}.{r}")
    sc, psc = c.get("securityContext", {}), spec.get("securityContext", {})
    if sc.get("allowPrivilegeEscalation") is not False:
        err(where, "securityContext.allowPrivilegeEscalation is not false")
    if "ALL" not in sc.get("capabilities", {}).get("drop", []):
        err(where, "securityContext does not drop ALL capabilities")
    if not (sc.get("runAsNonRoot") or psc.get("runAsNonRoot")):
        err(where, "runAsNonRoot is not set")
    seccomp = sc.get("seccompProfile") or psc.get("seccompProfile") or {}
    if seccomp.get("type") not in ("RuntimeDefault", "Localhost"):
        err(where, "no seccompProfile RuntimeDefault")
    if sc.get("readOnlyRootFilesystem") is not True:
        err(where, "the root file system is writable (readOnlyRootFilesystem)")
    if role == "node" and "XDG_CACHE_HOME" not in {e["name"] for e in c.get("env", [])}:
        err(where, "a node on a read-only root needs XDG_CACHE_HOME on a volume (the driver's shader cache)")


def smp_merge(base, patch):
    """A strategic merge patch as kubectl applies it to the fields used here: maps merge, lists
    of maps with a `name` (containers, env, ports, volumes) merge by name, other lists replace."""
    if isinstance(base, dict) and isinstance(patch, dict):
        out = dict(base)
        for k, v in patch.items():
            out[k] = smp_merge(base[k], v) if k in base else v
        return out
    if (
        isinstance(base, list)
        and isinstance(patch, list)
        and all(isinstance(x, dict) and "name" in x for x in base + patch)
    ):
        out = [dict(x) for x in base]
        for p in patch:
            i = next((j for j, x in enumerate(out) if x["name"] == p["name"]), None)
            if i is None:
                out.append(p)
            else:
                out[i] = smp_merge(out[i], p)
        return out
    return patch


def gpu_variant():
    """The GPU variant's documents: `kubectl kustomize kubernetes-gpu` where kubectl is installed,
    else the kustomization's patches merged over its resources here."""
    try:
        r = subprocess.run(["kubectl", "kustomize", GPU_DIR], capture_output=True, text=True)
    except FileNotFoundError:
        r = None
    if r is not None:
        if r.returncode != 0:
            err("kubernetes-gpu", f"kubectl kustomize fails: {r.stderr.strip()}")
            return None
        return [d for d in yaml.safe_load_all(r.stdout) if d]
    print("lint: kubectl not installed; merging kubernetes-gpu's patch here (as kustomize would)")
    k = yaml.safe_load(read(os.path.join(GPU_DIR, "kustomization.yaml")))
    docs = []
    for res in k.get("resources", []):
        path = os.path.normpath(os.path.join(GPU_DIR, res))
        if os.path.isdir(path):
            sub = yaml.safe_load(read(os.path.join(path, "kustomization.yaml")))
            files = [os.path.join(path, f) for f in sub.get("resources", [])]
        else:
            files = [path]
        for f in files:
            docs += [d for d in yaml.safe_load_all(read(f)) if d]
    for p in k.get("patches", []):
        patch = yaml.safe_load(read(os.path.join(GPU_DIR, p["path"])))
        for i, d in enumerate(docs):
            if (d["kind"], d["metadata"]["name"]) == (patch["kind"], patch["metadata"]["name"]):
                docs[i] = smp_merge(d, patch)
    return docs


def lint_gpu_patch(flags):
    """The GPU patch is a strategic-merge patch kustomize can apply (apiVersion, kind, the render
    StatefulSet's name); the variant it makes passes every Kubernetes check, and its render nodes
    ask for a GPU, refuse a CPU rasteriser and ask NVIDIA's toolkit for `graphics`."""
    where = "kubernetes-gpu/render-gpu.patch.yaml"
    patch = yaml.safe_load(read(GPU_PATCH))
    docs = [d for d in yaml.safe_load_all(read(KUBE)) if d]
    base = next((d for d in docs if d["kind"] == "StatefulSet" and d["metadata"]["name"] == "render"), None)
    if base is None:
        err(where, "no render StatefulSet to patch")
        return
    for key, want in (("apiVersion", base["apiVersion"]), ("kind", "StatefulSet")):
        if patch.get(key) != want:
            err(where, f"{key} is {patch.get(key)!r}, not {want!r}: kustomize cannot tell what it patches")
    if (patch.get("metadata") or {}).get("name") != "render":
        err(where, "metadata.name is not render, the render StatefulSet of lightfold.yaml")
    k = yaml.safe_load(read(os.path.join(GPU_DIR, "kustomization.yaml")))
    if not any(p.get("path") == os.path.basename(GPU_PATCH) for p in k.get("patches", [])):
        err("kubernetes-gpu/kustomization.yaml", "does not apply render-gpu.patch.yaml")
    variant = gpu_variant()
    if variant is None:
        return
    lint_kubernetes(flags, variant, "kubernetes-gpu")
    render = next((d for d in variant if d["kind"] == "StatefulSet" and d["metadata"]["name"] == "render"), None)
    if render is None:
        err("kubernetes-gpu", "no render StatefulSet")
        return
    for c in render["spec"]["template"]["spec"]["containers"]:
        role, opts = parse_cmd(where, c.get("args", []), flags)
        if role != "node" or "--require-gpu" not in opts:
            err(where, "a GPU node without --require-gpu renders on the CPU when its GPU is missing")
        for k in ("requests", "limits"):
            if "nvidia.com/gpu" not in c.get("resources", {}).get(k, {}):
                err(where, f"no nvidia.com/gpu in resources.{k}")
        env = {e["name"]: e.get("value") for e in c.get("env", [])}
        if "graphics" not in (env.get("NVIDIA_DRIVER_CAPABILITIES") or ""):
            err(where, "NVIDIA_DRIVER_CAPABILITIES lacks graphics: no Vulkan driver in the container")
        if "NVIDIA_VISIBLE_DEVICES" in env:
            err(where, "sets NVIDIA_VISIBLE_DEVICES: the device plugin sets it from nvidia.com/gpu")
    for d in variant:
        if d["kind"] == "StatefulSet" and d["metadata"]["name"] != "render":
            for c in d["spec"]["template"]["spec"]["containers"]:
                if "nvidia.com/gpu" in str(c.get("resources")):
                    err("kubernetes-gpu", f"{d['metadata']['name']} asks for a GPU too")


def lint_container(binary):
    where = "container/Containerfile"
    text = read(CONTAINERFILE)
    stages = re.split(r"^FROM .*$", text, flags=re.MULTILINE)
    last = stages[-1]
    code = "\n".join(l for l in text.splitlines() if not l.lstrip().startswith("#"))
    if "NVIDIA_VISIBLE_DEVICES" in code:
        err(where, "sets NVIDIA_VISIBLE_DEVICES: every container of the image would see every GPU of its host")
    caps = re.search(r"NVIDIA_DRIVER_CAPABILITIES=(\S+)", last)
    if not caps or "graphics" not in caps.group(1).split(","):
        err(where, "NVIDIA_DRIVER_CAPABILITIES does not include graphics (the Vulkan driver)")
    build = re.sub(r"\\\n", " ", "".join(stages[1:-1]))
    run = next((l for l in build.splitlines() if l.startswith("RUN") and "cargo build" in l), "")
    for target in ("/usr/local/cargo/registry", "/src/target"):
        if not re.search(rf"--mount=type=cache,[^ ]*target={re.escape(target)}\b", run):
            err(where, f"cargo build without a cache mount on {target}: every build starts from nothing")
    copied = re.search(r"^COPY --from=\S+ (\S+) /usr/local/bin/lightfold$", last, re.MULTILINE)
    if copied and copied.group(1).startswith("/src/target/"):
        err(where, f"copies {copied.group(1)} from the target cache mount, which is not in the build stage's image")
    hc = re.search(r"^HEALTHCHECK .*?CMD (\[.*?\])", last, re.MULTILINE | re.DOTALL)
    if not hc:
        err(where, "no HEALTHCHECK")
    else:
        argv = yaml.safe_load(hc.group(1))
        sub = argv[1] if len(argv) > 1 else None
        if argv[0] != "/usr/local/bin/lightfold":
            err(where, f"HEALTHCHECK runs {argv[0]}, not the image's binary")
        elif os.access(binary, os.X_OK) and subprocess.run([binary, sub, "--help"], capture_output=True).returncode:
            err(where, f"HEALTHCHECK runs {argv}, which the binary does not have")
    listen = re.search(r"LIGHTFOLD_METRICS_LISTEN=(\S+)", last)
    if not listen or port_of(listen.group(1)) not in re.findall(r"^EXPOSE (.*)$", last, re.MULTILINE)[-1].split():
        err(where, "the metrics port (LIGHTFOLD_METRICS_LISTEN) is not set or not exposed")
    ignore = read(CONTAINERFILE + ".dockerignore").split()
    for path in ("target", ".git", "deploy/compose/token"):
        if path not in ignore:
            err(f"{where}.dockerignore", f"does not keep {path} out of the build context")
    for path in ("Cargo.toml", "Cargo.lock"):
        if path in ignore or not os.path.exists(os.path.join(REPO, path)):
            err(f"{where}.dockerignore", f"the build needs {path} in the context")


SLURM_STUBS = {
    # The allocation's hosts, as `scontrol show hostnames` prints them.
    "scontrol": 'printf "n0\\nn1\\nn2\\n"\n',
    # Each step: its argv, and the token as the daemons would find it.
    "srun": 'echo "srun $*" >> "$LOG"; stat -c "token %a %U" "$LIGHTFOLD_TOKEN_FILE" >> "$LOG"\n',
    "lightfold": 'echo "lightfold $*" >> "$LOG"; stat -c "token %a" "$LIGHTFOLD_TOKEN_FILE" >> "$LOG"\n'
    'stat -c "dir %a" "$(dirname "$LIGHTFOLD_TOKEN_FILE")" >> "$LOG"\n',
}


def run_sbatch(tmp, gpus, token=None):
    """The batch script as its batch step runs, with stand-ins for srun, scontrol and the binary:
    (exit status, stderr, the stand-ins' log lines, files left in the submit directory)."""
    stubs = os.path.join(tmp, "bin")
    os.makedirs(stubs, exist_ok=True)
    submit = tempfile.mkdtemp(dir=tmp, prefix="submit-")
    for name, body in SLURM_STUBS.items():
        write(os.path.join(stubs, name), "#!/bin/sh\n" + body)
        os.chmod(os.path.join(stubs, name), 0o755)
    log = os.path.join(submit, "stubs.log")
    env = {
        "PATH": f"{stubs}:/usr/bin:/bin",
        "HOME": tmp,
        "LOG": log,
        "LIGHTFOLD_BIN": os.path.join(stubs, "lightfold"),
        "SLURM_JOB_ID": "4242",
        "SLURM_JOB_NODELIST": "n[0-2]",
        "SLURM_SUBMIT_DIR": submit,
        "SLURM_GPUS_PER_NODE": gpus,
    }
    if token is not None:
        env["LIGHTFOLD_TOKEN_FILE"] = token
    r = subprocess.run(["bash", SBATCH], env=env, cwd=submit, capture_output=True, text=True)
    lines = read(log).splitlines() if os.path.exists(log) else []
    left = sorted(set(os.listdir(submit)) - {"stubs.log"})
    return r.returncode, r.stderr, lines, left


def lint_slurm():
    where = "slurm/lightfold.sbatch"
    text = read(SBATCH)
    if subprocess.run(["bash", "-n", SBATCH]).returncode != 0:
        err(where, "bash -n fails")
    code = "\n".join(l for l in text.splitlines() if not l.lstrip().startswith("#"))
    fixed = re.findall(r":(7[0-9]{3})\b", code)
    if fixed:
        err(where, f"fixed ports {sorted(set(fixed))}: two jobs on one host collide")
    if "SLURM_JOB_ID" not in code:
        err(where, "ports do not depend on the job")
    if "--gpus-per-task" not in code or "--require-gpu" not in code:
        err(where, "does not give render nodes the allocation's GPUs (--gpus-per-task, --require-gpu)")
    if "--metrics-listen" not in code:
        err(where, "daemons serve no metrics")
    # Arrays that may be empty, expanded bare: "unbound variable" under set -u before bash 4.4.
    for name in re.findall(r"^\s*(\w+)=\(\)", code, re.MULTILINE):
        if re.search(rf'(?<!\+)"\$\{{{name}\[@\]\}}"(?!\}})', code):
            err(where, f'"${{{name}[@]}}" of a possibly empty array: unbound under set -u in bash before 4.4')
    try:
        r = subprocess.run(["shellcheck", SBATCH], capture_output=True, text=True)
        if r.returncode:
            err(where, f"shellcheck: {r.stdout.strip()}")
    except FileNotFoundError:
        print("lint: SKIPPED shellcheck (not installed: Debian's shellcheck package)")
    with tempfile.TemporaryDirectory() as tmp:
        os.chmod(tmp, 0o755)
        for gpus in ("0", "1"):
            rc, stderr, lines, left = run_sbatch(tmp, gpus)
            if rc:
                err(where, f"with SLURM_GPUS_PER_NODE={gpus} and stand-ins it fails ({rc}): {stderr.strip()}")
                continue
            node = next((l for l in lines if l.startswith("srun") and "launch node" in l), "")
            if ("--gpus-per-task=1" in node) != (gpus != "0") or ("--require-gpu" in node) != (gpus != "0"):
                err(where, f"GPUs per node {gpus}: node step {node!r}")
            if "token 600" not in lines or "dir 700" not in lines:
                err(where, f"the token it makes is not 0600 in a 0700 directory: {lines}")
            if any(f.startswith(".lightfold-token") for f in left):
                err(where, f"leaves its token behind: {left}")
        token = os.path.join(tmp, "token")
        write(token, "t\n")
        os.chmod(token, 0o644)
        rc, stderr, lines, _ = run_sbatch(tmp, "0", token)
        if rc == 0 or lines or "chmod 600" not in stderr:
            err(where, f"runs with a token others can read (status {rc}, {stderr.strip()!r})")
        os.chmod(token, 0o600)
        rc, stderr, lines, left = run_sbatch(tmp, "0", token)
        if rc or f"--token-file {token}" not in " ".join(lines) or any(f.startswith(".lightfold") for f in left):
            err(where, f"does not use the given token file (status {rc}, {stderr.strip()!r})")


def lint_prometheus():
    """prometheus.yml passes any promtool, Debian's too (2.42, built without Kubernetes
    discovery); kubernetes-sd.yml passes one that has Kubernetes discovery."""
    doc = yaml.safe_load(read(PROMETHEUS))
    if "kubernetes_sd_configs" in str(doc):
        err("prometheus/prometheus.yml", "kubernetes_sd_configs: Debian's Prometheus rejects the whole file")
    names = {n for j in doc.get("scrape_configs", []) for c in j.get("dns_sd_configs", []) for n in c.get("names", [])}
    for svc in ("render", "comp"):
        if not any(n.split(".")[0] == svc for n in names):
            err("prometheus/prometheus.yml", f"does not discover the {svc} pods (DNS of the headless Service {svc})")
    k8s = yaml.safe_load(read(PROMETHEUS_K8S_SD))
    if not any(
        r.get("regex") == "metrics" and "__meta_kubernetes_pod_container_port_name" in r.get("source_labels", [])
        for j in k8s.get("scrape_configs", [])
        for r in j.get("relabel_configs", [])
    ):
        err("prometheus/kubernetes-sd.yml", "the Kubernetes job does not keep the `metrics` container port")
    for path in (PROMETHEUS, PROMETHEUS_K8S_SD):
        where = f"prometheus/{os.path.basename(path)}"
        try:
            r = subprocess.run(["promtool", "check", "config", path], capture_output=True, text=True)
        except FileNotFoundError:
            print(f"lint: SKIPPED promtool check config {where} (promtool not installed: Debian's prometheus package)")
            return
        out = r.stdout + r.stderr
        if r.returncode and path == PROMETHEUS_K8S_SD and "field kubernetes_sd_configs not found" in out:
            print(f"lint: SKIPPED promtool check config {where}: this promtool has no Kubernetes discovery")
        elif r.returncode:
            err(where, f"promtool check config: {out.strip()}")


def unit_run(path, instance, host, env=None):
    """A template unit's ExecStart for INSTANCE on HOST as systemd (specifiers, $$, line
    continuations) and then its /bin/sh -c script would run it, up to the daemon: (status, the
    daemon's argv or None, stderr). ${CREDENTIALS_DIRECTORY} and ${CACHE_DIRECTORY} stay unexpanded."""
    text = read(path)
    line = re.search(r"^ExecStart=(.*)$", re.sub(r"\\\n", " ", text), re.MULTILINE).group(1)
    line = line.replace("%i", str(instance)).replace("%H", host).replace("%%", "%")
    argv = [w.replace("$$", "$") for w in shlex.split(line)]
    if argv[:2] not in (["/bin/sh", "-c"], ["/usr/bin/sh", "-c"]):
        return 0, argv, ""
    script = argv[2]
    if "exec /usr/local/bin/lightfold " not in script:
        return 1, None, "the script does not exec /usr/local/bin/lightfold"
    script = script.replace("exec /usr/local/bin/lightfold ", "exec printf '%s\\0' /usr/local/bin/lightfold ")
    run_env = {
        "PATH": "/usr/bin:/bin",
        "CREDENTIALS_DIRECTORY": "${CREDENTIALS_DIRECTORY}",
        "CACHE_DIRECTORY": "${CACHE_DIRECTORY}",
        **(env or {}),
    }
    r = subprocess.run(["sh", "-c", script, *argv[3:]], env=run_env, capture_output=True, text=True)
    return r.returncode, r.stdout.split("\0")[:-1] if r.returncode == 0 else None, r.stderr


def unit_exec(path, instance, host):
    """The daemon's argv for INSTANCE on HOST, the unit's credentials and its text."""
    text = read(path)
    rc, argv, stderr = unit_run(path, instance, host)
    if rc:
        raise RuntimeError(f"{os.path.basename(path)} instance {instance}: status {rc}: {stderr.strip()}")
    creds = dict(re.findall(r"^LoadCredential=([^:]+):(.*)$", text, re.MULTILINE))
    return argv, creds, text


# Instances 0-99: ports base+N, metrics on loopback mbase+N; the sink keeps 7400.
UNIT_PORTS = {"lightfold-node@.service": (7300, 9300), "lightfold-compositor@.service": (7500, 9500)}
INSTANCES = range(100)
# The sandbox (docs/deploy.md); the exposure systemd-analyze gave them, not to be exceeded.
HARDENING = {
    "DynamicUser": "yes",
    "UMask": "0077",
    "NoNewPrivileges": "yes",
    "CapabilityBoundingSet": "",
    "ProtectSystem": "strict",
    "ProtectHome": "yes",
    "PrivateTmp": "yes",
    "PrivateMounts": "yes",
    "PrivateIPC": "yes",
    "ProtectHostname": "yes",
    "ProtectClock": "yes",
    "ProtectKernelTunables": "yes",
    "ProtectKernelModules": "yes",
    "ProtectKernelLogs": "yes",
    "ProtectControlGroups": "yes",
    "ProtectProc": "invisible",
    "RestrictAddressFamilies": "AF_INET AF_INET6 AF_UNIX",
    "RestrictNamespaces": "yes",
    "RestrictRealtime": "yes",
    "RestrictSUIDSGID": "yes",
    "LockPersonality": "yes",
    "RemoveIPC": "yes",
    "SystemCallArchitectures": "native",
    "SystemCallErrorNumber": "EPERM",
}
ROLE_HARDENING = {
    # Render nodes open the GPU (and llvmpipe or the driver JIT-compiles shaders).
    "lightfold-node@.service": {"DevicePolicy": "closed", "SupplementaryGroups": "render video"},
    "lightfold-compositor@.service": {
        "PrivateDevices": "yes",
        "PrivateUsers": "yes",
        "MemoryDenyWriteExecute": "yes",
        "ProcSubset": "pid",
    },
}
EXPOSURE = {"lightfold-node@.service": 2.0, "lightfold-compositor@.service": 1.5}


def check_unit_sandbox(where, path, text):
    name = os.path.basename(path)
    settings = {}
    for k, v in re.findall(r"^(\w+)=(.*)$", text, re.MULTILINE):
        settings.setdefault(k, []).append(v)
    for k, want in {**HARDENING, **ROLE_HARDENING[name]}.items():
        if want not in settings.get(k, []):
            err(where, f"no {k}={want}")
    filters = " ".join(settings.get("SystemCallFilter", []))
    wanted = ["@system-service", "~@privileged"] + (["@resources"] if "compositor" in name else [])
    for f in wanted:
        if f not in filters.split():
            err(where, f"SystemCallFilter= lacks {f}")
    if "node" in name:
        allowed = settings.get("DeviceAllow", [])
        for dev in ("char-drm rw", "char-nvidia* rw"):
            if dev not in allowed:
                err(where, f"no DeviceAllow={dev}: a render node cannot open its GPU")
        for k in ("PrivateDevices", "MemoryDenyWriteExecute"):
            if "yes" in settings.get(k, []):
                err(where, f"{k}=yes: a render node cannot use its GPU (devices, shader compilers)")
    with tempfile.TemporaryDirectory() as tmp:
        copy = os.path.join(tmp, name.replace("@", "@0"))
        write(copy, text)
        try:
            r = subprocess.run(
                ["systemd-analyze", "security", "--offline=true", "--no-pager", copy], capture_output=True, text=True
            )
        except FileNotFoundError:
            print(f"lint: SKIPPED systemd-analyze security {where} (systemd-analyze not installed)")
            return
        m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", r.stdout)
        if not m:
            err(where, f"systemd-analyze security: {r.stdout.strip()[-300:]}{r.stderr.strip()[-300:]}")
        elif float(m.group(1)) > EXPOSURE[name]:
            err(where, f"systemd-analyze security exposure {m.group(1)}, above {EXPOSURE[name]}")


def lint_systemd(flags):
    listen_ports, metrics_ports = {}, {}
    for path in UNITS:
        name = os.path.basename(path)
        where = f"systemd/{name}"
        base, mbase = UNIT_PORTS[name]
        argv, creds, text = unit_exec(path, 0, "render1")
        _, opts = parse_cmd(where, argv[1:], flags)
        tf = opts.get("--token-file", "")
        if not tf.startswith("${CREDENTIALS_DIRECTORY}/") or tf.split("/")[-1] not in creds:
            err(where, f"--token-file {tf} is not a LoadCredential= credential")
        if "--cache-dir" in opts and "CacheDirectory=" not in text:
            err(where, "--cache-dir without CacheDirectory= (a DynamicUser= service cannot write elsewhere)")
        check_daemon(where, opts, "render1")
        for key, want in (("Type", "notify"), ("NotifyAccess", "main")):
            if not re.search(rf"^{key}={want}$", text, re.MULTILINE):
                err(where, f"not {key}={want}: systemd does not wait for READY=1")
        if not re.search(r"^WatchdogSec=\d+", text, re.MULTILINE):
            err(where, "no WatchdogSec: a wedged daemon is not restarted")
        if not re.search(r"^EnvironmentFile=-?/etc/lightfold/", text, re.MULTILINE):
            err(where, "no EnvironmentFile under /etc/lightfold")
        ids, wrong = set(), []
        for i in INSTANCES:
            rc, argv, stderr = unit_run(path, i, "render1")
            if rc:
                wrong.append(f"{i} does not start: {stderr.strip()}")
                continue
            _, o = parse_cmd(where, argv[1:], flags)
            env = re.search(r"^Environment=LIGHTFOLD_METRICS_LISTEN=(\S+)$", text, re.MULTILINE)
            metrics = o.get("--metrics-listen") or (env.group(1).replace("%i", str(i)) if env else None)
            port = port_of(o.get("--listen"))
            if port != str(base + i) or metrics != f"127.0.0.1:{mbase + i}":
                wrong.append(f"{i} listens on {port}, metrics {metrics}, not {base + i} and 127.0.0.1:{mbase + i}")
            listen_ports[(name, i)], metrics_ports[(name, i)] = port, port_of(metrics)
            ids.add(o.get("--id"))
        if wrong:
            err(where, f"{len(wrong)} of instances 0-99 wrong, e.g. {wrong[0]}")
        if len(ids) != len(INSTANCES):
            err(where, "instances do not get distinct --id")
        for bad in ("100", "07", "-1", "x", "1e2", "5x", "999999"):
            rc, argv, stderr = unit_run(path, bad, "render1")
            if rc != 64 or "0 to 99" not in stderr:
                listen = argv[argv.index("--listen") + 1] if argv and "--listen" in argv else None
                err(where, f"instance {bad!r} is not refused with status 64 (status {rc}, --listen {listen})")
        if not re.search(r"^RestartPreventExitStatus=64$", text, re.MULTILINE):
            err(where, "an instance refused with 64 is restarted forever (RestartPreventExitStatus=64)")
        rc, argv, _ = unit_run(path, 3, "render1", {"LIGHTFOLD_METRICS_LISTEN": "0.0.0.0:9999"})
        if rc or "--metrics-listen" in argv and argv[argv.index("--metrics-listen") + 1] != "0.0.0.0:9999":
            err(where, "LIGHTFOLD_METRICS_LISTEN from the environment files does not move the metrics listener")
        check_unit_sandbox(where, path, text)
    every = list(listen_ports.values()) + list(metrics_ports.values())
    if len(set(every)) != len(every) or "7400" in every:
        err("systemd", "ports collide with each other or with the sink (7400)")


def lint(args):
    flags = {r: flags_of(args.bin, r) for r in ROLES}
    if not os.access(args.bin, os.X_OK):
        print(f"lint: SKIPPED the flag checks: no binary at {args.bin} (cargo build --release -p lightfold-cli)")
    lint_compose(flags)
    lint_kubernetes(flags)
    lint_systemd(flags)
    lint_gpu_patch(flags)
    lint_container(args.bin)
    lint_slurm()
    lint_prometheus()
    for e in dict.fromkeys(errors):  # a problem of a StatefulSet's template is found once per pod
        print("error:", e)
    print(f"lint: {len(dict.fromkeys(errors))} problems")
    return 1 if errors else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(REPO, "target", "release", "lightfold"))
    return lint(ap.parse_args())


if __name__ == "__main__":
    sys.exit(main())
