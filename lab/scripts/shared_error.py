#!/usr/bin/env python3
"""How much of two trajectories' error they share: is a gap between two methods larger
than what the ground truth itself can decide?

Each estimate is aligned to the ground truth (SE(3), Umeyama / Horn, as evo's ATE) and its
per-frame position error taken; then, for the two estimates A and B, on the frames both have:
their ATEs, the RMS of the difference of their error vectors, the correlation of the error
vectors (sum a.b / sqrt(sum a.a sum b.b)), the Sim(3) scale and Sim(3)-aligned ATE of each,
and the RMS of the relative-pose translation and rotation error over spans of 1, 10 and 40
frames. Errors that point the same way (correlation near 1) and differ by less than either's
ATE come from something both read: the ground truth's own error, or the sensor.

Usage: python3 lab/scripts/shared_error.py GROUNDTRUTH.txt A.txt B.txt
TUM trajectory files (`t tx ty tz qx qy qz qw`); each estimate's stamps are matched to the
nearest ground-truth stamp within 20 ms. Needs: numpy.
"""
import sys

import numpy as np


def quat_to_matrix(q):  # x y z w
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def load(path):
    poses = {}
    for line in open(path):
        if not line.strip() or line.startswith('#'):
            continue
        v = np.array([float(x) for x in line.split()[:8]])
        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(v[4:8])
        T[:3, 3] = v[1:4]
        poses[v[0]] = T
    return poses


def associate(est, gt, max_dt=0.02):
    stamps = np.array(sorted(gt))
    pairs = {}
    for t in sorted(est):
        i = np.searchsorted(stamps, t)
        near = [s for s in stamps[max(i - 1, 0):i + 1] if abs(s - t) <= max_dt]
        if near:
            pairs[t] = gt[min(near, key=lambda s: abs(s - t))]
    return pairs


def umeyama(a, b, with_scale):
    """R, t, s minimising |s R a + t - b|^2 over the rows."""
    ma, mb = a.mean(0), b.mean(0)
    ac, bc = a - ma, b - mb
    U, S, Vt = np.linalg.svd(bc.T @ ac / len(a))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    s = np.trace(np.diag(S) @ D) / (ac ** 2).sum(1).mean() if with_scale else 1.0
    return R, mb - s * R @ ma, s


def rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def angle_deg(R):
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    gt = load(sys.argv[1])
    names = sys.argv[2:]
    ests = [load(p) for p in names]
    matched = [associate(e, gt) for e in ests]
    common = sorted(set(matched[0]) & set(matched[1]))
    if len(common) < 3:
        sys.exit('fewer than 3 frames with ground truth in both estimates')
    errors = []
    for name, est, truth in zip(names, ests, matched):
        a = np.array([est[t][:3, 3] for t in common])
        b = np.array([truth[t][:3, 3] for t in common])
        R, t, _ = umeyama(a, b, False)
        err = a @ R.T + t - b
        errors.append(err)
        R3, t3, s = umeyama(a, b, True)
        sim3 = s * a @ R3.T + t3 - b
        spans = []
        for k in (1, 10, 40):
            dt, dr = [], []
            for i in range(len(common) - k):
                g = np.linalg.inv(truth[common[i]]) @ truth[common[i + k]]
                e = np.linalg.inv(est[common[i]]) @ est[common[i + k]]
                d = np.linalg.inv(g) @ e
                dt.append(np.linalg.norm(d[:3, 3]))
                dr.append(angle_deg(d[:3, :3]))
            if dt:
                spans.append(f'{k}: {1000 * rms(dt):.1f} mm {rms(dr):.2f} deg')
        print(f'{name}: {len(common)} frames, ATE {1000 * rms(np.linalg.norm(err, axis=1)):.1f} mm, '
              f'Sim(3) scale {s:.3f}, Sim(3) ATE {1000 * rms(np.linalg.norm(sim3, axis=1)):.1f} mm; '
              f'RPE over ' + ', '.join(spans))
    a, b = errors
    corr = (a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum())
    print(f'error vectors: RMS of their difference {1000 * rms(np.linalg.norm(a - b, axis=1)):.1f} mm, '
          f'correlation {corr:.2f}')


if __name__ == '__main__':
    main()
