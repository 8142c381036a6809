"""Copying a strided window of one tensor into another, zeros around it.

Every rewritten stem input (frames as channels, stride phases as channels) is the stem's
input read at shifted, strided positions, with zeros where those positions fall outside the
clip: the convolution's zero padding made explicit. One copy per block, no padded
intermediate.
"""

from __future__ import annotations

import torch

Span = tuple[int, int, int, int]
"""Along one axis: destination rows ``lo:hi`` take source rows ``start``, ``start + step``,
... (lo, hi, start, step); the destination's other rows are zeros."""


def span(size: int, out: int, offset: int, step: int) -> Span:
    """The span of ``out`` destination rows where row ``a`` reads source row ``step * a +
    offset`` of ``size`` (zeros where that is outside ``0 .. size - 1``)."""
    lo = min(out, max(0, -(offset // step)))  # first a with step * a + offset >= 0
    hi = max(lo, min(out, (size - 1 - offset) // step + 1))
    return lo, hi, step * lo + offset, step


def copy_spans(dst: torch.Tensor, src: torch.Tensor, spans: list[Span]) -> None:
    """Axes 1 .. len(``spans``) of ``dst``: the spans' rows from ``src`` (axis 0 and the
    axes after the spans are copied whole), zeros elsewhere."""
    inner: list[slice] = [slice(None)]
    for lo, hi, _, _ in spans:
        dst[(*inner, slice(None, lo))].zero_()
        dst[(*inner, slice(hi, None))].zero_()
        inner.append(slice(lo, hi))
    if all(hi > lo for lo, hi, _, _ in spans):
        dst[tuple(inner)].copy_(src[(slice(None), *(slice(s, s + st * (hi - lo), st)
                                                     for lo, hi, s, st in spans))])
