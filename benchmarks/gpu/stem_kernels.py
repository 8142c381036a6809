"""Ways to compute the stem's convolution, timed alone on one network pass's shape.

Why: under fp16 the exact fp32 stem costs about 0.10 s of the 0.23 s a 3 s 1024x1024 pair
takes on an H200, about 16 TFLOP/s where the GPU's fp32 units give some 60; TF32 takes
0.029 s but moves q by up to 0.14 on real content. fp16 reaches 350 pairs/min if the stem
costs at most about 0.04 s a pair with fp32's numbers. The end-to-end runs (session.py's
``fastpath``) say which stem wins only among those wired into the library; this section
times every candidate for the price of one pass each, with its error against float64, so
that one lease can tell which is worth wiring in.

The candidates (each the stem's convolution with its bias, fp32 out):

- ``fp32``: cuDNN's conv3d in fp32, TF32 off, channels-last (fp16's stem today);
- ``fp32-ncdhw``: the same in the contiguous layout (fp32 kernels that do not use tensor
  cores may prefer it);
- ``fp32-2d``, ``fp32-2d-pad``, ``fp32-2d-nchw``: the temporal taps as channels of one
  conv2d. The stem's temporal stride is 1, so output frame t sees input frames t-1, t, t+1:
  stacking them gives 9 channels and a 7x7 conv2d over all frames at once, the same
  products in another order (cuDNN's 2D kernels are tuned far more than its 3D ones;
  :class:`cgvqm_core.stem.FramesStem`, ``stem_2d=True``): channels-last, padded
  with zero channels to 12 (16-byte multiples), or contiguous;
- ``fp32-s2d``, ``fp32-s2d-nchw``: that conv2d over its input's stride phases
  (space-to-depth, :class:`cgvqm_core.stem.PhaseConv2d`, ``stem_s2d=True``): a 4x4 kernel
  of stride 1 over 36 channels instead of a 7x7 one of stride 2 over 9, as ResNet-50's
  stem is commonly rewritten for tensor cores; channels-last or contiguous;
- ``tf32-pad``: the TF32 stem padded to 4 channels (``--fast-stem``; not fp32's numbers, the
  speed to beat);
- ``split-int``, ``split-3xtf32``: the split stems of :mod:`cgvqm_core.stem.split` (fp32's
  numbers from one TF32 convolution of 8 or 12 channels), the time to make their input
  included; ``split-int-2d``: the int split as a 2D stem (24 channels);
  ``split-int-s2d``: that over its stride phases (96 channels).

    python benchmarks/gpu/stem_kernels.py --device cuda
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from cgvqm_core.features import MEAN, STD, FeatureNet
from cgvqm_core.hub import random_backbone
from cgvqm_core.precision import cudnn_tf32
from cgvqm_core.stem import FramesStem, SplitStem, pad_stem_conv, padded_input

KINDS = ("fp32", "fp32-ncdhw", "fp32-2d", "fp32-2d-pad", "fp32-2d-nchw", "fp32-s2d",
         "fp32-s2d-nchw", "tf32-pad", "split-int", "split-3xtf32", "split-int-2d",
         "split-int-s2d")
"""The candidates, in the order they are timed."""

#: patch videos (30 frames of 256x256) per pair of 3 s 1024x1024 stimuli with four tests per
#: reference: 1.25 videos x 3 clips x 16 patches
PATCH_VIDEOS_PER_PAIR = 60
#: what the stem may cost a pair for fp16 to reach 350 pairs/min (docs/performance.md)
TARGET_S_PER_PAIR = 0.04

Stem = Callable[[torch.Tensor], torch.Tensor]


def stem_net(device: str, seed: int = 0) -> FeatureNet:
    """A strict-fp32 network of a random backbone, batch norm folded, channels-last (the
    values of the published weights do not change the timings): its stem convolution
    (``model.stem[0]``) is what every kind computes, its :meth:`~FeatureNet.to_input` what
    they take."""
    return FeatureNet(random_backbone(seed), 2, device=device, precision="fp32",
                      fuse_bn=True, channels_last=True)


def pixels(net: FeatureNet, shape: tuple[int, int, int, int], batch: int, seed: int = 0
           ) -> torch.Tensor:
    """``batch`` random uint8 videos of (frames, height, width, 3) as ``net`` takes them:
    (B, 3, T, H, W) float32, normalised, channels-last."""
    g = torch.Generator().manual_seed(seed)
    return net.to_input(torch.randint(0, 256, (batch, *shape), generator=g,
                                      dtype=torch.uint8))


def make(kind: str, conv: nn.Conv3d) -> Stem:
    """The stem computed the ``kind`` way (:data:`KINDS`) from fp32 ``x``."""
    dev = conv.weight.device
    if kind in ("fp32", "fp32-ncdhw"):
        cl = kind == "fp32"
        w = conv.weight.contiguous(memory_format=torch.channels_last_3d if cl
                                   else torch.contiguous_format)

        def plain(x: torch.Tensor) -> torch.Tensor:
            x = x if cl else x.contiguous()
            with cudnn_tf32(False):
                return F.conv3d(x, w, conv.bias, conv.stride, conv.padding)
        return plain
    if kind.startswith(("fp32-2d", "fp32-s2d")):
        cl = not kind.endswith("-nchw")
        taps = conv.kernel_size[0] * conv.in_channels  # 9; padded to a multiple of 4: 12
        run2d = FramesStem(conv, cl, -(-taps // 4) * 4 if kind == "fp32-2d-pad" else None,
                           space_to_depth=kind.startswith("fp32-s2d"))

        def two_d(x: torch.Tensor) -> torch.Tensor:
            with cudnn_tf32(False):
                return run2d(x)
        return two_d
    if kind == "tf32-pad":
        padded = pad_stem_conv(conv, 4, True)

        def tf32(x: torch.Tensor) -> torch.Tensor:
            with cudnn_tf32(True):
                return padded(padded_input(x, 4, torch.float32, True))
        return tf32
    if kind.startswith("split-"):
        name = kind.removeprefix("split-").removesuffix("-2d").removesuffix("-s2d")
        split = SplitStem(name, MEAN, STD, dev)
        sconv = split.conv(conv, True)
        if kind.endswith("2d"):
            sconv = FramesStem(sconv, True, space_to_depth=kind.endswith("-s2d"))

        def split_run(x: torch.Tensor) -> torch.Tensor:
            with cudnn_tf32(True):
                return sconv(split.input(x, True))
        return split_run
    raise ValueError(f"unknown stem {kind!r}; choose from {', '.join(KINDS)}")


def exact(conv: nn.Conv3d, x: torch.Tensor) -> torch.Tensor:
    """The stem in float64 on the CPU (the reference every candidate is measured against)."""
    return F.conv3d(x.double().cpu(), conv.weight.double().cpu(), conv.bias.double().cpu(),
                    conv.stride, conv.padding)


def error(out: torch.Tensor, ref: torch.Tensor) -> float:
    """Largest deviation from the float64 stem, relative to the stem's largest value."""
    return float((out.double().cpu() - ref).abs().max() / ref.abs().max())


def measure(net: FeatureNet, batch: int, shape: tuple[int, int, int, int], repeats: int,
            check_shape: tuple[int, int, int, int] = (6, 64, 64, 3),
            kinds: tuple[str, ...] = KINDS,
            clock: Callable[[], float] = time.perf_counter) -> dict[str, dict]:
    """Each kind's best time per pass of ``batch`` videos of ``shape`` (T, H, W, 3), its
    seconds per pair (3 s 1024x1024, four tests per reference; :data:`PATCH_VIDEOS_PER_PAIR`)
    and TFLOP/s, and its error against float64 on a small input."""
    conv = net.model.stem[0]
    cuda = net.device.type == "cuda"
    small = pixels(net, check_shape, 1, seed=1)
    ref = exact(conv, small)
    x = pixels(net, shape, batch)
    t, h, w = shape[:3]
    flops = 2 * batch * t * (h // 2) * (w // 2) * conv.weight.numel()
    saved = torch.backends.cudnn.benchmark
    torch.backends.cudnn.benchmark = True  # as scoring runs
    out: dict[str, dict] = {}
    try:
        with torch.inference_mode():
            for kind in kinds:
                fn = make(kind, conv)
                err = error(fn(small), ref)
                fn(x)  # cuDNN's algorithm search, once per shape as a run pays it
                best = float("inf")
                for _ in range(repeats):
                    if cuda:
                        torch.cuda.synchronize()
                    t0 = clock()
                    fn(x)
                    if cuda:
                        torch.cuda.synchronize()
                    best = min(best, clock() - t0)
                out[kind] = {"s_per_pass": best, "error_vs_fp64": err,
                             "s_per_pair": best * PATCH_VIDEOS_PER_PAIR / batch,
                             "tflops": flops / best / 1e12}
    finally:
        torch.backends.cudnn.benchmark = saved
    return out


def keeps_fp32(res: dict[str, dict], kind: str) -> bool:
    """Whether ``kind`` computed fp32's numbers: within four times the error of cuDNN's own
    fp32 stem (summation order aside, TF32's rounding is some 100 times that)."""
    return res[kind]["error_vs_fp64"] <= 4 * res.get("fp32", {}).get("error_vs_fp64",
                                                                       float("nan"))


def fastest_exact(res: dict[str, dict]) -> str | None:
    """The fastest kind that keeps fp32's numbers (None when none was measured)."""
    exact_kinds = [k for k in res if keeps_fp32(res, k)]
    return min(exact_kinds, key=lambda k: res[k]["s_per_pair"]) if exact_kinds else None


def report(res: dict[str, dict]) -> list[str]:
    """One line per kind: time, rate, error, and whether it keeps fp32's numbers
    (:func:`keeps_fp32`) at the speed fp16 needs."""
    lines = []
    for kind, r in res.items():
        fp32_like = keeps_fp32(res, kind)
        fast = r["s_per_pair"] <= TARGET_S_PER_PAIR
        verdict = ("fp32's numbers" if fp32_like else "NOT fp32's numbers") + (
            f", within {TARGET_S_PER_PAIR} s/pair" if fast else "")
        lines.append(f"  {kind:13s} {1e3 * r['s_per_pass']:8.2f} ms/pass "
                     f"{r['s_per_pair']:.4f} s/pair {r['tflops']:6.1f} TFLOP/s  "
                     f"error {r['error_vs_fp64']:.1e}  ({verdict})")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--batch", type=int, default=4, help="patch videos per pass (4: the "
                    "CUDA default for 1024x1024 stimuli)")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--size", type=int, default=256, help="patch height and width")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    res = measure(stem_net(a.device), a.batch, (a.frames, a.size, a.size, 3), a.repeats)
    print(f"stem alone, {a.batch} x {a.frames}x{a.size}x{a.size} per pass on {a.device}:")
    print("\n".join(report(res)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
