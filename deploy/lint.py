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
(the coordinator makes them ready), the GPU patch asks for a GPU and refuses a CPU rasteriser;
systemd units are Type=notify with a watchdog, an EnvironmentFile and distinct metrics ports; the
image asks NVIDIA's toolkit for `graphics` and has a HEALTHCHECK the binary answers; the Slurm
script has no fixed ports and asks for GPUs when allocated; the Prometheus example passes
`promtool check config` (where promtool is installed). Needs Python 3.11 with PyYAML.
deploy/emulate.py runs the same files.
"""

import argparse
import os
import pathlib
import re
import shlex
import subprocess
import sys
import tomllib

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
COMPOSE = os.path.join(HERE, "compose", "compose.yaml")
KUBE = os.path.join(HERE, "kubernetes", "lightfold.yaml")
UNITS = [os.path.join(HERE, "systemd", f) for f in ("lightfold-node@.service", "lightfold-compositor@.service")]
CONTAINERFILE = os.path.join(HERE, "container", "Containerfile")
GPU_PATCH = os.path.join(HERE, "kubernetes", "render-gpu.patch.yaml")
SBATCH = os.path.join(HERE, "slurm", "lightfold.sbatch")
PROMETHEUS = os.path.join(HERE, "prometheus", "prometheus.yml")
ROLES = ("node", "compositor", "coordinator")
errors = []


def read(path):
    return pathlib.Path(path).read_text()


def write(path, text):
    pathlib.Path(path).write_text(text)


def err(where, msg):
    errors.append(f"{where}: {msg}")


def flags_of(binary, sub):
    """{'--flag': takes_value} from `lightfold SUB --help`."""
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
        if flags[role][a]:
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


def lint_kubernetes(flags):
    docs = [d for d in yaml.safe_load_all(read(KUBE)) if d]
    kinds = {(d["kind"], d["metadata"]["name"]): d for d in docs}
    advertised, ids, cluster_text, sink_name = {"node": set(), "compositor": set()}, {}, None, None
    for d in docs:
        if d["kind"] not in ("StatefulSet", "Job"):
            continue
        spec = d["spec"]["template"]["spec"]
        where = f"kubernetes/{d['kind']}/{d['metadata']['name']}"
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
        err("kubernetes", "no cluster.toml ConfigMap mounted by the coordinator")
    else:
        check_cluster("kubernetes/ConfigMap", cluster_text, advertised, sink_name, ids)


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


def lint_gpu_patch(flags):
    """The GPU patch, merged over the render StatefulSet the way `kubectl patch` merges it."""
    where = "kubernetes/render-gpu.patch.yaml"
    patch = yaml.safe_load(read(GPU_PATCH))
    docs = [d for d in yaml.safe_load_all(read(KUBE)) if d]
    base = next((d for d in docs if d["kind"] == "StatefulSet" and d["metadata"]["name"] == "render"), None)
    if base is None:
        err(where, "no render StatefulSet to patch")
        return
    spec = base["spec"]["template"]["spec"]
    for pc in patch["spec"]["template"]["spec"]["containers"]:
        c = next((x for x in spec["containers"] if x["name"] == pc["name"]), None)
        if c is None:
            err(where, f"patches container {pc['name']}, which the StatefulSet does not have")
            continue
        merged = dict(c)
        merged.update({k: v for k, v in pc.items() if k != "name"})
        role, opts = parse_cmd(where, merged.get("args", []), flags)
        if role != "node" or "--require-gpu" not in opts:
            err(where, "a GPU node without --require-gpu renders on the CPU when its GPU is missing")
        if opts.get("--metrics-listen") != "0.0.0.0:9300":
            err(where, "the patch changes the metrics port the probes ask")
        for k in ("requests", "limits"):
            if "nvidia.com/gpu" not in merged.get("resources", {}).get(k, {}):
                err(where, f"no nvidia.com/gpu in resources.{k}")
        env = {e["name"]: e.get("value") for e in merged.get("env", [])}
        if "graphics" not in (env.get("NVIDIA_DRIVER_CAPABILITIES") or ""):
            err(where, "NVIDIA_DRIVER_CAPABILITIES lacks graphics: no Vulkan driver in the container")
        if "POD_NAME" not in env:
            err(where, "the patch's env (a list, replaced whole) drops POD_NAME")


def lint_container(binary):
    where = "container/Containerfile"
    text = read(CONTAINERFILE)
    last = re.split(r"^FROM .*$", text, flags=re.MULTILINE)[-1]
    caps = re.search(r"NVIDIA_DRIVER_CAPABILITIES=(\S+)", last)
    if not caps or "graphics" not in caps.group(1).split(","):
        err(where, "NVIDIA_DRIVER_CAPABILITIES does not include graphics (the Vulkan driver)")
    hc = re.search(r"^HEALTHCHECK .*?CMD (\[.*?\])", last, re.MULTILINE | re.DOTALL)
    if not hc:
        err(where, "no HEALTHCHECK")
    else:
        argv = yaml.safe_load(hc.group(1))
        sub = argv[1] if len(argv) > 1 else None
        if argv[0] != "/usr/local/bin/lightfold" or subprocess.run(
            [binary, sub, "--help"], capture_output=True
        ).returncode != 0:
            err(where, f"HEALTHCHECK runs {argv}, which the binary does not have")
    listen = re.search(r"LIGHTFOLD_METRICS_LISTEN=(\S+)", last)
    if not listen or port_of(listen.group(1)) not in re.findall(r"^EXPOSE (.*)$", last, re.MULTILINE)[-1].split():
        err(where, "the metrics port (LIGHTFOLD_METRICS_LISTEN) is not set or not exposed")


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


def lint_prometheus():
    where = "prometheus/prometheus.yml"
    doc = yaml.safe_load(read(PROMETHEUS))
    if not any(
        r.get("regex") == "metrics" and "__meta_kubernetes_pod_container_port_name" in r.get("source_labels", [])
        for j in doc.get("scrape_configs", [])
        for r in j.get("relabel_configs", [])
    ):
        err(where, "the Kubernetes job does not keep the `metrics` container port")
    try:
        r = subprocess.run(["promtool", "check", "config", PROMETHEUS], capture_output=True, text=True)
    except FileNotFoundError:
        print("lint: SKIPPED promtool check config (promtool not installed: Debian's prometheus package)")
        return
    if r.returncode != 0 and "field kubernetes_sd_configs not found" in r.stdout + r.stderr:
        # Debian's prometheus is built without Kubernetes discovery: check the rest, say so.
        print("lint: this promtool has no kubernetes_sd_configs (Debian's build); checking the other jobs")
        doc["scrape_configs"] = [j for j in doc["scrape_configs"] if "kubernetes_sd_configs" not in j]
        rest = os.path.join(HERE, "prometheus", ".without-kubernetes.yml")
        write(rest, yaml.safe_dump(doc))
        try:
            r = subprocess.run(["promtool", "check", "config", rest], capture_output=True, text=True)
        finally:
            os.remove(rest)
    if r.returncode != 0:
        err(where, f"promtool check config: {r.stdout}{r.stderr}")


def unit_exec(path, instance, host):
    """ExecStart of a template unit with %i/%H and the credential and cache variables expanded."""
    text = read(path)
    line = re.search(r"^ExecStart=(.*)$", text, re.MULTILINE).group(1)
    creds = dict(re.findall(r"^LoadCredential=([^:]+):(.*)$", text, re.MULTILINE))
    argv = shlex.split(line.replace("%i", str(instance)).replace("%H", host))
    return argv, creds, text


def unit_port(path, instance):
    argv = unit_exec(path, instance, "h")[0]
    return port_of(argv[argv.index("--listen") + 1])


def lint_systemd(flags):
    all_metrics = set()
    for path in UNITS:
        where = f"systemd/{os.path.basename(path)}"
        argv, creds, text = unit_exec(path, 0, "render1")
        _, opts = parse_cmd(where, argv[1:], flags)
        tf = opts.get("--token-file", "")
        if not tf.startswith("${CREDENTIALS_DIRECTORY}/") or tf.split("/")[-1] not in creds:
            err(where, f"--token-file {tf} is not a LoadCredential= credential")
        if "--cache-dir" in opts and "CacheDirectory=" not in text:
            err(where, "--cache-dir without CacheDirectory= (a DynamicUser= service cannot write elsewhere)")
        check_daemon(where, opts, "render1")
        ports = {unit_port(path, i) for i in range(10)}
        if len(ports) != 10:
            err(where, "instances 0-9 do not get distinct ports")
        for key, want in (("Type", "notify"), ("NotifyAccess", "main")):
            if not re.search(rf"^{key}={want}$", text, re.MULTILINE):
                err(where, f"not {key}={want}: systemd does not wait for READY=1")
        if not re.search(r"^WatchdogSec=\d+", text, re.MULTILINE):
            err(where, "no WatchdogSec: a wedged daemon is not restarted")
        if not re.search(r"^EnvironmentFile=-?/etc/lightfold/", text, re.MULTILINE):
            err(where, "no EnvironmentFile under /etc/lightfold")
        metrics = {
            port_of(re.search(r"^Environment=LIGHTFOLD_METRICS_LISTEN=(\S+)$", unit_exec(path, i, "h")[2].replace("%i", str(i)), re.MULTILINE).group(1))
            for i in range(10)
        } if "LIGHTFOLD_METRICS_LISTEN=" in text else set()
        if len(metrics) != 10:
            err(where, "instances 0-9 do not get distinct metrics ports (LIGHTFOLD_METRICS_LISTEN)")
        all_metrics.update(metrics)
    if all_metrics & {unit_port(p, i) for p in UNITS for i in range(10)} or len(all_metrics) != 20:
        err("systemd", "metrics ports collide with each other or with daemon ports")
    a, b = (unit_port(p, 0) for p in UNITS)
    if a == b or "7400" in (a, b):
        err("systemd", f"instance 0 ports {a} and {b} collide with each other or with the sink (7400)")


def lint(args):
    flags = {r: flags_of(args.bin, r) for r in ROLES}
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
