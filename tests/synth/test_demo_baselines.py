"""PSNR and SSIM of the demo's baselines against values known in closed form."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[2] / "scripts" / "demo_baselines.py"
_spec = importlib.util.spec_from_file_location("demo_baselines", _PATH)
baselines = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(baselines)


def test_psnr_of_a_known_error():
    ref = np.full((2, 8, 8, 3), 100, dtype=np.uint8)
    test = ref.copy()
    test[0, 0, 0, 0] = 110  # one value off by 10: MSE = 100 / (2 * 8 * 8 * 3)
    mse = 100.0 / ref.size
    assert baselines.psnr(ref, test) == pytest.approx(10 * np.log10(255**2 / mse))
    assert baselines.psnr(ref, ref) == baselines.PSNR_CAP_DB


def test_ssim_known_cases():
    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, size=(2, 32, 32, 3), dtype=np.uint8)
    assert baselines.ssim(ref, ref) == pytest.approx(1.0)
    # a constant offset on flat frames: only the luminance term is below 1, and for a flat
    # image it is (2 a b + C1) / (a^2 + b^2 + C1)
    flat_a = np.full((1, 16, 16, 3), 100, dtype=np.uint8)
    flat_b = np.full((1, 16, 16, 3), 120, dtype=np.uint8)
    c1 = (0.01 * 255) ** 2
    expected = (2 * 100 * 120 + c1) / (100**2 + 120**2 + c1)
    assert baselines.ssim(flat_a, flat_b) == pytest.approx(expected, rel=1e-9)
    noisy = np.clip(ref + rng.normal(0, 30, ref.shape), 0, 255).astype(np.uint8)
    noisier = np.clip(ref + rng.normal(0, 60, ref.shape), 0, 255).astype(np.uint8)
    assert 0 < baselines.ssim(ref, noisier) < baselines.ssim(ref, noisy) < 1
    assert baselines.ssim(ref, noisy) == pytest.approx(baselines.ssim(noisy, ref))
