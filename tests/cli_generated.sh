#!/bin/sh
# Generated code matches its generator: reruns each code generator into a temporary folder and
# compares its output byte for byte with the committed file. A stale file fails with one line
# naming it and the command that regenerates it (or `make generate`, which reruns them all).
# Runs on Debian's /usr/bin/python3 (what CI has; the generators use the standard library only);
# skipped (exit 77) where no Python 3 is found.
# Usage: sh cli_generated.sh PENUMBRA_BIN SOURCE_DIR
set -u
SRC=$(cd "$2" && pwd)
PY=/usr/bin/python3
[ -x "$PY" ] || PY=$(command -v python3 || true)
if [ -z "$PY" ]; then
    echo "SKIP: no python3 to run the generators"
    exit 77
fi
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0

# check GENERATOR OUTPUT [ARGUMENT]: both paths relative to the source folder.
check() {
    out="$T/$(basename "$2")"
    if ! (cd "$SRC" && PYTHONDONTWRITEBYTECODE=1 "$PY" "$1" ${3:-} > "$out"); then
        echo "FAIL: $1 did not run"
        fails=$((fails + 1))
    elif ! cmp -s "$out" "$SRC/$2"; then
        echo "FAIL: $2 is stale: regenerate it with \`python3 $1${3:+ $3} > $2\` (or \`make generate\`)"
        fails=$((fails + 1))
    else
        echo "ok   $2 matches $1"
    fi
}

check scripts/gen_sh_tables.py src/sh/tables.c
for L in 3 4 5 6; do
    check scripts/gen_sh_fast.py src/sh/sh_fast_product_$L.inc $L
done

[ $fails -eq 0 ] || exit 1
