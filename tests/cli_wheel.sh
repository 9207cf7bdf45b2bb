#!/bin/sh
# `pip install` of the Python binding (setup.py; docs/python.md, "Install with pip"), as a user
# does it on Debian 12 with no network:
#  - the source tree (the working tree's tracked files and untracked, unignored ones, so that
#    uncommitted work is what is checked; the whole folder when it is no git checkout) is copied
#    to a temporary folder and a wheel is built there with Debian's pip, setuptools and wheel
#    (pip wheel --no-build-isolation --no-deps, no index), CMake building the library;
#  - the build leaves that tree as it found it;
#  - the wheel: tagged py3-none-<platform>, the package with libpenumbra.so inside (SONAME
#    libpenumbra.so.0, every library it needs found), the version of include/penumbra/version.h,
#    licence Apache-2.0 and the LICENSE file, and no hard dependency (torch is the user's);
#  - installed in a fresh venv that sees Debian's torch (--system-site-packages) and run from a
#    folder outside the tree with no PENUMBRA_* variable: the package and the one libpenumbra
#    mapped into the process are the venv's, and the bundled Spot scene (64x64, its 32 spheres
#    fitted afresh: a few seconds) renders with a finite, non-zero gradient of its SH lighting.
# One to two minutes on 2 cores, most of it the library's build.
# Exit 77 (ctest: skipped) when a Debian package it needs is missing, named in one line; and in a
# sanitizer build (make test-asan): the wheel builds its own uninstrumented library, so that pass
# would only repeat `make test`'s run of this test.
# Usage: sh cli_wheel.sh PENUMBRA_BIN SRC_DIR   (PENUMBRA_BIN only tells a sanitizer build)
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
PY=/usr/bin/python3

skip() { echo "skipped: $*"; exit 77; }
if [ ! -x "$PY" ] || ! "$PY" -c "import torch, numpy" >/dev/null 2>&1; then
    skip "python3-torch or python3-numpy not installed (/usr/bin/python3 cannot import them)"
fi
"$PY" -m pip --version >/dev/null 2>&1 || skip "python3-pip not installed"
"$PY" -c "import setuptools" >/dev/null 2>&1 || skip "python3-setuptools not installed"
"$PY" -c "import wheel" >/dev/null 2>&1 || skip "python3-wheel not installed"
"$PY" -c "import ensurepip" >/dev/null 2>&1 || skip "python3-venv not installed"
if ldd "$BIN" 2>/dev/null | grep -q 'libasan[.]so'; then
    skip "sanitizer build: the wheel builds its own uninstrumented library (make test runs this)"
fi

T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
VERSION=$(sed -n 's/^#define PEN_VERSION_STRING "\(.*\)"$/\1/p' "$SRC/include/penumbra/version.h")

# ---- The tree, copied; the wheel built from it --------------------------------------------------
mkdir "$T/src" "$T/dist" "$T/elsewhere"
if git -C "$SRC" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    # (--ignore-failed-read: a tracked file deleted in the working tree is left out.)
    git -C "$SRC" ls-files -z --cached --others --exclude-standard |
        tar -C "$SRC" --null -T - --ignore-failed-read -cf - 2>"$T/tar.log" |
        tar -C "$T/src" -xf - || { cat "$T/tar.log"; echo "FAIL: copying $SRC"; exit 1; }
else
    tar -C "$SRC" --exclude='./build*' --exclude=./.git -cf - . | tar -C "$T/src" -xf - ||
        { echo "FAIL: copying $SRC"; exit 1; }
fi
(cd "$T/src" && find . | sort) >"$T/tree.before"
if ! (cd "$T" && env HOME="$T" PIP_NO_INDEX=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    CMAKE_BUILD_PARALLEL_LEVEL="${CMAKE_BUILD_PARALLEL_LEVEL:-2}" \
    "$PY" -m pip wheel --no-build-isolation --no-deps -w "$T/dist" "$T/src") >"$T/wheel.log" 2>&1
then
    tail -40 "$T/wheel.log"
    echo "FAIL: pip wheel"
    exit 1
fi
(cd "$T/src" && find . | sort) >"$T/tree.after"
diff "$T/tree.before" "$T/tree.after" >"$T/tree.diff" ||
    fail "building the wheel changed the source tree: $(grep '^[<>]' "$T/tree.diff" | head -5)"

set -- "$T"/dist/*.whl
if [ $# -ne 1 ] || [ ! -f "$1" ]; then
    echo "FAIL: not one wheel: $*"
    exit 1
fi
WHL=$1
"$PY" - "$WHL" "$VERSION" "$T/src/python/penumbra" <<'EOF' || fail "the wheel's contents"
import os, sys, zipfile
whl, version, package = sys.argv[1:]
z = zipfile.ZipFile(whl)
names = set(z.namelist())
info = "penumbra-%s.dist-info/" % version
meta = z.read(info + "METADATA").decode().splitlines()
tags = z.read(info + "WHEEL").decode().splitlines()
bad = []
if not os.path.basename(whl).startswith("penumbra-%s-py3-none-linux_" % version):
    bad.append("file name %s" % os.path.basename(whl))
if "Root-Is-Purelib: false" not in tags or not any(t.startswith("Tag: py3-none-linux_")
                                                   for t in tags):
    bad.append("tags %s" % tags)
want = {"penumbra/" + f for f in os.listdir(package) if f.endswith(".py")}
want |= {"penumbra/libpenumbra.so", info + "LICENSE"}
if want - names:
    bad.append("missing %s" % sorted(want - names))
stray = [n for n in names if not n.startswith(("penumbra/", info))]
if stray:
    bad.append("files outside the package: %s" % sorted(stray))
for line in ("Version: " + version, "License: Apache-2.0"):
    if line not in meta:
        bad.append("METADATA has no '%s'" % line)
hard = [m for m in meta if m.startswith("Requires-Dist:") and "extra ==" not in m]
if hard:
    bad.append("hard dependencies %s" % hard)
for b in bad:
    print("wheel:", b)
sys.exit(1 if bad else 0)
EOF

# ---- Installed in a venv that sees Debian's torch -----------------------------------------------
V=$T/venv
if ! "$PY" -m venv --system-site-packages "$V" >"$T/venv.log" 2>&1 ||
    ! env HOME="$T" PIP_NO_INDEX=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
        "$V/bin/python" -m pip install --no-deps "$WHL" >>"$T/venv.log" 2>&1; then
    cat "$T/venv.log"
    echo "FAIL: installing the wheel into a venv"
    exit 1
fi
LIB=$(find "$V" -path '*/penumbra/libpenumbra.so')
[ -n "$LIB" ] || { echo "FAIL: no penumbra/libpenumbra.so in the venv"; exit 1; }
objdump -p "$LIB" | grep -q 'SONAME *libpenumbra.so.0$' || fail "the bundled library's SONAME"
missing=$(ldd "$LIB" | grep 'not found')
[ -z "$missing" ] || fail "the bundled library needs: $missing"

cat >"$T/use.py" <<EOF
import dataclasses, os, sys
import torch
import penumbra

venv = os.path.realpath(sys.prefix) + os.sep
here = os.path.realpath(penumbra.__file__)
assert here.startswith(venv), "penumbra imported from %s, not the venv %s" % (here, venv)
assert penumbra.version() == "$VERSION", penumbra.version()
# Every mapping of a libpenumbra in this process is the venv's copy.
with open("/proc/self/maps") as f:
    mapped = {os.path.realpath(line.split(None, 5)[5].strip()) for line in f
              if len(line.split(None, 5)) == 6 and "libpenumbra" in line}
bundled = os.path.join(os.path.dirname(here), "libpenumbra.so")
assert mapped == {bundled}, "libpenumbra loaded from %s, not %s" % (sorted(mapped), bundled)

scene = penumbra.load_scene("$SRC/examples/scenes/spot_city.json")   # fits its 32 spheres
scene.camera = dataclasses.replace(scene.camera, width=64, height=64)
scene.sh.requires_grad_()
image = penumbra.render_scene(scene)
assert image.shape == (64, 64, 3) and torch.isfinite(image).all() and image.max() > 0
image.mean().backward()
g = scene.sh.grad
assert g is not None and torch.isfinite(g).all() and g.abs().sum() > 0, g
print("wheel: penumbra %s from %s, library %s, |d mean / d sh| = %.4g"
      % (penumbra.version(), here, bundled, g.abs().sum().item()))
EOF
# No PENUMBRA_* variable, PYTHONPATH or LD_LIBRARY_PATH; the sphere fit's cache is private.
if ! (cd "$T/elsewhere" && env -i PATH=/usr/bin:/bin HOME="$T" XDG_CACHE_HOME="$T/cache" \
    "$V/bin/python" "$T/use.py"); then
    fail "the installed wheel"
fi

if [ "$fails" -ne 0 ]; then
    echo "cli_wheel: $fails failure(s)"
    exit 1
fi
echo "cli_wheel: ok ($(basename "$WHL"))"
