"""Reduced-precision features of test videos, carried as differences from their reference's.

Why: in bf16 an activation keeps 8 significant bits. A reference and a test video that differ a
little are rounded independently at every layer, and CGVQM squares the difference of their
features, so the rounding noise adds to every mean squared difference. On the demo study (a
random backbone) it added 0.1 % (layer1) to 0.5 % (layer4) on average, up to 70 % on
near-identical patches, and moved q by up to 0.12 where the bound is 0.05.

Between its ReLUs the network is linear (convolutions, batch norm, residual sums), so a test's
activation can be carried as the reference's ``r`` plus a difference ``d`` with only ``d``
rounded to bf16: its rounding error is then relative to the difference CGVQM measures, not to
the activation. Across a ReLU the new difference is exactly

    relu(r + d) - relu(r) = max(d + min(r, 0), -relu(r)),

which rounds nothing where r > 0 and only the test's own activation r + d where r <= 0. What
remains is the rounding of the weights to bf16, one network for both videos.

The references run as one batch (G) and the differences of their tests as another (G x n,
convolutions without bias): the FLOPs of running every video, and the references' numbers
are those of the plain path. A :class:`RefTape` keeps what a reference contributes, so that
later passes over more tests of the same position do not run it again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .backbone import BasicBlock, VideoResNet
from .errors import CGVQMError
from .precision import cudnn_tf32
from .unit_norm import unit_norm_fp32

LevelPair = tuple[torch.Tensor, torch.Tensor]


class RefTape:
    """A reference's tensors that passes over its test videos need, in the order they use
    them: the pass that has the reference in its batch records, later passes replay."""

    def __init__(self) -> None:
        self.items: list[Any] = []
        self.filled = False
        self._next = 0

    def rewind(self) -> None:
        self._next = 0

    def through(self, make: Callable[[], Any]) -> Any:
        """``make()`` while recording (and kept); the recorded value when replaying."""
        if self.filled:
            value = self.items[self._next]
            self._next += 1
            return value
        value = make()
        self.items.append(value)
        return value


class _DifferencePass:
    """One pass: G references (None when replayed from the tape) and the differences of their
    n tests each, module by module."""

    def __init__(self, G: int, tape: RefTape | None) -> None:
        self.G = G
        self.tape = tape
        self.replay = tape is not None and tape.filled
        if tape is not None:
            tape.rewind()

    def ref(self, make: Callable[[], Any]) -> Any:
        return make() if self.tape is None else self.tape.through(make)

    def apply(self, m: nn.Module, r: torch.Tensor | None, d: torch.Tensor | None
              ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        if isinstance(m, BasicBlock):
            return self.block(m, r, d)
        if isinstance(m, nn.Conv3d):
            return (None if r is None else m(r),
                    None if d is None else F.conv3d(d, m.weight, None, m.stride, m.padding,
                                                    m.dilation, m.groups))
        if isinstance(m, nn.BatchNorm3d):
            scale = (m.weight.float() / torch.sqrt(m.running_var.float() + m.eps))
            return (None if r is None else m(r),
                    None if d is None else d * scale.to(d.dtype).view(1, -1, 1, 1, 1))
        if isinstance(m, nn.ReLU):
            return self.relu(r, d)
        if isinstance(m, nn.Identity):
            return r, d
        if isinstance(m, nn.Sequential):
            for child in m:
                r, d = self.apply(child, r, d)
            return r, d
        raise CGVQMError(f"internal error: no difference rule for {type(m).__name__}")

    def relu(self, r: torch.Tensor | None, d: torch.Tensor | None
             ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        out = None

        def make() -> tuple[torch.Tensor, torch.Tensor]:
            nonlocal out
            assert r is not None
            neg = r.clamp(max=0)
            out = r.clamp_min_(0)  # r is a fresh convolution output or residual sum
            return neg, out.neg()

        neg, minus_out = self.ref(make)
        if d is not None:
            d.unflatten(0, (self.G, -1)).add_(neg.unsqueeze(1)).clamp_(
                min=minus_out.unsqueeze(1))
        return out, d

    def block(self, m: BasicBlock, r: torch.Tensor | None, d: torch.Tensor | None
              ) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        rr, rd = (r, d) if m.downsample is None else self.apply(m.downsample, r, d)
        a, ad = self.apply(m.conv1, r, d)
        b, bd = self.apply(m.conv2, a, ad)
        if b is not None:
            b += rr
        if bd is not None:
            bd += rd
        return self.relu(b, bd)

    def level(self, r: torch.Tensor | None, d: torch.Tensor | None) -> LevelPair:
        """References' features (G, 1, C, ...) and tests' (G, n, C, ...), unit-normalised."""
        r_act, r_norm = self.ref(lambda: (r, unit_norm_fp32(r)))
        rn = r_norm.unsqueeze(1)
        if d is None:
            return rn, rn[:, :0]
        t = d.to(torch.float32, copy=True)  # d goes on to the next stage
        t.unflatten(0, (self.G, -1)).add_(r_act.unsqueeze(1))
        return rn, unit_norm_fp32(t, inplace=True).unflatten(0, (self.G, -1))


def difference_levels(model: VideoResNet, x: torch.Tensor, G: int, n: int, n_levels: int,
                      dtype: torch.dtype, fp32_stem: bool, tape: RefTape | None, *,
                      tf32_stem: bool = False) -> Iterator[LevelPair]:
    """Per level, the references' and the tests' features (see :meth:`FeatureNet.pair_levels`).

    ``x`` is the fp32 input of the G references followed by their G x n tests (the tests
    only, when ``tape`` replays); the stem runs on all of them in fp32 when ``fp32_stem``
    (cuDNN's TF32 mode allowed for it when ``tf32_stem``).
    """
    p = _DifferencePass(G, tape)
    xr = p.ref(lambda: x[:G].clone() if tape is not None else x[:G])
    xt = x if p.replay else x[G:]
    yield xr.unsqueeze(1), xt.unflatten(0, (G, n))
    stages = model.stages()[: n_levels - 1]
    if not stages:
        return
    if fp32_stem:
        with cudnn_tf32(tf32_stem):
            h = stages[0](x)
        hr = p.ref(lambda: h[:G].clone() if tape is not None else h[:G])
        ht = h if p.replay else h[G:]
        d = (ht.unflatten(0, (G, n)) - hr.unsqueeze(1)).flatten(0, 1).to(dtype) if n else None
        r = None if p.replay else hr.to(dtype)
        rn = p.ref(lambda: unit_norm_fp32(hr)).unsqueeze(1)
        yield rn, unit_norm_fp32(ht, inplace=True).unflatten(0, (G, n))
        del h, ht
        stages = stages[1:]
    else:
        d = (xt.unflatten(0, (G, n)) - xr.unsqueeze(1)).flatten(0, 1).to(dtype) if n else None
        r = None if p.replay else xr.to(dtype)
    for stage in stages:
        r, d = p.apply(stage, r, d)
        yield p.level(r, d)
    if tape is not None:
        tape.filled = True
