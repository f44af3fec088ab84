#!/usr/bin/env python3
"""Classical visual-odometry baselines on a TUM RGB-D sequence, with OpenCV.

Writes two TUM trajectories (camera-to-world, first pose = ground truth at the
first frame) that serve as real estimated trajectories for testing `eval`
against evo, and as baselines for `slam`:

  <out>/<name>.opencv_rgbd_odometry.txt  cv2.rgbd.RgbdOdometry (Steinbruecker et al.), frame to frame
  <out>/<name>.opencv_orb_pnp.txt        ORB (500) + BF Hamming cross-check + solvePnPRansac, frame to frame

Usage: python3 scripts/opencv_baselines.py SEQUENCE_DIR OUT_DIR NAME
Needs: pip install "opencv-contrib-python-headless<5" numpy  (OpenCV 4: cv2.rgbd)
"""
import sys, os
import numpy as np
import cv2

seq, out, name = sys.argv[1], sys.argv[2], sys.argv[3]
K = np.array([[517.3, 0, 318.6], [0, 516.5, 255.3], [0, 0, 1]])
dist = np.array([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])

def read_list(p):
    return [l.split() for l in open(p) if l.strip() and not l.startswith('#')]

assoc = read_list(os.path.join(seq, 'associations.txt'))
gt = np.array([[float(x) for x in l] for l in read_list(os.path.join(seq, 'groundtruth.txt'))])

def quat_to_R(q):  # x y z w
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1-2*(y*y+z*z), 2*(x*y-z*w), 2*(x*z+y*w)],
                     [2*(x*y+z*w), 1-2*(x*x+z*z), 2*(y*z-x*w)],
                     [2*(x*z-y*w), 2*(y*z+x*w), 1-2*(x*x+y*y)]])

def R_to_quat(R):
    w = np.sqrt(max(0.0, 1 + R[0,0] + R[1,1] + R[2,2])) / 2
    x = np.sqrt(max(0.0, 1 + R[0,0] - R[1,1] - R[2,2])) / 2
    y = np.sqrt(max(0.0, 1 - R[0,0] + R[1,1] - R[2,2])) / 2
    z = np.sqrt(max(0.0, 1 - R[0,0] - R[1,1] + R[2,2])) / 2
    x = np.copysign(x, R[2,1] - R[1,2]); y = np.copysign(y, R[0,2] - R[2,0]); z = np.copysign(z, R[1,0] - R[0,1])
    return np.array([x, y, z, w])

t0 = float(assoc[0][0])
i = np.argmin(np.abs(gt[:, 0] - t0))
T0 = np.eye(4); T0[:3, :3] = quat_to_R(gt[i, 4:8]); T0[:3, 3] = gt[i, 1:4]

def load(k):
    rgb = cv2.imread(os.path.join(seq, assoc[k][1]), cv2.IMREAD_COLOR)
    gray = cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY)
    depth = cv2.imread(os.path.join(seq, assoc[k][3]), cv2.IMREAD_UNCHANGED).astype(np.float32) / 5000.0
    return gray, depth

def write(path, poses):
    with open(path, 'w') as f:
        f.write('# timestamp tx ty tz qx qy qz qw\n')
        for a, T in zip(assoc, poses):
            q = R_to_quat(T[:3, :3]); t = T[:3, 3]
            f.write(f"{a[0]} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")
    print('wrote', path)

# RGB-D odometry: Rt maps points of the source (previous) frame into the destination (current) frame.
odo = cv2.rgbd.RgbdOdometry_create(K.astype(np.float32))
poses = [T0]; prev = load(0)
for k in range(1, len(assoc)):
    cur = load(k)
    ok, Rt = odo.compute(prev[0], prev[1], None, cur[0], cur[1], None)
    if not ok:
        Rt = np.eye(4)
    poses.append(poses[-1] @ np.linalg.inv(Rt))
    prev = cur
write(os.path.join(out, f'{name}.opencv_rgbd_odometry.txt'), poses)

# ORB + PnP: 3D points of the previous frame (depth), 2D in the current frame.
orb = cv2.ORB_create(500)
bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
poses = [T0]; prev = load(0); kp0, d0 = orb.detectAndCompute(prev[0], None)
for k in range(1, len(assoc)):
    cur = load(k); kp1, d1 = orb.detectAndCompute(cur[0], None)
    T = np.eye(4)
    if d0 is not None and d1 is not None:
        pts3, pts2 = [], []
        for m in bf.match(d0, d1):
            u, v = kp0[m.queryIdx].pt
            z = prev[1][int(round(v)), int(round(u))] if 0 <= int(round(v)) < 480 and 0 <= int(round(u)) < 640 else 0
            if z <= 0: continue
            n = cv2.undistortPoints(np.array([[[u, v]]]), K, dist)[0, 0]
            pts3.append([n[0]*z, n[1]*z, z]); pts2.append(kp1[m.trainIdx].pt)
        if len(pts3) >= 6:
            ok, rvec, tvec, inl = cv2.solvePnPRansac(np.array(pts3), np.array(pts2), K, dist, reprojectionError=3.0, iterationsCount=200)
            if ok:
                R, _ = cv2.Rodrigues(rvec); T[:3, :3] = R; T[:3, 3] = tvec[:, 0]
    poses.append(poses[-1] @ np.linalg.inv(T))
    prev, kp0, d0 = cur, kp1, d1
write(os.path.join(out, f'{name}.opencv_orb_pnp.txt'), poses)
