"""Fixtures of the analysis tests: generated studies (known truth) and the SUREAL data."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.synthetic import SyntheticStudy, synthetic_study


@pytest.fixture
def sureal_dir(shared_data: Path) -> Path:
    """../shared/data/sureal (skipped when absent)."""
    path = shared_data / "sureal"
    if not path.is_dir():
        pytest.skip("../shared/data/sureal is not present")
    return path


@pytest.fixture(scope="session")
def study() -> SyntheticStudy:
    """20 raters x 3 repetitions x 70 stimuli, one random (outlier) rater, P01."""
    return synthetic_study(n_scenes=10, methods=("blur", "noise", "alias"), levels=2,
                           n_raters=20, n_outliers=1, noise_sd=6.0, bias_sd=4.0, seed=3)
