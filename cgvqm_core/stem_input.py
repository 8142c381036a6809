"""The stem's convolution rewritten over more input channels, for cuDNN's fast kernels.

Three rewrites, each a new stem convolution and the input it takes:

- **Padded** (:func:`pad_stem_conv`, :func:`padded_input`): zero channels, same function.
- **Split** (:class:`SplitStem`): fp32's function from one TF32 convolution, for a fast
  stem that is not TF32's (see below).
- **Frames** (:class:`FramesStem`): the 3D convolution as one 2D convolution over all
  frames, its temporal taps as input channels (see below).

Padding. The stem convolves 3-channel video. In the channels-last layout a voxel's three values
are 12 bytes (fp32) or 6 bytes (bf16/fp16), which rules out cuDNN's vectorised kernels:
on an H200 the fp32 stem ran at half the fp32 convolution rate, a third of CGVQM-2's
network time under fp16. One or five zero channels (16 bytes a voxel) with zero weights
leave every product the convolution sums unchanged (the added products are exact zeros),
so the stem computes the same function up to summation order.

Splitting. A TF32 stem rounds both operands to 11 significant bits; on real content that moved
q by up to 0.14 against fp32 (docs/performance.md), while the exact fp32 stem costs fp16 a
third of its speed. But a product of two TF32 numbers is exact in fp32, and the tensor cores
add products in fp32. So each operand is written as a sum of TF32 numbers and the products
that matter at fp32's precision become extra input channels of one TF32 convolution:

- ``"3xtf32"``: x = x_hi + x_lo and w = w_hi + w_lo give x*w = x_hi*w_hi + x_hi*w_lo +
  x_lo*w_hi (+ x_lo*w_lo, about 2^-22 of it, dropped): input [x_hi, x_hi, x_lo] against
  weights [w_hi, w_lo, w_hi], 9 channels padded to 12. Any input.
- ``"int"``: the input is uint8 video normalised, x_c = a_c (p - q_c) + e_c with
  a_c = 1/(255 std_c), q_c the integer nearest 255 mean_c and e_c = a_c (q_c - 255 mean_c).
  The integers p - q_c are exact in TF32, so only the weights need splitting: input
  [p - q, p - q, 1, 1] against [(a w)_hi, (a w)_lo, E_hi, E_lo], 8 channels, where
  E = sum_c e_c w_c and the ones channel is zero in the convolution's padding exactly where x
  is. Two thirds of the products of ``"3xtf32"``; the input must come from uint8 pixels
  normalised by ``mean`` and ``std`` (what :meth:`.features.FeatureNet.to_input` makes).

Either way the products are exact, their sum fp32, and the result within about 2^-22 of the
fp32 stem in relative terms: fp32's numbers, at whatever speed cuDNN's TF32 kernels give
8 or 12 channels (to be measured on a GPU).

Frames. The stem's temporal stride is 1, so output frame t sees input frames t-1, t and
t+1 with the same weights wherever t is. Stacking those frames' channels (9, zeros beyond
the clip's ends, as the 3D convolution pads) makes the stem a 7x7 conv2d over every frame
at once: the same products in another order, so fp32's numbers in fp32. cuDNN's fp32 conv3d
ran the stem at about 16 TFLOP/s on an H200, a quarter of its fp32 units; its 2D kernels
are tuned for far more networks (whether they do better here is for a GPU to show). It
composes with a split: the split convolution is a 3D convolution like the stem's.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

SPLITS = ("int", "3xtf32")
"""The split stems, by name (see the module docstring)."""


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
    for k, d in enumerate(dst):
        # output frames j with a source frame j - pad + k inside the clip
        lo, hi = max(0, pad - k), max(0, min(t_out, t + pad - k))
        d[:, :lo].zero_()
        d[:, hi:].zero_()
        if hi > lo:
            d[:, lo:hi].copy_(src[:, lo - pad + k: hi - pad + k])
    if channels_last:
        return out.view(b * t_out, h, w, n).permute(0, 3, 1, 2)
    return out.view(b * t_out, n, h, w)


class FramesStem(nn.Module):
    """A 3D convolution of temporal stride 1 computed as one 2D convolution over all frames,
    its temporal taps as input channels (``channels`` pads them with zeros, channels-last
    only). Same function, same products, in another order."""

    def __init__(self, conv: nn.Conv3d, channels_last: bool, channels: int | None = None
                 ) -> None:
        super().__init__()
        kt, kh, kw = conv.kernel_size
        if conv.stride[0] != 1 or conv.dilation[0] != 1 or conv.groups != 1 \
                or isinstance(conv.padding, str) or conv.padding_mode != "zeros":
            raise ValueError("the temporal taps become channels only for a convolution with "
                             "temporal stride 1, no dilation, no groups and zero padding")
        o, c = conv.out_channels, conv.in_channels
        n = channels or kt * c
        w = conv.weight.detach()
        w2 = torch.zeros((o, n, kh, kw), dtype=w.dtype, device=w.device)
        w2[:, : kt * c] = w.permute(0, 2, 1, 3, 4).reshape(o, kt * c, kh, kw)
        if channels_last:
            w2 = w2.contiguous(memory_format=torch.channels_last)
        self.weight = nn.Parameter(w2, requires_grad=False)
        self.bias = None if conv.bias is None else nn.Parameter(conv.bias.detach().clone(),
                                                                requires_grad=False)
        self.taps, self.pad = kt, conv.padding[0]
        self.stride, self.padding = conv.stride[1:], conv.padding[1:]
        self.dilation = conv.dilation[1:]
        self.channels_last = channels_last

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        frames = frames_as_channels(x.to(self.weight.dtype), self.taps, self.pad,
                                    self.channels_last, self.weight.shape[1])
        y = F.conv2d(frames, self.weight, self.bias, self.stride, self.padding,
                     self.dilation)
        return y.unflatten(0, (x.shape[0], -1)).transpose(1, 2)  # (B, O, T', H', W')


def round_tf32(x: torch.Tensor) -> torch.Tensor:
    """fp32 ``x`` rounded to TF32's 10 mantissa bits (to nearest, ties away from zero, as a
    GPU converts fp32 to TF32); still an fp32 tensor, in ``x``'s layout. Integer arithmetic
    with Python constants only: nothing is copied to the device."""
    i = x.view(torch.int32)
    mag = i & 0x7FFFFFFF
    return (((mag + 0x1000) & ~0x1FFF) | (i ^ mag)).view(torch.float32)


def _hi_lo(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """fp32 ``x`` (or float64, rounded once) as hi + lo, both TF32 numbers; the rest is
    about 2^-22 of x."""
    hi = round_tf32(x.to(torch.float32))
    return hi, round_tf32((x - hi.to(x.dtype)).to(torch.float32))


class SplitStem:
    """One split stem (``split`` in :data:`SPLITS`) for a network whose input is normalised
    by ``mean`` and ``std``: the convolution it runs and the input that convolution takes.
    Its constants live on ``device`` from the start, so that making the input never waits
    for the GPU."""

    def __init__(self, split: str, mean: Sequence[float], std: Sequence[float],
                 device: torch.device | str = "cpu") -> None:
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; choose from {', '.join(SPLITS)}")
        if len(mean) != len(std):
            raise ValueError("a mean and a std per channel")
        self.split = split
        m = torch.tensor(mean, dtype=torch.float32).double()
        s = torch.tensor(std, dtype=torch.float32).double()
        # x_c = a_c (p - q_c) + e_c, with p the uint8 pixel (see the module docstring)
        self.a = 1.0 / (255.0 * s)
        self.q = torch.round(255.0 * m)
        self.e = self.a * (self.q - 255.0 * m)
        shape = (1, len(mean), 1, 1, 1)
        # p - q recovered from x: x * 255 std + (255 mean - q) is within 1e-4 of an integer
        self._scale = (255.0 * s).float().view(shape).to(device)
        self._offset = (255.0 * m - self.q).float().view(shape).to(device)

    def channels(self, c: int) -> int:
        """Input channels of the split convolution for a ``c``-channel stem (16-byte
        voxels: 8 for "int", 12 for "3xtf32" of 3)."""
        return 2 * c + 2 if self.split == "int" else -(-3 * c // 4) * 4

    def conv(self, conv: nn.Conv3d, channels_last: bool) -> nn.Conv3d:
        """A copy of fp32 ``conv`` over the split input, its weights split into TF32
        numbers."""
        w = conv.weight.detach().double()
        c = conv.in_channels
        if self.split == "3xtf32":
            hi, lo = _hi_lo(w)
            parts = [hi, lo, hi]
        else:
            if c != self.a.numel():
                raise ValueError(f"the int split needs a mean and std per channel ({c})")
            shape = (1, c, 1, 1, 1)
            scaled = w * self.a.to(w.device).view(shape)
            ones = (w * self.e.to(w.device).view(shape)).sum(1, True)
            parts = [*_hi_lo(scaled), *_hi_lo(ones)]
        out = pad_stem_conv(conv, self.channels(c), False)
        with torch.no_grad():
            out.weight.zero_()
            out.weight[:, : sum(p.shape[1] for p in parts)].copy_(torch.cat(parts, 1))
        if channels_last:
            out.weight = nn.Parameter(
                out.weight.contiguous(memory_format=torch.channels_last_3d),
                requires_grad=False)
        return out

    def input(self, x: torch.Tensor, channels_last: bool, *, check: bool = False
              ) -> torch.Tensor:
        """What :meth:`conv`'s convolution takes for the fp32 input ``x`` (B, C, T, H, W).
        For "int", ``x`` must be uint8 pixels normalised by the mean and std, which
        ``check`` verifies (a ValueError otherwise; it waits for the GPU, so once per
        network is enough)."""
        b, c, t, h, w = x.shape
        ones = 0
        if self.split == "3xtf32":
            hi, lo = _hi_lo(x)
            parts = [hi, hi, lo]
        else:
            pq = torch.addcmul(self._offset, x, self._scale)
            if check:
                off = (pq - pq.round()).abs().max().item()
                if off > 1e-2:
                    raise ValueError("the int split stem needs uint8 pixels normalised by "
                                     f"the network's mean and std; this input is {off:.2f} "
                                     "from them")
            pq.round_()
            parts, ones = [pq, pq], 2
        n = self.channels(c)
        if channels_last:
            out = torch.empty((b, t, h, w, n), dtype=torch.float32,
                              device=x.device).permute(0, 4, 1, 2, 3)
        else:
            out = torch.empty((b, n, t, h, w), dtype=torch.float32, device=x.device)
        at = 0
        for part in parts:
            out[:, at: at + c].copy_(part)
            at += c
        out[:, at: at + ones].fill_(1.0)
        out[:, at + ones:].zero_()
        return out


class StemRewrite:
    """The stem's convolution as a network runs it: as it is, or split (``split``, a name in
    :data:`SPLITS`), as a 2D stem (``two_d``) or both, or with zero channels (``pad``: the
    16-byte voxels of :func:`padded_channels`; a 2D stem pads its taps' channels, only in
    the channels-last layout). :attr:`module` replaces the convolution, :meth:`input` makes
    what it takes, and :attr:`padded` says whether padding applied. The convolution must be
    a plain 3D one (``None`` for a stem that is none, which only ``pad`` tolerates: it is
    then left out); a ValueError says why otherwise."""

    def __init__(self, conv: nn.Module | None, *, split: str | None, two_d: bool, pad: bool,
                 channels_last: bool, mean: Sequence[float], std: Sequence[float],
                 device: torch.device | str = "cpu") -> None:
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
            channels = None  # or the taps' channels padded to 16-byte voxels
            if pad and channels_last and self.split is None:
                unit = padded_channels(conv.weight.dtype)
                channels = -(-conv.kernel_size[0] * conv.in_channels // unit) * unit
            self.padded = channels is not None
            self.module = FramesStem(conv, channels_last, channels)
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
