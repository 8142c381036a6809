"""The stem as one 2D convolution over all frames, its temporal taps as input channels.

The stem's temporal stride is 1, so output frame t sees input frames t-1, t and t+1 with the
same weights wherever t is. Stacking those frames' channels (9, zeros beyond the clip's
ends, as the 3D convolution pads) makes the stem a 7x7 conv2d over every frame at once: the
same products in another order, so fp32's numbers in fp32. cuDNN's fp32 conv3d ran the stem
at about 16 TFLOP/s on an H200, a quarter of its fp32 units; its 2D kernels are tuned for far
more networks (whether they do better here is for a GPU to show). It composes with a split
(:mod:`.split`): the split convolution is a 3D convolution like the stem's.
"""

from __future__ import annotations

import torch
from torch import nn

from .phases import PhaseConv2d, phase_grid
from .windows import copy_spans, span


def frames_as_channels(x: torch.Tensor, taps: int, pad: int, channels_last: bool,
                       channels: int | None = None) -> torch.Tensor:
    """(B, C, T, H, W) as (B*T', taps*C, H, W), T' = T + 2 ``pad`` - ``taps`` + 1 (the
    frames a temporal convolution of ``taps`` taps and ``pad`` zeros at each end outputs):
    for output frame t the channels of input frames t - ``pad`` ... t - ``pad`` + ``taps``
    - 1 in that order, zeros for frames beyond the ends; then zero channels up to
    ``channels`` (channels-last only), in ``x``'s dtype and the channels-last layout or not."""
    b, c, t, h, w = x.shape
    n = channels or taps * c
    t_out = t + 2 * pad - taps + 1
    if t_out < 1:
        raise ValueError(f"{t} frames are fewer than {taps} taps with {pad} padding")
    if n < taps * c or (n != taps * c and not channels_last):
        raise ValueError(f"{taps * c} channels cannot be padded to {n}"
                         + ("" if channels_last else " in the contiguous layout"))
    if channels_last:
        out = torch.empty((b, t_out, h, w, n), dtype=x.dtype, device=x.device)
        src = x.permute(0, 2, 3, 4, 1)  # (B, T, H, W, C)
        dst = [out[..., k * c: (k + 1) * c] for k in range(taps)]
        out[..., taps * c:].zero_()
    else:
        out = torch.empty((b, t_out, taps, c, h, w), dtype=x.dtype, device=x.device)
        src = x.transpose(1, 2)  # (B, T, C, H, W)
        dst = [out[:, :, k] for k in range(taps)]
    for k, d in enumerate(dst):  # output frame j reads input frame j - pad + k
        copy_spans(d, src, [span(t, t_out, k - pad, 1)])
    if channels_last:
        return out.view(b * t_out, h, w, n).permute(0, 3, 1, 2)
    return out.view(b * t_out, n, h, w)


def frames_phases_as_channels(x: torch.Tensor, taps: int, pad: int,
                              stride: tuple[int, int], padding: tuple[int, int],
                              kernel: tuple[int, int], channels_last: bool,
                              channels: int | None = None) -> torch.Tensor:
    """:func:`frames_as_channels` then :func:`.phases.phases_as_channels` in one copy of
    ``x``: (B*T', sh*sw*taps*C, H2, W2), channel ((i*sw + j)*taps + k)*C + c holding
    channel c of input frame t - ``pad`` + k at padded pixel (sh*a + i, sw*b + j)."""
    b, c, t, h, w = x.shape
    (sh, sw), (ph, pw) = stride, padding
    t_out = t + 2 * pad - taps + 1
    if t_out < 1:
        raise ValueError(f"{t} frames are fewer than {taps} taps with {pad} padding")
    h2, w2 = phase_grid(h, kernel[0], sh, ph), phase_grid(w, kernel[1], sw, pw)
    blocks = sh * sw * taps
    n = channels or blocks * c
    if n < blocks * c or (n != blocks * c and not channels_last):
        raise ValueError(f"{blocks * c} channels cannot be padded to {n}"
                         + ("" if channels_last else " in the contiguous layout"))
    src = x.permute(0, 2, 3, 4, 1)  # (B, T, H, W, C), as every block's view
    if channels_last:
        out = torch.empty((b, t_out, h2, w2, n), dtype=x.dtype, device=x.device)
        out[..., blocks * c:].zero_()
        dst = [out[..., q * c: (q + 1) * c] for q in range(blocks)]
    else:
        out = torch.empty((b, t_out, blocks, c, h2, w2), dtype=x.dtype, device=x.device)
        dst = [out[:, :, q].permute(0, 1, 3, 4, 2) for q in range(blocks)]
    for i in range(sh):
        rows = span(h, h2, i - ph, sh)
        for j in range(sw):
            cols = span(w, w2, j - pw, sw)
            for k in range(taps):
                copy_spans(dst[(i * sw + j) * taps + k], src,
                           [span(t, t_out, k - pad, 1), rows, cols])
    if channels_last:
        return out.view(b * t_out, h2, w2, n).permute(0, 3, 1, 2)
    return out.view(b * t_out, n, h2, w2)


class FramesStem(nn.Module):
    """A 3D convolution of temporal stride 1 computed as one 2D convolution over all frames,
    its temporal taps as input channels (``channels`` pads them with zeros, channels-last
    only). Same function, same products, in another order. ``space_to_depth`` runs that 2D
    convolution over its input's stride phases (:class:`.phases.PhaseConv2d`; ``channels``
    then pads the phases' channels), frames and phases made in one copy."""

    def __init__(self, conv: nn.Conv3d, channels_last: bool, channels: int | None = None,
                 *, space_to_depth: bool = False) -> None:
        super().__init__()
        kt, kh, kw = conv.kernel_size
        if conv.stride[0] != 1 or conv.dilation[0] != 1 or conv.groups != 1 \
                or isinstance(conv.padding, str) or conv.padding_mode != "zeros":
            raise ValueError("the temporal taps become channels only for a convolution with "
                             "temporal stride 1, no dilation, no groups and zero padding")
        if space_to_depth and conv.dilation != (1, 1, 1):
            raise ValueError("space-to-depth needs a convolution without dilation")
        o, c = conv.out_channels, conv.in_channels
        w = conv.weight.detach().permute(0, 2, 1, 3, 4).reshape(o, kt * c, kh, kw)
        self.taps, self.pad = kt, conv.padding[0]
        self.channels_last = channels_last
        self.conv2d: nn.Module
        if space_to_depth:
            self.frame_channels = kt * c
            self.conv2d = PhaseConv2d(w, conv.bias, conv.stride[1:], conv.padding[1:],
                                      channels_last, channels)
            return
        self.frame_channels = channels or kt * c
        conv2d = nn.Conv2d(self.frame_channels, o, (kh, kw), conv.stride[1:],
                           conv.padding[1:], conv.dilation[1:], bias=conv.bias is not None,
                           device=w.device, dtype=w.dtype)
        w2 = torch.zeros_like(conv2d.weight)
        w2[:, : kt * c] = w
        if channels_last:
            w2 = w2.contiguous(memory_format=torch.channels_last)
        conv2d.weight = nn.Parameter(w2, requires_grad=False)
        if conv.bias is not None:
            conv2d.bias = nn.Parameter(conv.bias.detach().clone(), requires_grad=False)
        self.conv2d = conv2d

    @property
    def in_channels(self) -> int:
        """Input channels of the 2D convolution it runs (zero channels included)."""
        return self.conv2d.weight.shape[1]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x.to(self.conv2d.weight.dtype)
        if isinstance(self.conv2d, PhaseConv2d):  # frames and phases in one copy
            p = self.conv2d
            y = p.convolve(frames_phases_as_channels(
                x, self.taps, self.pad, p.stride, p.padding, p.kernel, self.channels_last,
                self.in_channels))
        else:
            y = self.conv2d(frames_as_channels(x, self.taps, self.pad, self.channels_last,
                                               self.frame_channels))
        return y.unflatten(0, (x.shape[0], -1)).transpose(1, 2)  # (B, O, T', H', W')
