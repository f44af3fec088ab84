#!/usr/bin/env python3
"""Open3D's dense RGB-D SLAM (frame-to-model tracking against a TSDF) on a TUM-layout
sequence: the dense classical reference of the README's RGB-D SLAM tables.

It is Open3D's own example `examples/python/t_reconstruction_system/dense_slam.py` with that
example's defaults (voxels of 3.0 / 512 m = 5.9 mm, 16^3-voxel blocks, depth cut at 3 m,
truncation 8 voxels, odometry distance threshold 7 cm): each frame is tracked against a
ray-cast of the model built from the frames before it (`track_frame_to_model`: point-to-plane
ICP on a pyramid, then integrated at the tracked pose). No loop closure, no lens distortion.

Writes a TUM trajectory (camera-to-world; the first pose is the ground truth at the first
frame, so `eval ate --align none` is meaningful too), then prints the frames/s.

Usage:
  python3 scripts/open3d_baseline.py SEQUENCE_DIR OUT.txt [--first N] [--count N]
      [--camera fx fy cx cy] [--depth-scale 5000] [--device CPU:0]
Camera: the sequence's camera.toml if it has one, else TUM freiburg1 (517.3, 516.5, 318.6,
255.3). Needs: python3 -m venv ~/.venvs/o3d && ~/.venvs/o3d/bin/pip install open3d numpy
(Open3D 0.20 on Python 3.11 was used for the README's figures).
"""
import argparse
import os
import sys
import time

import numpy as np
import open3d as o3d
import open3d.core as o3c


def read_list(path):
    with open(path) as f:
        return [l.split() for l in f if l.strip() and not l.startswith('#')]


def camera_of(seq, given):
    if given:
        return given
    toml = os.path.join(seq, 'camera.toml')
    if os.path.exists(toml):
        vals = {}
        for line in open(toml):
            line = line.split('#')[0].strip()
            if '=' in line:
                k, v = (s.strip() for s in line.split('=', 1))
                vals[k] = v
        try:
            return [float(vals[k]) for k in ('fx', 'fy', 'cx', 'cy')]
        except KeyError as e:
            sys.exit(f'{toml}: no {e.args[0]}')
    return [517.3, 516.5, 318.6, 255.3]


def quat_to_R(q):  # x y z w
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def R_to_quat(R):
    w = np.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = np.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = np.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = np.copysign(x, R[2, 1] - R[1, 2])
    y = np.copysign(y, R[0, 2] - R[2, 0])
    z = np.copysign(z, R[1, 0] - R[0, 1])
    return np.array([x, y, z, w])


def first_pose(seq, stamp):
    """Ground-truth camera-to-world pose nearest to `stamp` (identity without ground truth)."""
    path = os.path.join(seq, 'groundtruth.txt')
    if not os.path.exists(path):
        return np.identity(4)
    gt = np.array([[float(x) for x in l] for l in read_list(path)])
    row = gt[np.argmin(np.abs(gt[:, 0] - stamp))]
    T = np.identity(4)
    T[:3, :3] = quat_to_R(row[4:8])
    T[:3, 3] = row[1:4]
    return T


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('sequence')
    ap.add_argument('out')
    ap.add_argument('--first', type=int, default=0)
    ap.add_argument('--count', type=int, default=0, help='frames (0: to the end)')
    ap.add_argument('--camera', type=float, nargs=4, metavar=('FX', 'FY', 'CX', 'CY'))
    ap.add_argument('--depth-scale', type=float, default=5000.0)
    ap.add_argument('--device', default='CPU:0')
    # Open3D's dense_slam example defaults.
    ap.add_argument('--voxel-size', type=float, default=3.0 / 512)
    ap.add_argument('--depth-min', type=float, default=0.1)
    ap.add_argument('--depth-max', type=float, default=3.0)
    ap.add_argument('--trunc-voxel-multiplier', type=float, default=8.0)
    ap.add_argument('--odometry-distance-thr', type=float, default=0.07)
    ap.add_argument('--block-count', type=int, default=40000)
    a = ap.parse_args()

    assoc = read_list(os.path.join(a.sequence, 'associations.txt'))
    end = len(assoc) if a.count <= 0 else min(len(assoc), a.first + a.count)
    frames = assoc[a.first:end]
    if len(frames) < 2:
        sys.exit(f'{a.sequence}: fewer than two frames from {a.first}')
    fx, fy, cx, cy = camera_of(a.sequence, a.camera)
    device = o3c.Device(a.device)
    intrinsic = o3c.Tensor([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], o3c.Dtype.Float64)

    T = o3c.Tensor(np.identity(4))
    model = o3d.t.pipelines.slam.Model(a.voxel_size, 16, a.block_count, T, device)
    read = lambda rel: o3d.t.io.read_image(os.path.join(a.sequence, rel)).to(device)
    depth0 = read(frames[0][3])
    input_frame = o3d.t.pipelines.slam.Frame(depth0.rows, depth0.columns, intrinsic, device)
    raycast_frame = o3d.t.pipelines.slam.Frame(depth0.rows, depth0.columns, intrinsic, device)
    start = first_pose(a.sequence, float(frames[0][0]))
    lines = []
    t0 = time.time()
    for i, (t_rgb, rgb, _, depth) in enumerate(frames):
        input_frame.set_data_from_image('depth', read(depth))
        input_frame.set_data_from_image('color', read(rgb))
        if i > 0:
            result = model.track_frame_to_model(input_frame, raycast_frame, a.depth_scale,
                                                a.depth_max, a.odometry_distance_thr)
            T = T @ result.transformation
        model.update_frame_pose(i, T)
        model.integrate(input_frame, a.depth_scale, a.depth_max, a.trunc_voxel_multiplier)
        model.synthesize_model_frame(raycast_frame, a.depth_scale, a.depth_min, a.depth_max,
                                     a.trunc_voxel_multiplier, False)
        P = start @ T.cpu().numpy()
        q = R_to_quat(P[:3, :3])
        lines.append(f'{t_rgb} {P[0, 3]:.6f} {P[1, 3]:.6f} {P[2, 3]:.6f} '
                     f'{q[0]:.6f} {q[1]:.6f} {q[2]:.6f} {q[3]:.6f}\n')
    secs = time.time() - t0
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    tmp = a.out + '.tmp'
    with open(tmp, 'w') as f:
        f.write('# Open3D dense SLAM (frame to model), scripts/open3d_baseline.py\n')
        f.writelines(lines)
    os.replace(tmp, a.out)
    print(f'{len(frames)} frames ({a.first}..{end - 1}) in {secs:.1f} s '
          f'({len(frames) / secs:.2f} frames/s) -> {a.out}')


if __name__ == '__main__':
    try:
        main()
    except (OSError, ValueError, RuntimeError, IndexError) as e:
        # Unreadable files, malformed lists or camera values, Open3D failures: one line.
        sys.exit(f'open3d_baseline: {e}')
