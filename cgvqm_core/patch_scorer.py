"""The metric's core: per-patch, per-channel mean squared feature differences.

For one patch (a clip x row x column block of both videos) and every channel c of every level
(input, stem, layer1, ...; channel unit-normalised from the stem on), CGVQM needs

    m_c = mean over t, h, w of (a_test - a_ref)^2            (N = 131 or 1027 numbers)

and the patch error is e_p = alpha * sum_c |omega_c| m_c. This module computes m (and, when
weights are given, the per-frame series and error map derived from the same differences)
for a reference patch and any number of test patches, running the reference through the
network (:class:`.features.FeatureNet`) once. Everything about frames, clips and padding
lives in :mod:`.stream`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from .backbone import LEVEL_CHANNELS
from .errors import CGVQMError
from .features import FeatureNet
from .host_memory import MAX_KEPT_BLOCK
from .ref_delta import RefTape
from .stage_clock import StageClock, stage

__all__ = ["CUDA_PASS_VOXELS", "PatchDiff", "PatchScorer", "default_batch_size"]


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
