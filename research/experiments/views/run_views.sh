#!/bin/sh
# The multi-view lighting experiment of docs/results/views.md ("Placements, more views"):
# can 4 views reach half the 1-view lighting error? For each MESH:ENVMAP (default
# spot:city), make_views.py writes the cameras of four placements (ring = today's single
# elevation, ring_far, ring_near, elev = several elevations up to top-down), each with 1, 2, 4
# and 8 views, and two held-back validation views; `penumbra reference` ray-traces every
# camera's target with the full map (128x128, 256 spp; the scenes keep "lights": "none", so the
# map's 4-band projection is the true lighting); the lighting is then recovered from black
# (4 bands, everything else known) by each solver: ls (least squares, default ridge 1e-2), ls4
# (ridge 1e-4), adam (Adam with the task defaults: no ridge, 500 iterations at most).
# Usage: sh research/experiments/views/run_views.sh PENUMBRA_BIN [MESH:ENVMAP ...]
#   MESH spot or bob (examples/optimize/MESH_truth.json), ENVMAP a bundled .hdr (city, interior)
# Environment: PEN_VIEWS_PLACEMENTS (default "ring elev ring_far ring_near"), PEN_VIEWS_COUNTS
#   (default "1 2 4 8"), PEN_VIEWS_SOLVERS (default "ls ls4 adam") pick the runs;
#   PEN_VIEWS_TARGETS (default "map") the targets: map (the full map, the experiment), and two
#   controls that tell the limits apart, solved by least squares only: sh (ray-traced with the
#   map's 4-band projection, `reference --lighting sh`: exact visibility, the light the model
#   can represent) and model (penumbra's own render of the truth: the model exact, so only the
#   views' coverage of the lighting is left).
# Writes out/views/MESH_ENVMAP/ (ignored by git; finished runs are kept and not run again):
# t_<camera>.exr targets, true_val<i>.exr (the truth scene rendered by penumbra, i.e. the true
# map's 4-band projection, at the held-back views), run_<placement>_<n>_<solver>/ (the
# optimize outputs; run_..._sh, run_..._model for the controls), and out/views/results.tsv (every finished run of every MESH_ENVMAP, one
# line each) with a markdown table on stdout. The "val" column is the held-back views' mean
# rel. RMSE against the ray-traced truth, "true" the same of the true projection, "ratio" =
# val / true (the experiment's limit: at most 1.15 + 0.01 / true).
# Cost on the shared 2-core machine: the 33 targets about 2 min per MESH:ENVMAP, a
# least-squares run a few seconds per view, an Adam run about 0.1-0.3 s per view and iteration.
set -eu
BIN=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
[ $# -ge 1 ] && shift
CASES=${*:-spot:city}
PLACEMENTS=${PEN_VIEWS_PLACEMENTS:-ring elev ring_far ring_near}
COUNTS=${PEN_VIEWS_COUNTS:-1 2 4 8}
SOLVERS=${PEN_VIEWS_SOLVERS:-ls ls4 adam}
TARGETS=${PEN_VIEWS_TARGETS:-map}
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
for c in $CASES; do
    mesh=${c%%:*} envmap=${c#*:}
    dir=$ROOT/out/views/${mesh}_$envmap
    cams=$(python3 "$HERE/make_views.py" "$dir" "$mesh" "$envmap")
    for targets in $TARGETS; do
        for cam in $cams; do
            case $targets in
            map) t=$dir/t_$cam.exr
                [ -s "$t" ] || "$BIN" reference "$dir/cam_$cam.json" -o "$t" --spp 256 > /dev/null ;;
            sh) t=$dir/t_${cam}_sh.exr
                [ -s "$t" ] || "$BIN" reference "$dir/cam_$cam.json" -o "$t" --spp 256 \
                    --lighting sh > /dev/null ;;
            model) t=$dir/t_${cam}_model.exr
                [ -s "$t" ] || "$BIN" render "$dir/cam_$cam.json" -o "$t" > /dev/null ;;
            *) echo "unknown targets $targets (expected map, sh or model)" >&2 && exit 2 ;;
            esac
        done
    done
    for v in val1 val2; do
        [ -s "$dir/true_$v.exr" ] || "$BIN" render "$dir/cam_$v.json" -o "$dir/true_$v.exr" > /dev/null
        "$BIN" compare "$dir/true_$v.exr" "$dir/t_$v.exr" > "$dir/true_$v.json"
    done
    for placement in $PLACEMENTS; do
        for n in $COUNTS; do
            for solver in $SOLVERS; do
                for targets in $TARGETS; do
                    case $targets in map) suffix="" ;; *) suffix=_$targets ;; esac
                    task=$dir/task_${placement}_${n}_$solver$suffix.json
                    run=$dir/run_${placement}_${n}_$solver$suffix
                    [ ! -f "$task" ] || [ -s "$run/result.json" ] ||
                        "$BIN" optimize "$task" -o "$run" -q
                done
            done
        done
    done
done
python3 "$HERE/views_table.py" "$ROOT/out/views"
