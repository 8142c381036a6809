"""Fixtures of the calibration tests: synthetic data with known true weights."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from calib_synthetic import Synthetic, make


@pytest.fixture(scope="session")
def synth() -> Synthetic:
    return make()
