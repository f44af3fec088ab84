#!/usr/bin/env python3
"""A 7-Scenes-layout folder from a TUM-layout copy made with the default registration of
`dataset seven-scenes` (the inverse of that conversion), to check the converter on data that
has no original files beside it (README, *Data formats*, 7-Scenes):

    python3 lab/scripts/seven_scenes_from_tum.py ../shared/data/7scenes_redkitchen_0_799 \
        /tmp/redkitchen_raw --first 700 --count 100
    cargo run --release --bin dataset -- seven-scenes /tmp/redkitchen_raw --out /tmp/redkitchen_tum

Each registered depth reading goes back into the depth camera (585, 585, 320, 240) by
`X_depth = X_colour - offset` (nearest surface wins; no reading = 65535, millimetres), each
colour-camera pose back to the depth camera (`T_wd = T_wc` translated by `+offset`), each
colour image is written as PNG. Files are named by frame number, n = (stamp - 1000) * 30;
--first and --count select rows of associations.txt. Needs numpy and Pillow.
"""
import argparse
import os

import numpy as np
from PIL import Image

COLOUR = (527.0, 527.0, 323.0, 236.0)  # fx, fy, cx, cy
DEPTH = (585.0, 585.0, 320.0, 240.0)
OFFSET = np.array([-0.035, 0.005, 0.0])  # X_colour = X_depth + OFFSET, metres


def quat_to_matrix(q):
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rows(path):
    return [line.split() for line in open(path) if line.strip() and not line.startswith("#")]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tum", help="TUM-layout folder (associations.txt, groundtruth.txt)")
    ap.add_argument("out", help="output folder (7-Scenes layout)")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--count", type=int, default=None)
    a = ap.parse_args()
    assoc = rows(os.path.join(a.tum, "associations.txt"))
    gt = {round(float(r[0]), 4): [float(v) for v in r[1:8]] for r in rows(os.path.join(a.tum, "groundtruth.txt"))}
    end = len(assoc) if a.count is None else min(len(assoc), a.first + a.count)
    os.makedirs(a.out, exist_ok=True)
    fxc, fyc, cxc, cyc = COLOUR
    fxd, fyd, cxd, cyd = DEPTH
    for i in range(a.first, end):
        stamp, rgb, _, depth = assoc[i][:4]
        number = round((float(stamp) - 1000.0) * 30.0)
        stem = os.path.join(a.out, "frame-%06d" % number)
        g = gt.get(round(float(stamp), 4))
        if g is None:
            raise SystemExit("%s: no ground-truth pose at %s" % (os.path.join(a.tum, "groundtruth.txt"), stamp))
        twc = np.eye(4)
        twc[:3, :3] = quat_to_matrix(g[3:7])
        twc[:3, 3] = g[0:3]
        tcd = np.eye(4)
        tcd[:3, 3] = OFFSET
        np.savetxt(stem + ".pose.txt", twc @ tcd, fmt="%.9e", delimiter="\t")
        Image.open(os.path.join(a.tum, rgb)).save(stem + ".color.png")
        dc = np.asarray(Image.open(os.path.join(a.tum, depth))).astype(np.float64) / 5000.0
        v, u = np.nonzero(dc > 0)
        z = dc[v, u]
        x = np.stack([(u - cxc) * z / fxc, (v - cyc) * z / fyc, z], 1) - OFFSET
        ud = np.round(fxd * x[:, 0] / x[:, 2] + cxd).astype(int)
        vd = np.round(fyd * x[:, 1] / x[:, 2] + cyd).astype(int)
        ok = (ud >= 0) & (ud < 640) & (vd >= 0) & (vd < 480)
        d = np.full((480, 640), np.inf)
        np.minimum.at(d, (vd[ok], ud[ok]), x[ok, 2])
        mm = np.where(np.isfinite(d), np.round(d * 1000.0), 65535).astype(np.uint16)
        Image.fromarray(mm).save(stem + ".depth.png")


if __name__ == "__main__":
    main()
