#!/bin/sh
# The first multi-view lighting experiment (docs/results/views.md): Spot under the city map,
# targets ray-traced by `penumbra reference` (128x128, 64 spp) from 4 cameras around it and one
# held-back camera (views_setup.py), lit by the map itself and by its 4-band projection
# (_sh); the lighting recovered by least squares from 1, 2 and 4 of them (ridge 1e-2, the
# default, and 1e-4), and, for the map's targets, by Adam from the unshadowed fit over the same
# views ("init": "fit", at most 300 iterations). Prints one line per run: the lighting errors,
# the image error on the held-back view, and first the same error of the true map's 4-band
# projection rendered by penumbra there (what the true lighting achieves in this model).
# Usage: sh research/experiments/optimize/views_experiment.sh PENUMBRA_BIN
# Writes out/optimize/views/ (ignored by git; finished runs are kept and not run again). About
# 8 minutes on the shared 2-core machine, most of it Adam's runs.
set -eu
BIN=$1
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=$HERE/../../../out/optimize/views
python3 "$HERE/views_setup.py" "$OUT"
cd "$OUT"
for c in 0 1 2 3 val; do
    [ -f "t_$c.exr" ] || "$BIN" reference "cam_$c.json" -o "t_$c.exr" --spp 64 >/dev/null
    [ -f "t_${c}_sh.exr" ] ||
        "$BIN" reference "cam_$c.json" -o "t_${c}_sh.exr" --spp 64 --lighting sh >/dev/null
done
"$BIN" render cam_val.json -o true_val.exr >/dev/null
echo "true lighting on the held-back view, map targets: $("$BIN" compare true_val.exr t_val.exr)"
echo "true lighting on the held-back view, _sh targets: $("$BIN" compare true_val.exr t_val_sh.exr)"
for solver in ls ls1e-4 adam_fit ls_sh ls1e-4_sh; do
    for n in 1 2 4; do
        run=run_${n}_$solver
        [ -f "$run/result.json" ] || "$BIN" optimize "task_${n}_$solver.json" -o "$run" -q
        python3 - "$run/result.json" "$n" "$solver" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
m, v = r["metrics"], r["validation_views"][0]
print("%-9s %d view(s): lighting_rel_error %.4f, bands 0-2 %.4f, sky %.4f; held-back view "
      "rel. RMSE %.4f (RMSE %.4f); views rel. RMSE %s; %s after %d iterations, %.1f s"
      % (sys.argv[3], int(sys.argv[2]), m["lighting_rel_error"], m["lighting_rel_error_bands_0_2"],
         m["lighting_rel_error_sky"], v["image_rel_rmse"], v["image_rmse"],
         " ".join("%.4f" % w["image_rel_rmse"] for w in r["views"]), r["stop_reason"],
         r["iterations"], r["seconds"]))
PY
    done
done
