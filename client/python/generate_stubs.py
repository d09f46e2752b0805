#!/usr/bin/python3
"""Generates the Python stubs of proto/epr/v1 for the eprfarm package.

    generate_stubs.py [--proto-dir DIR] [--protoc PROTOC] [--plugin GRPC_PYTHON_PLUGIN] OUT

runs protoc with Debian's gRPC Python plugin (protobuf-compiler, protobuf-compiler-grpc) on the
client-facing protos (job_service, render_settings, scene) and writes them into the package folder
OUT (e.g. build/lib/eprfarm/proto): job_service_pb2.py, job_service_pb2_grpc.py, ... and an
__init__.py. protoc names the imports between them after the proto package (`from epr.v1 import
scene_pb2`); they are rewritten to relative imports, so the stubs live inside eprfarm. Used by
setup.py (pip install) and by CMake (the build tree's copy for the tests).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from typing import List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_PROTO_DIR = os.path.normpath(os.path.join(HERE, "..", "..", "proto"))
PROTOS = ("epr/v1/job_service.proto", "epr/v1/render_settings.proto", "epr/v1/scene.proto")
PLUGIN = "grpc_python_plugin"


def _tool(name: str, given: Optional[str]) -> str:
    path = given or shutil.which(name)
    if not path:
        raise RuntimeError(f"{name} not found: install Debian's protobuf-compiler and protobuf-compiler-grpc")
    return path


def generate(
    out_dir: str, proto_dir: str = DEFAULT_PROTO_DIR, protoc: Optional[str] = None, plugin: Optional[str] = None
) -> List[str]:
    """Writes the stubs into out_dir; returns the paths written. protoc and plugin: the programs
    (default: found on PATH)."""
    for p in PROTOS:
        if not os.path.isfile(os.path.join(proto_dir, p)):
            raise RuntimeError(f"{os.path.join(proto_dir, p)} not found: build the package from the repository")
    os.makedirs(out_dir, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [
                _tool("protoc", protoc),
                f"--proto_path={proto_dir}",
                f"--python_out={tmp}",
                f"--grpc_python_out={tmp}",
                f"--plugin=protoc-gen-grpc_python={_tool(PLUGIN, plugin)}",
                *PROTOS,
            ],
            check=True,
        )
        generated = os.path.join(tmp, "epr", "v1")
        for name in sorted(os.listdir(generated)):
            if not name.endswith(".py"):
                continue
            with open(os.path.join(generated, name)) as f:
                text = f.read()
            text = re.sub(r"^from epr\.v1 import ", "from . import ", text, flags=re.M)
            target = os.path.join(out_dir, name)
            with open(target, "w") as f:
                f.write(text)
            written.append(target)
    init = os.path.join(out_dir, "__init__.py")
    with open(init, "w") as f:
        f.write('"""Stubs generated from proto/epr/v1 by protoc and grpc_python_plugin (generate_stubs.py)."""\n')
    written.append(init)
    return written


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", help="package folder to write, e.g. build/lib/eprfarm/proto")
    parser.add_argument("--proto-dir", default=DEFAULT_PROTO_DIR, help="the repository's proto/ folder")
    parser.add_argument("--protoc", help="the protoc program (default: found on PATH)")
    parser.add_argument("--plugin", help=f"the {PLUGIN} program (default: found on PATH)")
    args = parser.parse_args()
    try:
        generate(args.out, args.proto_dir, args.protoc, args.plugin)
    except (RuntimeError, subprocess.CalledProcessError) as e:
        print(f"generate_stubs.py: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
