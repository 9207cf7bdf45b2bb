#!/bin/sh
# The library's layering (README "Layout", docs/design.md sec. 6.1), checked on this build's
# objects by scripts/check_layers.py: no cycle between the src/ folders, no two files calling each
# other, no source file over 900 lines, each public header implemented by one folder.
# Skipped (exit 77) where no Python 3 or nm is found.
# Usage: sh cli_layers.sh PENUMBRA_BIN SOURCE_DIR
set -u
BUILD=$(cd "$(dirname "$1")" && pwd)
SRC=$(cd "$2" && pwd)
PY=/usr/bin/python3
[ -x "$PY" ] || PY=$(command -v python3 || true)
if [ -z "$PY" ] || ! command -v nm >/dev/null 2>&1; then
    echo "SKIP: no python3 or nm"
    exit 77
fi
PYTHONDONTWRITEBYTECODE=1 "$PY" "$SRC/scripts/check_layers.py" "$BUILD"
