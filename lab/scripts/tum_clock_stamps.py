#!/usr/bin/env python3
"""A copy of a TUM RGB-D sequence whose colour stamps lie on the camera's frame clock.

TUM RGB-D stamps each Kinect image when it reached the recording PC. On fr1_rpy the gaps
between consecutive colour stamps run 27-40 ms around the camera's 33.3 ms period, and where
the camera turns fast a stamp a few ms off moves the ground truth's projection by several
pixels (lab/notes/fpfdcnn-results.md, *Colour stamps on the camera's clock*). This script fits the colour stamps
to a regular clock, t_k = t0 + n_k * period, by least squares (n_k: each frame's number of
periods after the first, rounded; dropped frames keep their place), and writes a copy of the
sequence with those stamps in rgb.txt and associations.txt. Depth stamps, depth.txt,
groundtruth.txt, camera.toml and the image files are kept (images and depth as symbolic
links). A diagnostic: it changes the data, so figures measured on the copy are not those of
the benchmark.

Usage: python3 lab/scripts/tum_clock_stamps.py SEQUENCE_DIR OUT_DIR [--rate 30]
Needs Python 3 only.
"""
import argparse
import os
import shutil
import sys


def data_lines(path):
    with open(path) as f:
        return [l.split() for l in f if l.strip() and not l.startswith('#')]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('sequence')
    ap.add_argument('out')
    ap.add_argument('--rate', type=float, default=30.0, help='nominal frame rate, Hz')
    a = ap.parse_args()
    if not 1.0 <= a.rate <= 1000.0:
        sys.exit(f'--rate must be in [1, 1000] Hz, got {a.rate}')
    seq, out = os.path.abspath(a.sequence), os.path.abspath(a.out)
    if seq == out:
        sys.exit('OUT_DIR must differ from SEQUENCE_DIR')
    for name in ('rgb.txt', 'associations.txt'):
        if not os.path.isfile(os.path.join(seq, name)):
            sys.exit(f'{os.path.join(seq, name)}: missing (a TUM sequence with associations.txt is needed)')

    rgb = data_lines(os.path.join(seq, 'rgb.txt'))
    try:
        stamps = [float(l[0]) for l in rgb]
    except (ValueError, IndexError) as e:
        sys.exit(f'{os.path.join(seq, "rgb.txt")}: {e}')
    if len(stamps) < 3 or any(b <= a_ for a_, b in zip(stamps, stamps[1:])):
        sys.exit(f'{os.path.join(seq, "rgb.txt")}: needs at least 3 increasing stamps')
    n = [round((t - stamps[0]) * a.rate) for t in stamps]
    if len(set(n)) != len(n):
        sys.exit(f'two colour stamps fall on the same period at {a.rate} Hz: is --rate right?')
    m = len(n)
    sn, st = sum(n), sum(stamps)
    snn = sum(x * x for x in n)
    snt = sum(x * t for x, t in zip(n, stamps))
    period = (m * snt - sn * st) / (m * snn - sn * sn)
    t0 = (st - period * sn) / m
    fitted = [t0 + period * x for x in n]
    resid = [(t - f) * 1000 for t, f in zip(stamps, fitted)]
    rms = (sum(r * r for r in resid) / m) ** 0.5
    print(f'{m} colour stamps: period {period * 1000:.3f} ms, stamps minus clock RMS {rms:.2f} ms, '
          f'range {min(resid):.1f} to {max(resid):.1f} ms')

    new = {l[0]: f'{f:.6f}' for l, f in zip(rgb, fitted)}
    os.makedirs(out, exist_ok=True)
    for d in ('rgb', 'depth'):
        link = os.path.join(out, d)
        if not os.path.lexists(link):
            os.symlink(os.path.join(seq, d), link)
    for name in ('depth.txt', 'groundtruth.txt', 'camera.toml'):
        if os.path.isfile(os.path.join(seq, name)):
            shutil.copyfile(os.path.join(seq, name), os.path.join(out, name))
    with open(os.path.join(out, 'rgb.txt'), 'w') as f:
        f.write('# colour stamps fitted to the frame clock by lab/scripts/tum_clock_stamps.py\n')
        for l in rgb:
            f.write(' '.join([new[l[0]]] + l[1:]) + '\n')
    with open(os.path.join(out, 'associations.txt'), 'w') as f:
        f.write('# colour stamps fitted to the frame clock by lab/scripts/tum_clock_stamps.py\n')
        for l in data_lines(os.path.join(seq, 'associations.txt')):
            if l[0] not in new:
                sys.exit(f'associations.txt: colour stamp {l[0]} is not in rgb.txt')
            f.write(' '.join([new[l[0]]] + l[1:]) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
