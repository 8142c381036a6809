"""Fixtures shared by every test area. Area-specific fixtures live in tests/<area>/conftest.py.

Helpers several areas need live in tests/support/ and are imported as ``support`` (this file
puts the tests folder on the import path); the fixtures among them are registered here for
every area: ``egl`` (an off-screen OpenGL context or a skip), ``tiny_study`` and
``study_factory`` (study folders made on the fly), ``xdisplay``, ``xvfb_factory`` and
``app_driver`` (the participant's app under Xvfb).
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
SHARED_DATA = REPO.parent / "shared" / "data"

pytest_plugins = ("support.egl", "support.studies", "support.gui")


@pytest.fixture
def shared_data() -> Path:
    """../shared/data (real reference data); the test is skipped when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present (fresh clone without the shared folder)")
    return SHARED_DATA
