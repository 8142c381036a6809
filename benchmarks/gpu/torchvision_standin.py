"""A rehearsal-only stand-in for the few torchvision pieces the authors' cgvqm code imports.

torchvision cannot be imported next to this project's CPU torch, so ``session.py
--rehearse`` puts these modules in ``sys.modules`` (and takes them out again) to run the
authors' ``run_cgvqm`` on a CPU before a GPU lease: the harness is checked, not torchvision.
On the GPU machine the real torchvision is used and this file is not loaded.

What is provided: the weight-enum plumbing its ``resnet18.py`` declares its Kinetics
weights with (never loaded here), the legacy ``_ModelURLs``, ``_log_api_usage_once``,
and the two tensor functions its ``preprocess`` calls (uint8 -> float in [0, 1],
per-channel normalisation). ``io.video`` is left out, as in torchvision 0.26, so the
session's PyAV reader is exercised.
"""

from __future__ import annotations

import contextlib
import enum
import sys
import types
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from cgvqm_core.metrics.standins import modules_replaced


@dataclass(eq=False)
class Weights:
    url: str
    transforms: Callable[..., Any]
    meta: dict[str, Any] = field(default_factory=dict)


class WeightsEnum(enum.Enum):
    @classmethod
    def verify(cls, obj: Any) -> Any:
        return cls[obj.split(".")[-1]] if isinstance(obj, str) else obj

    @property
    def url(self) -> str:
        return self.value.url

    @property
    def meta(self) -> dict[str, Any]:
        return self.value.meta


class VideoClassification:
    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs


def convert_image_dtype(image: torch.Tensor, dtype: torch.dtype = torch.float) -> torch.Tensor:
    if image.dtype == torch.uint8 and dtype.is_floating_point:
        return image.to(dtype) / 255
    return image.to(dtype)


def normalize(tensor: torch.Tensor, mean: Sequence[float], std: Sequence[float]
              ) -> torch.Tensor:
    m = torch.as_tensor(mean, dtype=tensor.dtype).view(-1, 1, 1)
    s = torch.as_tensor(std, dtype=tensor.dtype).view(-1, 1, 1)
    return (tensor - m) / s


def _ovewrite_named_param(kwargs: dict[str, Any], param: str, new_value: Any) -> None:
    kwargs[param] = new_value


def handle_legacy_interface(**_weights: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    return lambda fn: fn


def _modules() -> dict[str, types.ModuleType]:
    names = ("torchvision", "torchvision.transforms", "torchvision.transforms.functional",
             "torchvision.transforms._presets", "torchvision.utils", "torchvision.models",
             "torchvision.models._api", "torchvision.models._meta", "torchvision.models._utils",
             "torchvision.io")
    mods = {n: types.ModuleType(n) for n in names}
    for n, mod in mods.items():  # parents know their children, as after a real import
        parent, _, child = n.rpartition(".")
        if parent:
            setattr(mods[parent], child, mod)
    mods["torchvision.transforms.functional"].convert_image_dtype = convert_image_dtype
    mods["torchvision.transforms.functional"].normalize = normalize
    mods["torchvision.transforms._presets"].VideoClassification = VideoClassification
    mods["torchvision.utils"]._log_api_usage_once = lambda _obj: None
    mods["torchvision.models._api"].Weights = Weights
    mods["torchvision.models._api"].WeightsEnum = WeightsEnum
    mods["torchvision.models._meta"]._KINETICS400_CATEGORIES = [f"c{i}" for i in range(400)]
    mods["torchvision.models._utils"]._ovewrite_named_param = _ovewrite_named_param
    mods["torchvision.models._utils"].handle_legacy_interface = handle_legacy_interface
    mods["torchvision.models._utils"]._ModelURLs = dict
    return mods


@contextlib.contextmanager
def installed() -> Iterator[None]:
    """The stand-in in ``sys.modules`` while the block runs; afterwards no torchvision
    module is left there (the session's reader adds ``torchvision.io.video``)."""
    if "torchvision" in sys.modules:
        raise RuntimeError("a torchvision is already imported; the stand-in is not needed")
    try:
        with modules_replaced(_modules()):
            yield
    finally:
        for n in [n for n in sys.modules if n.startswith("torchvision.")]:
            del sys.modules[n]
