"""The metric's core: per-patch, per-channel mean squared feature differences.

For one patch (a clip x row x column block of both videos) and every channel c of every level
(input, stem, layer1, ...; channel unit-normalised from the stem on), CGVQM needs

    m_c = mean over t, h, w of (a_test - a_ref)^2            (N = 131 or 1027 numbers)

and the patch error is e_p = alpha * sum_c |omega_c| m_c. This module computes m (and, when
weights are given, the per-frame series and error map derived from the same differences)
for a reference patch and any number of test patches, running the reference through the
network once. Everything about frames, clips and padding lives in :mod:`.stream`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from .backbone import LEVEL_CHANNELS, Conv2Plus1D, VideoResNet, build_backbone
from .errors import CGVQMError
from .fused_conv import fusable, fused_stage
from .host_memory import MAX_KEPT_BLOCK
from .hub import Backbone
from .precision import DTYPES, PRECISIONS, check, cudnn_tf32, fast_path, resolve, tf32_mode
from .ref_delta import LevelPair, RefTape, difference_levels
from .stage_clock import StageClock, stage
from .stem_input import pad_stem_conv, padded_channels, padded_input
from .unit_norm import EPS, unit_norm_fp32

#: torchvision's Kinetics-400 normalisation (applied after scaling uint8 to [0, 1])
MEAN = (0.43216, 0.394666, 0.37645)
STD = (0.22803, 0.22145, 0.216989)
__all__ = ["EPS", "PRECISIONS", "FeatureNet", "PatchDiff", "PatchScorer", "RefTape"]


def _fuse_batchnorm(model: nn.Module) -> None:
    """Fold every eval-mode BatchNorm3d into the convolution before it (same function)."""
    for seq in [m for m in model.modules() if isinstance(m, nn.Sequential)]:
        kids = list(seq.children())
        for i in range(len(kids) - 1):
            conv, bn = kids[i], kids[i + 1]
            if not isinstance(bn, nn.BatchNorm3d):
                continue
            if isinstance(conv, Conv2Plus1D):
                conv[3] = fuse_conv_bn_eval(conv[3], bn)
            elif isinstance(conv, nn.Conv3d):
                seq[i] = fuse_conv_bn_eval(conv, bn)
            else:
                continue
            seq[i + 1] = nn.Identity()


class FeatureNet:
    """The backbone prepared for scoring: truncated to the levels needed, eval mode.

    ``fuse_bn`` folds batch norm into the convolutions and ``channels_last`` uses the
    channels-last-3d memory format (both faster on CPU, equal numbers up to float rounding).
    Folding is the default except under ``tf32``: TF32 rounds every convolution's weights to
    10 mantissa bits, and folded weights round differently from upstream's, which would
    move q by up to about 5e-3; unfolded, the convolutions see upstream's very operands.
    ``cudnn_benchmark`` lets cuDNN pick the fastest algorithm per shape (CUDA).
    ``precision`` (:mod:`.precision`): ``auto`` (default: ``fp32`` on CPU, exact; ``tf32`` on
    CUDA, as upstream runs there), ``fp32`` (exact; TF32 off on CUDA),
    ``bf16``/``fp16`` (weights and activations between convolutions in that type,
    convolutions accumulate in fp32; level 0, the unit normalisation and the differences in
    fp32; bf16 on CPU only with AMX/AVX512-BF16) or ``tf32`` (CUDA). Not bit-exact but fp32.
    ``fp32_stem`` keeps the stem convolution in fp32 under bf16/fp16: the stem level carries
    most of |omega| (92 % in CGVQM-2, 57 % in CGVQM-5), so this removes most of the drift for
    about 5 % of the time. Channels-last is the default on CPU and for bf16/fp16.
    ``differences`` (default: on for bf16) carries each test video's activations as exact
    differences from its reference's (:mod:`.ref_delta`), so bf16 rounding no longer adds
    noise to the differences CGVQM measures. fp16 keeps the plain path: small differences
    would fall into its subnormal range. (Asked for in fp32 it computes the plain path's
    numbers up to float rounding, which is how the tests check it.)
    ``tf32_stem`` lets that fp32 stem use cuDNN's TF32 mode (CUDA). ``fused`` runs each
    convolution with its bias, residual and ReLU as one cuDNN call (:mod:`.fused_conv`;
    CUDA, batch norm folded). ``pad_stem`` gives the stem a 16-byte voxel by adding zero
    input channels (:mod:`.stem_input`; meant for cuDNN). None of the three changes the
    function beyond rounding; None (the default) picks what was measured fastest within
    the drift bound (:func:`.precision.fast_path`; figures in docs/performance.md).
    """

    def __init__(self, backbone: Backbone, n_levels: int, *, device: str | torch.device = "cpu",
                 precision: str = "auto", fuse_bn: bool | None = None,
                 channels_last: bool | None = None, fp32_stem: bool = True,
                 cudnn_benchmark: bool = True, differences: bool | None = None,
                 tf32_stem: bool | None = None, fused: bool | None = None,
                 pad_stem: bool | None = None) -> None:
        if not 1 <= n_levels <= 6:
            raise CGVQMError(f"n_levels must be 1..6, got {n_levels}")
        try:
            self.device = torch.device(device)
        except (RuntimeError, ValueError):
            raise CGVQMError(f"unknown device {device!r}; use cpu or cuda") from None
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise CGVQMError("--device cuda was asked for but this PyTorch has no usable CUDA "
                             "device; use --device cpu")
        requested = precision
        precision = resolve(precision, self.device)
        self.precision_info = check(precision, self.device)
        if requested == "auto":
            self.precision_info["requested"] = "auto"
        self.n_levels = n_levels
        self.precision = precision
        self.dtype = DTYPES[precision]
        self.fp32_stem = bool(fp32_stem) and self.dtype != torch.float32
        if self.fp32_stem:
            self.precision_info["fp32_stem"] = True
        if differences is None:
            differences = self.dtype == torch.bfloat16
        self.differences = bool(differences)
        if self.differences:
            self.precision_info["differences"] = "propagated from the reference"
        if channels_last is None:
            channels_last = self.device.type == "cpu" or self.dtype != torch.float32
        self.channels_last = channels_last
        self.fuse_bn = precision != "tf32" if fuse_bn is None else bool(fuse_bn)
        self.cudnn_benchmark = bool(cudnn_benchmark)
        fast = fast_path(self.device, self.dtype, fp32_stem=self.fp32_stem,
                         differences=self.differences, fuse_bn=self.fuse_bn,
                         tf32_stem=tf32_stem, fused=fused, pad_stem=pad_stem)
        self.tf32_stem, self.fused, self.pad_stem = fast.tf32_stem, fast.fused, fast.pad_stem
        for key, on in (("tf32_stem", self.tf32_stem), ("fused", self.fused),
                        ("pad_stem", self.pad_stem)):
            if on:
                self.precision_info[key] = True
        self._fused_proven = False
        self.model = self._build(backbone, max(n_levels - 2, 0), self.fuse_bn)
        # made once: a tensor built from a list on CUDA is a blocking copy, which would
        # make the host wait for the GPU at every pass
        self._mean = torch.tensor(MEAN, device=self.device).view(1, 3, 1, 1, 1)
        self._std = torch.tensor(STD, device=self.device).view(1, 3, 1, 1, 1)

    def _build(self, backbone: Backbone, depth: int, fuse_bn: bool) -> VideoResNet:
        with torch.device("meta"):
            model = build_backbone(backbone.arch, depth=depth, classifier=False)
        wanted = model.state_dict().keys()
        sub = {}
        for k in wanted:
            if k in backbone.state_dict:
                sub[k] = backbone.state_dict[k].detach().to(torch.float32).clone()
            elif k.endswith("num_batches_tracked"):
                sub[k] = torch.tensor(0, dtype=torch.long)
            else:
                raise CGVQMError(f"backbone {backbone.label} lacks {k}")
        model.load_state_dict(sub, strict=True, assign=True)
        model.eval()
        if fuse_bn:
            _fuse_batchnorm(model)
        model = model.to(self.device)
        if self.dtype != torch.float32:  # folded in fp32 first, then cast
            for i, stage in enumerate(model.stages()):
                if i > 0 or not self.fp32_stem:
                    stage.to(self.dtype)
        if self.channels_last:
            model = model.to(memory_format=torch.channels_last_3d)
        stem = model.stages()[0]
        if self.pad_stem and isinstance(stem, nn.Sequential) \
                and isinstance(stem[0], nn.Conv3d):
            stem[0] = pad_stem_conv(stem[0], padded_channels(stem[0].weight.dtype),
                                    self.channels_last)
        else:
            self.pad_stem = False
            self.precision_info.pop("pad_stem", None)
        for p in model.parameters():
            p.requires_grad_(False)
        return model

    def stem_input(self, x: torch.Tensor) -> torch.Tensor:
        """What the stem convolves: ``x`` in the stem's dtype, zero-padded when ``pad_stem``."""
        dtype = self.stage_dtypes[0]
        if self.pad_stem:
            return padded_input(x, self.model.stem[0].in_channels, dtype, self.channels_last)
        return x.to(dtype)

    def run_stage(self, i: int, stage: nn.Module, h: torch.Tensor) -> torch.Tensor:
        """Stage ``i`` (0 is the stem) on ``h``: fused when asked and possible, the stem in
        TF32 when asked. A cuDNN without the fused operation for these shapes turns fusion
        off for this network (recorded in :attr:`precision_info`) on its first call."""
        with cudnn_tf32(True) if i == 0 and self.tf32_stem else contextlib.nullcontext():
            if self.fused and fusable(stage):
                try:
                    out = fused_stage(stage, h)
                    self._fused_proven = True
                    return out
                except RuntimeError as exc:
                    if self._fused_proven:
                        raise
                    self.fused = False
                    self.precision_info["fused"] = f"unavailable: {str(exc).splitlines()[0]}"
            return stage(h)

    def to_input(self, clips_u8: torch.Tensor) -> torch.Tensor:
        """(B, T, H, W, 3) uint8 -> normalised float (B, 3, T, H, W), as torchvision does it."""
        x = clips_u8.to(self.device, non_blocking=True).permute(0, 4, 1, 2, 3)
        if not self.channels_last:
            x = x.contiguous()
        x = x.to(torch.float32).div_(255)
        return x.sub_(self._mean).div_(self._std)

    def levels(self, x: torch.Tensor) -> Iterator[torch.Tensor]:
        """Level activations in float32, unit-normalised across channels from level 1 on.

        ``x`` is the fp32 input of :meth:`to_input`; level 0 is ``x`` itself whatever the
        precision, the network sees it cast to the compute type.
        """
        with torch.inference_mode(), tf32_mode(self.device, self.precision == "tf32",
                                               benchmark=self.cudnn_benchmark):
            yield x
            stages = self.model.stages()[: self.n_levels - 1]
            if self.dtype == torch.float32:
                h = self.stem_input(x) if self.pad_stem else x
                for i, stage in enumerate(stages):
                    h = self.run_stage(i, stage, h)
                    yield h / torch.linalg.vector_norm(h, dim=1, keepdim=True).add_(EPS)
                return
            h = self.stem_input(x)
            for i, stage in enumerate(stages):
                out = self.run_stage(i, stage, h)
                # the next stage's input first: then the fp32 stem's output is free to be
                # normalised in place
                h = out.to(self.stage_dtypes[i + 1]) if i + 1 < len(stages) else None
                yield unit_norm_fp32(out, inplace=h is not out)
                del out

    def pair_levels(self, x: torch.Tensor, G: int, n: int, tape: RefTape | None = None
                    ) -> Iterator[LevelPair]:
        """Per level, G references' features (G, 1, C, T, H, W) and those of their n tests
        each (G, n, C, T, H, W), in float32, unit-normalised from level 1 on.

        ``x`` (from :meth:`to_input`) holds the G references, then their tests in reference
        order. With a ``tape`` the first pass records what the references contribute and
        later passes, whose ``x`` holds tests only (G == 1), replay it.
        """
        if self.differences:
            with torch.inference_mode(), tf32_mode(self.device, False,
                                                   benchmark=self.cudnn_benchmark):
                yield from difference_levels(self.model, x, G, n, self.n_levels,
                                             self.dtype, self.fp32_stem, tape,
                                             tf32_stem=self.tf32_stem)
            return
        replay = tape is not None and tape.filled
        if tape is not None:
            tape.rewind()
        for a in self.levels(x):
            if replay:
                assert tape is not None
                r, t = tape.through(lambda: None), a
            else:
                r, t = a[:G], a[G:]
                if tape is not None:
                    tape.through(lambda r=r: r.clone())
            yield r.unsqueeze(1), t.unflatten(0, (G, n))
        if tape is not None:
            tape.filled = True

    @property
    def stage_dtypes(self) -> list[torch.dtype]:
        """The dtype each stage computes in (stem, layer1, ...)."""
        return [next(s.parameters()).dtype for s in self.model.stages()]


def _mean_hw(d: torch.Tensor) -> torch.Tensor:
    """Mean over H and W of (B, C, T, H, W); reads channels-last tensors in memory order."""
    if d.dim() == 5 and d.is_contiguous(memory_format=torch.channels_last_3d):
        b, c, t, h, w = d.shape
        return d.permute(0, 2, 3, 4, 1).reshape(b, t, h * w, c).mean(2).permute(0, 2, 1)
    return d.mean(dim=(3, 4))


@dataclass
class PatchDiff:
    """What one patch yields for each test video (k of them)."""

    msd: torch.Tensor  # (k, N) mean squared difference per channel of every level
    series: torch.Tensor | None  # (k, T) per-frame patch error (needs weights)
    emap: torch.Tensor | None  # (k, T, h, w) error map (needs weights, only when asked)


#: what one network pass may hold on CUDA when no batch size is given, in video voxels
#: (frames x height x width of each patch, summed over the videos of the pass): 16 patches
#: of 30x128x128, those of a 512x512 video, which peak at about 2.5 GB in fp32
CUDA_PASS_VOXELS = 16 * 30 * 128 * 128


def default_batch_size(device: str | torch.device, patch_voxels: int,
                       separate_reference: bool = False) -> int:
    """Videos per network pass when none is given.

    On a CPU two (reference + test) when both videos' largest activation (64 channels at
    half the patch's height and width, fp32: 64 bytes per patch voxel) stays within the
    32 MiB blocks glibc can keep for the next pass (:mod:`.host_memory`), else one: larger
    batches run no faster there, and fresh pages for every pass cost 9 % (one video per
    pass at 30x128x128, the patches of a 512x512 video). Two whatever the size when the
    reference runs as a tensor of its own (``separate_reference``: bf16 tests carried as
    differences), as a second pass would only replay it. On CUDA as many patches as fill
    :data:`CUDA_PASS_VOXELS` (16 at 30x128x128, 4 at 30x256x256, 2 for 1080p), so that
    several patch positions share a pass while memory stays that of a 512x512 video's."""
    voxels = max(int(patch_voxels), 1)
    if torch.device(device).type != "cuda":
        return 2 if separate_reference or 2 * 64 * voxels <= MAX_KEPT_BLOCK else 1
    return max(2, CUDA_PASS_VOXELS // voxels)


class PatchScorer:
    """Compares reference patches with their test patches through a :class:`FeatureNet`.

    ``level_weights`` (|omega| split per level) and ``alpha`` are needed only for the
    per-frame series and the error map; ``patch_channel_msd`` works without them.
    ``batch_size`` videos go through the network together (default
    :func:`default_batch_size`, from the device and the patch size): several patch
    positions at once when each position's reference and k tests fit (:meth:`compare`),
    otherwise one position in chunks, the reference's normalised levels kept while later
    chunks of test videos are processed.
    """

    def __init__(self, net: FeatureNet, level_weights: list[np.ndarray] | None = None,
                 alpha: float = 1.0, batch_size: int | None = None) -> None:
        self.net = net
        self.alpha = float(alpha)
        self.batch_size = None if batch_size is None else max(1, int(batch_size))
        self.w = None
        if level_weights is not None:
            if len(level_weights) != net.n_levels:
                raise CGVQMError(f"weights have {len(level_weights)} levels, the network "
                                 f"{net.n_levels}")
            self.w = [torch.as_tensor(w, dtype=torch.float32, device=net.device)
                      for w in level_weights]

    def videos_per_pass(self, patch_voxels: int) -> int:
        """The batch size for patches of ``patch_voxels`` (frames x height x width)."""
        if self.batch_size is not None:
            return self.batch_size
        return default_batch_size(self.net.device, patch_voxels, self.net.differences)

    def positions_per_pass(self, k: int, patch_voxels: int) -> int:
        """How many patch positions (each a reference and ``k`` tests) one pass takes."""
        return max(1, self.videos_per_pass(patch_voxels) // (1 + k))

    def __call__(self, ref: torch.Tensor, tests: list[torch.Tensor], *,
                 emap: bool = False,
                 cores: tuple[tuple[slice, slice], ...] | None = None) -> PatchDiff:
        """One position: ``ref`` and each test are (T, h, w, 3) uint8 patches; results on
        the host.

        ``cores`` (seamless tiling) keeps, per level, only that (rows, columns) part of the
        features: the input was a crop around the patch and the rest is its halo.
        """
        out = self.compare([ref], [tests], emap=emap, cores=cores)
        self.check_finite(out.msd)
        return PatchDiff(out.msd[0].cpu(),
                         None if out.series is None else out.series[0].cpu(),
                         None if out.emap is None else out.emap[0].cpu())

    def check_finite(self, msd: torch.Tensor) -> None:
        """Refuse features that overflowed (bf16/fp16); a host sync on CUDA, so callers do
        it once per clip."""
        if self.net.dtype != torch.float32 and not bool(torch.isfinite(msd).all()):
            raise CGVQMError(f"the network overflowed in {self.net.precision} (non-finite "
                             "features); score this video with --precision bf16 or fp32")

    def compare(self, refs: list[torch.Tensor], tests: list[list[torch.Tensor]], *,
                emap: bool = False, cores: tuple[tuple[slice, slice], ...] | None = None,
                clock: StageClock | None = None) -> PatchDiff:
        """G positions at once: ``refs[g]`` and every ``tests[g][j]`` are (T, h, w, 3) uint8
        patches of position g (on the host or already on the device).

        Returns a :class:`PatchDiff` whose tensors have a leading position axis, (G, k, ...),
        left on the network's device (no synchronisation). Several positions need all
        G * (1 + k) videos to fit in one pass (see :meth:`positions_per_pass`).
        """
        if emap and self.w is None:
            raise CGVQMError("an error map needs feature weights")
        if emap and cores is not None:
            raise CGVQMError("error maps are not offered in seamless mode")
        G, k = len(refs), len(tests[0]) if tests else 0
        T, h, w = refs[0].shape[:3]
        if k == 0:
            n = sum(LEVEL_CHANNELS[: self.net.n_levels])
            return PatchDiff(torch.zeros(G, 0, n, device=self.net.device), None, None)
        batch = self.videos_per_pass(T * h * w)
        if G * (1 + k) <= batch:
            parts = [self._pass(refs, [v for g in tests for v in g], G, k, None, (T, h, w),
                                emap, cores, clock)]
        else:
            if G > 1:
                raise CGVQMError(f"{G} positions of {1 + k} videos do not fit a batch of "
                                 f"{batch}")
            parts = self._chunked(refs[0], tests[0], batch, (T, h, w), emap, cores, clock)
        msd = torch.cat([p[0] for p in parts], dim=1)
        series = (torch.cat([p[1] for p in parts], dim=1) * self.alpha
                  if parts[0][1] is not None else None)
        em = torch.cat([p[2] for p in parts], dim=1) * self.alpha if emap else None
        return PatchDiff(msd, series, em)

    def _chunked(self, ref: torch.Tensor, tests: list[torch.Tensor], batch: int,
                 shape: tuple[int, ...], emap: bool,
                 cores: tuple[tuple[slice, slice], ...] | None,
                 clock: StageClock | None) -> list[tuple]:
        """One position whose reference and tests do not fit one pass of ``batch`` videos:
        the reference goes with the first tests, what it contributes is kept on a tape for
        the later chunks."""
        first = tests[: batch - 1]
        rest = tests[len(first):]
        tape = RefTape()
        parts = [self._pass([ref], first, 1, len(first), tape, shape, emap, cores, clock)]
        for i in range(0, len(rest), batch):
            chunk = rest[i: i + batch]
            parts.append(self._pass([], chunk, 1, len(chunk), tape, shape, emap, cores, clock))
        return [p for p in parts if p[0].shape[1] > 0]

    def _pass(self, refs: list[torch.Tensor], tests: list[torch.Tensor], G: int, n: int,
              tape: RefTape | None, shape: tuple[int, ...], emap: bool,
              cores: tuple[tuple[slice, slice], ...] | None, clock: StageClock | None
              ) -> tuple:
        """One network pass over G references (none when ``tape`` replays them) and their
        ``n`` tests each (``tests`` in reference order)."""
        T, h, w = shape
        with stage(clock, "copy"):
            x = self.net.to_input(torch.stack([*refs, *tests]))
        msd_l: list[torch.Tensor] = []
        series = em = None
        levels = self.net.pair_levels(x, G, n, tape)
        for li in range(self.net.n_levels):
            with stage(clock, "backbone"):
                r, t = next(levels)
            with stage(clock, "pooling"):
                if n == 0:
                    del r, t
                    continue
                if cores is not None:
                    r = r[..., cores[li][0], cores[li][1]]
                    t = t[..., cores[li][0], cores[li][1]]
                # (t - r)^2 in one pass (a subtraction, then squaring in place, made two)
                d = F.mse_loss(t, r.expand_as(t), reduction="none").flatten(0, 1)
                mt = _mean_hw(d)  # (G * n, C, t_l)
                msd_l.append(mt.mean(dim=2))
                if self.w is not None:
                    wl = self.w[li]
                    s = (mt * wl.view(1, -1, 1)).sum(1)
                    if s.shape[1] != T:
                        s = F.interpolate(s[:, None], size=T, mode="linear",
                                          align_corners=False)[:, 0]
                    series = s if series is None else series + s
                    if emap:
                        e = (d * wl.view(1, -1, 1, 1, 1)).sum(1, keepdim=True)
                        e = F.interpolate(e, size=(T, h, w), mode="trilinear",
                                          align_corners=False)[:, 0]
                        em = e if em is None else em + e
                del r, t, d  # free this level before the network computes the next
        for _ in levels:  # let the generator finish (restores its precision switches)
            pass
        if n == 0:
            n_ch = sum(LEVEL_CHANNELS[: self.net.n_levels])
            return (torch.zeros(G, 0, n_ch, device=self.net.device), None, None)
        with stage(clock, "pooling"):
            msd = torch.cat(msd_l, dim=1).unflatten(0, (G, n))
            return (msd,
                    None if series is None else series.unflatten(0, (G, n)),
                    None if em is None else em.unflatten(0, (G, n)))
