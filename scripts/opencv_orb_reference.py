#!/usr/bin/env python3
"""OpenCV's ORB keypoints and descriptors of one image, the reference that
`features::orb` is tested against.

Usage: python3 scripts/opencv_orb_reference.py IMAGE OUT.txt
Writes one line per keypoint: `x y octave angle response descriptor_hex`
(cv2.ORB_create(500) on cv2.cvtColor(imread(IMAGE), BGR2GRAY)).
Needs: pip install opencv-python-headless numpy
"""
import sys
import cv2

img, out = sys.argv[1], sys.argv[2]
gray = cv2.cvtColor(cv2.imread(img, cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)
kps, desc = cv2.ORB_create(500).detectAndCompute(gray, None)
with open(out, 'w') as f:
    f.write(f'# cv2.ORB_create(500), OpenCV {cv2.__version__}, {img}\n')
    f.write('# x y octave angle_deg response descriptor_hex\n')
    for k, d in zip(kps, desc):
        f.write(f'{k.pt[0]:.4f} {k.pt[1]:.4f} {k.octave} {k.angle:.4f} {k.response:.9g} {bytes(d).hex()}\n')
print('wrote', out, len(kps), 'keypoints')
