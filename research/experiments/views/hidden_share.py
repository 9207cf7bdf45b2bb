"""How much of the multi-view lighting error lies below the horizon, where the ground hides the
light from every camera (the multi-view experiment's 0.5x question; docs/results/views.md, "What the
views cannot see: the light below the horizon").

The lighting error of result.json is |e| / |t| over all SH coefficients (e the recovered minus the
true coefficients, t the true ones). The SH basis is orthonormal over the sphere, so |e|^2 splits
into the integral of the squared error function above the horizon (y > 0), e^T M e with M the
basis's Gram matrix on the upper hemisphere, and below it, e^T (I - M) e. This script reports the
error's share below the horizon, below = sqrt(e^T (I - M) e) / |t|, so that
error^2 = above^2 + below^2. Whatever the views do to the sky, n views cannot bring the error
under their own `below`; where below(4 views) exceeds half the 1-view error, 4 views cannot reach
0.5x unless they move the light below the horizon, which no camera above the ground sees.

It reads the runs that run_views.sh (run_<placement>_<n>_ls[_model]) and run_views_lights.py
(run_<placement>_<n>_lights) left in out/views/<mesh>_<envmap>/, with the recovered lighting in
each run's scene.json and the true lighting from the truth scene loaded by the Python binding
(truth.json: the map's 4-band projection; truth_lights.json: the map's residual after its lights).
M is integrated exactly (Gauss-Legendre in y, uniform in phi) with the basis of
scripts/sh_common.py, which is src/sh's.
Usage: PYTHONPATH=python python3 research/experiments/views/hidden_share.py [CASE ...]
       (CASE as spot_city; default: Spot and Bob under city and interior)
"""
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..", "..")
sys.path.insert(0, os.path.join(ROOT, "scripts"))
from sh_common import gauss_legendre, sh_eval  # noqa: E402

BANDS = 4
VARIANTS = (("lights", "truth_lights.json", "lights"), ("SH alone", "truth.json", "ls"),
            ("model control", "truth.json", "ls_model"))


def gram_above(L):
    """M_jk = integral over y > 0 of Y_j Y_k (exact: the integrand is a polynomial of degree
    <= 2(L-1) in y once averaged over phi)."""
    n = L * L
    xs, ws = gauss_legendre(L)
    M = [[0.0] * n for _ in range(n)]
    for x, w in zip(xs, ws):
        y = 0.5 * (x + 1.0)
        s = math.sqrt(max(0.0, 1.0 - y * y))
        for b in range(2 * L):
            phi = 2.0 * math.pi * (b + 0.5) / (2 * L)
            Y = sh_eval(L, (s * math.cos(phi), y, s * math.sin(phi)))
            for j in range(n):
                for k in range(n):
                    M[j][k] += 0.5 * w * 2.0 * math.pi / (2 * L) * Y[j] * Y[k]
    return M


def split(sh, truth, M):
    """(error, above, below) relative to |t|, summed over the three channels."""
    n = len(M)
    tot = up = norm = 0.0
    for ch in range(3):
        e = [sh[k][ch] - truth[k][ch] for k in range(n)]
        tot += sum(v * v for v in e)
        up += sum(e[j] * M[j][k] * e[k] for j in range(n) for k in range(n))
        norm += sum(truth[k][ch] ** 2 for k in range(n))
    return tuple(math.sqrt(max(v, 0.0) / norm) for v in (tot, up, tot - up))


def main():
    import penumbra  # the binding: loads the truth's lighting as penumbra render does

    cases = sys.argv[1:] or ["spot_city", "bob_city", "spot_interior", "bob_interior"]
    M = gram_above(BANDS)
    print("| scene | model | placement | error: all = above (+) below, 1 / 4 / 8 views | "
          "4 / 1 | below(4) / all(1) |")
    print("|---|---|---|---|---|---|")
    for case in cases:
        d = os.path.join(ROOT, "out", "views", case)
        for label, truth_file, suffix in VARIANTS:
            if not os.path.exists(os.path.join(d, "run_ring_1_%s" % suffix, "result.json")):
                continue
            truth = penumbra.load_scene(os.path.join(d, truth_file)).sh.tolist()
            for placement in ("ring", "ring_near"):
                s = {}
                for n in (1, 4, 8):
                    run = os.path.join(d, "run_%s_%d_%s" % (placement, n, suffix))
                    if not os.path.exists(os.path.join(run, "result.json")):
                        continue
                    with open(os.path.join(run, "scene.json")) as f:
                        sh = json.load(f)["lighting"]["sh"]
                    s[n] = split(sh, truth, M)
                    with open(os.path.join(run, "result.json")) as f:
                        reported = json.load(f)["metrics"]["lighting_rel_error"]
                    if abs(reported - s[n][0]) > 1e-4 * max(1.0, reported):
                        sys.exit("%s: lighting error %.6f, result.json says %.6f: the truth "
                                 "loaded here is not the run's" % (run, s[n][0], reported))
                if 1 not in s or 4 not in s:
                    continue
                cells = " / ".join("%.3f = %.3f (+) %.3f" % s[n] for n in (1, 4, 8) if n in s)
                print("| %s | %s | %s | %s | %.2f× | %.2f× |" % (
                    case.replace("_", ", "), label, placement, cells, s[4][0] / s[1][0],
                    s[4][2] / s[1][0]))


if __name__ == "__main__":
    main()
