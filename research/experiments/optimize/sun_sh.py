#!/usr/bin/env python3
"""Prints the SH lighting (4 bands unless --bands) of a sun over a uniform sky as the "sh" rows of
a scene JSON.

The sun is a delta of power `sun` in direction `--dir`, projected onto real SH with the
Condon-Shortley phase (penumbra's convention: index l*l + l + m, Y_1,-1 = -0.488603 y,
Y_1,0 = 0.488603 z, Y_1,1 = -0.488603 x), each band l of N scaled by the Hann window
cos^2(pi l / 2N) (4 bands: 1, 0.85, 0.5, 0.15) against ringing; the sky adds `sky` radiance from every
direction (coefficient 0 += sky * sqrt(4 pi)). `--tint` scales the three channels. Standard
library only. Example (the shape-from-shadow experiments' lighting):

    python3 sun_sh.py --dir 0.55 0.45 -0.70 --sun 2 --sky 0.5 --tint 1 0.97 0.9
"""
import argparse
import math
import os
import sys

# The real SH basis of the code generators (scripts/sh_common.py: src/sh/sh_ops.inc's recurrence).
ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")
sys.path.insert(0, os.path.join(ROOT, "scripts"))
from sh_common import sh_eval  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", type=float, nargs=3, required=True, help="towards the sun")
    ap.add_argument("--sun", type=float, default=2.0, help="the sun's power")
    ap.add_argument("--sky", type=float, default=0.5, help="the sky's radiance")
    ap.add_argument("--bands", type=int, default=4, help="SH bands (1 to 8)")
    ap.add_argument("--tint", type=float, nargs=3, default=[1.0, 1.0, 1.0])
    a = ap.parse_args()
    n = math.sqrt(sum(v * v for v in a.dir))
    if n == 0:
        ap.error("--dir must not be zero")
    if not 1 <= a.bands <= 8:
        ap.error("--bands must be 1 to 8")
    y = sh_eval(a.bands, [v / n for v in a.dir])
    rows = []
    for l in range(a.bands):
        window = math.cos(math.pi * l / (2 * a.bands)) ** 2
        for m in range(-l, l + 1):
            i = l * l + l + m
            v = a.sun * window * y[i] + (a.sky * math.sqrt(4 * math.pi) if i == 0 else 0.0)
            rows.append("[%.4f, %.4f, %.4f]" % tuple(v * t for t in a.tint))
    print(", ".join(rows))


if __name__ == "__main__":
    main()
