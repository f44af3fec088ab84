#!/usr/bin/env python3
"""Reference figures from evo (pip install evo==1.38.1) for the `eval` tests.

Runs evo's own APE/RPE (the functions behind evo_ape / evo_rpe) on the
trajectory pairs in datasets/fixtures/trajectories and writes
tests/data/evo_reference.json, which tests/eval_vs_evo.rs compares against.
Also writes the 'jittered' estimate: ground truth with dropped poses, jittered
timestamps and a smooth perturbation, to exercise association.

Usage: python3 scripts/evo_reference.py   (from the repository root)
"""
import json, copy
import numpy as np
import evo
from evo.tools import file_interface
from evo.core import sync, metrics
from evo.main_ape import ape
from evo.main_rpe import rpe

D = 'datasets/fixtures/trajectories/'
GT = D + 'fr1_rpy_head80.groundtruth.txt'

# A hard association case made from the ground truth itself.
rng = np.random.default_rng(7)
rows = [l.split() for l in open(D + 'fr1_rpy_head80.opencv_rgbd_odometry.txt') if not l.startswith('#')]
gt = file_interface.read_tum_trajectory_file(GT)
keep = [i for i in range(len(rows)) if rng.random() > 0.2]
with open(D + 'fr1_rpy_head80.jittered.txt', 'w') as f:
    f.write('# ground truth at RGB stamps, 20% dropped, stamps jittered by up to 12 ms, poses perturbed\n')
    for i in keep:
        t = float(rows[i][0]) + rng.uniform(-0.012, 0.012)
        k = int(np.argmin(np.abs(gt.timestamps - float(rows[i][0]))))
        p = gt.positions_xyz[k] + 0.01 * np.array([np.sin(i / 7), np.cos(i / 5), np.sin(i / 3)])
        q = gt.orientations_quat_wxyz[k] + 0.01 * rng.standard_normal(4)
        q = q / np.linalg.norm(q) * (-1 if i % 3 == 0 else 1)  # sign flips too
        f.write(f"{t:.6f} {p[0]:.7f} {p[1]:.7f} {p[2]:.7f} {q[1]:.7f} {q[2]:.7f} {q[3]:.7f} {q[0]:.7f}\n")

def stats(res):
    s = res.stats
    return {k: float(s[k]) for k in ['rmse', 'mean', 'median', 'std', 'min', 'max']} | {'pairs': int(len(res.np_arrays['error_array']))}

cases = []
for est in ['opencv_rgbd_odometry', 'opencv_orb_pnp', 'jittered']:
    for t_max in [0.01, 0.02]:
        ref = file_interface.read_tum_trajectory_file(GT)
        e = file_interface.read_tum_trajectory_file(D + f'fr1_rpy_head80.{est}.txt')
        ref, e = sync.associate_trajectories(ref, e, max_diff=t_max)
        for align in ['none', 'se3', 'sim3', 'scale']:
            kw = dict(align=align in ('se3', 'sim3'), correct_scale=align in ('sim3', 'scale'))
            r = ape(copy.deepcopy(ref), copy.deepcopy(e), metrics.PoseRelation.translation_part, **kw)
            cases.append({'kind': 'ate', 'estimate': est, 't_max_diff': t_max, 'align': align, 'stats': stats(r)})
            for delta, unit in [(1, 'frames'), (5, 'frames'), (0.02, 'metres')]:
                u = metrics.Unit.frames if unit == 'frames' else metrics.Unit.meters
                for rel, key in [(metrics.PoseRelation.translation_part, 'trans'), (metrics.PoseRelation.rotation_angle_deg, 'rot_deg')]:
                    r = rpe(copy.deepcopy(ref), copy.deepcopy(e), rel, delta=delta, delta_unit=u, **kw)
                    cases.append({'kind': 'rpe_' + key, 'estimate': est, 't_max_diff': t_max, 'align': align,
                                  'delta': delta, 'unit': unit, 'stats': stats(r)})
json.dump({'evo_version': evo.__version__, 'reference': 'fr1_rpy_head80.groundtruth.txt', 'cases': cases},
          open('tests/data/evo_reference.json', 'w'), indent=1)
print(len(cases), 'cases written with evo', evo.__version__)
