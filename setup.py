"""The pip package of the Python binding: python/penumbra with libpenumbra.so inside it.

`pip install --no-build-isolation .` (docs/python.md, "Install with pip") configures the library
with CMake in a temporary folder, builds only the shared library (no CLI, tests or fuzzers) and
copies it into the package as penumbra/libpenumbra.so, the first place python/penumbra/_lib.py
looks. It links the system's libraries (the Debian packages of scripts/install-deps.sh), so the
wheel is for machines with those packages, not for PyPI. The binding is ctypes over a C ABI, not
a CPython extension: one wheel serves every Python 3 and every torch, which comes from the user's
environment and is therefore no requirement pip would download. $CMAKE_ARGS adds CMake options
(e.g. -DPEN_NATIVE=ON); $CMAKE_BUILD_PARALLEL_LEVEL sets the build's jobs (default: every core).

Nothing is written into the checkout: setuptools' build folder and its egg-info go to a temporary
folder as well (build/ is the CMake build's).
"""

import atexit
import os
import re
import shlex
import shutil
import subprocess
import tempfile

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.dist import Distribution

try:  # setuptools >= 70.1 has its own; before, the wheel package's
    from setuptools.command.bdist_wheel import bdist_wheel
except ImportError:
    from wheel.bdist_wheel import bdist_wheel

ROOT = os.path.dirname(os.path.abspath(__file__))
LIB_NAME = "libpenumbra.so"  # beside the package's __init__.py, where _lib.py looks first


def version():
    """PEN_VERSION_STRING of include/penumbra/version.h (CMake checks it against the project's)."""
    with open(os.path.join(ROOT, "include", "penumbra", "version.h")) as f:
        m = re.search(r'^#define PEN_VERSION_STRING "([^"]+)"$', f.read(), re.M)
    if not m:
        raise RuntimeError("include/penumbra/version.h: no PEN_VERSION_STRING")
    return m.group(1)


def cmake_build(build_dir):
    """Configures and builds the shared library alone in build_dir; returns its path."""
    subprocess.check_call(
        ["cmake", "-S", ROOT, "-B", build_dir, "-DCMAKE_BUILD_TYPE=Release", "-DPEN_TESTS=OFF",
         "-DPENUMBRA_MPI=OFF"] + shlex.split(os.environ.get("CMAKE_ARGS", "")))
    jobs = [] if os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL") else ["--parallel",
                                                                      str(os.cpu_count() or 1)]
    subprocess.check_call(["cmake", "--build", build_dir, "--target", "penumbra"] + jobs)
    return os.path.realpath(os.path.join(build_dir, LIB_NAME))  # libpenumbra.so.0.x.y


class BuildPyWithLibrary(build_py):
    """build_py, then libpenumbra.so built and copied into the package."""

    def run(self):
        super().run()
        if self.dry_run:
            return
        with tempfile.TemporaryDirectory(prefix="penumbra-cmake-") as build_dir:
            shutil.copy(cmake_build(build_dir), os.path.join(self.build_lib, "penumbra", LIB_NAME))

    def get_outputs(self, include_bytecode=True):
        return super().get_outputs(include_bytecode) + [
            os.path.join(self.build_lib, "penumbra", LIB_NAME)]


class WithLibrary(Distribution):
    """A distribution with native code: installed into platlib, the wheel for one platform."""

    def has_ext_modules(self):
        return True


class PlatformWheel(bdist_wheel):
    """Tagged py3-none-<platform>: a native library inside, but no CPython ABI."""

    def get_tag(self):
        return "py3", "none", super().get_tag()[2]


SCRATCH = tempfile.mkdtemp(prefix="penumbra-setup-")
atexit.register(shutil.rmtree, SCRATCH, True)

setup(
    name="penumbra",
    version=version(),
    description="Differentiable soft-shadow rendering (SH visibility from sphere proxies) for "
                "PyTorch: the ctypes binding of libpenumbra",
    license="Apache-2.0",
    license_files=["LICENSE"],
    python_requires=">=3.8",
    # torch and numpy are the environment's (Debian's python3-torch and python3-numpy, or the
    # user's own torch): never downloaded by a plain install. `pip install .[torch]` asks for them.
    extras_require={"torch": ["torch", "numpy"]},
    package_dir={"": "python"},
    packages=["penumbra"],
    zip_safe=False,
    distclass=WithLibrary,
    cmdclass={"build_py": BuildPyWithLibrary, "bdist_wheel": PlatformWheel},
    options={"build": {"build_base": os.path.join(SCRATCH, "build")},
             "egg_info": {"egg_base": SCRATCH}},
)
