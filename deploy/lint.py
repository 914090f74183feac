#!/usr/bin/env python3
"""Checks the deployment files against the lightfold binary's real flags, without any engine.

  deploy/lint.py [--bin target/release/lightfold]

Every command line in compose, Kubernetes and the systemd units uses flags the subcommand has;
listen and advertised ports agree, each daemon advertises the name the others resolve, the
cluster files list exactly the advertised daemons (and ids) with a reachable sink, tokens come from
mounted secrets or credentials, and the coordinator's images (also its default out.png/out.exr,
relative to the image's WORKDIR) land on a writable volume. Needs Python 3.11 with PyYAML.
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
            for pod in pods:
                env = {"POD_NAME": pod} if pod and "POD_NAME" in env_names else {}
                argv = [expand(a, env) for a in c.get("args", [])]
                role, opts = parse_cmd(where, argv, flags)
                check_files(where, opts, mounts, "LIGHTFOLD_TOKEN" in env_names, role)
                if role in ("node", "compositor"):
                    svc = d["spec"]["serviceName"]
                    if ("Service", svc) not in kinds or kinds[("Service", svc)]["spec"].get("clusterIP") != "None":
                        err(where, f"serviceName {svc} is not a headless Service")
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
    a, b = (unit_port(p, 0) for p in UNITS)
    if a == b or "7400" in (a, b):
        err("systemd", f"instance 0 ports {a} and {b} collide with each other or with the sink (7400)")


def lint(args):
    flags = {r: flags_of(args.bin, r) for r in ROLES}
    lint_compose(flags)
    lint_kubernetes(flags)
    lint_systemd(flags)
    for e in errors:
        print("error:", e)
    print(f"lint: {len(errors)} problems")
    return 1 if errors else 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(REPO, "target", "release", "lightfold"))
    return lint(ap.parse_args())


if __name__ == "__main__":
    sys.exit(main())
