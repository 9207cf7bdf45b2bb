#!/bin/sh
# The Python binding's tests (python/tests, unittest) with Debian's own Python 3 and its
# python3-torch and python3-numpy; the binding loads the libpenumbra.so built beside the CLI.
# Skips when /usr/bin/python3 cannot import torch: exit 77, which CMakeLists.txt declares as this
# test's SKIP_RETURN_CODE, so ctest reports it as skipped, not passed.
# Usage: sh cli_python.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$2
PY=/usr/bin/python3
LIBDIR=$(dirname "$BIN")
if [ ! -x "$PY" ] || ! "$PY" -c "import torch, numpy" >/dev/null 2>&1; then
    echo "skipped: python3-torch not installed (/usr/bin/python3 cannot import torch and numpy)"
    exit 77
fi
if [ ! -f "$LIBDIR/libpenumbra.so" ]; then
    echo "FAIL: $LIBDIR/libpenumbra.so not built"
    exit 1
fi
# A sanitizer build (make test-asan): Python can load the library only with the sanitizer
# runtimes preloaded (ASan first). Leak detection stays with the C tests: the interpreter and
# torch keep memory until exit by design.
san() { ldd "$LIBDIR/libpenumbra.so" 2>/dev/null | awk -v n="$1" '$1 ~ n {print $3}'; }
PRELOAD=$(echo $(san '^libasan[.]so') $(san '^libubsan[.]so'))
SAN_OPTS=${ASAN_OPTIONS:-}
if [ -n "$PRELOAD" ]; then
    echo "sanitizer build: preloading $PRELOAD"
    SAN_OPTS="${SAN_OPTS:+$SAN_OPTS:}detect_leaks=0"
fi
# The tests write nothing into the source tree (bytecode included).
env LD_PRELOAD="$PRELOAD" ASAN_OPTIONS="$SAN_OPTS" PYTHONDONTWRITEBYTECODE=1 \
    PYTHONPATH="$SRC/python" PENUMBRA_LIB="$LIBDIR/libpenumbra.so" PENUMBRA_CLI="$BIN" \
    PENUMBRA_SRC="$SRC" \
    "$PY" -m unittest discover -s "$SRC/python/tests" -t "$SRC/python/tests" -v 2>&1
