#!/usr/bin/env python3
"""Makes an object mask PNG from a bounding box: the box itself, or (default) OpenCV's
GrabCut seeded with the box. For trying `b2tf estimate` on photos that come with boxes only.

    pip install opencv-python-headless numpy
    python3 tools/box_to_mask.py IMAGE X1 Y1 X2 Y2 OUT.png [--box-only]
"""

import argparse
import sys

import cv2
import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("image")
    ap.add_argument("box", nargs=4, type=int, metavar=("X1", "Y1", "X2", "Y2"))
    ap.add_argument("out")
    ap.add_argument("--box-only", action="store_true", help="write the filled box, no segmentation")
    ap.add_argument("--iterations", type=int, default=8)
    a = ap.parse_args()
    img = cv2.imread(a.image, cv2.IMREAD_COLOR)
    if img is None:
        print(f"cannot read image {a.image}", file=sys.stderr)
        return 1
    h, w = img.shape[:2]
    x1, y1, x2, y2 = a.box
    if not (0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h):
        print(f"box {a.box} is not inside the {w}x{h} image", file=sys.stderr)
        return 1
    mask = np.zeros((h, w), np.uint8)
    if a.box_only:
        mask[y1:y2, x1:x2] = 255
    else:
        gc = np.zeros((h, w), np.uint8)
        bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
        cv2.grabCut(img, gc, (x1, y1, x2 - x1, y2 - y1), bgd, fgd, a.iterations, cv2.GC_INIT_WITH_RECT)
        fg = (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)
        # Keep the largest connected component: GrabCut leaves specks in clutter.
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg.astype(np.uint8))
        if n > 1:
            biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            mask[labels == biggest] = 255
    cv2.imwrite(a.out, mask)
    print(f"wrote {a.out}: {int((mask > 0).sum())} object pixels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
