#!/bin/sh
# Installs the Debian packages penumbra builds and tests with, only those that are missing.
# Called by `make`; safe to run again. Needs root (or sudo) only when something is missing.
# `install-deps.sh --fuzz` (called by `make fuzz`) adds clang and its libFuzzer runtime.
set -e
PKGS="build-essential cmake pkg-config libembree-dev libcjson-dev libstb-dev libopenexr-dev \
zlib1g-dev libpng-dev libjpeg-dev"
# Open MPI: `penumbra optimize` under mpirun splits a task's views across processes and machines
# (README, "Running on a cluster"); optional to the build (CMake PENUMBRA_MPI), installed so
# that the test suite checks it (tests/mpi_optimize.sh).
PKGS="$PKGS libopenmpi-dev openmpi-bin"
# The Python binding and its tests run on Debian's own Python 3 (/usr/bin/python3).
PKGS="$PKGS python3 python3-numpy python3-torch"
# `pip install .` of the binding with no network (setup.py), and its test (tests/cli_wheel.sh):
# Debian's pip and build backend, and venv to install the wheel into.
PKGS="$PKGS python3-pip python3-setuptools python3-wheel python3-venv"
[ "${1:-}" = "--fuzz" ] && PKGS="$PKGS clang-14 libclang-rt-14-dev"
missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "penumbra: installing Debian packages:$missing"
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends $missing
