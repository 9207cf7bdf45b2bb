"""Side-by-side pictures of cells of lights_table.py (docs/results/lights.md's table).

Usage: python3 research/experiments/accuracy/lights_sheet.py OUTDIR SHEET.png [--suffix S]
                                                             [--cells mesh:map,...]

One row per cell, four columns: the full-map truth (reference --lighting envmap), the default
render (its lights found in the map), "lights": "none" (the SH light alone) and --no-shadows, read
from OUTDIR/img as lights_table.py wrote them (--suffix: the renders' suffix of that run). Linear
values are shown through the sRGB curve, clamped at 1, with no other tone mapping, so the columns
compare as the metric does.
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import visibility_table as vt  # noqa: E402

CELLS = "scorpion:night,koala:city,spot_triangulated:interior,bob_tri:night"


def main():
    args = sys.argv[1:]
    if len(args) < 2:
        sys.exit(__doc__)
    out, sheet = args[0], args[1]
    opts, _ = vt.parse_options(args[2:], {"--suffix": "", "--cells": CELLS})
    rows = []
    for cell in opts["--cells"].split(","):
        mesh, env = cell.split(":")
        base = os.path.join(out, "img", "%s_%s_" % (mesh, env))
        rows.append([base + "truth.exr"] + [base + k + opts["--suffix"] + ".exr"
                                            for k in ("lights", "none", "no-shadows")])
    tiles = [[vt.rgb(p) for p in row] for row in rows]
    w, h = tiles[0][0][0], tiles[0][0][1]
    if any(t[0] != w or t[1] != h for row in tiles for t in row):
        sys.exit("lights_sheet: the images differ in size")
    W, H = w * 4, h * len(rows)
    pixels = [(0, 0, 0)] * (W * H)
    for r, row in enumerate(tiles):
        for c, (_, _, ch) in enumerate(row):
            for y in range(h):
                for x in range(w):
                    i = y * w + x
                    pixels[(r * h + y) * W + c * w + x] = tuple(vt.srgb8(ch[k][i]) for k in range(3))
    vt.write_png(sheet, W, H, pixels)


if __name__ == "__main__":
    main()
