"""Fixtures of the peer-metric tests: real photographic content (scikit-image's bundled
photographs) panned into short videos, graded distortions of them, and no network."""

from __future__ import annotations

import numpy as np
import pytest
import torch


def real_video(frames: int = 8, height: int = 176, width: int = 176, *,
               image: str = "astronaut", step: int = 3) -> np.ndarray:
    """A camera pan over a real photograph: (frames, height, width, 3) uint8."""
    data = pytest.importorskip("skimage.data")
    img = getattr(data, image)()
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    out = [img[40: 40 + height, 30 + step * t: 30 + step * t + width] for t in range(frames)]
    return np.ascontiguousarray(np.stack(out))


def blurred(video: np.ndarray, sigma: float) -> np.ndarray:
    from scipy import ndimage

    if sigma == 0:
        return video.copy()
    out = ndimage.gaussian_filter(video.astype(np.float32), sigma=(0, sigma, sigma, 0))
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def noisy(video: np.ndarray, std: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(np.round(video + rng.normal(0, std, video.shape)), 0, 255).astype(np.uint8)


def as_batch(video: np.ndarray) -> torch.Tensor:
    """(T, H, W, 3) uint8 -> (T, 3, H, W) float32 in [0, 1], as the engine converts it."""
    return torch.from_numpy(video).permute(0, 3, 1, 2).to(torch.float32) / 255.0
