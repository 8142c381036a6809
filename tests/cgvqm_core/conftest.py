"""Fixtures of the cgvqm tests: a seeded random backbone in torchvision's key layout (with
random batch-norm statistics), small synthetic videos, and the upstream weights when present."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cgvqm_core.backbone import build_backbone
from cgvqm_core.hub import Backbone, from_state_dict

UPSTREAM = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "cgvqm_upstream"
GPU_BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "gpu"


def random_state_dict(seed: int = 123, arch: str = "r3d_18") -> dict[str, torch.Tensor]:
    """torchvision-style init plus random BN statistics, so every BN does real work."""
    g = torch.Generator().manual_seed(seed)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        sd = build_backbone(arch).state_dict()
    for k, v in sd.items():
        if k.endswith("running_mean") or k.endswith(".bias"):
            sd[k] = torch.randn(v.shape, generator=g) * 0.1
        elif k.endswith("running_var") or (k.endswith(".weight") and v.ndim == 1):
            sd[k] = torch.rand(v.shape, generator=g) + 0.5
    return sd


@pytest.fixture(scope="module")
def session():
    """benchmarks/gpu/session.py (and through it stem_kernels.py), imported as it runs."""
    sys.path.insert(0, str(GPU_BENCH))
    try:
        yield importlib.import_module("session")
    finally:
        sys.path.remove(str(GPU_BENCH))


@pytest.fixture(scope="module")
def targets(session):
    """benchmarks/gpu/targets.py: the issue's targets and the session's verdicts on them."""
    return sys.modules["targets"]


@pytest.fixture(scope="session")
def state_dict() -> dict[str, torch.Tensor]:
    return random_state_dict()


@pytest.fixture(scope="session")
def backbone(state_dict: dict[str, torch.Tensor]) -> Backbone:
    """The random state dict wrapped once (hashing 33M parameters takes a moment)."""
    return from_state_dict(state_dict, label="test-random")


@pytest.fixture(scope="session")
def backbone_file(tmp_path_factory: pytest.TempPathFactory,
                  state_dict: dict[str, torch.Tensor]) -> Path:
    path = tmp_path_factory.mktemp("backbone") / "random_r3d18.pth"
    torch.save(state_dict, path)
    return path


@pytest.fixture
def upstream_dir() -> Path:
    if not (UPSTREAM / "cgvqm-2.pickle").is_file():
        pytest.skip("../shared/data/cgvqm_upstream is not present")
    return UPSTREAM


@pytest.fixture(scope="session", autouse=True)
def _one_thread():
    """The test videos are tiny: one thread avoids thread-pool contention on a busy machine.
    (Applies to metrics/ and calibration/ below too.)"""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(autouse=True)
def _no_network(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Tests never reach the network nor the user's caches."""
    monkeypatch.setenv("CGVQM_OFFLINE", "1")
    monkeypatch.setenv("CGVQM_CACHE", str(tmp_path / "cgvqm-cache"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.delenv("CGVQM_BACKBONE", raising=False)
    monkeypatch.delenv("CGVQM_WEIGHTS_DIR", raising=False)


def smooth_video(seed: int, frames: int, height: int, width: int) -> np.ndarray:
    """A moving smooth pattern with texture (uint8), so features are not all noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None, None]
    y = np.arange(height)[None, :, None, None]
    x = np.arange(width)[None, None, :, None]
    phase = rng.uniform(0, 2 * np.pi, size=(1, 1, 1, 3))
    base = 128 + 80 * np.sin(0.35 * x + 0.25 * y + 0.4 * t + phase)
    base += rng.normal(0, 12, size=(frames, height, width, 3))
    return np.clip(base, 0, 255).astype(np.uint8)


def distort(video: np.ndarray, seed: int, sigma: float = 6.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(video + rng.normal(0, sigma, video.shape), 0, 255).astype(np.uint8)


class Videos:
    """Synthetic-video helpers, handed to tests as the ``vids`` fixture."""

    smooth = staticmethod(smooth_video)
    distort = staticmethod(distort)


@pytest.fixture(scope="session")
def vids() -> type[Videos]:
    return Videos
