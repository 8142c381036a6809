"""The one check of a ``--device`` string, shared by CGVQM and the peer metrics: what this
PyTorch can run on, refused in one line otherwise (``mps`` on a Mac, a CUDA index past the
last GPU), never a traceback from deep inside a model."""

from __future__ import annotations

import torch

from .errors import CGVQMError


def torch_device(device: str | torch.device) -> torch.device:
    """``device`` as a :class:`torch.device` this toolkit can use (cpu or an existing CUDA
    device); :class:`CGVQMError` otherwise."""
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError, TypeError):
        raise CGVQMError(f"unknown device {device!r}; use cpu or cuda") from None
    if dev.type not in ("cpu", "cuda"):
        raise CGVQMError(f"device {str(device)!r} is not supported; use cpu or cuda")
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise CGVQMError("--device cuda was asked for but this PyTorch has no usable CUDA "
                             "device; use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise CGVQMError(f"--device {device}: this machine has "
                             f"{torch.cuda.device_count()} CUDA device(s), numbered from 0")
    return dev
