"""A torch-only equivalent of torchvision's ``transforms.GaussianBlur`` for ColorVideoVDP.

ColorVideoVDP imports ``GaussianBlur`` from torchvision at its top level and uses it in its
default configuration (the phase-uncertainty blur, sigma 3, 13 taps). Where torchvision cannot
be imported (as beside some CPU builds of torch), this module supplies the same operation:
a normalised 1-D Gaussian ``exp(-x^2 / (2 sigma^2))`` on ``x = -(k-1)/2 .. (k-1)/2``, its
outer product as the 2-D kernel (applied here as two 1-D passes), reflect padding of k // 2;
a scalar sigma is used as is (torchvision draws it from [sigma, sigma]). Tests check it
against a separable SciPy computation of the same filter.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F


def gaussian_kernel1d(size: int, sigma: float, dtype: torch.dtype,
                      device: torch.device) -> torch.Tensor:
    half = (size - 1) * 0.5
    x = torch.linspace(-half, half, steps=size)
    pdf = torch.exp(-0.5 * (x / sigma).pow(2))
    return (pdf / pdf.sum()).to(device=device, dtype=dtype)


def gaussian_blur(img: torch.Tensor, kernel_size: Sequence[int],
                  sigma: Sequence[float]) -> torch.Tensor:
    """Blur (..., C, H, W) float images; kernel_size and sigma are (x, y) pairs."""
    shape = img.shape
    x = img.reshape(-1, *shape[-3:]) if img.dim() != 4 else img
    c = x.size(1)
    kx = gaussian_kernel1d(kernel_size[0], sigma[0], x.dtype, x.device)
    ky = gaussian_kernel1d(kernel_size[1], sigma[1], x.dtype, x.device)
    pad = [kernel_size[0] // 2, kernel_size[0] // 2, kernel_size[1] // 2, kernel_size[1] // 2]
    x = F.pad(x, pad, mode="reflect")
    # the 2-D kernel is the outer product ky kx^T: two 1-D passes give the same filter with
    # 2k instead of k^2 multiply-adds (equal up to float rounding)
    x = F.conv2d(x, kx.view(1, 1, 1, -1).expand(c, 1, 1, kernel_size[0]), groups=c)
    x = F.conv2d(x, ky.view(1, 1, -1, 1).expand(c, 1, kernel_size[1], 1), groups=c)
    return x.reshape(shape)


class GaussianBlur(torch.nn.Module):
    """``GaussianBlur(kernel_size, sigma)`` with a fixed sigma, like torchvision's."""

    def __init__(self, kernel_size: int | Sequence[int],
                 sigma: float | Sequence[float] = (0.1, 2.0)) -> None:
        super().__init__()
        ks = (kernel_size, kernel_size) if isinstance(kernel_size, int) else tuple(kernel_size)
        if any(k <= 0 or k % 2 == 0 for k in ks):
            raise ValueError("kernel size must be positive and odd")
        lo, hi = (sigma, sigma) if isinstance(sigma, int | float) else tuple(sigma)
        if lo != hi:
            raise ValueError("this stand-in supports a fixed sigma only")
        self.kernel_size = ks
        self.sigma = float(lo)

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        return gaussian_blur(img, self.kernel_size, (self.sigma, self.sigma))
