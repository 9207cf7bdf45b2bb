#!/bin/sh
# The deformation and shape-from-shadow tasks from 1, 2, 4 and 8 views (multi-view experiments;
# docs/results/views.md, "Deformation and shape from shadow from several views"). For each MESH
# (default spot), make_views_shape.py writes the scenes, cameras and tasks (the single-view
# tasks' settings, otherwise defaults); `penumbra reference` ray-traces every camera's target
# (128x128, PEN_VIEWS_SPP samples per pixel, default 256): the bent truth under the full city
# map, the shadow truth under its own 4-band sun; then each task runs from each placement's
# first 1, 2, 4 and 8 cameras (deformation: ring; shape: ring and top, make_views_shape.py).
# Usage: sh research/experiments/views/run_views_shape.sh PENUMBRA_BIN [MESH ...]  (spot or bob)
# Environment: PEN_VIEWS_SHAPE_RUNS (default "deformation_ring shape_ring shape_top") and
#   PEN_VIEWS_COUNTS (default "1 2 4 8") pick the runs; PEN_VIEWS_SPP the targets' samples;
#   PEN_VIEWS_ITERATIONS overrides the tasks' iteration limit (runs run_..._it<N>/, beside the
#   runs at the tasks' own limit: does a run at the limit still gain, or has it stalled?);
#   PEN_VIEWS_THREADS sets the thread count (runs run_..._t<N>/: the same result, bit for bit,
#   in another time; with 1 view and 2 threads the view renders with both, in turn, which on a
#   loaded machine is the slow way: docs/optimize.md, "Views in parallel").
# Writes out/views_shape/MESH/ (ignored by git; finished targets and runs are kept and not run
# again): t_<task>_<camera>.exr, run_<task>_<placement>_<n>[_it<N>][_t<T>]/ (the optimize
# outputs), run_shape_start/ (the shape's start: one step without shadows, the spheres
# unmoved), and
# out/views_shape/results.tsv with a markdown table on stdout (views_shape_table.py).
# The inputs the single-view table makes (run_table.sh) are made here too when missing, by the
# same commands: out/optimize/meshes/MESH_bent.obj and out/optimize/spheres/MESH_start.json.
# Cost on the shared 2-core machine (nice'd, loaded): about 5 minutes per mesh; the targets 2-5 s
# each, an iteration 0.02-0.04 s per view (docs/results/views.md has the measured s/it).
set -eu
BIN=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
[ $# -ge 1 ] && shift
MESHES=${*:-spot}
RUNS=${PEN_VIEWS_SHAPE_RUNS:-deformation_ring shape_ring shape_top}
COUNTS=${PEN_VIEWS_COUNTS:-1 2 4 8}
SPP=${PEN_VIEWS_SPP:-256}
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../../.." && pwd)
OPT=$ROOT/research/experiments/optimize
. "$OPT/prepare.sh"
GEN=$ROOT/out/optimize
mkdir -p "$GEN/meshes" "$GEN/spheres"
for mesh in $MESHES; do
    pen_prepare "$OPT" "$ROOT" "$BIN" "$GEN" "$mesh"
    dir=$ROOT/out/views_shape/$mesh
    for key in $(python3 "$HERE/make_views_shape.py" "$dir" "$mesh"); do
        # the deformation's targets are lit by the map itself; the shape's by their SH sun
        case $key in deformation_*) lighting=envmap ;; *) lighting=sh ;; esac
        t=$dir/t_$key.exr
        [ -s "$t" ] || "$BIN" reference "$dir/cam_$key.json" -o "$t" --spp "$SPP" \
            --lighting $lighting > /dev/null
    done
    # the shape's start metrics: one step without shadows, in which the spheres do not move
    case " $RUNS " in *" shape_"*)
        [ -s "$dir/run_shape_start/result.json" ] || "$BIN" optimize "$dir/task_shape_ring_1.json" \
            -o "$dir/run_shape_start" -q --no-shadows --iterations 1 ;;
    esac
    for run in $RUNS; do
        for n in $COUNTS; do
            set -- -q
            name=run_${run}_$n
            if [ -n "${PEN_VIEWS_ITERATIONS:-}" ]; then
                set -- "$@" --iterations "$PEN_VIEWS_ITERATIONS"
                name=${name}_it$PEN_VIEWS_ITERATIONS
            fi
            if [ -n "${PEN_VIEWS_THREADS:-}" ]; then
                set -- "$@" --threads "$PEN_VIEWS_THREADS"
                name=${name}_t$PEN_VIEWS_THREADS
            fi
            [ -s "$dir/$name/result.json" ] ||
                "$BIN" optimize "$dir/task_${run}_$n.json" -o "$dir/$name" "$@"
        done
    done
done
python3 "$HERE/views_shape_table.py" "$ROOT/out/views_shape"
