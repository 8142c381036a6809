"""fp32's stem from one TF32 convolution of split operands.

A TF32 stem rounds both operands to 11 significant bits; on real content that moved
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
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .padding import pad_stem_conv

SPLITS = ("int", "3xtf32")
"""The split stems, by name (see the module docstring)."""


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
