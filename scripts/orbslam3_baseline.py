#!/usr/bin/env python3
"""ORB-SLAM3 (RGB-D and monocular) on a TUM-layout sequence, scored with this project's `eval`:
the feature-based SLAM reference beside Open3D and OpenCV in the results tables.

ORB-SLAM3 runs through the `pyorbslam3` wheel (Python bindings with ORB-SLAM3, GPL-3.0; optional,
never needed by the build or the tests):

  python3 -m venv ~/.venvs/orbslam3
  ~/.venvs/orbslam3/bin/pip install -r scripts/requirements-baselines.txt

Usage:
  python3 scripts/orbslam3_baseline.py SEQUENCE_DIR [--camera fr1|fr2|fr3|CAMERA.toml]
      [--mode rgbd|mono|both] [--first N] [--count N] [--vocabulary ORBvoc.txt]
      [--vocab-images DIR] [--out DIR] [--realtime] [--verbose]

SEQUENCE_DIR is in the TUM layout: rgb.txt and depth.txt (or associations.txt), the images, and
groundtruth.txt for the score. Frames are the associated RGB-D pairs in order (associations.txt
where it exists, else rgb.txt and depth.txt paired by nearest time stamp, at most 20 ms apart);
--first/--count select from them as `slam`'s --first/--max-frames do; monocular mode reads
their colour images only. Camera: a preset (fr1, fr2, fr3: configs/cameras/*.toml) or a
camera.toml in the project's format; by default the sequence's camera.toml, else fr1. Depth
images are 16-bit, metres = value / --depth-scale (5000, TUM's). ORB-SLAM3's settings are those
of its TUM examples (Examples/RGB-D/TUM1.yaml): 1000 ORB features, 8 levels of scale 1.2, FAST
thresholds 20 / 7, depth threshold 40 baselines of 0.07732 m.

The ORB vocabulary. ORB-SLAM3 needs a DBoW2 vocabulary of ORB descriptors; it was trained with
ORBvoc.txt (k = 10, L = 6, up to a million words, trained by its authors on a large image set;
139 MB): pass it
with --vocabulary where you have it (ORB-SLAM3's repository, Vocabulary/ORBvoc.txt.tar.gz).
Without it this script builds a small DBoW2 text vocabulary itself, by hierarchical k-means on
binary descriptors (kmeans++ seeding, majority-vote centres, Hamming distance, as DBoW2 does) over
OpenCV ORB features (1000 a frame, 8 levels of scale 1.2) of the sequence's own selected frames
(at most 200, evenly spaced), or of the images in --vocab-images DIR; k = 10, L = 4 by default,
TF-IDF weights with L1 scoring (ORBvoc.txt's types). It is cached under --vocab-cache. Such a
vocabulary is far smaller than ORBvoc.txt and seen only these images, so ORB-SLAM3's place
recognition (relocalisation, loop closing, map merging) is weaker with it; with L <= 4 every
feature also falls in one node of ORB-SLAM3's feature vector (it looks 4 levels up from the
words), so its bag-of-words matching becomes brute force among all features. The figures this
script prints say which vocabulary they used.

Per mode it writes OUT/MODE/: settings.yaml (ORB-SLAM3's settings), trajectory.txt (TUM format,
camera-to-world, seconds: every frame ORB-SLAM3 localised in its largest map, each as its
reference keyframe's final pose times the frame's relative pose: ORB-SLAM3's own trajectory
export, SaveTrajectoryEuRoC, with the time stamps back in seconds), tracking.txt (the pose each
track call returned, as it was then), orbslam3.log (ORB-SLAM3's console output, unless
--verbose) and ate.json; then OUT/summary.md and OUT/summary.json. Scores: `eval ate GT TRAJ
--align se3` for RGB-D and `--align sim3` for monocular (whose scale is arbitrary; the table
gives the Sim(3) scale). Frames/s: of the track calls alone, and of the whole frame loop with
image reading and decoding (as `slam`'s overall figure counts its loading); the start-up, whose
time is mostly loading the vocabulary, is timed apart. Frames are fed as fast as ORB-SLAM3 takes
them unless --realtime paces them to their time stamps, as ORB-SLAM3's examples do (the loop's
frames/s then counts the waits).
ORB-SLAM3 is multi-threaded and not deterministic: repeated runs differ, monocular ones on
hard sequences by much (run it a few times).
"""
import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

try:
    import numpy as np
except ImportError as e:
    sys.exit(f'orbslam3_baseline: cannot import numpy ({e}): '
             'pip install -r scripts/requirements-baselines.txt')

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PRESETS = {'fr1': 'fr1.toml', 'fr2': 'fr2.toml', 'fr3': 'fr3.toml'}
ORB_FEATURES, ORB_SCALE, ORB_LEVELS, FAST_INI, FAST_MIN = 1000, 1.2, 8, 20, 7


class Failure(Exception):
    """A message for the user, printed as one line."""


def need(path, what=''):
    if not os.path.exists(path):
        raise Failure(f'missing {what + " " if what else ""}{path}')
    return path


def read_list(path):
    with open(need(path)) as f:
        return [line.split() for line in f if line.strip() and not line.lstrip().startswith('#')]


# ---------------------------------------------------------------------------- sequence, camera

def associate(seq):
    """[(t_rgb, rgb_rel, t_depth, depth_rel)] of the sequence, in order."""
    assoc = os.path.join(seq, 'associations.txt')
    if os.path.exists(assoc):
        rows = read_list(assoc)
        bad = [r for r in rows if len(r) < 4]
        if bad:
            raise Failure(f'{assoc}: a line without 4 fields: {" ".join(bad[0])}')
        return [(float(r[0]), r[1], float(r[2]), r[3]) for r in rows]
    rgb = read_list(os.path.join(seq, 'rgb.txt'))
    depth = read_list(os.path.join(seq, 'depth.txt'))
    if not depth:
        raise Failure(f'{seq}/depth.txt lists no images')
    dt = np.array([float(r[0]) for r in depth])
    out, used = [], set()
    for r in rgb:
        t = float(r[0])
        j = int(np.argmin(np.abs(dt - t)))
        if abs(dt[j] - t) <= 0.02 and j not in used:
            used.add(j)
            out.append((t, r[1], float(depth[j][0]), depth[j][1]))
    return out


def parse_toml(path):
    try:
        import tomllib
        with open(path, 'rb') as f:
            return tomllib.load(f)
    except ImportError:  # Python < 3.11: the flat tables of a camera file are enough
        data, table = {}, None
        for line in open(path):
            line = line.split('#')[0].strip()
            if line.startswith('['):
                table = data.setdefault(line.strip('[]').strip(), {})
            elif '=' in line:
                k, v = (s.strip() for s in line.split('=', 1))
                v = v.strip('"') if v.startswith('"') else float(v)
                (table if table is not None else data)[k] = v
        return data


def load_camera(seq, spec):
    if spec is None:
        own = os.path.join(seq, 'camera.toml')
        spec, note = (own, 'the sequence\'s camera.toml') if os.path.exists(own) else \
            ('fr1', 'no camera.toml in the sequence: the fr1 preset')
    else:
        note = spec
    path = os.path.join(REPO, 'configs', 'cameras', PRESETS[spec]) if spec in PRESETS else spec
    if not os.path.exists(path):
        raise Failure(f'camera {spec}: no such preset (fr1, fr2, fr3) or file')
    try:
        c = parse_toml(path)
        cam = {k: float(c[k]) for k in ('fx', 'fy', 'cx', 'cy', 'width', 'height')}
        dist = {k: float(c.get('distortion', {}).get(k, 0.0)) for k in ('k1', 'k2', 'p1', 'p2', 'k3')}
    except KeyError as e:
        raise Failure(f'{path}: no {e.args[0]}')
    except (ValueError, TypeError) as e:
        raise Failure(f'{path}: {e}')
    cam['distortion'] = dist
    cam['name'] = str(c.get('name', os.path.basename(path)))
    cam['note'] = f'{cam["name"]} ({note})'
    return cam


def settings_yaml(cam, depth_scale, fps):
    d = cam['distortion']
    lines = ['%YAML:1.0', '# Written by scripts/orbslam3_baseline.py: ORB-SLAM3 TUM example settings.',
             'File.version: "1.0"', 'Camera.type: "PinHole"']
    lines += [f'Camera1.{k}: {cam[k]:.6f}' for k in ('fx', 'fy', 'cx', 'cy')]
    if any(v != 0.0 for v in d.values()):
        lines += [f'Camera1.{k}: {d[k]:.6f}' for k in ('k1', 'k2', 'p1', 'p2', 'k3')]
    lines += [f'Camera.width: {int(cam["width"])}', f'Camera.height: {int(cam["height"])}',
              f'Camera.fps: {int(round(fps))}',
              'Camera.RGB: 0  # the images are fed as OpenCV reads them: BGR',
              'Stereo.ThDepth: 40.0', 'Stereo.b: 0.07732', f'RGBD.DepthMapFactor: {depth_scale:.6f}',
              f'ORBextractor.nFeatures: {ORB_FEATURES}', f'ORBextractor.scaleFactor: {ORB_SCALE:.6f}',
              f'ORBextractor.nLevels: {ORB_LEVELS}', f'ORBextractor.iniThFAST: {FAST_INI}',
              f'ORBextractor.minThFAST: {FAST_MIN}',
              '# Viewer (unused: no viewer is opened, but ORB-SLAM3 requires the keys)',
              'Viewer.KeyFrameSize: 0.05', 'Viewer.KeyFrameLineWidth: 1.0',
              'Viewer.GraphLineWidth: 0.9', 'Viewer.PointSize: 2.0', 'Viewer.CameraSize: 0.08',
              'Viewer.CameraLineWidth: 3.0', 'Viewer.ViewpointX: 0.0', 'Viewer.ViewpointY: -0.7',
              'Viewer.ViewpointZ: -1.8', 'Viewer.ViewpointF: 500.0']
    return '\n'.join(lines) + '\n'


# ---------------------------------------------------------------------------- DBoW2 vocabulary

def hamming(xb, cb):
    """Hamming distances between bit rows (float32 0/1 arrays): (n, m)."""
    return xb.sum(1)[:, None] + cb.sum(1)[None, :] - 2.0 * (xb @ cb.T)


def kmeans_binary(xb, k, rng, max_iter=50):
    """DBoW2's k-means step on binary descriptors: kmeans++ seeds, majority-vote centres.
    Returns (centres (c, 256) float32, assignment (n,)); empty clusters are dropped."""
    n = len(xb)
    if n <= k:
        return xb.copy(), np.arange(n)
    centres = [xb[rng.integers(n)]]
    dmin = hamming(xb, centres[0][None])[:, 0]
    while len(centres) < k:
        w = dmin.astype(np.float64) ** 2
        if w.sum() <= 0:
            break
        centres.append(xb[rng.choice(n, p=w / w.sum())])
        dmin = np.minimum(dmin, hamming(xb, centres[-1][None])[:, 0])
    c = np.stack(centres)
    assign = None
    for _ in range(max_iter):
        new = np.argmin(hamming(xb, c), axis=1)
        if assign is not None and np.array_equal(new, assign):
            break
        assign = new
        for j in range(len(c)):
            members = xb[assign == j]
            if len(members):  # FORB::meanValue: a bit is set where at least half the members have it
                c[j] = (members.sum(0) >= (len(members) + 1) // 2).astype(np.float32)
    keep = [j for j in range(len(c)) if np.any(assign == j)]
    remap = -np.ones(len(c), dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    return c[keep], remap[assign]


def build_vocabulary(per_image, k, levels, seed):
    """DBoW2 tree over the descriptors of each image (lists of (n, 32) uint8): nodes in
    DBoW2's creation order, node 0 the root. Returns (parents, descriptors, is_leaf, weights)."""
    rng = np.random.default_rng(seed)
    xb = np.unpackbits(np.concatenate(per_image), axis=1).astype(np.float32)
    parents, descs, children = [-1], [np.zeros(256, np.float32)], [[]]

    def step(node, idx, level):
        c, assign = kmeans_binary(xb[idx], k, rng)
        ids = []
        for j in range(len(c)):
            parents.append(node)
            descs.append(c[j])
            children.append([])
            ids.append(len(parents) - 1)
        children[node].extend(ids)
        if level < levels:
            for j, nid in enumerate(ids):
                sub = idx[assign == j]
                if len(sub) > 1:
                    step(nid, sub, level + 1)

    step(0, np.arange(len(xb)), 1)
    # ORB-SLAM3 groups features by the node 4 levels above their word (Frame::ComputeBoW),
    # i.e. at level L - 4: a word shallower than that would leave the node id unset.
    depth = [0] * len(parents)
    for i in range(1, len(parents)):
        depth[i] = depth[parents[i]] + 1
    shallow = min(depth[i] for i in range(1, len(parents)) if not children[i])
    if shallow < levels - 4:
        raise Failure(f'the built vocabulary has words at level {shallow}, above level '
                      f'{levels - 4} where ORB-SLAM3 reads feature groups: too few descriptors '
                      f'for L = {levels}; use a smaller --vocab-levels')
    descs = np.stack(descs)
    is_leaf = np.array([len(ch) == 0 for ch in children])
    is_leaf[0] = False
    # IDF weights of the words, ln(N / N_i) over the training images (DBoW2's setNodeWeights).
    weights = np.zeros(len(parents))
    seen = np.zeros(len(parents))
    for d in per_image:
        words = transform(np.unpackbits(d, axis=1).astype(np.float32), children, descs)
        seen[np.unique(words)] += 1
    has = is_leaf & (seen > 0)
    weights[has] = np.log(len(per_image) / seen[has])
    return parents, descs, is_leaf, weights


def transform(xb, children, descs):
    """Word (leaf node id) of each descriptor: down the tree to the nearest child, first on ties."""
    node = np.zeros(len(xb), dtype=np.int64)
    while True:
        active = np.unique(node[[len(children[n]) > 0 for n in node]])
        if len(active) == 0:
            return node
        for n in active:
            sel = node == n
            ch = np.array(children[n])
            node[sel] = ch[np.argmin(hamming(xb[sel], descs[ch]), axis=1)]


def write_vocabulary(path, k, levels, parents, descs, is_leaf, weights):
    """DBoW2 text format of ORB-SLAM3 (TemplatedVocabulary::loadFromTextFile): a line
    `k L scoring weighting` (0 0: L1 norm, TF-IDF), then one line per node after the root:
    `parent isLeaf d0 .. d31 weight`. No newline after the last node: the loader reads one
    more (empty) node when the file ends with one."""
    packed = np.packbits(descs.astype(np.uint8), axis=1)
    lines = [f'{k} {levels} 0 0']
    for i in range(1, len(parents)):
        lines.append(f'{parents[i]} {int(is_leaf[i])} ' + ' '.join(str(int(b)) for b in packed[i]) +
                     f' {weights[i]:.6f}')
    tmp = path + '.tmp'
    with open(tmp, 'w') as f:
        f.write('\n'.join(lines))
    os.replace(tmp, path)


def training_images(args, frames):
    if args.vocab_images:
        d = need(args.vocab_images, 'vocabulary image folder')
        paths = sorted(os.path.join(d, f) for f in os.listdir(d)
                       if f.lower().endswith(('.png', '.jpg', '.jpeg', '.ppm', '.bmp')))
        if not paths:
            raise Failure(f'{d}: no .png/.jpg images')
        source = f'{len(paths)} images of {d}'
    else:
        paths = [os.path.join(args.sequence, f[1]) for f in frames]
        source = f'the {len(paths)} selected frames of {args.sequence}'
    if len(paths) > args.vocab_max_images:
        pick = np.linspace(0, len(paths) - 1, args.vocab_max_images).round().astype(int)
        paths = [paths[i] for i in pick]
        source += f' (every {len(pick)} evenly spaced)'
    return paths, source


def vocabulary(args, frames, cv2):
    """Path of the vocabulary to use and a line saying what it is."""
    if args.vocabulary:
        need(args.vocabulary, 'vocabulary')
        return args.vocabulary, f'{args.vocabulary} (given)', None
    paths, source = training_images(args, frames)
    key = hashlib.sha1(json.dumps({
        'images': [(os.path.abspath(p), os.path.getsize(need(p, 'image'))) for p in paths],
        'k': args.vocab_k, 'L': args.vocab_levels, 'seed': args.vocab_seed,
        'orb': [ORB_FEATURES, ORB_SCALE, ORB_LEVELS, FAST_INI], 'opencv': cv2.__version__,
        'format': 1}).encode()).hexdigest()[:12]
    os.makedirs(args.vocab_cache, exist_ok=True)
    path = os.path.join(args.vocab_cache, f'dbow2_orb_k{args.vocab_k}_L{args.vocab_levels}_{key}.txt')
    meta_path = path[:-4] + '.json'
    if os.path.exists(path) and os.path.exists(meta_path):
        meta = json.load(open(meta_path))
        return path, f'{path} (cached: {meta["words"]} words, k {args.vocab_k}, L {args.vocab_levels}, ' \
                     f'built from {meta["source"]})', None
    t0 = time.perf_counter()
    orb = cv2.ORB_create(nfeatures=ORB_FEATURES, scaleFactor=ORB_SCALE, nlevels=ORB_LEVELS,
                         fastThreshold=FAST_INI)
    per_image = []
    for p in paths:
        img = cv2.imread(p, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise Failure(f'cannot read image {p}')
        _, d = orb.detectAndCompute(img, None)
        if d is not None and len(d):
            per_image.append(d)
    if not per_image:
        raise Failure(f'no ORB features in {source}')
    tree = build_vocabulary(per_image, args.vocab_k, args.vocab_levels, args.vocab_seed)
    write_vocabulary(path, args.vocab_k, args.vocab_levels, *tree)
    words = int(tree[2].sum())
    n_desc = sum(len(d) for d in per_image)
    secs = time.perf_counter() - t0
    with open(meta_path, 'w') as f:
        json.dump({'source': source, 'descriptors': n_desc, 'words': words, 'k': args.vocab_k,
                   'L': args.vocab_levels, 'seed': args.vocab_seed, 'seconds': round(secs, 1)}, f)
    return path, f'{path} (built now in {secs:.1f} s: {words} words, k {args.vocab_k}, ' \
                 f'L {args.vocab_levels}, from {n_desc} OpenCV ORB descriptors of {source})', secs


# ---------------------------------------------------------------------------- ORB-SLAM3 run

def rot_to_quat(R):  # -> x y z w
    w = np.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return x, y, z, w


class ConsoleTo:
    """Sends the process's stdout and stderr (ORB-SLAM3's C++ console output) to a file meanwhile."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        if self.path is None:
            return self
        sys.stdout.flush()
        sys.stderr.flush()
        self.saved = (os.dup(1), os.dup(2))
        self.f = open(self.path, 'w')
        os.dup2(self.f.fileno(), 1)
        os.dup2(self.f.fileno(), 2)
        return self

    def __exit__(self, *exc):
        if self.path is None:
            return
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, saved in zip((1, 2), self.saved):
            os.dup2(saved, fd)
            os.close(saved)
        self.f.close()


def run_mode(mode, args, frames, cam, vocab, pos, cv2):
    out = os.path.join(args.out, mode)
    os.makedirs(out, exist_ok=True)
    stamps = [f[0] for f in frames]
    fps = (len(stamps) - 1) / (stamps[-1] - stamps[0]) if stamps[-1] > stamps[0] else 30.0
    settings = os.path.join(out, 'settings.yaml')
    with open(settings, 'w') as f:
        f.write(settings_yaml(cam, args.depth_scale, fps))
    log = None if args.verbose else os.path.join(out, 'orbslam3.log')
    if log:
        # ORB-SLAM3 ends the process itself on some errors (a settings key missing, a
        # vocabulary it cannot parse): its last words are then in this log.
        print(f'[{mode}] ORB-SLAM3 console output -> {log}', file=sys.stderr)
    sensor = pos.Sensor.RGBD if mode == 'rgbd' else pos.Sensor.MONOCULAR
    rows, states = [], {}
    read_s = track_s = 0.0
    with ConsoleTo(log):
        t0 = time.perf_counter()
        slam = pos.Slam(vocab_file=vocab, settings_file=settings, sensor=sensor, use_viewer=False)
        startup_s = time.perf_counter() - t0
        loop0 = time.perf_counter()
        for i, (t, rgb_rel, _, depth_rel) in enumerate(frames):
            r0 = time.perf_counter()
            img = cv2.imread(os.path.join(args.sequence, rgb_rel), cv2.IMREAD_COLOR)
            if img is None:
                raise Failure(f'cannot read image {os.path.join(args.sequence, rgb_rel)}')
            if mode == 'rgbd':
                dpath = os.path.join(args.sequence, depth_rel)
                depth = cv2.imread(dpath, cv2.IMREAD_UNCHANGED)
                if depth is None:
                    raise Failure(f'cannot read depth image {dpath}')
                depth = depth.astype(np.float32)
            r1 = time.perf_counter()
            read_s += r1 - r0
            res = slam.track_rgbd(img, depth, t) if mode == 'rgbd' else slam.track_monocular(img, t)
            dt = time.perf_counter() - r1
            track_s += dt
            name = str(res.state).split('.')[-1]
            states[name] = states.get(name, 0) + 1
            if res.pose_valid and res.pose_wc is not None:
                P = np.asarray(res.pose_wc)
                q = rot_to_quat(P[:3, :3])
                rows.append(f'{t:.6f} {P[0, 3]:.7f} {P[1, 3]:.7f} {P[2, 3]:.7f} '
                            f'{q[0]:.7f} {q[1]:.7f} {q[2]:.7f} {q[3]:.7f}\n')
            if args.realtime and i + 1 < len(frames):
                wait = (frames[i + 1][0] - t) - (time.perf_counter() - r0)
                if wait > 0:
                    time.sleep(wait)
        loop_s = time.perf_counter() - loop0
        s0 = time.perf_counter()
        slam.shutdown()
        shutdown_s = time.perf_counter() - s0
        euroc = os.path.join(out, 'trajectory.euroc.txt')
        slam.save_trajectory_euroc(euroc)
    with open(os.path.join(out, 'tracking.txt'), 'w') as f:
        f.write('# ORB-SLAM3 per-frame track() poses (camera-to-world, as returned), '
                'scripts/orbslam3_baseline.py\n')
        f.writelines(rows)
    # ORB-SLAM3's export: nanoseconds; back to the frames' own time stamps in seconds. A frame
    # it could not place repeats the entry before it (Tracking::Track): kept once.
    traj = os.path.join(out, 'trajectory.txt')
    st = np.array(stamps)
    n_traj, last = 0, -np.inf
    with open(traj, 'w') as f:
        f.write(f'# ORB-SLAM3 {mode} ({"given vocabulary" if args.vocabulary else "built vocabulary"}), '
                'scripts/orbslam3_baseline.py\n')
        for r in (read_list(euroc) if os.path.exists(euroc) else []):
            t = st[np.argmin(np.abs(st - float(r[0]) * 1e-9))]
            if t <= last:
                continue
            last = t
            f.write(f'{t:.6f} ' + ' '.join(r[1:8]) + '\n')
            n_traj += 1
    return {'mode': mode, 'frames': len(frames), 'states': states, 'tracked_ok': states.get('OK', 0),
            'in_trajectory': n_traj, 'startup_s': startup_s, 'read_s': read_s, 'track_s': track_s,
            'loop_s': loop_s, 'shutdown_s': shutdown_s,
            'track_fps': len(frames) / track_s if track_s > 0 else 0.0,
            'loop_fps': len(frames) / loop_s if loop_s > 0 else 0.0,
            'trajectory': traj, 'tracking': os.path.join(out, 'tracking.txt'), 'out': out}


def eval_command(args):
    if args.eval:
        return [args.eval]
    built = os.path.join(REPO, 'target', 'release', 'eval')
    if os.path.exists(built):
        return [built]
    if shutil.which('cargo'):
        return ['cargo', 'run', '--quiet', '--release', '--manifest-path',
                os.path.join(REPO, 'Cargo.toml'), '--bin', 'eval', '--']
    return None


def score(r, args):
    gt = os.path.join(args.sequence, 'groundtruth.txt')
    if not os.path.exists(gt):
        r['score_note'] = f'no score: missing {gt}'
        return
    if r['in_trajectory'] < 3:
        r['score_note'] = f'no score: {r["in_trajectory"]} poses in the trajectory'
        return
    cmd = eval_command(args)
    if cmd is None:
        r['score_note'] = 'no score: no target/release/eval and no cargo (build the project first)'
        return
    align = 'se3' if r['mode'] == 'rgbd' else 'sim3'
    js = os.path.join(r['out'], 'ate.json')
    cmd = cmd + ['ate', gt, r['trajectory'], '--align', align, '--json', js]
    r['eval_command'] = ' '.join(cmd)
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        msg = (p.stderr or p.stdout).strip().splitlines()
        r['score_note'] = 'eval failed: ' + (msg[0] if msg else f'exit status {p.returncode}')
        return
    v = json.load(open(js))
    r['align'] = align
    r['ate_rmse'] = v['ate']['rmse']
    r['ate_pairs'] = v['ate'].get('pairs')
    r['scale'] = v.get('alignment', {}).get('scale')


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].replace('\n', ' '),
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog='See the module documentation (head of this file) for details.')
    ap.add_argument('sequence', help='TUM-layout sequence folder')
    ap.add_argument('--camera', help='fr1 | fr2 | fr3 | CAMERA.toml (default: the sequence\'s '
                    'camera.toml, else fr1)')
    ap.add_argument('--mode', choices=('rgbd', 'mono', 'both'), default='both',
                    help='RGB-D, monocular (Sim(3)-scored) or both (default)')
    ap.add_argument('--first', type=int, default=0, help='first frame (0-based, of the associated pairs)')
    ap.add_argument('--count', type=int, default=0, help='frames (0: to the end)')
    ap.add_argument('--depth-scale', type=float, default=5000.0, help='depth value per metre')
    ap.add_argument('--vocabulary', help='ORBvoc.txt (DBoW2 text format); without it one is built')
    ap.add_argument('--vocab-images', help='train the built vocabulary on this image folder '
                    '(default: the selected frames)')
    ap.add_argument('--vocab-max-images', type=int, default=200,
                    help='train on at most this many images, evenly spaced')
    ap.add_argument('--vocab-k', type=int, default=10, help='branching factor of the built vocabulary')
    ap.add_argument('--vocab-levels', type=int, default=4, help='depth L of the built vocabulary')
    ap.add_argument('--vocab-seed', type=int, default=0, help='k-means seed of the built vocabulary')
    ap.add_argument('--vocab-cache', default=os.path.join(
        os.environ.get('XDG_CACHE_HOME', os.path.expanduser('~/.cache')), 'sdf-slam', 'orbslam3'),
        help='folder of built vocabularies (default ~/.cache/sdf-slam/orbslam3)')
    ap.add_argument('--out', default=os.path.join('runs', 'orbslam3'), help='output folder')
    ap.add_argument('--eval', help='the eval binary (default target/release/eval, else cargo run)')
    ap.add_argument('--realtime', action='store_true', help='pace frames to their time stamps')
    ap.add_argument('--verbose', action='store_true', help='show ORB-SLAM3\'s console output')
    args = ap.parse_args()
    if args.first < 0 or args.count < 0:
        raise Failure('--first and --count must not be negative')
    if not 2 <= args.vocab_k <= 20 or not 1 <= args.vocab_levels <= 10:
        raise Failure('ORB-SLAM3 loads vocabularies with 2 <= k <= 20 and 1 <= L <= 10')
    if args.vocab_max_images < 1:
        raise Failure('--vocab-max-images must be at least 1')

    try:
        import pyorbslam3 as pos
    except ImportError as e:
        raise Failure(f'cannot import pyorbslam3 ({e}): pip install pyorbslam3 (GPL-3.0, optional; '
                      'see scripts/requirements-baselines.txt)')
    try:
        import cv2
    except ImportError as e:
        raise Failure(f'cannot import cv2 ({e}): pip install opencv-python-headless')

    need(args.sequence, 'sequence folder')
    all_frames = associate(args.sequence)
    end = len(all_frames) if args.count == 0 else min(len(all_frames), args.first + args.count)
    frames = all_frames[args.first:end]
    if len(frames) < 2:
        raise Failure(f'{args.sequence}: fewer than two frames from {args.first} '
                      f'({len(all_frames)} associated pairs)')
    cam = load_camera(args.sequence, args.camera)
    for f in frames[:1] + frames[-1:]:
        need(os.path.join(args.sequence, f[1]), 'image')
    vocab, vocab_note, _ = vocabulary(args, frames, cv2)
    print(f'sequence {args.sequence}, frames {args.first}..{end - 1} ({len(frames)}), '
          f'camera {cam["note"]}')
    print(f'vocabulary {vocab_note}')
    if not args.vocabulary:
        print('  (a small vocabulary built from these images, not ORBvoc.txt: ORB-SLAM3\'s '
              'relocalisation and loop closing are weaker with it)')

    modes = ['rgbd', 'mono'] if args.mode == 'both' else [args.mode]
    results = []
    for mode in modes:
        r = run_mode(mode, args, frames, cam, vocab, pos, cv2)
        score(r, args)
        results.append(r)

    head = ('| mode | frames | tracked (OK) | in trajectory (largest map) | frames/s: track calls | '
            'frames/s: with image reading | start-up s (vocabulary) | ATE rmse m | alignment | '
            'Sim(3) scale |')
    table = [head, '|' + '---|' * 10]
    for r in results:
        ate = f'{r["ate_rmse"]:.4f}' if 'ate_rmse' in r else r.get('score_note', '-')
        scale = f'{r["scale"]:.3f}' if r.get('align') == 'sim3' and r.get('scale') else '-'
        table.append(f'| {r["mode"]} | {r["frames"]} | {r["tracked_ok"]} | {r["in_trajectory"]} | '
                     f'{r["track_fps"]:.1f} | {r["loop_fps"]:.1f} | {r["startup_s"]:.1f} | {ate} | '
                     f'{r.get("align", "-")} | {scale} |')
    print()
    print('\n'.join(table))
    for r in results:
        print(f'{r["mode"]}: states {r["states"]}; track {r["track_s"]:.2f} s, image reading '
              f'{r["read_s"]:.2f} s, loop {r["loop_s"]:.2f} s, shutdown {r["shutdown_s"]:.2f} s; '
              f'{r["trajectory"]}')
        if 'eval_command' in r:
            print(f'  {r["eval_command"]}')
    summary = {'sequence': os.path.abspath(args.sequence), 'first': args.first, 'count': len(frames),
               'camera': cam['note'], 'vocabulary': vocab_note, 'realtime': args.realtime,
               'results': [{k: v for k, v in r.items() if k != 'out'} for r in results]}
    with open(os.path.join(args.out, 'summary.json'), 'w') as f:
        json.dump(summary, f, indent=1)
    with open(os.path.join(args.out, 'summary.md'), 'w') as f:
        f.write(f'ORB-SLAM3 (pyorbslam3) on {args.sequence}, frames {args.first}..{end - 1}; '
                f'camera {cam["note"]}; vocabulary {vocab_note}\n\n' + '\n'.join(table) + '\n')
    print(f'wrote {os.path.join(args.out, "summary.md")} and summary.json')


if __name__ == '__main__':
    try:
        main()
    except Failure as e:
        sys.exit(f'orbslam3_baseline: {e}')
    except (OSError, ValueError, RuntimeError, IndexError) as e:
        # Unreadable files, malformed lists, ORB-SLAM3's exceptions: one line.
        sys.exit(f'orbslam3_baseline: {type(e).__name__}: {e}')
