"""The participant's base install, imitated: a child Python in which the research stack
(torch, scipy, pandas ...) cannot be imported. ``lean_site/`` holds the blocker."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LEAN_SITE = Path(__file__).resolve().parent / "lean_site"


def lean_pythonpath() -> str:
    """PYTHONPATH of a child that sees this checkout but not the research stack (the
    blocker first, so its ``sitecustomize`` runs at start-up)."""
    return f"{LEAN_SITE}{os.pathsep}{REPO}"
