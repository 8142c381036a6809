"""Building blocks shared by the image metrics: kernels, colour transforms, similarity maps."""

from __future__ import annotations

import torch
import torch.nn.functional as F

#: RGB -> YIQ (NTSC), rows Y, I, Q
YIQ = ((0.299, 0.587, 0.114), (0.5959, -0.2746, -0.3213), (0.2115, -0.5227, 0.3112))
#: RGB -> LMN opponent space of VSI (Zhang et al. 2014)
LMN = ((0.06, 0.63, 0.27), (0.30, 0.04, -0.35), (0.34, -0.60, 0.17))
#: RGB -> LHM of MDSI (Nafchi et al. 2016)
LHM = ((0.2989, 0.587, 0.114), (0.30, 0.04, -0.35), (0.34, -0.60, 0.17))


#: How far outside [0, 1] a value may lie and still be rounding, not another range.
RANGE_SLACK = 1e-4


def check_pair(test: torch.Tensor, ref: torch.Tensor, *, channels: tuple[int, ...] = (1, 3)
               ) -> None:
    """Both (B, C, H, W) of one shape, C in ``channels``, float32 or float64 alike, finite,
    in [0, 1].

    Every formula here assumes that range (their constants are set for it): 0..255 input
    gives PSNR -26 dB and a wrong SSIM without any error, and a NaN pixel a plausible
    VIF or DSS; half precision overflows in several of them. So each is refused here."""
    if test.shape != ref.shape or test.dim() != 4:
        raise ValueError(f"expected two (B, C, H, W) tensors of one shape, got {tuple(test.shape)}"
                         f" and {tuple(ref.shape)}")
    if test.size(1) not in channels:
        hint = " (channels last? use .permute(0, 3, 1, 2))" if test.size(-1) in channels else ""
        allowed = " or ".join(str(c) for c in channels)
        raise ValueError(f"expected (B, C, H, W) with C {allowed}, got {tuple(test.shape)}"
                         f"{hint}")
    if test.dtype not in (torch.float32, torch.float64) or ref.dtype != test.dtype:
        raise ValueError(f"image metrics take float32 or float64 images in [0, 1], both of "
                         f"one type; got {test.dtype} and {ref.dtype} (uint8: divide by 255)")
    for name, x in (("test", test), ("reference", ref)):
        lo, hi = torch.aminmax(x)
        if not (torch.isfinite(lo) and torch.isfinite(hi)):
            raise ValueError(f"the {name} image holds NaN or infinite values")
        if lo < -RANGE_SLACK or hi > 1 + RANGE_SLACK:
            raise ValueError(f"the {name} image spans {float(lo):g}..{float(hi):g}; image "
                             "metrics take [0, 1] (uint8: divide by 255)")


def colour_transform(x: torch.Tensor, matrix: tuple[tuple[float, ...], ...]) -> torch.Tensor:
    """Apply a 3x3 colour matrix to (B, 3, H, W)."""
    m = torch.tensor(matrix, dtype=x.dtype, device=x.device)
    return torch.einsum("oc,bchw->bohw", m, x)


def luma_yiq(x: torch.Tensor) -> torch.Tensor:
    """The Y of YIQ (BT.601 luma weights) as (B, 1, H, W); grey input passes through."""
    if x.size(1) == 1:
        return x
    w = torch.tensor(YIQ[0], dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    return (x * w).sum(1, keepdim=True)


def gaussian_kernel(size: int, sigma: float, *, dtype: torch.dtype = torch.float32,
                    device: torch.device | str | None = None) -> torch.Tensor:
    """A normalised (size, size) Gaussian centred on the kernel's middle."""
    r = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2.0
    g = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * sigma**2))
    return g / g.sum()


def depthwise(x: torch.Tensor, kernel2d: torch.Tensor, padding: int = 0) -> torch.Tensor:
    """Filter every channel with the same 2-D kernel (correlation, like conv2d)."""
    c = x.size(1)
    k = kernel2d.to(x.dtype).expand(c, 1, *kernel2d.shape[-2:])
    return F.conv2d(x, k, padding=padding, groups=c)


def prewitt(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    k = torch.tensor([[-1.0, 0.0, 1.0]] * 3, dtype=dtype, device=device) / 3
    return torch.stack([k, k.t()])[:, None]  # (2, 1, 3, 3): horizontal, vertical


def scharr(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    k = torch.tensor([[-3.0, 0.0, 3.0], [-10.0, 0.0, 10.0], [-3.0, 0.0, 3.0]], dtype=dtype,
                     device=device) / 16
    return torch.stack([k, k.t()])[:, None]


def gradient_magnitude(x: torch.Tensor, kernels: torch.Tensor) -> torch.Tensor:
    """sqrt(gx^2 + gy^2) of a one-channel image, zero padding (size preserved)."""
    g = F.conv2d(x, kernels, padding=kernels.size(-1) // 2)
    return g.pow(2).sum(1, keepdim=True).sqrt()


def similarity(a: torch.Tensor, b: torch.Tensor, c: float, alpha: float = 0.0) -> torch.Tensor:
    """(2ab - alpha ab + c) / (a^2 + b^2 - alpha ab + c): the similarity of two feature maps."""
    ab = a * b
    return (2.0 * ab - alpha * ab + c) / (a**2 + b**2 - alpha * ab + c)


def pad_avg_pool(x: torch.Tensor, k: int, *, before: int, after: int,
                 mode: str = "constant") -> torch.Tensor:
    """Pad (left=top=before, right=bottom=after) then average-pool with a k x k window."""
    if before or after:
        x = F.pad(x, [before, after, before, after], mode=mode)
    return F.avg_pool2d(x, k) if k > 1 else x


def halve(x: torch.Tensor) -> torch.Tensor:
    """2x2 average pooling after zero padding odd sizes at the end (down-sampling step)."""
    p = max(x.size(2) % 2, x.size(3) % 2)
    if p:
        x = F.pad(x, [0, p, 0, p])
    return F.avg_pool2d(x, 2)


def frequency_grid(h: int, w: int, *, dtype: torch.dtype,
                   device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised frequency coordinates (rows, columns) centred on zero, as in MATLAB's
    filter-construction code of FSIM and VSI: odd sizes span [-0.5, 0.5], even sizes
    [-0.5, 0.5)."""

    def axis(n: int) -> torch.Tensor:
        if n % 2:
            return torch.arange(-(n - 1) / 2, n / 2, dtype=dtype, device=device) / (n - 1)
        return torch.arange(-n / 2, n / 2, dtype=dtype, device=device) / n

    return torch.meshgrid(axis(h), axis(w), indexing="ij")


def per_image_minmax(x: torch.Tensor, eps: float) -> torch.Tensor:
    """Scale every image of (B, C, H, W) to [0, 1] by its own minimum and maximum."""
    lo = x.amin(dim=(1, 2, 3), keepdim=True)
    hi = x.amax(dim=(1, 2, 3), keepdim=True)
    return (x - lo) / (hi - lo + eps)
