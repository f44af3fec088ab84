"""Montage of synthetic frames for the README: RGB | depth | NYU40 labels per row.

python3 lab/scripts/synth_figure.py OUT.png SEQ_DIR:FRAME [SEQ_DIR:FRAME ...]
(reads rgb/, depth/ (5000 per metre, 0 = no reading) and labels/ (0-based NYU40, 255 void)
of TUM-layout sequences written by `synth`; needs Pillow and NumPy).
"""
import csv, sys, os
import numpy as np
from PIL import Image, ImageDraw

root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
palette = np.zeros((256, 3), np.uint8)
with open(os.path.join(root, "datasets/meta/nyuv2/nyu40_colormap_scannet.csv")) as f:
    for row in csv.DictReader(f):
        k = int(row["nyu40id"])
        if k >= 1:
            palette[k - 1] = (int(row["r"]), int(row["g"]), int(row["b"]))
palette[255] = (0, 0, 0)


def turbo_like(x):
    # A perceptual blue->yellow->red ramp (simple piecewise, no matplotlib needed).
    stops = np.array([[48, 18, 59], [40, 130, 230], [50, 200, 130], [240, 220, 50], [220, 50, 30]], float)
    x = np.clip(x, 0, 1) * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)
    t = (x - i)[..., None]
    return (stops[i] * (1 - t) + stops[i + 1] * t).astype(np.uint8)


def frame(seq, k):
    names = sorted(os.listdir(os.path.join(seq, "rgb")))
    n = names[k]
    rgb = np.array(Image.open(os.path.join(seq, "rgb", n)).convert("RGB"))
    d = np.array(Image.open(os.path.join(seq, "depth", n))).astype(float) / 5000.0
    lab = np.array(Image.open(os.path.join(seq, "labels", n)))
    dc = turbo_like(d / 6.0)
    dc[d == 0] = 0
    return [rgb, dc, palette[lab]]


out, specs = sys.argv[1], sys.argv[2:]
rows = [frame(s.rsplit(":", 1)[0], int(s.rsplit(":", 1)[1])) for s in specs]
w, h = 320, 240
canvas = Image.new("RGB", (3 * w + 8, len(rows) * (h + 4) + 20), "white")
draw = ImageDraw.Draw(canvas)
for c, title in enumerate(["RGB", "depth (0-6 m, black: no reading)", "NYU40 labels"]):
    draw.text((c * (w + 4) + 4, 4), title, fill="black")
for r, imgs in enumerate(rows):
    for c, img in enumerate(imgs):
        resample = Image.NEAREST if c == 2 else Image.BILINEAR
        canvas.paste(Image.fromarray(img).resize((w, h), resample), (c * (w + 4), 20 + r * (h + 4)))
canvas.save(out, optimize=True)
print("wrote", out)
