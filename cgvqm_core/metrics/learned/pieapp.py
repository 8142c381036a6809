"""PieAPP (Prashnani et al. 2018) as PIQ 0.8 defines it.

The network takes 64x64 RGB patches in [0, 255]: eleven 3x3 convolutions with ReLU and
2x2 max-pooling, features of five depths concatenated (120,832 numbers per patch) and the
last convolution's output (2,048). For a test and a reference image, patches are cut at
PIQ's stride (27 pixels, the authors' "sparse" sampling; no patch at the far edge if the
stride does not reach it); per patch, an error from the feature difference (reference minus
test) through ``fc1_score``/``fc2_score``/``ref_score_subtract`` and a weight from the
last-layer difference through ``fc1_weight``/``fc2_weight`` (+1e-6); the image's PieAPP is
the weighted mean of its patch errors. Patches are processed a band at a time, so memory
does not grow with the frame size. Parameter names equal PIQ's and the authors' PyTorch
model, so ``PieAPPv0.1.pth`` loads strictly.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from ..iqa._common import check_pair

PATCH = 64
STRIDE = 27
FEATURES = 64


class PieAPPNet(nn.Module):
    """PieAPP v0.1's network (module names as in the published state dict)."""

    EPS = 1e-6

    def __init__(self) -> None:
        super().__init__()
        f = FEATURES
        chans = [(3, f), (f, f), (f, f), (f, 2 * f), (2 * f, 2 * f), (2 * f, 2 * f),
                 (2 * f, 4 * f), (4 * f, 4 * f), (4 * f, 4 * f), (4 * f, 8 * f), (8 * f, 8 * f)]
        for i, (cin, cout) in enumerate(chans, start=1):
            setattr(self, f"conv{i}", nn.Conv2d(cin, cout, kernel_size=3, padding=1))
        self.fc1_score = nn.Linear(120832, 512)
        self.fc2_score = nn.Linear(512, 1)
        self.fc1_weight = nn.Linear(2048, 512)
        self.fc2_weight = nn.Linear(512, 1)
        self.ref_score_subtract = nn.Linear(1, 1)

    def _c(self, i: int, x: torch.Tensor) -> torch.Tensor:
        return F.relu(getattr(self, f"conv{i}")(x))

    def patch_features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(multi-scale features (N, 120832), last-layer features (N, 2048)) of (N, 3, 64, 64)
        patches in [0, 255]."""
        pool = lambda t: F.max_pool2d(t, 2, 2)  # noqa: E731
        x3 = self._c(3, pool(self._c(2, self._c(1, x))))
        x5 = self._c(5, pool(self._c(4, x3)))
        x7 = self._c(7, pool(self._c(6, x5)))
        x9 = self._c(9, pool(self._c(8, x7)))
        x11 = self._c(11, pool(self._c(10, x9))).flatten(1)
        feats = torch.cat([x3.flatten(1), x5.flatten(1), x7.flatten(1), x9.flatten(1), x11],
                          dim=1)
        return feats, x11

    def patch_scores(self, feat_diff: torch.Tensor, weight_diff: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """(errors (N, 1), weights (N, 1)) of patches from their feature differences."""
        error = self.ref_score_subtract(0.01 * self.fc2_score(F.relu(self.fc1_score(feat_diff))))
        weight = self.fc2_weight(F.relu(self.fc1_weight(weight_diff))) + self.EPS
        return error, weight


def patch_grid(height: int, width: int, stride: int = STRIDE) -> tuple[int, int]:
    """Patches per column and per row (PIQ's ``unfold``: no partial patch at the edges)."""
    return (height - PATCH) // stride + 1, (width - PATCH) // stride + 1


def pieapp(net: PieAPPNet, x: torch.Tensor, y: torch.Tensor, *, stride: int = STRIDE,
           chunk: int = 64) -> torch.Tensor:
    """(N,) float64 PieAPP of test images ``x`` against references ``y`` ((N, 3, H, W) in
    [0, 1]), about ``chunk`` patches per image side and pass."""
    check_pair(x, y, channels=(3,))
    n, c, h, w = x.shape
    if min(h, w) < PATCH:
        raise ValueError(f"PieAPP needs at least {PATCH}x{PATCH} pixels, got {w}x{h}")
    rows, cols = patch_grid(h, w, stride)
    # a view (no copy): (N, 3, rows, cols, 64, 64)
    xs = (x * 255).unfold(2, PATCH, stride).unfold(3, PATCH, stride)
    ys = (y * 255).unfold(2, PATCH, stride).unfold(3, PATCH, stride)
    band = max(1, chunk // max(1, n * cols))
    num = torch.zeros(n, dtype=torch.float64, device=x.device)
    den = torch.zeros_like(num)
    def cut(t: torch.Tensor, r0: int) -> torch.Tensor:  # (N * band * cols, 3, 64, 64)
        return t[:, :, r0:r0 + band].permute(0, 2, 3, 1, 4, 5).reshape(-1, c, PATCH, PATCH)

    for r0 in range(0, rows, band):
        tp, rp = cut(xs, r0), cut(ys, r0)
        m = tp.shape[0]
        feats, last = net.patch_features(torch.cat([tp, rp]))
        err, wt = net.patch_scores(feats[m:] - feats[:m], last[m:] - last[:m])
        err, wt = err.reshape(n, -1).double(), wt.reshape(n, -1).double()
        num += (err * wt).sum(dim=1)
        den += wt.sum(dim=1)
    return num / den
