#!/usr/bin/env python3
"""PyTorch CPU reference for `bench`: FPFDCNN (Table 12) and SDFCNN (Table 13) defined shape
for shape as src/fpfdcnn/model.rs and src/sdfcnn/model.rs, timed on the same cases.

Optional: the project never needs PyTorch (no test imports it). Install it in a venv:

    python3 -m venv ~/.venvs/torch && ~/.venvs/torch/bin/pip install torch

(PyPI's Linux wheel pulls CUDA libraries, about 3 GB, and runs on the CPU as well; on a
machine that reaches download.pytorch.org, `--index-url https://download.pytorch.org/whl/cpu`
gives the 200 MB CPU-only wheel.) Then let `bench` run it between its own cases:

    cargo run --release --bin bench -- --torch ~/.venvs/torch/bin/python

or alone, one case, printing one JSON line:

    ~/.venvs/torch/bin/python scripts/bench_torch.py --case fpfdcnn-infer --runs 5 --threads 2

Cases (the names and definitions of `bench`, src/bin/bench.rs):
* fpfdcnn-infer: forward of one 480x640 grey image, descriptors bilinearly sampled at 500
  keypoints of the coarse map (the FD layer without upsampling all 256 channels);
* sdfcnn-infer: one 640x480 RGB image: Layer0 resize to 300x400 + eq. 15 normalisation,
  encoder, decoder, judge, bilinear to 640x480 (40 logits + depth), labels by argmax;
* fpfdcnn-train: one SGD step (momentum 0.9, lr 0.01), batch 4, 240x320, loss = mean of the
  probability map + mean of the descriptors;
* sdfcnn-train: one SGD step, batch 4, 240x320: forward to the judge layer (1/4 of 300x400),
  eq. 21 with lambda 0.4 (cross entropy ignoring 255 + berHu on depth > 0), targets resized
  there by nearest neighbour, BN in training mode.
"""

import argparse
import json
import statistics
import sys
import time
import warnings

# PyTorch wheels warn on import when NumPy is absent; this script does not use NumPy.
warnings.filterwarnings("ignore", message="Failed to initialize NumPy")

try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError:
    sys.exit(
        "bench_torch.py needs PyTorch: python3 -m venv ~/.venvs/torch && "
        "~/.venvs/torch/bin/pip install torch (see the top of this file)"
    )

CASES = ["fpfdcnn-infer", "sdfcnn-infer", "fpfdcnn-train", "sdfcnn-train"]
FPFDCNN_PARAMS = 3_025_248  # Table 12, src/fpfdcnn/model.rs
SDFCNN_PARAMS = 2_988_137  # Table 13, src/sdfcnn/model.rs


class Fpfdcnn(nn.Module):
    """L1-L6 encoder (ELU), detector L7 (3x3 ELU) + L8 (1x1 sigmoid) + pixel shuffle,
    descriptor L9 (3x3 ELU) + L10 (1x1 linear)."""

    def __init__(self, channels=(32, 64, 128, 128, 256, 256), dim=256, cell=16):
        super().__init__()
        c1, c2, c3, c4, c5, c6 = channels
        self.encoder = nn.ModuleList(
            [
                nn.Conv2d(1, c1, 4, 2, 1),
                nn.Conv2d(c1, c2, 4, 2, 1),
                nn.Conv2d(c2, c3, 3, 1, 1),
                nn.Conv2d(c3, c4, 4, 2, 1),
                nn.Conv2d(c4, c5, 3, 1, 1),
                nn.Conv2d(c5, c6, 4, 2, 1),
            ]
        )
        self.l7 = nn.Conv2d(c6, dim, 3, 1, 1)
        self.l8 = nn.Conv2d(dim, cell * cell, 1)
        self.l9 = nn.Conv2d(c6, dim, 3, 1, 1)
        self.l10 = nn.Conv2d(dim, dim, 1)
        self.cell = cell

    def forward(self, x):
        for conv in self.encoder:
            x = F.elu(conv(x))
        prob = F.pixel_shuffle(torch.sigmoid(self.l8(F.elu(self.l7(x)))), self.cell)
        descriptors = self.l10(F.elu(self.l9(x)))
        return prob, descriptors


def sample_descriptors(coarse, size, points):
    """Values that F.interpolate(coarse, size, bilinear, align_corners=False) would hold at
    integer pixels `points` ([N, 2] as x, y): grid_sample at the matching coordinates."""
    h, w = size
    _, _, hc, wc = coarse.shape
    # Full-resolution pixel centre -> source coordinate (half-pixel, clamped as interpolate).
    sx = ((points[:, 0] + 0.5) * wc / w - 0.5).clamp(0, wc - 1)
    sy = ((points[:, 1] + 0.5) * hc / h - 0.5).clamp(0, hc - 1)
    grid = torch.stack([(sx + 0.5) / wc * 2 - 1, (sy + 0.5) / hc * 2 - 1], dim=-1)
    out = F.grid_sample(coarse, grid.view(1, 1, -1, 2), mode="bilinear", align_corners=False)
    return out[0, :, 0, :].t()


def conv_bn(cin, cout, kernel, stride, groups, relu6):
    layers = [
        nn.Conv2d(cin, cout, kernel, stride, kernel // 2, groups=groups, bias=False),
        nn.BatchNorm2d(cout),
    ]
    if relu6:
        layers.append(nn.ReLU6())
    return nn.Sequential(*layers)


class InvertedResidual(nn.Module):
    """MobileNetV2's block; as src/sdfcnn/blocks.rs, expansion 1 keeps its 1x1 expand conv."""

    def __init__(self, cin, cout, expansion, stride):
        super().__init__()
        hidden = cin * expansion
        self.body = nn.Sequential(
            conv_bn(cin, hidden, 1, 1, 1, True),
            conv_bn(hidden, hidden, 3, stride, hidden, True),
            conv_bn(hidden, cout, 1, 1, 1, False),
        )
        self.residual = stride == 1 and cin == cout

    def forward(self, x):
        y = self.body(x)
        return y + x if self.residual else y


class Crp(nn.Module):
    """Chained residual pooling: 5x5 max pool s1 then a bias-free 1x1 conv, summed, 4 times."""

    def __init__(self, channels, stages=4, depthwise=False):
        super().__init__()
        groups = channels if depthwise else 1
        self.convs = nn.ModuleList(
            [nn.Conv2d(channels, channels, 1, groups=groups, bias=False) for _ in range(stages)]
        )

    def forward(self, x):
        top = x
        for conv in self.convs:
            top = conv(F.max_pool2d(top, 5, 1, 2))
            x = x + top
        return x


ENCODER = [(1, 16, 1, 1), (6, 24, 2, 2), (6, 32, 3, 2), (6, 64, 4, 2), (6, 96, 3, 1),
           (6, 160, 3, 2), (6, 320, 1, 1)]


def resize(x, size):
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


class Sdfcnn(nn.Module):
    """MobileNetV2 encoder + Light-Weight RefineNet decoder + seg/depth judge (Table 13)."""

    def __init__(self, classes=40, inner=(300, 400), d=256):
        super().__init__()
        self.inner = inner
        self.register_buffer("mean", torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1))
        self.layer1 = conv_bn(3, 32, 3, 2, 1, True)
        stages, cin = [], 32
        for t, c, n, s in ENCODER:
            stages.append(nn.Sequential(
                *[InvertedResidual(cin if i == 0 else c, c, t, s if i == 0 else 1)
                  for i in range(n)]))
            cin = c
        self.stages = nn.ModuleList(stages)

        def c1x1(cin):
            return nn.Conv2d(cin, d, 1, bias=False)

        self.conv8, self.conv7, self.conv6 = c1x1(320), c1x1(160), c1x1(96)
        self.conv5, self.conv4, self.conv3 = c1x1(64), c1x1(32), c1x1(24)
        self.crp4, self.crp3, self.crp2 = Crp(d), Crp(d), Crp(d)
        self.crp1 = Crp(d, depthwise=True)
        self.adapt4, self.adapt3, self.adapt2 = c1x1(d), c1x1(d), c1x1(d)
        self.pre_seg = nn.Conv2d(d, d, 1, groups=d, bias=False)
        self.seg = nn.Conv2d(d, classes, 1)
        self.pre_depth = nn.Conv2d(d, d, 1, groups=d, bias=False)
        self.depth = nn.Conv2d(d, 1, 3, 1, 1)

    def forward_quarter(self, image):
        x = (resize(image, self.inner) - self.mean) / self.std
        x = self.layer1(x)
        feats = []
        for stage in self.stages:
            x = stage(x)
            feats.append(x)
        _, l24, l32, l64, l96, l160, l320 = feats
        x = F.relu(self.conv8(l320) + self.conv7(l160))
        x = resize(self.adapt4(self.crp4(x)), l96.shape[2:])
        x = F.relu(self.conv6(l96) + self.conv5(l64) + x)
        x = resize(self.adapt3(self.crp3(x)), l32.shape[2:])
        x = F.relu(self.conv4(l32) + x)
        x = resize(self.adapt2(self.crp2(x)), l24.shape[2:])
        x = self.crp1(F.relu(self.conv3(l24) + x))
        seg = self.seg(F.relu(self.pre_seg(x)))
        depth = self.depth(F.relu(self.pre_depth(x)))
        return seg, depth

    def forward(self, image):
        seg, depth = self.forward_quarter(image)
        size = image.shape[2:]
        return resize(seg, size), resize(depth, size)


def sdfcnn_loss(seg, depth, labels, target, lam=0.4, ratio=0.2):
    """Eq. 21 as src/sdfcnn/loss.rs: nearest-neighbour targets at the output size."""
    h, w = seg.shape[2:]
    # nearest-exact: pixel centres, as src/sdfcnn/loss.rs's nearest_indices.
    labels = F.interpolate(labels[:, None].float(), size=(h, w), mode="nearest-exact")[:, 0].long()
    target = F.interpolate(target, size=depth.shape[2:], mode="nearest-exact")
    ce = F.cross_entropy(seg, labels, ignore_index=255)
    valid = target > 0
    r = (depth - target)[valid]
    a = r.abs()
    c = (a.detach().max() * ratio).clamp_min(1e-6)
    berhu = torch.where(a > c, (r * r + c * c) / (2 * c), a).mean()
    return lam * ce + (1 - lam) * berhu


def params(model):
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def make_case(case, gen):
    """The model and a step function for one case."""
    if case.startswith("fpfdcnn"):
        model = Fpfdcnn()
        assert params(model) == FPFDCNN_PARAMS, params(model)
    else:
        model = Sdfcnn()
        assert params(model) == SDFCNN_PARAMS, params(model)
    if case == "fpfdcnn-infer":
        model.eval()
        x = torch.rand(1, 1, 480, 640, generator=gen)
        pts = torch.stack([torch.randint(0, 640, (500,), generator=gen),
                           torch.randint(0, 480, (500,), generator=gen)], dim=1).float()

        def step():
            with torch.inference_mode():
                prob, desc = model(x)
                d = sample_descriptors(desc, (480, 640), pts)
                assert d.shape == (500, 256) and prob.shape == (1, 1, 480, 640)
        return model, step
    if case == "sdfcnn-infer":
        model.eval()
        x = torch.rand(1, 3, 480, 640, generator=gen)

        def step():
            with torch.inference_mode():
                seg, depth = model(x)
                labels = seg.argmax(1)
                assert labels.shape == (1, 480, 640) and depth.shape == (1, 1, 480, 640)
        return model, step
    opt = torch.optim.SGD(model.parameters(), lr=0.01, momentum=0.9)
    model.train()
    if case == "fpfdcnn-train":
        x = torch.rand(4, 1, 240, 320, generator=gen)

        def step():
            opt.zero_grad(set_to_none=True)
            prob, desc = model(x)
            (prob.mean() + desc.mean()).backward()
            opt.step()
        return model, step
    if case == "sdfcnn-train":
        x = torch.rand(4, 3, 240, 320, generator=gen)
        depth = torch.rand(4, 1, 240, 320, generator=gen) * 5
        labels = torch.randint(0, 41, (4, 240, 320), generator=gen)
        labels[labels == 40] = 255

        def step():
            opt.zero_grad(set_to_none=True)
            seg, d = model.forward_quarter(x)
            sdfcnn_loss(seg, d, labels, depth).backward()
            opt.step()
        return model, step
    raise ValueError(f"unknown case {case}")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--case", choices=CASES, required=True)
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    if not (1 <= a.runs <= 1000 and 0 <= a.warmup <= 1000 and 1 <= a.threads <= 1024):
        p.error("--runs 1-1000, --warmup 0-1000, --threads 1-1024")
    torch.set_num_threads(a.threads)
    gen = torch.Generator().manual_seed(7)
    model, step = make_case(a.case, gen)
    for _ in range(a.warmup):
        step()
    ms = []
    for _ in range(a.runs):
        t = time.perf_counter()
        step()
        ms.append((time.perf_counter() - t) * 1e3)
    print(json.dumps({
        "case": a.case, "median_ms": statistics.median(ms), "min_ms": min(ms), "runs_ms": ms,
        "threads": torch.get_num_threads(), "torch": torch.__version__,
        "parameters": params(model),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
    }))


if __name__ == "__main__":
    main()
