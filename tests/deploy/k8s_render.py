#!/usr/bin/python3
"""Renders a kustomization of deploy/k8s into its list of objects, for check_deploy.py:

    render(DIR, components=())   -> [object, ...]   with `kubectl kustomize` when kubectl is installed
    render_plain(DIR, components) -> [object, ...]   always without it

The plain renderer understands what deploy/k8s uses and nothing more: `resources` (files, and folders
holding a kustomization), `namespace` (set on every object but Namespaces), `components` (their
resources, and `$patch: delete` patches that remove an object by kind and name). Anything else in a
kustomization is refused, so that a new feature cannot pass the checks unrendered. Needs python3-yaml.
"""
import os
import shutil
import subprocess
import tempfile

import yaml

KNOWN_KEYS = {"apiVersion", "kind", "namespace", "resources", "components", "patches"}


def kubectl():
    return shutil.which("kubectl")


def _load_kustomization(path):
    with open(os.path.join(path, "kustomization.yaml")) as f:
        k = yaml.safe_load(f)
    unknown = set(k) - KNOWN_KEYS
    if unknown:
        raise ValueError(f"{path}/kustomization.yaml: {sorted(unknown)} is beyond the plain renderer")
    return k


def _load_resource(base, entry):
    path = os.path.normpath(os.path.join(base, entry))
    if os.path.isdir(path):
        return render_plain(path)
    with open(path) as f:
        return [d for d in yaml.safe_load_all(f) if d is not None]


def _delete_patches(k, where):
    deleted = []
    for p in k.get("patches") or []:
        doc = yaml.safe_load(p["patch"]) if "patch" in p else None
        if not doc or doc.get("$patch") != "delete":
            raise ValueError(f"{where}: only inline `$patch: delete` patches are understood")
        deleted.append((doc["kind"], doc["metadata"]["name"]))
    return deleted


def render_plain(path, components=()):
    k = _load_kustomization(path)
    if k.get("kind") not in (None, "Kustomization"):
        raise ValueError(f"{path}: a {k.get('kind')} is not a kustomization")
    objects = []
    for entry in k.get("resources") or []:
        objects.extend(_load_resource(path, entry))
    deleted = _delete_patches(k, path)
    for c in list(k.get("components") or []) + [os.path.relpath(c, path) for c in components]:
        cpath = os.path.normpath(os.path.join(path, c))
        ck = _load_kustomization(cpath)
        if ck.get("kind") != "Component":
            raise ValueError(f"{cpath}: not a kustomize Component")
        for entry in ck.get("resources") or []:
            objects.extend(_load_resource(cpath, entry))
        deleted.extend(_delete_patches(ck, cpath))
    for kind, name in deleted:
        found = [o for o in objects if o.get("kind") == kind and o.get("metadata", {}).get("name") == name]
        if not found:
            raise ValueError(f"{path}: a patch deletes {kind}/{name}, which is not there")
        objects = [o for o in objects if o not in found]
    if k.get("namespace"):
        for o in objects:
            if o.get("kind") != "Namespace":
                o.setdefault("metadata", {})["namespace"] = k["namespace"]
    return objects


def render_kubectl(path, components=()):
    """`kubectl kustomize` of PATH; with components, of an overlay made for them in a temp folder."""
    target = path
    with tempfile.TemporaryDirectory() as tmp:
        if components:
            # kustomize wants relative paths, and no overlay inside the folder it renders.
            overlay = {
                "apiVersion": "kustomize.config.k8s.io/v1beta1",
                "kind": "Kustomization",
                "resources": [os.path.relpath(path, tmp)],
                "components": [os.path.relpath(c, tmp) for c in components],
            }
            with open(os.path.join(tmp, "kustomization.yaml"), "w") as f:
                yaml.safe_dump(overlay, f)
            target = tmp
        r = subprocess.run([kubectl(), "kustomize", target], capture_output=True, text=True)
    if r.returncode != 0:
        raise AssertionError(f"kubectl kustomize {path} {list(components)} failed:\n{r.stderr}")
    return [d for d in yaml.safe_load_all(r.stdout) if d is not None]


def render(path, components=()):
    return render_kubectl(path, components) if kubectl() else render_plain(path, components)
