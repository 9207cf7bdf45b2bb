#!/bin/sh
# Contract of `penumbra bench` (docs/design.md sec. 5, docs/bench.md): --json prints one JSON object
# per case with the contract's fields, finite positive times, the headline case among them; flags
# select cases, threads and repeats; usage errors exit 2 with one error line. No timing is
# asserted: the numbers are the benchmark's business, not the test's.
# Usage: sh cli_bench.sh PENUMBRA_BIN SRC_DIR
set -u
BIN=$1
SRC=$(cd "$2" && pwd)
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
fails=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# The bundled scene with its mesh copied here; the sphere fits the bench asks for are cached in
# $XDG_CACHE_HOME/penumbra, a folder of this test (never the user's cache).
export XDG_CACHE_HOME="$T/cache"
unset PENUMBRA_NO_CACHE
cp "$SRC/data/meshes/spot_triangulated.obj" "$T/spot.obj"
sed -e "s|\.\./\.\./data/meshes/spot_triangulated.obj|$T/spot.obj|" \
    -e "s|\.\./\.\./data/|$SRC/data/|g" "$SRC/examples/scenes/spot_city.json" > "$T/scene.json"
grep -q "$T/spot.obj" "$T/scene.json" || fail "scene copy does not use the mesh copy"

# Checks a file of JSON lines: every line an object with the contract's fields, finite positive
# times, stage times >= 0, reference fields null or positive; prints the case names.
check_json() { # file expected-threads expected-repeat
    python3 - "$1" "$2" "$3" <<'PY'
import json, math, sys
path, threads, repeat = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
need = ["name", "width", "height", "spheres", "bands", "threads", "forward_ms", "backward_ms",
        "total_ms", "fwd_prepare_ms", "fwd_shade_ms", "fwd_visibility_ms", "fwd_exp_ms",
        "fwd_antialias_ms", "bwd_antialias_ms", "bwd_shade_ms", "bwd_visibility_ms", "bwd_exp_ms",
        "bwd_scatter_ms", "sh_rel_rmse", "truth_spp", "reference_spp", "reference_ms",
        "reference_vs_forward", "reference_vs_total", "repeat", "load_avg_1min", "forward_min_ms",
        "backward_min_ms", "total_min_ms", "reference_rel_rmse", "quick", "loss",
        "first_forward_ms", "self"]
bad = []
names = []
lines = open(path).read().splitlines()
if not lines:
    bad.append("no output")
for n, line in enumerate(lines, 1):
    try:
        o = json.loads(line)
    except ValueError as e:
        bad.append("line %d is not JSON: %s" % (n, e))
        continue
    if not isinstance(o, dict):
        bad.append("line %d is not an object" % n)
        continue
    missing = [k for k in need if k not in o]
    if missing:
        bad.append("line %d lacks %s" % (n, missing))
        continue
    names.append(o["name"])
    for k in ("width", "height", "spheres", "bands", "threads"):
        if not isinstance(o[k], int) or o[k] < 1:
            bad.append("%s: %s = %r" % (o["name"], k, o[k]))
    for k in ("forward_ms", "backward_ms", "total_ms", "forward_min_ms", "backward_min_ms",
              "total_min_ms", "fwd_shade_ms", "bwd_shade_ms"):
        v = o[k]
        if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            bad.append("%s: %s = %r is not a finite positive time" % (o["name"], k, v))
    for k in need:
        if k.endswith("_ms") and k.startswith(("fwd_", "bwd_")):
            v = o[k]
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                bad.append("%s: %s = %r" % (o["name"], k, v))
    if o["threads"] != threads:
        bad.append("%s: threads %r, expected %d" % (o["name"], o["threads"], threads))
    if o["repeat"] != repeat:
        bad.append("%s: repeat %r, expected %d" % (o["name"], o["repeat"], repeat))
    for k in ("reference_spp", "reference_ms", "reference_vs_forward", "reference_vs_total",
              "sh_rel_rmse", "truth_spp"):
        v = o[k]
        if v is not None and (not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0):
            bad.append("%s: %s = %r" % (o["name"], k, v))
    if o["reference_spp"] is not None:
        if o["reference_ms"] is None or o["reference_ms"] <= 0:
            bad.append("%s: a reference spp without a time" % o["name"])
        elif abs(o["reference_vs_forward"] - o["reference_ms"] / o["forward_ms"]) > \
                1e-3 * o["reference_vs_forward"] + 1e-4:
            bad.append("%s: reference_vs_forward is not reference_ms / forward_ms" % o["name"])
        if o["reference_rel_rmse"] is None or o["reference_rel_rmse"] > o["sh_rel_rmse"]:
            bad.append("%s: the reference's error does not reach the SH render's" % o["name"])
    for k in ("forward", "backward", "total"):
        mn, md = o.get(k + "_min_ms"), o[k + "_ms"]
        if isinstance(mn, (int, float)) and isinstance(md, (int, float)) and mn > md:
            bad.append("%s: %s_min_ms %r above the median %r" % (o["name"], k, mn, md))
if len(set(names)) != len(names):
    bad.append("duplicate case names: %s" % names)
for b in bad:
    print("FAIL:", b)
print(" ".join(names))
sys.exit(1 if bad else 0)
PY
}

if ! command -v python3 >/dev/null 2>&1; then
    echo "cli_bench: python3 not found, skipped"
    exit 0
fi

# The whole quick suite: every case, the headline among them, all cores. Under the sanitizers
# (PEN_TEST_QUICK=1) two cases only: the sphere fits and the reference are slow there.
all="headline res32 res128 spheres8 spheres128 bands3 bands5 bands6 lights1 lights3 transfer groundgrid"
only=""
if [ "${PEN_TEST_QUICK:-0}" = 1 ]; then
    all="headline bands3"
    only="--case headline --case bands3"
fi
# shellcheck disable=SC2086 # $only is a list of arguments
if ! "$BIN" bench --json --quick $only --scene "$T/scene.json" > "$T/all.jsonl" 2> "$T/err"; then
    fail "bench --json --quick: $(cat "$T/err")"
fi
threads=$(python3 -c 'import json,sys; print(json.loads(open(sys.argv[1]).readline())["threads"])' \
    "$T/all.jsonl" 2>/dev/null || echo 0)
[ "$threads" -ge 1 ] 2>/dev/null || fail "no thread count in the output"
names=$(check_json "$T/all.jsonl" "$threads" 3) || fail "quick suite: $names"
for c in $all; do
    case " $names " in *" $c "*) ;; *) fail "case $c missing from: $names" ;; esac
done
[ "$(echo "$names" | wc -w)" -eq "$(echo "$all" | wc -w)" ] || fail "cases: $names, expected $all"
python3 - "$T/all.jsonl" <<'PY' || fail "headline case is not 64x64, 32 spheres, 4 bands"
import json, sys
h = [o for o in map(json.loads, open(sys.argv[1])) if o["name"] == "headline"]
sys.exit(0 if len(h) == 1 and (h[0]["width"], h[0]["height"], h[0]["spheres"], h[0]["bands"])
         == (64, 64, 32, 4) and h[0]["quick"] is True and h[0]["sh_rel_rmse"] is not None else 1)
PY
# The fits were cached in the cache folder, not beside the mesh.
ls "$T/cache/penumbra" | grep -q '^spot\.obj-[0-9a-f]*-32-' || fail "no cached fit in the cache"
ls "$T" | grep -q 'fit-' && fail "a cached fit beside the mesh copy"

# One case, one thread, one repeat, no reference: one line, its reference fields null.
if ! "$BIN" bench --json --quick --scene "$T/scene.json" --case headline --threads 1 \
    --repeat 1 --warmup 0 --no-reference > "$T/one.jsonl" 2> "$T/err"; then
    fail "bench --case headline: $(cat "$T/err")"
fi
[ "$(wc -l < "$T/one.jsonl")" -eq 1 ] || fail "--case headline printed $(wc -l < "$T/one.jsonl") lines"
names=$(check_json "$T/one.jsonl" 1 1) || fail "one case: $names"
[ "$names" = "headline" ] || fail "--case headline ran: $names"
grep -q '"reference_ms": null' "$T/one.jsonl" || fail "--no-reference left a reference time"

# The readable table: a header and the case's row, then the stage table.
if ! "$BIN" bench --quick --scene "$T/scene.json" --case bands3 --repeat 1 --no-reference \
    > "$T/table" 2> "$T/err"; then
    fail "bench table: $(cat "$T/err")"
fi
grep -q '^case ' "$T/table" || fail "no table header: $(cat "$T/table")"
grep -q '^bands3 .*64x64' "$T/table" || fail "no bands3 row: $(cat "$T/table")"
grep -q '^stages' "$T/table" || fail "no stage table"
"$BIN" bench --help | grep -q -- '--no-reference' || fail "--help does not list --no-reference"

# Errors: usage errors exit 2, runtime errors 1; one error line (usage errors add the usual
# "Try ... --help" hint), nothing on stdout.
expect_error() { # expected-status fragment args...
    want=$1 frag=$2
    shift 2
    "$BIN" bench "$@" > "$T/out" 2> "$T/err"
    rc=$?
    [ "$rc" -eq "$want" ] || fail "bench $*: exit $rc, expected $want"
    [ "$(grep -c '^penumbra bench: ' "$T/err")" -eq 1 ] || fail "bench $*: stderr: $(cat "$T/err")"
    [ "$(wc -l < "$T/err")" -le 2 ] || fail "bench $*: $(wc -l < "$T/err") lines on stderr"
    grep -q -- "$frag" "$T/err" || fail "bench $*: stderr lacks '$frag': $(cat "$T/err")"
    [ ! -s "$T/out" ] || fail "bench $*: wrote to stdout: $(cat "$T/out")"
    return 0
}
expect_error 2 "unknown option" --bogus
expect_error 2 "unexpected argument" extra
expect_error 2 "--repeat" --repeat 0
expect_error 2 "--threads" --threads -1
expect_error 2 "--repeat" --repeat
expect_error 2 "no case 'nosuch'" --case nosuch
expect_error 2 "no case 'res256'" --quick --case res256
expect_error 1 "nosuch.json" --quick --scene "$T/nosuch.json" --case headline

# A build folder outside the checkout (cmake -B /elsewhere) finds the bundled scene through the
# source path CMake leaves beside the executable; without that file, and with no data beside it,
# the bundled file is reported missing with the places tried.
mkdir -p "$T/elsewhere/bin"
cp "$BIN" "$T/elsewhere/bin/penumbra"
if (cd "$T" && PENUMBRA_DATA_DIR= "$T/elsewhere/bin/penumbra" bench --quick --case headline \
        --no-reference --repeat 1 > "$T/out" 2> "$T/err"); then
    fail "bench from a folder with no data and no source path ran: $(cat "$T/out")"
fi
grep -q "bundled file examples/scenes/spot_city.json not found" "$T/err" ||
    fail "missing bundled data: $(cat "$T/err")"
echo "$SRC" > "$T/elsewhere/bin/penumbra-source"
(cd "$T" && PENUMBRA_DATA_DIR= "$T/elsewhere/bin/penumbra" bench --quick --case headline \
    --no-reference --repeat 1 --json > "$T/out" 2> "$T/err") ||
    fail "bench from a build folder outside the checkout: $(cat "$T/err")"
grep -q '"name": "headline"' "$T/out" || fail "bench outside the checkout: no headline case"

if [ "$fails" -ne 0 ]; then
    echo "$fails failed"
    exit 1
fi
echo "cli_bench: all passed"
