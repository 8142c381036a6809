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

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from .backbone import LEVEL_CHANNELS, Conv2Plus1D, VideoResNet, build_backbone
from .errors import CGVQMError
from .hub import Backbone
from .precision import DTYPES, PRECISIONS, check, resolve, tf32_mode

#: torchvision's Kinetics-400 normalisation (applied after scaling uint8 to [0, 1])
MEAN = (0.43216, 0.394666, 0.37645)
STD = (0.22803, 0.22145, 0.216989)
EPS = 1e-10
__all__ = ["PRECISIONS", "FeatureNet", "PatchDiff", "PatchScorer"]


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
    ``precision`` (:mod:`.precision`): ``auto`` (default: ``fp32`` on CPU, exact; ``tf32`` on
    CUDA, as upstream runs there), ``fp32`` (exact; TF32 off on CUDA),
    ``bf16``/``fp16`` (weights and activations between convolutions in that type,
    convolutions accumulate in fp32; level 0, the unit normalisation and the differences in
    fp32; bf16 on CPU only with AMX/AVX512-BF16) or ``tf32`` (CUDA). Not bit-exact but fp32.
    ``fp32_stem`` keeps the stem convolution in fp32 under bf16/fp16: the stem level carries
    most of |omega| (92 % in CGVQM-2, 57 % in CGVQM-5), so this removes most of the drift for
    about 5 % of the time. Channels-last is the default on CPU and for bf16/fp16.
    """

    def __init__(self, backbone: Backbone, n_levels: int, *, device: str | torch.device = "cpu",
                 precision: str = "auto", fuse_bn: bool = True,
                 channels_last: bool | None = None, fp32_stem: bool = True) -> None:
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
        if channels_last is None:
            channels_last = self.device.type == "cpu" or self.dtype != torch.float32
        self.channels_last = channels_last
        self.model = self._build(backbone, max(n_levels - 2, 0), fuse_bn)

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
        for p in model.parameters():
            p.requires_grad_(False)
        return model

    def to_input(self, clips_u8: torch.Tensor) -> torch.Tensor:
        """(B, T, H, W, 3) uint8 -> normalised float (B, 3, T, H, W), as torchvision does it."""
        x = clips_u8.to(self.device, non_blocking=True).permute(0, 4, 1, 2, 3)
        if not self.channels_last:
            x = x.contiguous()
        x = x.to(torch.float32).div_(255)
        mean = torch.tensor(MEAN, dtype=torch.float32, device=self.device).view(1, 3, 1, 1, 1)
        std = torch.tensor(STD, dtype=torch.float32, device=self.device).view(1, 3, 1, 1, 1)
        return x.sub_(mean).div_(std)

    def levels(self, x: torch.Tensor) -> Iterator[torch.Tensor]:
        """Level activations in float32, unit-normalised across channels from level 1 on.

        ``x`` is the fp32 input of :meth:`to_input`; level 0 is ``x`` itself whatever the
        precision, the network sees it cast to the compute type.
        """
        with torch.inference_mode(), tf32_mode(self.device, self.precision == "tf32"):
            if self.dtype == torch.float32:
                it = self.model.levels(x, self.n_levels)
                for _ in range(self.n_levels):
                    a = next(it)
                    yield a if a is x else a / torch.linalg.vector_norm(
                        a, dim=1, keepdim=True).add_(EPS)
                return
            yield x
            stages = self.model.stages()[: self.n_levels - 1]
            h = x.to(self.stage_dtypes[0])
            for i, stage in enumerate(stages):
                out = stage(h)
                # the next stage's input first: then the fp32 stem's output is free to be
                # normalised in place
                h = out.to(self.stage_dtypes[i + 1]) if i + 1 < len(stages) else None
                yield _unit_norm_fp32(out, inplace=h is not out)
                del out

    @property
    def stage_dtypes(self) -> list[torch.dtype]:
        """The dtype each stage computes in (stem, layer1, ...)."""
        return [next(s.parameters()).dtype for s in self.model.stages()]


def _unit_norm_fp32(a: torch.Tensor, *, inplace: bool = False) -> torch.Tensor:
    """An activation (bf16/fp16, or the fp32 stem's) as fp32, unit-normalised across channels.

    Channels-last tensors are normalised in their memory order (channels innermost), which
    saves a pass over memory against the broadcast division of the fp32 path. ``inplace``
    lets an fp32 activation that nothing else needs be overwritten.
    """
    cl = a.dim() == 5 and a.is_contiguous(memory_format=torch.channels_last_3d)
    v = a.permute(0, 2, 3, 4, 1) if cl else a  # (B, T, H, W, C) contiguous when cl
    dim = -1 if cl else 1
    if v.dtype == torch.float32 and not inplace:
        v = v / torch.linalg.vector_norm(v, dim=dim, keepdim=True).add_(EPS)
    else:
        v = v.float()  # a copy unless already fp32
        v.div_(torch.linalg.vector_norm(v, dim=dim, keepdim=True).add_(EPS))
    return v.permute(0, 4, 1, 2, 3) if cl else v


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


class PatchScorer:
    """Compares one reference patch with k test patches through a :class:`FeatureNet`.

    ``level_weights`` (|omega| split per level) and ``alpha`` are needed only for the
    per-frame series and the error map; ``patch_channel_msd`` works without them.
    ``batch_size`` videos go through the network together; the reference's normalised
    levels are kept while later chunks of test videos are processed.
    """

    def __init__(self, net: FeatureNet, level_weights: list[np.ndarray] | None = None,
                 alpha: float = 1.0, batch_size: int = 2) -> None:
        self.net = net
        self.alpha = float(alpha)
        self.batch_size = max(1, int(batch_size))
        self.w = None
        if level_weights is not None:
            if len(level_weights) != net.n_levels:
                raise CGVQMError(f"weights have {len(level_weights)} levels, the network "
                                 f"{net.n_levels}")
            self.w = [torch.as_tensor(w, dtype=torch.float32, device=net.device)
                      for w in level_weights]

    def __call__(self, ref: torch.Tensor, tests: list[torch.Tensor], *,
                 emap: bool = False,
                 cores: tuple[tuple[slice, slice], ...] | None = None) -> PatchDiff:
        """``ref`` and each test: (T, h, w, 3) uint8 patches.

        ``cores`` (seamless tiling) keeps, per level, only that (rows, columns) part of the
        features: the input was a crop around the patch and the rest is its halo.
        """
        if emap and self.w is None:
            raise CGVQMError("an error map needs feature weights")
        if emap and cores is not None:
            raise CGVQMError("error maps are not offered in seamless mode")
        T, h, w = ref.shape[:3]
        k = len(tests)
        chunks: list[list[torch.Tensor]] = []
        first = tests[: self.batch_size - 1] if self.batch_size > 1 else []
        chunks.append([ref, *first])
        rest = tests[len(first):]
        chunks += [rest[i: i + self.batch_size] for i in range(0, len(rest), self.batch_size)]
        ref_levels: list[torch.Tensor] = []
        msd_parts: list[torch.Tensor] = []
        series_parts: list[torch.Tensor] = []
        emap_parts: list[torch.Tensor] = []
        keep_ref = len(chunks) > 1
        for ci, chunk in enumerate(chunks):
            x = self.net.to_input(torch.stack(chunk))
            msd_l, series, em = [], None, None
            for li, a in enumerate(self.net.levels(x)):
                if cores is not None:
                    a = a[..., cores[li][0], cores[li][1]]
                if ci == 0:
                    r, t = a[:1], a[1:]
                    if keep_ref:
                        ref_levels.append(r)
                else:
                    r, t = ref_levels[li], a
                if t.shape[0] == 0:
                    del a, t, r
                    continue
                d = (t - r).pow_(2)
                mt = _mean_hw(d)  # (b, C, t_l)
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
                del a, t, r, d  # free this level before the network computes the next
            if msd_l:
                msd_parts.append(torch.cat(msd_l, dim=1))
                if series is not None:
                    series_parts.append(series * self.alpha)
                if em is not None:
                    emap_parts.append(em * self.alpha)
        if k == 0:
            n = sum(LEVEL_CHANNELS[: self.net.n_levels])
            return PatchDiff(torch.zeros(0, n), None, None)
        msd = torch.cat(msd_parts).cpu()
        if self.net.dtype != torch.float32 and not bool(torch.isfinite(msd).all()):
            raise CGVQMError(f"the network overflowed in {self.net.precision} (non-finite "
                             "features); score this video with --precision bf16 or fp32")
        return PatchDiff(
            msd,
            torch.cat(series_parts).cpu() if series_parts else None,
            torch.cat(emap_parts).cpu() if emap_parts else None,
        )
