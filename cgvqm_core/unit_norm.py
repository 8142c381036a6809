"""Unit normalisation of features across channels, in fp32 whatever they were computed in.

CGVQM compares features after dividing every voxel's channel vector by its length (levels 1
on); the small ``EPS`` keeps an all-zero vector (a dead ReLU region) at zero.
"""

from __future__ import annotations

import torch

EPS = 1e-10


def unit_norm_fp32(a: torch.Tensor, *, inplace: bool = False) -> torch.Tensor:
    """An activation (bf16/fp16, or fp32) as fp32, unit-normalised across channels.

    Channels-last tensors are normalised in their memory order (channels innermost), which
    saves a pass over memory against a broadcast division. ``inplace`` lets an fp32
    activation that nothing else needs be overwritten.
    """
    cl = a.dim() == 5 and a.is_contiguous(memory_format=torch.channels_last_3d)
    v = a.permute(0, 2, 3, 4, 1) if cl else a  # (B, T, H, W, C) contiguous when cl
    dim = -1 if cl else 1
    # the norm read straight from bf16/fp16 with fp32 arithmetic, and one division that
    # promotes to fp32: two passes over the activation, where a copy to fp32 first made four
    norm = torch.linalg.vector_norm(v, dim=dim, keepdim=True, dtype=torch.float32).add_(EPS)
    v = v.div_(norm) if v.dtype == torch.float32 and inplace else torch.div(v, norm)
    return v.permute(0, 4, 1, 2, 3) if cl else v
