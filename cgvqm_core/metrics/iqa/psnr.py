"""PSNR on RGB in [0, 1]: one mean squared error over all channels and pixels of an image."""

from __future__ import annotations

import torch

from ._common import check_pair

#: added to the MSE so that identical images give a finite 80 dB (PIQ's convention)
EPS = 1e-8


def psnr(test: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """10 log10(1 / (MSE + 1e-8)) per image, in dB (higher is better)."""
    check_pair(test, ref)
    mse = (test - ref).pow(2).mean(dim=(1, 2, 3))
    return -10.0 * torch.log10(mse + EPS)
