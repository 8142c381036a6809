"""Seamless tiling: patches whose features do not depend on where the patch grid falls.

Upstream runs the network on each patch on its own, so every feature near a patch edge sees
the convolutions' zero padding there and changes when the grid moves. In seamless mode each
patch is run on a crop of the (unpadded) frame that extends past the patch by the network's
spatial receptive-field radius (the halo), with the crop's origin on the deepest level's
stride so its feature grid lines up with the whole frame's; only the features of the patch's
core are kept. Every feature is then the one a network run over the whole frame would give,
whatever the grid, and the grid only decides how they are pooled. A feature at level stride
``s`` with index ``j`` sits at input pixel ``j * s`` and belongs to the patch holding it.

Not upstream-identical: results are marked ``mode: seamless`` and error maps are not offered.
Time is still split into upstream's clips.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from torch import nn

from .errors import CGVQMError


@dataclass(frozen=True)
class Halo:
    """The spatial geometry seamless tiling needs from the network."""

    radius: int  # receptive-field radius of the deepest level, in input pixels
    strides: tuple[int, ...]  # spatial stride of every level (level 0, the input, is 1)

    @property
    def align(self) -> int:
        return self.strides[-1]


def network_halo(model: nn.Module, n_levels: int) -> Halo:
    """Receptive-field radius and level strides, walked over the convolutions in order.

    Shortcut (downsample) convolutions are 1x1 and see a subset of the main path, so they
    are skipped; the main path's radius bounds the block's.
    """
    stages = model.stages()[: n_levels - 1]  # type: ignore[operator]
    strides = [1]
    stride, radius = 1, 0
    for stage in stages:
        for name, mod in stage.named_modules():
            if not isinstance(mod, nn.Conv3d) or "downsample" in name:
                continue
            k = max(mod.kernel_size[1], mod.kernel_size[2])
            radius += (k // 2) * stride
            stride *= max(mod.stride[1], mod.stride[2])
        strides.append(stride)
    return Halo(radius, tuple(strides))


@dataclass(frozen=True)
class Tile:
    """One patch in seamless mode: the crop to run and, per level, the core to keep."""

    crop_h: slice
    crop_w: slice
    cores: tuple[tuple[slice, slice], ...]  # per level, in the crop's feature coordinates


def _axis(start: int, stop: int, size: int, halo: Halo) -> tuple[slice, list[slice]]:
    """Crop of one axis for the core [start, stop) of a frame axis of ``size`` pixels."""
    a = max(0, (start - halo.radius) // halo.align * halo.align)
    b = min(size, stop + halo.radius + halo.align)
    cores = []
    for s in halo.strides:
        j0, j1 = math.ceil(start / s), math.ceil(stop / s)
        if j1 <= j0:
            raise CGVQMError(
                f"patches of {stop - start} pixels are too small for seamless mode (a level "
                f"has a stride of {s} pixels); use a smaller --patch-scale")
        cores.append(slice(j0 - a // s, j1 - a // s))
    return slice(a, b), cores


def tile(row: int, col: int, patch_h: int, patch_w: int, height: int, width: int,
         halo: Halo) -> Tile:
    """The crop and level cores of patch (row, col) of a frame ``height`` x ``width``."""
    ch, cores_h = _axis(row * patch_h, min((row + 1) * patch_h, height), height, halo)
    cw, cores_w = _axis(col * patch_w, min((col + 1) * patch_w, width), width, halo)
    return Tile(ch, cw, tuple(zip(cores_h, cores_w, strict=True)))
