#!/usr/bin/env python3
"""Prints the 4-band SH lighting of a sun over a uniform sky as the "sh" rows of a scene JSON.

The sun is a delta of power `sun` in direction `--dir`, projected onto real SH with the
Condon-Shortley phase (penumbra's convention: index l*l + l + m, Y_1,-1 = -0.488603 y,
Y_1,0 = 0.488603 z, Y_1,1 = -0.488603 x), each band l scaled by the Hann window
cos^2(pi l / 8) = 1, 0.85, 0.5, 0.15 against ringing; the sky adds `sky` radiance from every
direction (coefficient 0 += sky * sqrt(4 pi)). `--tint` scales the three channels. Standard
library only. Example (the shape-from-shadow experiments' lighting):

    python3 sun_sh.py --dir 0.55 0.45 -0.70 --sun 2 --sky 0.5 --tint 1 0.97 0.9
"""
import argparse
import math


def sh_band3(x, y, z):
    """Real SH Y_i(x, y, z), i < 16, of a unit vector (Condon-Shortley phase)."""
    return [
        0.282095,
        -0.488603 * y, 0.488603 * z, -0.488603 * x,
        1.092548 * x * y, -1.092548 * y * z, 0.315392 * (3 * z * z - 1),
        -1.092548 * x * z, 0.546274 * (x * x - y * y),
        -0.590044 * y * (3 * x * x - y * y), 2.890611 * x * y * z,
        -0.457046 * y * (5 * z * z - 1), 0.373176 * z * (5 * z * z - 3),
        -0.457046 * x * (5 * z * z - 1), 1.445306 * z * (x * x - y * y),
        -0.590044 * x * (x * x - 3 * y * y),
    ]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", type=float, nargs=3, required=True, help="towards the sun")
    ap.add_argument("--sun", type=float, default=2.0, help="the sun's power")
    ap.add_argument("--sky", type=float, default=0.5, help="the sky's radiance")
    ap.add_argument("--tint", type=float, nargs=3, default=[1.0, 1.0, 1.0])
    a = ap.parse_args()
    n = math.sqrt(sum(v * v for v in a.dir))
    if n == 0:
        ap.error("--dir must not be zero")
    y = sh_band3(*(v / n for v in a.dir))
    rows = []
    for l in range(4):
        window = math.cos(math.pi * l / 8) ** 2
        for m in range(-l, l + 1):
            i = l * l + l + m
            v = a.sun * window * y[i] + (a.sky * math.sqrt(4 * math.pi) if i == 0 else 0.0)
            rows.append("[%.4f, %.4f, %.4f]" % tuple(v * t for t in a.tint))
    print(", ".join(rows))


if __name__ == "__main__":
    main()
