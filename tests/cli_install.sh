#!/bin/sh
# The library as others get it: `cmake --install` of this build into an empty prefix, then
#  - only the public API in libpenumbra.so (no pen__ symbol; every PEN_API function present, and
#    every public declaration marked PEN_API: scripts/pen_api.sh --check),
#  - the C examples (examples/c: render.c renders a scene; fit_lighting.c recovers its lighting
#    through the loss and the backward pass) built with `pkg-config --cflags --libs penumbra`
#    alone and run on the installed bundled scene, made small; fit_lighting.c also with the rpath
#    of docs/library.md, linked statically from libpenumbra.a with `pkg-config --static`, and
#    both through find_package(penumbra) (examples/c/CMakeLists.txt),
#  - the installed CLI finding its bundled data under share/penumbra, with no source path in it,
#  - the installed Python package (Debian's /usr/bin/python3) importing and rendering with no
#    environment variable. Exit 77 (ctest: skipped) when only this last part cannot run because
#    torch does not import; everything before it has passed by then.
# Usage: sh cli_install.sh PENUMBRA_BIN SRC_DIR   (PENUMBRA_BIN in the build folder to install)
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
BUILD=$(dirname "$BIN")
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
P=$T/prefix
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }
CC=${CC:-cc}

if ! cmake --install "$BUILD" --prefix "$P" >"$T/install.log" 2>&1; then
    cat "$T/install.log"
    echo "FAIL: cmake --install"
    exit 1
fi
export PKG_CONFIG_PATH="$P/lib/pkgconfig:$P/lib/$(gcc -print-multiarch 2>/dev/null)/pkgconfig"
LIBDIR=$(pkg-config --variable=libdir penumbra) || { echo "FAIL: no penumbra.pc"; exit 1; }
for f in "$LIBDIR/libpenumbra.so.0" "$LIBDIR/libpenumbra.a" "$P/include/penumbra/penumbra.h" \
    "$P/include/penumbra/version.h" "$P/bin/penumbra" \
    "$LIBDIR/cmake/penumbra/penumbraConfig.cmake" "$LIBDIR/pkgconfig/penumbra.pc" \
    "$P/share/penumbra/examples/scenes/spot_city.json" "$P/share/penumbra/data/envmaps/city.hdr"; do
    [ -e "$f" ] || fail "not installed: ${f#"$P"/}"
done
[ "$(readlink "$LIBDIR/libpenumbra.so")" = libpenumbra.so.0 ] || fail "libpenumbra.so -> .so.0"
objdump -p "$LIBDIR/libpenumbra.so.0" | grep -q 'SONAME *libpenumbra.so.0$' || fail "SONAME"

# A sanitizer build (make test-asan) installs an instrumented library: programs using it are
# compiled with the same sanitizers, and Python, which is not, preloads their runtimes (ASan
# first), as tests/cli_python.sh does.
san_lib() { ldd "$LIBDIR/libpenumbra.so.0" 2>/dev/null | awk -v n="$1" '$1 ~ n {print $3}'; }
SAN= PRELOAD=
if [ -n "$(san_lib '^libasan[.]so')" ]; then
    SAN="-fsanitize=address,undefined"
    PRELOAD=$(echo $(san_lib '^libasan[.]so') $(san_lib '^libubsan[.]so'))
fi

# ---- Exported symbols: the public API and nothing else --------------------------------------
nm -D --defined-only "$LIBDIR/libpenumbra.so.0" | awk '{print $3}' | sort >"$T/exported"
if grep -q '^pen__' "$T/exported"; then
    fail "internal symbols exported: $(grep '^pen__' "$T/exported" | head -5 | tr '\n' ' ')..."
fi
sed -n 's/^PEN_API [^(]*[ *]\(pen_[a-z0-9_]*\)(.*/\1/p' "$P"/include/penumbra/*.h | sort -u \
    >"$T/declared"
[ -s "$T/declared" ] || fail "no PEN_API declaration in the installed headers"
missing=$(comm -23 "$T/declared" "$T/exported")
[ -z "$missing" ] || fail "declared PEN_API but not exported: $(echo $missing)"
# Every exported name of the library's own is a PEN_API declaration. (Weak C++ template instances
# of OpenEXR's headers, which src/io/exr.cpp instantiates, can appear in unoptimised builds; they
# are not ours to name.)
extra=$(grep '^_*pen' "$T/exported" | comm -13 "$T/declared" -)
[ -z "$extra" ] || fail "exported but not declared PEN_API in a public header: $(echo $extra)"
sh "$SRC/scripts/pen_api.sh" --check "$SRC/include/penumbra" || fail "pen_api.sh --check"
# The Python binding calls only exported functions (the names its ctypes declarations use).
# Quoted struct names (the layout table's keys) are types, not symbols: left out.
grep -ho 'typedef struct pen_[a-z0-9_]*' "$P"/include/penumbra/*.h | awk '{print $3}' | sort -u \
    >"$T/types"
grep -ho '"pen_[a-z0-9_]*"' "$SRC"/python/penumbra/*.py | tr -d '"' | sort -u |
    comm -23 - "$T/types" >"$T/python_uses"
missing=$(comm -23 "$T/python_uses" "$T/exported")
[ -z "$missing" ] || fail "python/penumbra uses symbols not exported: $(echo $missing)"

# ---- The C examples: pkg-config alone (shared), with an rpath, --static, find_package ---------
# The installed bundled scene at 48x48 with 8 fitted spheres (seconds, not minutes), its paths
# into the installed data.
SCENE=$P/share/penumbra/examples/scenes/spot_city.json
sed -e 's/"width": [0-9]*/"width": 48/' -e 's/"height": [0-9]*/"height": 48/' \
    -e 's/"fit": [0-9]*/"fit": 8/' -e "s#\"\.\./\.\./data/#\"$P/share/penumbra/data/#g" \
    "$SCENE" >"$T/small.json"
EX=$SRC/examples/c
FIT=$EX/fit_lighting.c
# fit_lighting exits 1 unless its loss fell; 30 Adam steps take it down by orders of magnitude.
fit() { # program image [env ...]
    _prog=$1 _img=$2
    shift 2
    env "$@" "$_prog" "$T/small.json" "$_img" 30 >"$T/fit.out" 2>&1 && [ -s "$_img" ] &&
        grep -q "^fit_lighting: penumbra .*, 48x48, 30 steps, loss" "$T/fit.out" ||
        { cat "$T/fit.out"; return 1; }
}
# shellcheck disable=SC2046
if $CC $SAN -o "$T/render" "$EX/render.c" $(pkg-config --cflags --libs penumbra); then
    LD_LIBRARY_PATH=$LIBDIR "$T/render" "$T/small.json" "$T/render.png" ||
        fail "render (shared) ran"
    [ -s "$T/render.png" ] || fail "render (shared) wrote no image"
    # It runs against the installed library, not the build's.
    LD_LIBRARY_PATH=$LIBDIR ldd "$T/render" | grep -q "$LIBDIR/libpenumbra.so.0" ||
        fail "render not linked to the installed libpenumbra.so.0"
else
    fail "render.c does not build with pkg-config --cflags --libs penumbra"
fi
# shellcheck disable=SC2046
if $CC $SAN -o "$T/fit" "$FIT" $(pkg-config --cflags --libs penumbra) -lm; then
    fit "$T/fit" "$T/fit.png" LD_LIBRARY_PATH="$LIBDIR" || fail "fit_lighting (shared) ran"
else
    fail "fit_lighting.c does not build with pkg-config --cflags --libs penumbra"
fi
# As docs/library.md builds it for a prefix of one's own: the rpath from pkg-config's libdir, so
# that it runs with no LD_LIBRARY_PATH.
# shellcheck disable=SC2046
if $CC $SAN -o "$T/fit_rpath" "$FIT" $(pkg-config --cflags --libs penumbra) -lm \
    -Wl,-rpath,"$(pkg-config --variable=libdir penumbra)"; then
    fit "$T/fit_rpath" "$T/fit_rpath.png" -u LD_LIBRARY_PATH ||
        fail "fit_lighting (rpath, no LD_LIBRARY_PATH) ran"
else
    fail "fit_lighting.c does not build with the rpath of docs/library.md"
fi
STATIC_LIBS=$(pkg-config --static --libs penumbra | sed 's/\(^\| \)-lpenumbra\( \|$\)/ /')
# shellcheck disable=SC2046,SC2086
if $CC $SAN -o "$T/fit_static" "$FIT" $(pkg-config --cflags penumbra) "$LIBDIR/libpenumbra.a" \
    $STATIC_LIBS -lm; then
    fit "$T/fit_static" "$T/fit_static.png" || fail "fit_lighting (static) ran"
else
    fail "fit_lighting.c does not link libpenumbra.a with pkg-config --static --libs penumbra"
fi
if cmake -S "$EX" -B "$T/fp" -DCMAKE_PREFIX_PATH="$P" -DCMAKE_BUILD_TYPE=Release \
    -DCMAKE_C_FLAGS="$SAN" -DCMAKE_EXE_LINKER_FLAGS="$SAN" >"$T/fp.log" 2>&1 &&
    cmake --build "$T/fp" >>"$T/fp.log" 2>&1; then
    # The imported target carries no rpath into the prefix: the loader is told where.
    LD_LIBRARY_PATH=$LIBDIR "$T/fp/render" "$T/small.json" "$T/fp.png" ||
        fail "render (find_package)"
    fit "$T/fp/fit_lighting" "$T/fp_fit.png" LD_LIBRARY_PATH="$LIBDIR" ||
        fail "fit_lighting (find_package)"
else
    cat "$T/fp.log"
    fail "examples/c does not build with find_package(penumbra)"
fi

# ---- The installed CLI: bundled data found beside it, no source path compiled in -------------
if ! "$P/bin/penumbra" --version >/dev/null; then fail "installed penumbra --version"; fi
# (Not in a sanitizer build: the sanitizers record source locations for their reports.)
if [ -z "$SAN" ] && objcopy -O binary --only-section=.rodata "$P/bin/penumbra" "$T/rodata" &&
    grep -q "$SRC/" "$T/rodata"; then
    fail "the CLI has the source path $SRC compiled in"
fi
mv "$P/share/penumbra" "$T/moved"
if PENUMBRA_DATA_DIR= "$P/bin/penumbra" bench --quick --no-reference >/dev/null 2>"$T/err"; then
    fail "bench ran without its bundled scene"
fi
grep -q "examples/scenes/spot_city.json not found (looked at .*$P/bin/../share/penumbra/" \
    "$T/err" || fail "no error naming the places looked at: $(cat "$T/err")"
mv "$T/moved" "$P/share/penumbra"
# With the data in place: sh-accuracy (where the CLI has it) reads the bundled environment maps;
# a tiny run takes about a second, where bench would fit 32 spheres first.
if "$P/bin/penumbra" --help 2>&1 | grep -q sh-accuracy; then
    PENUMBRA_DATA_DIR= "$P/bin/penumbra" sh-accuracy --bands 3 --sets 1 --quadrature 16 \
        >"$T/acc" 2>&1 || fail "installed sh-accuracy: $(tail -1 "$T/acc")"
    grep -q "interior.hdr" "$T/acc" || fail "sh-accuracy did not use the bundled envmaps"
fi

if [ "$fails" -ne 0 ]; then
    echo "cli_install: $fails failure(s)"
    exit 1
fi

# ---- The installed Python package, no environment variable -----------------------------------
PY=/usr/bin/python3
if [ ! -x "$PY" ] || ! "$PY" -c "import torch" >/dev/null 2>&1; then
    echo "cli_install: C parts passed; Python part skipped (/usr/bin/python3 cannot import torch)"
    exit 77
fi
PYPKG=$(find "$P" -name _libpath.py -path '*/penumbra/*')
[ -n "$PYPKG" ] || { echo "FAIL: penumbra/_libpath.py not installed"; exit 1; }
PYDIR=$(dirname "$(dirname "$PYPKG")")
grep -q "^LIBRARY = \"$LIBDIR/libpenumbra.so.0\"$" "$PYPKG" || fail "_libpath.py: $(cat "$PYPKG")"
cat >"$T/use.py" <<EOF
import sys
sys.path.insert(0, "$PYDIR")
import torch
import penumbra
assert penumbra.__file__.startswith("$PYDIR/"), penumbra.__file__
assert penumbra.version() == "$(pkg-config --modversion penumbra)", penumbra.version()
# A tetrahedron over the ground with one proxy sphere, 24 x 20 pixels; gradient of the lighting.
v = torch.tensor([[0, 0.2, 0], [0.5, 0.2, 0], [0, 0.7, 0], [0, 0.2, 0.5]], dtype=torch.float32)
f = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=torch.int32)
sh = torch.zeros(16, 3)
sh[0] = 1.5
sh[2] = 0.8
sh.requires_grad_()
cam = penumbra.Camera(width=24, height=20, eye=(1.5, 1.2, 1.8), target=(0.1, 0.3, 0.1))
image = penumbra.render(v, f, sh, cam, albedo=(0.6, 0.5, 0.4),
                        spheres=torch.tensor([[0.12, 0.32, 0.12, 0.15]]))
assert image.shape == (20, 24, 3) and torch.isfinite(image).all() and image.max() > 0
image.mean().backward()
assert torch.isfinite(sh.grad).all() and sh.grad[0].abs().sum() > 0
print("python: penumbra", penumbra.version(), "from", penumbra.__file__)
EOF
# A clean environment: no PENUMBRA_LIB, PYTHONPATH or LD_LIBRARY_PATH leads it to the library
# (LD_PRELOAD only in a sanitizer build, for the runtimes; leaks are the C tests' business).
set -- PATH=/usr/bin:/bin HOME="$T" PYTHONDONTWRITEBYTECODE=1
[ -z "$PRELOAD" ] || set -- "$@" LD_PRELOAD="$PRELOAD" ASAN_OPTIONS=detect_leaks=0
if ! env -i "$@" "$PY" "$T/use.py"; then
    fail "installed Python package"
fi
if [ "$fails" -ne 0 ]; then
    echo "cli_install: $fails failure(s)"
    exit 1
fi
echo "cli_install: ok"
