"""Seamless tiling: every patch's features equal those of one network run over the whole
frame (the second computation here), whatever the patch grid."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import FeatureNet
from cgvqm_core.weights import uniform_weights


def whole_frame_msd(ref: np.ndarray, test: np.ndarray, backbone, n_levels: int, fps: int,
                    scale: int) -> np.ndarray:
    """(patches, N): per patch, the channel mean of squared differences of whole-frame
    features, each feature position assigned to the patch holding its input pixel."""
    net = FeatureNet(backbone, n_levels, fuse_bn=False, channels_last=False)
    T, H, W = ref.shape[:3]
    L, ph, pw = int(min(fps, 30)), int(H / scale), int(W / scale)
    rows, cols = math.ceil(H / ph), math.ceil(W / pw)
    pad = (-T) % L
    ref = np.concatenate([ref, np.repeat(ref[-1:], pad, 0)])
    test = np.concatenate([test, np.repeat(test[-1:], pad, 0)])
    out = []
    for t0 in range(0, T + pad, L):
        x = net.to_input(torch.from_numpy(np.stack([ref[t0:t0 + L], test[t0:t0 + L]])))
        per_level = []
        for a in net.levels(x):
            d = (a[1] - a[0]).pow(2)  # C, t, h, w
            s = next(s for s in (1, 2, 4, 8, 16) if math.ceil(H / s) == d.shape[2])
            row_of = np.arange(d.shape[2]) * s // ph
            col_of = np.arange(d.shape[3]) * s // pw
            per_level.append([[d[:, :, torch.from_numpy(row_of == r)][:, :, :,
                                torch.from_numpy(col_of == c)].mean((1, 2, 3))
                               for c in range(cols)] for r in range(rows)])
        for r in range(rows):
            for c in range(cols):
                out.append(torch.cat([lv[r][c] for lv in per_level]).numpy())
    return np.array(out)


@pytest.mark.parametrize("variant,n_levels,shape,fps,scales", [
    ("cgvqm-2", 3, (10, 30, 38), 8, (4, 3)),
    ("cgvqm-5", 6, (3, 32, 288), 3, (2,)),
])
def test_seamless_patches_equal_whole_frame_features(vids, backbone, variant, n_levels, shape,
                                                     fps, scales):
    ref = vids.smooth(5, *shape)
    test = vids.distort(ref, 6, sigma=10)
    for scale in scales:
        m = CGVQM(variant, weights=uniform_weights(variant), backbone=backbone,
                  patch_scale=scale, seamless=True)
        got = m.channel_msd(ref, [test], fps=fps)[0].msd
        want = whole_frame_msd(ref, test, backbone, n_levels, fps, scale)
        # per level, against that level's largest value: float noise is ~1e-5 of it, a
        # halo 32 px short of the receptive field gives ~5e-4 at layer4
        edges = np.cumsum([0, 3, 64, 64, 128, 256, 512][: n_levels + 1])
        for a, b in itertools.pairwise(edges):
            err = np.abs(got[:, a:b] - want[:, a:b]).max() / np.abs(want[:, a:b]).max()
            assert err < 1e-4, (variant, scale, a, err)
        # upstream tiling sees zero padding at every patch edge: measurably different
        up = CGVQM(variant, weights=uniform_weights(variant), backbone=backbone,
                   patch_scale=scale).channel_msd(ref, [test], fps=fps)[0].msd
        assert np.abs(up[:, 3:] - want[:, 3:]).max() > 1e-3 * np.abs(want[:, 3:]).max()


def test_seamless_is_marked_and_refuses_error_maps(vids, backbone):
    ref = vids.smooth(1, 4, 24, 24)
    test = vids.distort(ref, 2)
    m = CGVQM("cgvqm-2", weights=uniform_weights("cgvqm-2"), backbone=backbone, seamless=True)
    res = m.score(ref, test, fps=4)
    assert res.provenance["mode"] == "seamless"
    assert "not upstream-identical" in res.to_dict()["mode"]
    with pytest.raises(CGVQMError, match="seamless"):
        m.score(ref, test, fps=4, emap=True)
    tiny = CGVQM("cgvqm-5", weights=uniform_weights("cgvqm-5"), backbone=backbone,
                 seamless=True, patch_scale=4)
    with pytest.raises(CGVQMError, match="too small for seamless"):
        tiny.score(ref, test, fps=4)
