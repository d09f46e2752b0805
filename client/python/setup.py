"""Builds the eprfarm Python client: the package sources plus the gRPC stubs, which are generated
from the repository's proto/ folder while the package is built (generate_stubs.py: protoc and Debian's
grpc_python_plugin). Install from a clone of the repository with Debian's pip, for example

    /usr/bin/python3 -m pip install --no-build-isolation --break-system-packages ./client/python

or into a venv made with --system-site-packages (see README.md). The runtime dependencies come from
Debian: python3-grpcio, python3-protobuf, and for get(as_arrays=True) python3-numpy and
python3-openimageio.
"""

import atexit
import os
import re
import shutil
import sys
import tempfile

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from generate_stubs import generate  # noqa: E402


def project_version() -> str:
    """The version in the repository's CMakeLists.txt: project(eprfarm VERSION x.y.z)."""
    with open(os.path.join(HERE, "..", "..", "CMakeLists.txt")) as f:
        return re.search(r"project\(\s*eprfarm\s+VERSION\s+([0-9.]+)", f.read()).group(1)


class BuildWithStubs(build_py):
    """build_py, then the stubs into the built package (never into the source tree)."""

    def run(self):
        super().run()
        generate(os.path.join(self.build_lib, "eprfarm", "proto"))


# pip builds in the source folder: the build's intermediate files (build/, eprfarm.egg-info) go to a
# temporary folder instead, removed when the build ends, so that the clone stays as it was.
SCRATCH = tempfile.mkdtemp(prefix="eprfarm-build-")
atexit.register(shutil.rmtree, SCRATCH, True)

setup(
    name="eprfarm",
    version=project_version(),
    description="Python client for the eprfarm render farm (submit, watch, get, cancel, list)",
    packages=["eprfarm"],
    python_requires=">=3.9",
    install_requires=["grpcio", "protobuf"],
    extras_require={"arrays": ["numpy"]},
    cmdclass={"build_py": BuildWithStubs},
    options={"build": {"build_base": os.path.join(SCRATCH, "build")}, "egg_info": {"egg_base": SCRATCH}},
)
