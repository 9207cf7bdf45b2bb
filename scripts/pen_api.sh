#!/bin/sh
# Marks the exported functions of the public headers with PEN_API (include/penumbra/api.h).
# The rule, mechanical so that it can be re-applied after declarations move between headers:
# in include/penumbra/*.h, every line whose first column starts a function declaration
# (a return type, then a `pen_...(` name) gets PEN_API in front; lines starting with typedef,
# static, extern, #, or already PEN_API are left alone. Continuation lines are indented, so
# they never match.
# Usage: sh scripts/pen_api.sh [--check] [INCLUDE_DIR]
#   (no option)  annotate the headers in place
#   --check      change nothing; list the declarations missing PEN_API and exit 1 if any
set -eu
MODE=apply
if [ "${1:-}" = "--check" ]; then MODE=check; shift; fi
DIR=${1:-$(dirname "$0")/../include/penumbra}
# A declaration at column 0: optional qualifiers, a type name, stars/spaces, then pen_name(.
DECL='^((const|unsigned|struct|enum) +)*[A-Za-z_][A-Za-z_0-9]*[ *]+pen_[a-z0-9_]+\('
SKIP='^(typedef|static|extern|PEN_API|#)'
if [ "$MODE" = check ]; then
    missing=$(grep -HnE "$DECL" "$DIR"/*.h | grep -vE "^[^:]*:[0-9]+:($SKIP)" || true)
    if [ -n "$missing" ]; then
        echo "declarations without PEN_API (run sh scripts/pen_api.sh):"
        echo "$missing"
        exit 1
    fi
    exit 0
fi
for h in "$DIR"/*.h; do
    # Line ranges of the declarations about to be marked (first line to the one with the `;`),
    # so that clang-format re-wraps those and nothing else in the file.
    ranges=$(awk -v decl="$DECL" -v skip="$SKIP" '
        start == 0 && $0 ~ decl && $0 !~ skip { start = NR }
        start > 0 && /;/ { printf " --lines=%d:%d", start, NR; start = 0 }' "$h")
    [ -n "$ranges" ] || continue
    sed -E -i "/$SKIP/!s/($DECL)/PEN_API \1/" "$h"
    if command -v clang-format >/dev/null 2>&1; then
        # shellcheck disable=SC2086
        clang-format -i $ranges "$h"
    fi
done
