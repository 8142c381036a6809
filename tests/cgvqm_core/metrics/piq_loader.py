"""Load PIQ (the reference implementation of the image metrics) without torchvision.

PIQ imports torchvision at its top level only for its VGG-based perceptual metrics; the
classical metrics compared here never touch it. This test-only helper puts a minimal
stand-in module in ``sys.modules`` while PIQ is imported and removes it afterwards, so
nothing else in the process sees a fake torchvision.
"""

from __future__ import annotations

import sys
import types
from typing import Any

import pytest


def _unavailable(*_a: Any, **_k: Any) -> Any:
    raise RuntimeError("torchvision is not available in this test environment")


def load_piq() -> Any:
    """The ``piq`` module, or skip the test when it is not installed."""
    if "piq" in sys.modules:
        return sys.modules["piq"]
    try:
        import importlib.util

        if importlib.util.find_spec("piq") is None:
            pytest.skip("piq is not installed (pip install --no-deps piq)")
    except ValueError:
        pytest.skip("piq is not installed")
    import torch

    from cgvqm_core.metrics.standins import modules_replaced

    names = ("torchvision", "torchvision.models", "torchvision.models.utils",
             "torchvision.models.inception")
    fake = {name: types.ModuleType(name) for name in names}
    fake["torchvision"].models = fake["torchvision.models"]  # type: ignore[attr-defined]
    fake["torchvision.models"].inception = fake["torchvision.models.inception"]  # type: ignore
    for attr in ("vgg16", "vgg19", "inception_v3"):
        setattr(fake["torchvision.models"], attr, _unavailable)
    fake["torchvision.models.utils"].load_state_dict_from_url = _unavailable  # type: ignore

    def _block(name: str) -> type:  # base classes of PIQ's FID Inception blocks
        return type(name, (torch.nn.Module,), {})

    fake["torchvision.models.inception"].__getattr__ = _block  # type: ignore[attr-defined]
    with modules_replaced(fake):
        import piq
    return piq
