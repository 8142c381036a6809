"""Zero input channels for the stem: a 16-byte voxel for cuDNN's vectorised kernels.

The stem convolves 3-channel video. In the channels-last layout a voxel's three values are 12
bytes (fp32) or 6 bytes (bf16/fp16), which rules out cuDNN's vectorised kernels: on an H200
the fp32 stem ran at half the fp32 convolution rate, a third of CGVQM-2's network time under
fp16. One or five zero channels (16 bytes a voxel) with zero weights leave every product the
convolution sums unchanged (the added products are exact zeros), so the stem computes the
same function up to summation order.
"""

from __future__ import annotations

import torch
from torch import nn


def padded_channels(dtype: torch.dtype) -> int:
    """Channels that make a voxel 16 bytes: 4 in fp32, 8 in bf16/fp16."""
    return 16 // torch.empty((), dtype=dtype).element_size()


def pad_stem_conv(conv: nn.Conv3d, channels: int, channels_last: bool) -> nn.Conv3d:
    """A copy of ``conv`` taking ``channels`` input channels, the extra ones with zero
    weights (its weight in the channels-last layout when ``channels_last``)."""
    if channels < conv.in_channels:
        raise ValueError(f"cannot pad {conv.in_channels} input channels to {channels}")
    w = conv.weight
    out = nn.Conv3d(channels, conv.out_channels, conv.kernel_size, stride=conv.stride,
                    padding=conv.padding, dilation=conv.dilation, groups=conv.groups,
                    bias=conv.bias is not None, device=w.device, dtype=w.dtype)
    with torch.no_grad():
        out.weight.zero_()
        out.weight[:, : conv.in_channels].copy_(w)
        if conv.bias is not None:
            out.bias.copy_(conv.bias)
    if channels_last:
        out.weight = nn.Parameter(out.weight.contiguous(memory_format=torch.channels_last_3d),
                                  requires_grad=False)
    return out


def padded_input(x: torch.Tensor, channels: int, dtype: torch.dtype, channels_last: bool
                 ) -> torch.Tensor:
    """``x`` (B, C, T, H, W) as ``dtype`` with zero channels up to ``channels``, in the
    channels-last layout or not."""
    b, c, t, h, w = x.shape
    if not channels_last:
        out = torch.zeros((b, channels, t, h, w), dtype=dtype, device=x.device)
        out[:, :c].copy_(x)
        return out
    out = torch.empty((b, t, h, w, channels), dtype=dtype, device=x.device)
    out[..., c:].zero_()
    out[..., :c].copy_(x.permute(0, 2, 3, 4, 1))
    return out.permute(0, 4, 1, 2, 3)
