"""The backbone prepared for scoring: CGVQM's levels of a batch of patches.

:class:`FeatureNet` truncates the network to the levels a variant needs, folds batch norm,
picks the memory layout and the precision (and, on CUDA, the fast path of
:func:`.precision.fast_path`), and yields each level's activations unit-normalised across
channels, in fp32 whatever they were computed in. Comparing them is
:mod:`.patch_scorer`'s work.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from .backbone import Conv2Plus1D, VideoResNet, build_backbone
from .devices import torch_device
from .errors import CGVQMError
from .fused_conv import fusable, fused_stage
from .hub import Backbone
from .precision import DTYPES, PRECISIONS, check, cudnn_tf32, fast_path, resolve, tf32_mode
from .ref_delta import LevelPair, RefTape, difference_levels
from .stem import StemRewrite
from .unit_norm import EPS, unit_norm_fp32

#: torchvision's Kinetics-400 normalisation (applied after scaling uint8 to [0, 1])
MEAN = (0.43216, 0.394666, 0.37645)
STD = (0.22803, 0.22145, 0.216989)
__all__ = ["EPS", "MEAN", "PRECISIONS", "STD", "FeatureNet", "RefTape"]


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
    input channels (:mod:`.stem`; meant for cuDNN). ``split_stem`` (``"int"`` or
    ``"3xtf32"``, :mod:`.stem`) computes the fp32 stem as one TF32 convolution of
    split operands, fp32's numbers to about 2^-22 (a candidate for fp16's speed, not yet
    timed on a GPU; asked for only). ``stem_2d`` computes the stem as one 2D convolution
    over all frames with its temporal taps as channels (:class:`.stem.FramesStem`;
    the same products, another kernel; asked for only, not yet timed on a GPU); ``stem_s2d``
    runs that 2D stem over its input's stride phases as channels (space-to-depth,
    :class:`.stem.PhaseConv2d`; a 2D stem implied; asked for only). None of
    them changes the function beyond rounding; None (the default) picks what was measured
    fastest within the drift bound (:func:`.precision.fast_path`; figures in
    docs/performance.md); the TF32 stem, faster but further from fp32, only when asked for.
    """

    def __init__(self, backbone: Backbone, n_levels: int, *, device: str | torch.device = "cpu",
                 precision: str = "auto", fuse_bn: bool | None = None,
                 channels_last: bool | None = None, fp32_stem: bool = True,
                 cudnn_benchmark: bool = True, differences: bool | None = None,
                 tf32_stem: bool = False, fused: bool | None = None,
                 pad_stem: bool | None = None, split_stem: str | None = None,
                 stem_2d: bool = False, stem_s2d: bool = False) -> None:
        if not 1 <= n_levels <= 6:
            raise CGVQMError(f"n_levels must be 1..6, got {n_levels}")
        self.device = torch_device(device)
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
                         tf32_stem=tf32_stem, fused=fused, pad_stem=pad_stem,
                         split_stem=split_stem, tf32_net=precision == "tf32",
                         stem_2d=stem_2d, stem_s2d=stem_s2d)
        self.tf32_stem, self.fused, self.pad_stem = fast.tf32_stem, fast.fused, fast.pad_stem
        self.split_stem, self.stem_2d = fast.split_stem, fast.stem_2d
        self.stem_s2d = fast.stem_s2d
        for key, on in (("tf32_stem", self.tf32_stem), ("fused", self.fused),
                        ("pad_stem", self.pad_stem), ("stem_2d", self.stem_2d),
                        ("stem_s2d", self.stem_s2d)):
            if on:
                self.precision_info[key] = True
        if self.split_stem:
            self.precision_info["split_stem"] = self.split_stem
        self._fused_proven = False
        self._stem: StemRewrite  # made by _build
        self._split_checked = False  # the int split's input checked once, on the first pass
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
        plain_stem = isinstance(stem, nn.Sequential) and isinstance(stem[0], nn.Conv3d)
        try:
            self._stem = StemRewrite(stem[0] if plain_stem else None,
                                     split=self.split_stem, two_d=self.stem_2d,
                                     pad=self.pad_stem, channels_last=self.channels_last,
                                     mean=MEAN, std=STD, device=self.device,
                                     space_to_depth=self.stem_s2d)
        except ValueError as exc:
            raise CGVQMError(f"{exc}; {backbone.arch} has none") from None
        if self._stem.module is not None:
            stem[0] = self._stem.module
        self.pad_stem = self._stem.padded
        if not self.pad_stem:
            self.precision_info.pop("pad_stem", None)
        for p in model.parameters():
            p.requires_grad_(False)
        return model

    def stem_input(self, x: torch.Tensor) -> torch.Tensor:
        """What the stem convolves (:meth:`.stem.StemRewrite.input`): ``x`` in the
        stem's dtype, zero-padded when ``pad_stem``, split into TF32 numbers when
        ``split_stem``."""
        try:
            out = self._stem.input(x, self.stage_dtypes[0], check=not self._split_checked)
        except ValueError as exc:
            raise CGVQMError(str(exc)) from None
        self._split_checked = True
        return out

    def run_stage(self, i: int, stage: nn.Module, h: torch.Tensor) -> torch.Tensor:
        """Stage ``i`` (0 is the stem) on ``h``: fused when asked and possible, the stem in
        TF32 when asked. A cuDNN without the fused operation for these shapes turns fusion
        off for this network (recorded in :attr:`precision_info`) on its first call."""
        tf32 = i == 0 and (self.tf32_stem or self.split_stem is not None)
        with cudnn_tf32(True) if tf32 else contextlib.nullcontext():
            if self.fused and fusable(stage):
                try:
                    out = fused_stage(stage, h)
                    self._fused_proven = True
                    return out
                except RuntimeError as exc:
                    if self._fused_proven or isinstance(exc, torch.OutOfMemoryError):
                        raise  # (out of memory is not a missing operation)
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
                h = self.stem_input(x) if self._stem.rewritten else x
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
