"""Crops of EXR renders side by side, 2x, as one sRGB PNG (docs/images/thin_frame_ground.png).

    python3 research/experiments/thin/side_by_side.py OUT.png X0 Y0 W H A.exr B.exr ...
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
from visibility_table import rgb, srgb8, write_png  # noqa: E402


def main():
    out, (x0, y0, cw, ch), paths = sys.argv[1], map(int, sys.argv[2:6]), sys.argv[6:]
    imgs = [rgb(p) for p in paths]
    gap, z = 4, 2
    W = len(imgs) * cw * z + (len(imgs) - 1) * gap
    pix = [(255, 255, 255)] * (W * ch * z)
    for k, (w, _, planes) in enumerate(imgs):
        for y in range(ch * z):
            for x in range(cw * z):
                i = (y0 + y // z) * w + x0 + x // z
                pix[y * W + k * (cw * z + gap) + x] = tuple(srgb8(planes[c][i]) for c in range(3))
    write_png(out, W, ch * z, pix)


if __name__ == "__main__":
    main()
