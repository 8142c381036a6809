"""Nothing is downloaded (learned metrics, ColorVideoVDP's ML variant), the torchvision
stand-in blur is torchvision's operation, and the viewing condition matches ColorVideoVDP."""

from __future__ import annotations

import sys
import urllib.request

import numpy as np
import pytest
import torch

from cgvqm_core.metrics import MetricOptions, ViewingCondition, build_scorers, get_entry
from cgvqm_core.metrics._gaussian_blur import GaussianBlur


def test_nothing_downloads(monkeypatch):
    calls = []

    def refuse(*a, **k):
        calls.append(a)
        raise AssertionError("network access")

    monkeypatch.setattr(urllib.request, "urlopen", refuse)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", refuse)
    monkeypatch.setattr(torch.hub, "download_url_to_file", refuse)
    for name in ("lpips", "dists", "pieapp"):
        a = get_entry(name).availability()
        assert not a.ok and "nothing is downloaded" in a.reason
    if get_entry("cvvdp").availability().ok:
        build_scorers(["cvvdp"], MetricOptions())
        # the ML variant (which fetches weights from a model hub) is never even imported
        assert "pycvvdp.cvvdp_ml_metric" not in sys.modules
        assert "torchvision" not in sys.modules  # the stand-in did not leak
    assert calls == []


def test_standin_blur_is_a_reflect_padded_gaussian():
    ndimage = pytest.importorskip("scipy.ndimage")
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 37, 41, generator=g, dtype=torch.float64)
    blur = GaussianBlur(13, 3.0)
    got = blur(x).numpy()
    r = np.arange(13) - 6.0
    k = np.exp(-0.5 * (r / 3.0) ** 2)
    k /= k.sum()
    # torch 'reflect' padding excludes the edge sample: scipy's 'mirror'
    want = ndimage.correlate1d(ndimage.correlate1d(x.numpy(), k, axis=-1, mode="mirror"), k,
                               axis=-2, mode="mirror")
    # the kernel is built in float32 (as torchvision builds it), hence 1e-7, not 1e-15
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)
    assert blur(x.view(6, 1, 37, 41)).shape == (6, 1, 37, 41)
    with pytest.raises(ValueError):
        GaussianBlur(4, 1.0)


def test_viewing_condition_matches_cvvdp():
    if not get_entry("cvvdp").availability().ok:
        pytest.skip("cvvdp not installed")
    from cgvqm_core.metrics.cvvdp_entry import load_cvvdp
    from cgvqm_core.metrics.viewing import DISPLAYS

    load_cvvdp()
    from pycvvdp.display_model import vvdp_display_geometry

    for name in DISPLAYS:
        ours = ViewingCondition(name).pixels_per_degree
        assert ours == pytest.approx(vvdp_display_geometry.load(name, []).get_ppd(), rel=1e-9)
    assert ViewingCondition().pixels_per_degree == pytest.approx(75.4, abs=0.05)
    (s,) = build_scorers(["cvvdp"], MetricOptions(viewing=ViewingCondition(ppd=50.0)))
    assert s.settings()["ppd"] == 50.0
    (f,) = build_scorers(["flip"], MetricOptions(viewing=ViewingCondition(ppd=50.0)))
    assert f.settings()["ppd"] == 50.0


def test_flip_guards_its_exit():
    from cgvqm_core.errors import CGVQMError
    from cgvqm_core.metrics.flip_entry import flip_frame

    pytest.importorskip("flip_evaluator")
    a = np.zeros((8, 8, 3), np.float32)
    with pytest.raises(CGVQMError):
        flip_frame(a, a, -1.0)
    with pytest.raises(CGVQMError):
        ViewingCondition("no-such-display")
