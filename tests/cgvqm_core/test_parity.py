"""Parity of the fast, streamed, batched scorer with a straightforward reading of the spec.

``straightforward_cgvqm`` below is written from shared/spec/cgvqm.md alone: whole videos in
memory, functional conv3d / batch_norm on the state dict, one patch at a time, no batching,
no folding, no streaming. The package must agree with it to 1e-3 in q (both variants, both
poolings, sizes not divisible by the patch grid, test videos of another size and length)
and to 1e-3 relative in the error map.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cgvqm_core import CGVQM, FeatureWeights, patch_channel_msd
from cgvqm_core.features import FeatureNet
from cgvqm_core.weights import load_upstream_pickle

MEAN = torch.tensor([0.43216, 0.394666, 0.37645])
STD = torch.tensor([0.22803, 0.22145, 0.216989])
CHANNELS = [3, 64, 64, 128, 256, 512]


def _bn(x, sd, p):
    return F.batch_norm(x, sd[p + ".running_mean"], sd[p + ".running_var"], sd[p + ".weight"],
                        sd[p + ".bias"], training=False, momentum=0.0, eps=1e-5)


def _block(x, sd, p, stride):
    out = F.relu(_bn(F.conv3d(x, sd[p + ".conv1.0.weight"], stride=stride, padding=1), sd,
                     p + ".conv1.1"))
    out = _bn(F.conv3d(out, sd[p + ".conv2.0.weight"], stride=1, padding=1), sd, p + ".conv2.1")
    if p + ".downsample.0.weight" in sd:
        res = _bn(F.conv3d(x, sd[p + ".downsample.0.weight"], stride=stride), sd,
                  p + ".downsample.1")
    else:
        res = x
    return F.relu(out + res)


def _features(x, sd, n_levels):
    feats = [x]
    h = F.relu(_bn(F.conv3d(x, sd["stem.0.weight"], stride=(1, 2, 2), padding=(1, 3, 3)), sd,
                   "stem.1"))
    feats.append(h)
    for i, stride in enumerate([1, 2, 2, 2]):
        if len(feats) == n_levels:
            break
        h = _block(h, sd, f"layer{i + 1}.0", stride)
        h = _block(h, sd, f"layer{i + 1}.1", 1)
        feats.append(h)
    return feats[:n_levels]


def straightforward_cgvqm(ref, test, sd, omega, alpha, n_levels, fps, scale=4):
    """(q_max, q_mean, error map) following the spec step by step.

    Runs on PyTorch's native convolution (oneDNN off): a second implementation of the
    arithmetic too, and much faster than oneDNN on these tiny test patches.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        with torch.backends.mkldnn.flags(enabled=False):
            return _straightforward(ref, test, sd, omega, alpha, n_levels, fps, scale)


def _straightforward(ref, test, sd, omega, alpha, n_levels, fps, scale):
    R = torch.from_numpy(ref).permute(0, 3, 1, 2)  # T C H W uint8
    D = torch.from_numpy(test).permute(0, 3, 1, 2)
    T, _, H, W = R.shape
    if D.shape[2:] != R.shape[2:]:
        D = F.interpolate(D, size=(H, W), mode="bilinear")
    if D.shape[0] != T:
        D = F.interpolate(D.permute(1, 0, 2, 3)[None], size=(T, H, W), mode="nearest")
        D = D[0].permute(1, 0, 2, 3)

    def prep(v):
        x = v.float() / 255
        x = (x - MEAN.view(1, 3, 1, 1)) / STD.view(1, 3, 1, 1)
        return x.permute(1, 0, 2, 3)[None]

    Dn, Rn = prep(D), prep(R)
    ph, pw = int(H / scale), int(W / scale)
    L = int(min(fps, 30))
    pad = (0, (pw - W % pw) % pw, 0, (ph - H % ph) % ph, 0, (L - T % L) % L)
    Dn, Rn = F.pad(Dn, pad, mode="replicate"), F.pad(Rn, pad, mode="replicate")
    w = torch.split(torch.from_numpy(np.abs(omega)).view(1, -1, 1, 1, 1), CHANNELS[:n_levels],
                    dim=1)
    emap = torch.zeros(Dn.shape[2:])
    errors = []
    for i in range(0, Dn.shape[2], L):
        for h in range(0, Dn.shape[3], ph):
            for c in range(0, Dn.shape[4], pw):
                cd = Dn[:, :, i:i + L, h:h + ph, c:c + pw]
                cr = Rn[:, :, i:i + L, h:h + ph, c:c + pw]
                diff, em = 0.0, torch.zeros(1, 1, *cd.shape[2:])
                for lv, (a, b) in enumerate(zip(_features(cd, sd, n_levels),
                                                _features(cr, sd, n_levels), strict=True)):
                    if lv > 0:
                        a = a / (a.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
                        b = b / (b.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
                    d = (a - b).pow(2)
                    diff += float((w[lv] * d.mean([2, 3, 4], keepdim=True)).sum())
                    e = (w[lv] * d).sum(1, keepdim=True)
                    em += F.interpolate(e, size=tuple(cd.shape[2:]), mode="trilinear")
                errors.append(alpha * diff)
                emap[i:i + L, h:h + ph, c:c + pw] = alpha * em[0, 0]
    errors = np.array(errors)
    return 100 - errors.max(), 100 - errors.mean(), emap[:T, :H, :W].numpy()


def _random_weights(variant: str, n: int, seed: int) -> FeatureWeights:
    rng = np.random.default_rng(seed)
    omega = rng.normal(0, 1, n).astype(np.float32)  # signs on purpose: |omega| is used
    omega /= np.abs(omega).sum()
    return FeatureWeights(variant, omega, 300.0, "test", "test", "project")


CASES = {
    # name: (ref T, H, W), (test T, H, W), fps, patch scale
    "indivisible": ((10, 18, 22), (10, 18, 22), 4, 4),
    "mismatched": ((9, 17, 21), (6, 13, 16), 4, 4),
}
# CGVQM-5's layer3/4 weights are large: fewer, larger patches keep the test quick
CASES5 = {
    "indivisible": ((5, 17, 21), (5, 17, 21), 5, 2),
    "mismatched": ((7, 17, 21), (5, 13, 16), 4, 2),
}


@pytest.mark.parametrize("variant,n", [("cgvqm-2", 131), ("cgvqm-5", 1027)])
@pytest.mark.parametrize("case", list(CASES))
def test_q_and_emap_match_straightforward(vids, state_dict, backbone, variant, n, case):
    (rt, rh, rw), (tt, th, tw), fps, scale = (CASES if n == 131 else CASES5)[case]
    ref = vids.smooth(1, rt, rh, rw)
    test = vids.distort(vids.smooth(1, tt, th, tw), seed=2)
    weights = _random_weights(variant, n, seed=3)
    metric = CGVQM(variant, weights=weights, backbone=backbone,
                   patch_scale=scale)
    res = metric.score(ref, test, fps=fps, emap=True)
    q_max, q_mean, emap = straightforward_cgvqm(ref, test, state_dict, weights.omega,
                                                weights.alpha, metric.weights.n_levels, fps,
                                                scale)
    assert 0 < 100 - q_max < 100  # a meaningful range, so 1e-3 is a real tolerance
    assert res.quality("max") == pytest.approx(q_max, abs=1e-3)
    assert res.quality("mean") == pytest.approx(q_mean, abs=1e-3)
    assert res.q == res.quality("max")
    assert res.emap.shape == (rt, rh, rw)
    np.testing.assert_allclose(res.emap, emap, rtol=1e-3, atol=1e-3 * np.abs(emap).max())


def test_upstream_weights_parity(vids, state_dict, backbone, upstream_dir):
    """The published omega/alpha (loaded by the safe unpickler) give the same q too."""
    ref = vids.smooth(5, 8, 16, 20)
    test = vids.distort(ref, seed=6, sigma=2.0)
    for variant in ("cgvqm-2", "cgvqm-5"):
        w = load_upstream_pickle(upstream_dir / f"{variant}.pickle")
        metric = CGVQM(weights=w, backbone=backbone, batch_size=3,
                       patch_scale=2)
        res = metric.score(ref, test, fps=4)
        q_max, q_mean, _ = straightforward_cgvqm(ref, test, state_dict, w.omega, w.alpha,
                                                 w.n_levels, 4, 2)
        assert res.variant == variant
        assert res.quality("max") == pytest.approx(q_max, abs=1e-3)
        assert res.quality("mean") == pytest.approx(q_mean, abs=1e-3)


def test_reference_reuse_and_batching_give_same_numbers(vids, state_dict, backbone):
    """score_many (reference once, several chunkings) equals separate score calls."""
    ref = vids.smooth(7, 6, 16, 16)
    tests = [vids.distort(ref, seed=s, sigma=3.0 + s) for s in range(3)]
    weights = _random_weights("cgvqm-2", 131, seed=4)
    bb = backbone
    single = CGVQM(weights=weights, backbone=bb, batch_size=1, fuse_bn=False)
    expect = [single.score(ref, t, fps=3).quality("mean") for t in tests]
    for bs in (1, 2, 4):
        many = CGVQM(weights=weights, backbone=bb, batch_size=bs)
        got = [r.quality("mean") for r in many.score_many(ref, tests, fps=3)]
        np.testing.assert_allclose(got, expect, atol=1e-4)


def test_channel_msd_is_the_patch_error_basis(vids, state_dict, backbone):
    """alpha * msd @ |omega| reproduces the patch errors; identical videos give zeros."""
    ref = vids.smooth(8, 5, 12, 12)
    test = vids.distort(ref, seed=9)
    weights = _random_weights("cgvqm-2", 131, seed=5)
    metric = CGVQM(weights=weights, backbone=backbone)
    res = metric.score(ref, test, fps=5)
    net = FeatureNet(backbone, 3)
    out = patch_channel_msd(ref, [test, ref], net, fps=5)
    assert out[0].msd.shape == (res.n_patches, 131)
    np.testing.assert_allclose(weights.alpha * out[0].msd @ np.abs(weights.omega),
                               res.patch_errors.reshape(-1), rtol=1e-5)
    assert np.abs(out[1].msd).max() < 1e-10
    assert out[0].patch_index.tolist()[:2] == [[0, 0, 0], [0, 0, 1]]


def test_per_frame_series_average_to_patch_errors(vids, state_dict, backbone):
    """For CGVQM-2 every level keeps full time resolution: a clip's per-frame errors average
    exactly to its patch error."""
    ref = vids.smooth(10, 8, 12, 16)
    test = vids.distort(ref, seed=11)
    weights = _random_weights("cgvqm-2", 131, seed=6)
    res = CGVQM(weights=weights, backbone=backbone).score(ref, test, fps=4)
    fe = res.frame_errors.reshape(2, 4, *res.frame_errors.shape[1:]).mean(axis=1)
    np.testing.assert_allclose(fe, res.patch_errors, rtol=1e-5)
    assert len(res.per_frame) == 8 and len(res.per_clip) == 2
