#!/bin/sh
# The Python binding's tests (python/tests, unittest) with Debian's own Python 3 and its
# python3-torch and python3-numpy; the binding loads the libpenumbra.so built beside the CLI.
# Skips (exit 0) when /usr/bin/python3 cannot import torch.
# Usage: sh cli_python.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$2
PY=/usr/bin/python3
LIBDIR=$(dirname "$BIN")
if [ ! -x "$PY" ] || ! "$PY" -c "import torch, numpy" >/dev/null 2>&1; then
    echo "skipped: python3-torch not installed (/usr/bin/python3 cannot import torch and numpy)"
    exit 0
fi
if [ ! -f "$LIBDIR/libpenumbra.so" ]; then
    echo "FAIL: $LIBDIR/libpenumbra.so not built"
    exit 1
fi
# The tests write nothing into the source tree (bytecode included).
PYTHONDONTWRITEBYTECODE=1 PYTHONPATH="$SRC/python" PENUMBRA_LIB="$LIBDIR/libpenumbra.so" \
    PENUMBRA_CLI="$BIN" PENUMBRA_SRC="$SRC" \
    "$PY" -m unittest discover -s "$SRC/python/tests" -t "$SRC/python/tests" -v 2>&1
