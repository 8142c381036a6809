"""PyTorch files read with the safe loader only (tensors, never code), and one line saying
why a file was refused: torch's own message advises ``weights_only=False``, which would run
whatever code the file holds, so it is never passed on."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def load_tensors(path: Path) -> Any:
    """``torch.load`` with ``weights_only=True``, memory-mapped where the format allows."""
    import torch

    try:
        return torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except RuntimeError:  # legacy (non-zip) files cannot be memory-mapped
        return torch.load(path, map_location="cpu", weights_only=True)


def refusal_reason(exc: BaseException) -> str:
    """Why the safe loader refused a file, in a few words without torch's advice."""
    text = str(exc).strip()
    if "weights_only" in text:
        return "not a PyTorch file of tensors only"
    return (text.splitlines()[0] if text else type(exc).__name__)[:200]
