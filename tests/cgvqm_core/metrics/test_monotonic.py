"""Every available metric orders graded blur and graded noise on real content (a pan over a
photograph) monotonically, in its own direction."""

from __future__ import annotations

import numpy as np
import pytest

from cgvqm_core.metrics import HIGHER, MetricOptions, build_scorers, entries, score_reference
from stimuli_manifests import write_video

from .conftest import blurred, noisy, real_video

FPS = 8
LEVELS = {"blur": [0.6, 1.2, 2.0, 3.0], "noise": [4.0, 8.0, 16.0, 32.0]}


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    d = tmp_path_factory.mktemp("graded")
    ref = real_video(8, 176, 176, image="chelsea")
    r = write_video(d / "ref.mkv", ref, FPS)
    paths = {}
    for kind, levels in LEVELS.items():
        for i, lv in enumerate(levels):
            v = blurred(ref, lv) if kind == "blur" else noisy(ref, lv, seed=i)
            paths[(kind, i)] = write_video(d / f"{kind}{i}.mkv", v, FPS)
    return r, paths


@pytest.mark.slow  # about 50 s: run by CI after `make test` (.ci/run) and by `make test-slow`
def test_every_metric_orders_blur_and_noise(graded):
    ref, paths = graded
    # CGVQM with its published weights is not available offline: a random backbone with
    # uniform weights still has to order these distortions
    options = MetricOptions(random_backbone=0, weights="uniform")
    names = [e.spec.name for e in entries() if e.availability_for(options).ok]
    assert {"psnr", "ssim", "ms-ssim", "iw-ssim", "flip", "cvvdp", "cgvqm-2"} <= set(names)
    scorers = build_scorers(names, options)
    keys = list(paths)
    results = score_reference(ref, [paths[k] for k in keys], scorers)
    for j, s in enumerate(scorers):
        for kind in LEVELS:
            scores = [results[keys.index((kind, i))][j].score for i in range(4)]
            assert None not in scores, s.name
            d = np.diff(scores)
            worse = d < 0 if s.spec.direction == HIGHER else d > 0
            assert worse.all(), f"{s.name} does not order {kind}: {scores}"
