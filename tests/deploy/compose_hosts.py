#!/usr/bin/python3
"""Turns one service of `docker-compose config` output into shell variables, so that
netns_cluster_test.sh starts the real binaries exactly as the compose file's containers would:

    compose_hosts.py CONFIG.yml DOCKERFILE SERVICE ROOT      prints (for `eval`):
        SVC_ENV=(K=V ...)       the image's ENV (Dockerfile stage of build.target, with the stages it
                                derives from) overlaid with the service's environment
        SVC_CMD=(...)           entrypoint + command (the service's, else the image's)
        SVC_HEALTH=(...)        the healthcheck command (CMD form), empty if none or disabled
        SVC_SECRETS=(SRC=DST)   secret files to copy into the host's root
        SVC_ADDR=A.B.C.D        the service's fixed address on its network, if it has one
        SVC_ALIASES=(...)       its network aliases (names that compose's DNS answers with it too)
        SVC_SUBNET=A.B.C.D/N    the subnet of that network
    compose_hosts.py CONFIG.yml DOCKERFILE --check-scalable worker

A container's absolute paths (EPR_STATE_DIR=/var/lib/eprfarm, /run/secrets/...) are moved under
ROOT, the host's stand-in for the container's file system. Needs python3-yaml (Debian).
"""
import json
import shlex
import sys

import yaml


def dockerfile_stages(path):
    """{stage: {"from": base, "env": {..}, "entrypoint": [..] | None, "cmd": [..] | None}}"""
    lines, buf = [], ""
    with open(path) as f:
        for raw in f:
            line = raw.rstrip("\n")
            if not buf and line.lstrip().startswith("#"):
                continue
            if line.endswith("\\"):
                buf += line[:-1] + " "
                continue
            lines.append(buf + line)
            buf = ""
    stages, cur = {}, None
    for line in lines:
        words = line.strip().split(None, 1)
        if not words:
            continue
        op, rest = words[0].upper(), (words[1] if len(words) > 1 else "")
        if op == "FROM":
            parts = rest.split()
            name = parts[2] if len(parts) >= 3 and parts[1].upper() == "AS" else f"#{len(stages)}"
            cur = stages[name] = {"from": parts[0], "env": {}, "entrypoint": None, "cmd": None}
        elif cur is None:
            continue
        elif op == "ENV":
            for word in shlex.split(rest):
                key, _, value = word.partition("=")
                cur["env"][key] = value
        elif op in ("ENTRYPOINT", "CMD"):
            cur[op.lower()] = json.loads(rest)
    return stages


def image_config(stages, target):
    """ENV, ENTRYPOINT and CMD of a stage, inherited through FROM <earlier stage>."""
    chain, name = [], target
    while name in stages:
        chain.append(stages[name])
        name = stages[name]["from"]
    env, entrypoint, cmd = {}, None, None
    for st in reversed(chain):
        env.update(st["env"])
        if st["entrypoint"] is not None:
            entrypoint, cmd = st["entrypoint"], None  # a new ENTRYPOINT resets CMD
        if st["cmd"] is not None:
            cmd = st["cmd"]
    return env, entrypoint or [], cmd or []


def as_list(value):
    if value is None:
        return None
    return shlex.split(value) if isinstance(value, str) else [str(v) for v in value]


def reroot(value, root):
    return root.rstrip("/") + value if value.startswith("/") else value


def shell_array(name, items):
    return f"{name}=(" + " ".join(shlex.quote(i) for i in items) + ")"


def main(argv):
    if len(argv) == 4 and argv[2] == "--check-scalable":
        config = yaml.safe_load(open(argv[0]))
        svc = config["services"][argv[3]]
        problems = []
        if "container_name" in svc:
            problems.append("container_name")
        for net in (svc.get("networks") or {}).values():
            if net and net.get("ipv4_address"):
                problems.append("a fixed ipv4_address")
        for port in svc.get("ports") or []:
            if isinstance(port, dict) and port.get("published"):
                problems.append(f"a published host port {port['published']}")
        if problems:
            print(f"service {argv[3]} cannot be scaled: it has " + ", ".join(problems), file=sys.stderr)
            return 1
        return 0
    if len(argv) != 4:
        print(__doc__, file=sys.stderr)
        return 2
    config_path, dockerfile, service, root = argv
    config = yaml.safe_load(open(config_path))
    svc = config["services"][service]
    target = (svc.get("build") or {}).get("target")
    if not target:
        print(f"service {service} has no build.target: cannot tell its image's ENV", file=sys.stderr)
        return 1
    env, entrypoint, cmd = image_config(dockerfile_stages(dockerfile), target)
    environment = svc.get("environment") or {}
    if isinstance(environment, list):
        environment = dict(e.split("=", 1) for e in environment)
    env.update({k: "" if v is None else str(v) for k, v in environment.items()})
    if svc.get("entrypoint") is not None:
        entrypoint, cmd = as_list(svc["entrypoint"]), []
    if svc.get("command") is not None:
        cmd = as_list(svc["command"])

    health = []
    hc = svc.get("healthcheck") or {}
    test = as_list(hc.get("test"))
    if test and not hc.get("disable") and test[0] in ("CMD", "CMD-SHELL"):
        health = test[1:] if test[0] == "CMD" else ["sh", "-c", " ".join(test[1:])]

    secrets = []
    for s in svc.get("secrets") or []:
        source = s if isinstance(s, str) else s["source"]
        target_path = (None if isinstance(s, str) else s.get("target")) or source
        if not target_path.startswith("/"):
            target_path = "/run/secrets/" + target_path
        secrets.append(f"{config['secrets'][source]['file']}={reroot(target_path, root)}")

    addr, subnet, aliases = "", "", []
    networks = svc.get("networks") or {}
    for net_name, net in (networks.items() if isinstance(networks, dict) else [(n, None) for n in networks]):
        ipam = ((config.get("networks") or {}).get(net_name) or {}).get("ipam") or {}
        for c in ipam.get("config") or []:
            subnet = subnet or c.get("subnet", "")
        if net and net.get("ipv4_address"):
            addr = net["ipv4_address"]
        aliases += (net or {}).get("aliases") or []

    print(shell_array("SVC_ENV", [f"{k}={reroot(v, root)}" for k, v in sorted(env.items())]))
    print(shell_array("SVC_CMD", entrypoint + cmd))
    print(shell_array("SVC_HEALTH", health))
    print(shell_array("SVC_SECRETS", secrets))
    print(f"SVC_ADDR={shlex.quote(addr)}")
    print(shell_array("SVC_ALIASES", aliases))
    print(f"SVC_SUBNET={shlex.quote(subnet)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
