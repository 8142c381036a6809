"""Fixtures of the calibration tests: synthetic data with known true weights."""

from __future__ import annotations

import pytest

from .calib_synthetic import Synthetic, make


@pytest.fixture(scope="session")
def synth() -> Synthetic:
    return make()
