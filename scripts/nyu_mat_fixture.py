#!/usr/bin/env python3
"""Writes datasets/fixtures/nyuv2_mat/nyu_depth_v2_labeled_fixture.mat, a small stand-in
for the official NYU Depth v2 `nyu_depth_v2_labeled.mat` (MATLAB v7.3), for the tests of
src/dataset/nyu_mat.rs.

Same layout as the official file: HDF5 after a 512-byte MATLAB user block; datasets with
h5py shapes `images` (1449, 3, 640, 480) uint8, `depths` (1449, 640, 480) float32 metres,
`labels` (1449, 640, 480) uint16 894-class ids (0 = unlabelled), i.e. MATLAB's column-major
dims reversed (`images[i, c, x, y]` is channel c of pixel (x, y)); chunked + deflate.
Only images 433 and 464 (1-based) hold data, taken from datasets/fixtures/nyuv2 (RGB; depth
PNG / 5000; 40-class labels mapped back to the smallest 894-class id that
datasets/meta/nyuv2/nyu894_to_nyu40.csv maps to them, void 255 -> 0). The other 1447
images are unwritten chunks (zeros), which take no space. Chunks hold 2 images and do not
tile the image evenly (256 x 192), so a reader must cut windows out of chunks and clip
edge chunks.

Usage: pip install h5py pillow; python3 scripts/nyu_mat_fixture.py   (from the repository root)
"""
import csv
import numpy as np
import h5py
from PIL import Image

SRC = 'datasets/fixtures/nyuv2/'
OUT = 'datasets/fixtures/nyuv2_mat/nyu_depth_v2_labeled_fixture.mat'
N, W, H = 1449, 640, 480
IDS = [433, 464]

# 40-class (0-based) -> smallest 894-class id mapping to it.
to894 = {}
with open('datasets/meta/nyuv2/nyu894_to_nyu40.csv') as f:
    for row in csv.DictReader(f):
        to894.setdefault(int(row['id40']) - 1, int(row['id894']))

with h5py.File(OUT, 'w', userblock_size=512) as f:
    opts = dict(compression='gzip', compression_opts=9)
    images = f.create_dataset('images', (N, 3, W, H), np.uint8, chunks=(2, 1, 256, 192), **opts)
    depths = f.create_dataset('depths', (N, W, H), np.float32, chunks=(2, 256, 192), **opts)
    labels = f.create_dataset('labels', (N, W, H), np.uint16, chunks=(2, 256, 192), **opts)
    for d, cls in ((images, 'uint8'), (depths, 'single'), (labels, 'uint16')):
        d.attrs['MATLAB_class'] = np.bytes_(cls)
    for i in IDS:
        rgb = np.asarray(Image.open(f'{SRC}{i:06d}_rgb.png').convert('RGB'))  # (H, W, 3)
        depth = np.asarray(Image.open(f'{SRC}{i:06d}_depth.png'), dtype=np.uint16)
        seg40 = np.asarray(Image.open(f'{SRC}{i:06d}_seg40.png'))
        assert rgb.shape == (H, W, 3) and depth.shape == (H, W) and seg40.shape == (H, W)
        lut = np.zeros(256, np.uint16)  # 255 (void) and anything unknown -> 0 (unlabelled)
        for c, k in to894.items():
            lut[c] = k
        assert all(v == 255 or v in to894 for v in np.unique(seg40))
        images[i - 1] = rgb.transpose(2, 1, 0)
        depths[i - 1] = (depth.astype(np.float64) / 5000.0).astype(np.float32).T
        labels[i - 1] = lut[seg40].T

# MATLAB's 128-byte MAT-file header at the start of the user block: text, subsystem
# offset, version 0x0200 and the 'IM' endianness mark.
text = b'MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Thu Jan  1 00:00:00 2015 HDF5 schema 1.00 .'
header = text.ljust(116, b' ') + b'\0' * 8 + b'\x00\x02' + b'IM'
with open(OUT, 'r+b') as f:
    f.write(header)
print(OUT)
