"""A strided 2D convolution as a stride-1 one over its input's stride phases (space-to-depth).

The stem's 7x7 convolution of stride 2 reads few input channels (3, or 9 as a 2D stem) for
many outputs, the shape GEMM-based kernels handle worst: the reduction is short and the
strided reads waste the tensor cores' tiles. Splitting the zero-padded input into its
stride x stride phases (pixel (s a + i, s b + j) goes to channel (i, j) of pixel (a, b)) and
the kernel likewise (zero taps up to a multiple of the stride) gives a 4x4 convolution of
stride 1 over four times the channels: the same products plus exact zeros, in another
order, so fp32's numbers in fp32. This is how ResNet-50's 7x7 stem is commonly rewritten
for tensor cores; whether cuDNN's fp32 and TF32 kernels gain here is for a GPU to show
(``benchmarks/gpu/stem_kernels.py``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .windows import copy_spans, span


def phase_grid(size: int, kernel: int, stride: int, pad: int) -> int:
    """Phase-grid length along one axis: what a stride-1 kernel of ceil(``kernel`` /
    ``stride``) taps needs to give the strided convolution's outputs."""
    out = (size + 2 * pad - kernel) // stride + 1
    if out < 1:
        raise ValueError(f"a kernel of {kernel} with padding {pad} does not fit {size} pixels")
    return out + -(-kernel // stride) - 1


def phases_as_channels(x: torch.Tensor, stride: tuple[int, int], padding: tuple[int, int],
                       kernel: tuple[int, int], channels_last: bool,
                       channels: int | None = None) -> torch.Tensor:
    """(N, C, H, W) zero-padded by ``padding`` as (N, sh*sw*C, H2, W2): channel
    (i*sw + j)*C + c of pixel (a, b) holds padded pixel (sh*a + i, sw*b + j) of channel c,
    zeros beyond the image; H2 and W2 cover what a ``kernel`` of that ``stride`` reads. Then
    zero channels up to ``channels`` (channels-last only). One copy of ``x``."""
    n, c, h, w = x.shape
    (sh, sw), (ph, pw) = stride, padding
    h2, w2 = phase_grid(h, kernel[0], sh, ph), phase_grid(w, kernel[1], sw, pw)
    k = channels or sh * sw * c
    if k < sh * sw * c or (k != sh * sw * c and not channels_last):
        raise ValueError(f"{sh * sw * c} channels cannot be padded to {k}"
                         + ("" if channels_last else " in the contiguous layout"))
    if channels_last:
        out = torch.empty((n, h2, w2, k), dtype=x.dtype, device=x.device)
        out[..., sh * sw * c:].zero_()
        phases = [out[..., p * c: (p + 1) * c] for p in range(sh * sw)]
    else:
        out = torch.empty((n, sh * sw, c, h2, w2), dtype=x.dtype, device=x.device)
        phases = [out[:, p].permute(0, 2, 3, 1) for p in range(sh * sw)]
    src = x.permute(0, 2, 3, 1)  # (N, H, W, C), as every phase view
    for i in range(sh):  # phase row a reads padded row sh*a + i, image row sh*a + i - ph
        rows = span(h, h2, i - ph, sh)
        for j in range(sw):
            copy_spans(phases[i * sw + j], src, [rows, span(w, w2, j - pw, sw)])
    if channels_last:
        return out.permute(0, 3, 1, 2)
    return out.view(n, sh * sw * c, h2, w2)


def phase_weight(weight: torch.Tensor, stride: tuple[int, int],
                 channels: int | None = None) -> torch.Tensor:
    """A (O, C, KH, KW) kernel of ``stride`` as the stride-1 kernel over the phases of
    :func:`phases_as_channels`: (O, ``channels`` or sh*sw*C, ceil(KH/sh), ceil(KW/sw)),
    zero taps and zero channels added."""
    o, c, kh, kw = weight.shape
    sh, sw = stride
    kh2, kw2 = -(-kh // sh), -(-kw // sw)
    padded = weight.new_zeros((o, c, kh2 * sh, kw2 * sw))
    padded[:, :, :kh, :kw] = weight
    # (O, C, a, i, b, j) -> (O, i, j, C, a, b)
    phases = padded.view(o, c, kh2, sh, kw2, sw).permute(0, 3, 5, 1, 2, 4)
    out = weight.new_zeros((o, channels or sh * sw * c, kh2, kw2))
    out[:, : sh * sw * c] = phases.reshape(o, sh * sw * c, kh2, kw2)
    return out


class PhaseConv2d(nn.Module):
    """``F.conv2d(x, weight, bias, stride, padding)`` computed as a stride-1 convolution over
    ``x``'s stride phases (:func:`phases_as_channels`, :func:`phase_weight`); ``channels``
    pads the phases with zero channels (channels-last only). No dilation, no groups."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor | None,
                 stride: tuple[int, int], padding: tuple[int, int], channels_last: bool,
                 channels: int | None = None) -> None:
        super().__init__()
        w = phase_weight(weight.detach(), stride, channels)
        if channels_last:
            w = w.contiguous(memory_format=torch.channels_last)
        self.weight = nn.Parameter(w, requires_grad=False)
        self.bias = None if bias is None else nn.Parameter(bias.detach().clone(),
                                                           requires_grad=False)
        self.stride, self.padding = tuple(stride), tuple(padding)
        self.kernel = tuple(weight.shape[2:])
        self.channels_last = channels_last

    def convolve(self, phases: torch.Tensor) -> torch.Tensor:
        """The stride-1 convolution over ``phases`` made already (as
        :func:`phases_as_channels` makes them)."""
        return F.conv2d(phases, self.weight, self.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.convolve(phases_as_channels(x.to(self.weight.dtype), self.stride,
                                                self.padding, self.kernel,
                                                self.channels_last, self.weight.shape[1]))
