"""Which module replaces the stem's convolution, and the input it takes."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .frames import FramesStem
from .padding import pad_stem_conv, padded_channels, padded_input
from .split import SplitStem


class StemRewrite:
    """The stem's convolution as a network runs it: as it is, or split (``split``, a name in
    :data:`.split.SPLITS`), as a 2D stem (``two_d``, over its stride phases with
    ``space_to_depth``) or both, or with zero channels (``pad``: the 16-byte voxels of
    :func:`padded_channels`; a 2D stem pads the channels its conv2d reads, only in the
    channels-last layout). :attr:`module` replaces the convolution, :meth:`input` makes
    what it takes, and :attr:`padded` says whether padding applied. The convolution must be
    a plain 3D one (``None`` for a stem that is none, which only ``pad`` tolerates: it is
    then left out); a ValueError says why otherwise."""

    def __init__(self, conv: nn.Module | None, *, split: str | None, two_d: bool, pad: bool,
                 channels_last: bool, mean: Sequence[float], std: Sequence[float],
                 device: torch.device | str = "cpu", space_to_depth: bool = False) -> None:
        if space_to_depth and not two_d:
            raise ValueError("space-to-depth applies to a 2D stem only")
        self.channels_last = channels_last
        self.split = None if split is None else SplitStem(split, mean, std, device)
        self.two_d, self.padded = two_d, False
        if not isinstance(conv, nn.Conv3d):
            if split is not None or two_d:
                raise ValueError(f"a {'split' if split else '2D'} stem needs a plain 3D "
                                 "convolution as the stem")
            self.module: nn.Module | None = None
            return
        if self.split is not None:
            conv = self.split.conv(conv, channels_last)
        if two_d:  # (FramesStem refuses a temporal stride other than 1)
            channels = None  # or the conv2d's channels padded to 16-byte voxels
            if pad and channels_last and self.split is None:
                unit = padded_channels(conv.weight.dtype)
                phases = conv.stride[1] * conv.stride[2] if space_to_depth else 1
                n = conv.kernel_size[0] * conv.in_channels * phases
                channels = -(-n // unit) * unit
            self.padded = channels is not None
            self.module = FramesStem(conv, channels_last, channels,
                                     space_to_depth=space_to_depth)
        elif pad and self.split is None:
            self.padded = True
            self.module = pad_stem_conv(conv, padded_channels(conv.weight.dtype), channels_last)
        else:
            self.module = conv

    @property
    def rewritten(self) -> bool:
        """Whether the stem's input differs from the network's (split or zero-padded)."""
        return self.split is not None or (self.padded and not self.two_d)

    def input(self, x: torch.Tensor, dtype: torch.dtype, *, check: bool = False
              ) -> torch.Tensor:
        """What :attr:`module` takes for the network's fp32 input ``x``: split, or padded
        with zero channels (a 2D stem builds its own from ``x``), in ``dtype``. ``check``
        as :meth:`SplitStem.input`."""
        if self.split is not None:
            return self.split.input(x, self.channels_last, check=check)
        if self.padded and not self.two_d:
            assert isinstance(self.module, nn.Conv3d)
            return padded_input(x, self.module.in_channels, dtype, self.channels_last)
        return x.to(dtype)
