"""The authors' own ``run_cgvqm`` (IntelLabs/cgvqm), run as its users run it (benchmarks only).

The project never ships or imports that code. ``prepare.sh`` puts a copy of the authors'
repository files into the git-ignored ``.whl/upstream`` (with the published weight files
under ``weights/``, where ``run_cgvqm`` looks for them), and the GPU session imports it from
there, on a machine whose torch has a matching torchvision.

Two things cannot be as on a user's machine, and both are swapped at their seams only:

- the backbone: ``run_cgvqm`` asks torchvision for the pretrained R3D-18, a download. The
  machine has no network, so ``r3d_18`` is wrapped to build the same architecture without
  weights and load the state dict both sides are given (the random backbone of the
  benchmarks: speed does not depend on its values, and |dq| compares like with like);
- decoding, and one legacy name: torchvision 0.26 (torch 2.11) no longer has
  ``torchvision.io.read_video``, which the authors' ``utils.utils`` imports. Where it is
  missing, a PyAV reader with its contract (uint8 frames, TCHW, ``info["video_fps"]``;
  RGB through libswscale, as its PyAV backend decoded) takes its place; the authors' pin
  (torchvision 0.22) decoded through PyAV too. Likewise ``_ModelURLs``, if gone, is given
  back as the plain dict it was.

Everything else (model class swap, float32 host tensors, per-patch copies, batch 1,
feature differences, error maps copied back per patch, PyTorch's default precision
switches) is the authors' code, unchanged.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import time
import types
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

UPSTREAM_FILES = ("cgvqm.py", "utils/__init__.py", "utils/resnet18.py", "utils/utils.py")
_MODULES = ("cgvqm", "utils", "utils.resnet18", "utils.utils")


def read_video_pyav(path: str, start_pts: float = 0, end_pts: float | None = None,
                    pts_unit: str = "pts", output_format: str = "THWC"
                    ) -> tuple[torch.Tensor, torch.Tensor, dict[str, float]]:
    """``torchvision.io.read_video``'s contract for a whole video stream, through PyAV."""
    import av

    with av.open(str(path)) as box:
        stream = box.streams.video[0]
        fps = float(stream.average_rate or stream.guessed_rate or 30)
        frames = [f.to_ndarray(format="rgb24") for f in box.decode(stream)]
    vid = torch.from_numpy(np.stack(frames))
    if output_format.upper() == "TCHW":
        vid = vid.permute(0, 3, 1, 2)
    return vid, torch.empty(1, 0), {"video_fps": fps}


def _no_write_video(*_a: object, **_k: object) -> None:
    raise RuntimeError("write_video is not available here (error-map videos are not timed)")


@dataclass
class UpstreamOwn:
    """``run_cgvqm`` of the copy in ``folder``, with the backbone's state dict swapped in."""

    module: types.ModuleType
    shimmed_read_video: bool
    restored: list[str]  # torchvision names given back for the authors' code

    def score(self, test_path: str, ref_path: str, variant: str, device: str,
              pool: str = "max") -> tuple[float, float]:
        """(q, seconds) of one call, as a user's script makes it (model built per call)."""
        kind = (self.module.CGVQM_TYPE.CGVQM_2 if variant == "cgvqm-2"
                else self.module.CGVQM_TYPE.CGVQM_5)
        if str(device).startswith("cuda"):
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        q, _emap = self.module.run_cgvqm(test_path, ref_path, cgvqm_type=kind, device=device,
                                         patch_pool=pool)
        if str(device).startswith("cuda"):
            torch.cuda.synchronize()
        return float(q), time.perf_counter() - t0


def missing_files(folder: Path) -> list[str]:
    """The authors' files (and weights) the copy in ``folder`` lacks."""
    need = [*UPSTREAM_FILES, "weights/cgvqm-2.pickle", "weights/cgvqm-5.pickle"]
    return [n for n in need if not (folder / n).is_file()]


def _read_video_shim() -> bool:
    """Give ``torchvision.io.video`` a ``read_video`` where this torchvision lacks one."""
    try:
        from torchvision.io.video import read_video  # noqa: F401
        return False
    except ImportError:
        pass
    import torchvision.io as tv_io

    mod = sys.modules.get("torchvision.io.video") or types.ModuleType("torchvision.io.video")
    mod.read_video = read_video_pyav  # type: ignore[attr-defined]
    if not hasattr(mod, "write_video"):
        mod.write_video = _no_write_video  # type: ignore[attr-defined]
    sys.modules["torchvision.io.video"] = mod
    tv_io.video = mod  # type: ignore[attr-defined]
    return True


def _legacy_names() -> list[str]:
    """The authors' ``resnet18.py`` (torchvision 0.22's video ResNet) ends by building
    ``model_urls`` with ``torchvision.models._utils._ModelURLs``, a dict that torchvision
    marked for removal; give it back where a newer torchvision dropped it."""
    import torchvision.models._utils as tv_utils

    if hasattr(tv_utils, "_ModelURLs"):
        return []
    tv_utils._ModelURLs = dict  # type: ignore[attr-defined]
    return ["_ModelURLs"]


@contextlib.contextmanager
def imported(folder: Path, state_dict: dict[str, torch.Tensor]) -> Iterator[UpstreamOwn]:
    """The authors' ``cgvqm`` module from ``folder``, its ``r3d_18`` loading ``state_dict``;
    their module names (``cgvqm``, ``utils``) are removed from ``sys.modules`` afterwards."""
    gone = missing_files(folder)
    if gone:
        raise FileNotFoundError(f"{folder} lacks {', '.join(gone)} (run benchmarks/gpu/"
                                "prepare.sh where a copy of IntelLabs/cgvqm is at hand)")
    saved = {n: sys.modules.pop(n) for n in _MODULES if n in sys.modules}
    sys.path.insert(0, str(folder))
    try:
        shimmed = _read_video_shim()
        restored = _legacy_names()
        module = importlib.import_module("cgvqm")
        arch = module.resnet18
        build = arch.r3d_18

        def r3d_18_given(*, weights: object = None, progress: bool = True,
                         **kwargs: object) -> torch.nn.Module:
            model = build(weights=None, progress=progress, **kwargs)
            missing, unexpected = model.load_state_dict(state_dict, strict=False)
            if unexpected or any(not k.startswith("fc.") for k in missing):
                raise RuntimeError(f"state dict does not fit r3d_18: missing {missing}, "
                                   f"unexpected {unexpected}")
            return model

        arch.r3d_18 = r3d_18_given
        yield UpstreamOwn(module, shimmed, restored)
    finally:
        sys.path.remove(str(folder))
        for n in _MODULES:
            sys.modules.pop(n, None)
        sys.modules.update(saved)
