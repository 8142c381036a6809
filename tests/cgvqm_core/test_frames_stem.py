"""The 2D stem: the stem's 3D convolution as one conv2d over all frames, its temporal taps
as channels. Checked against the 3D convolution itself, in float64 (where the two must agree
to summation order) and through whole scores."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import MEAN, STD, FeatureNet
from cgvqm_core.hub import random_backbone
from cgvqm_core.precision import fast_path
from cgvqm_core.stem import FramesStem, PhaseConv2d, StemRewrite, frames_as_channels

from .test_parity import _random_weights

CUDA = torch.device("cuda")


def assert_same_levels(net_a: FeatureNet, net_b: FeatureNet, x: torch.Tensor) -> None:
    """Both networks' level activations for ``x`` agree to fp32's summation noise."""
    for a, b in zip(net_a.levels(x), net_b.levels(x), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def _stem(kernel=(3, 7, 7), stride=(1, 2, 2), padding=(1, 3, 3), cin=3) -> torch.nn.Conv3d:
    torch.manual_seed(4)
    return torch.nn.Conv3d(cin, 16, kernel, stride=stride, padding=padding).double()


@pytest.mark.parametrize("frames", [1, 2, 7])
@pytest.mark.parametrize("layout", ["channels_last", "padded", "contiguous"])
def test_the_2d_stem_is_the_3d_convolution(frames, layout):
    conv = _stem()
    x = torch.randn(2, 3, frames, 23, 18, dtype=torch.float64)  # odd: every border differs
    if layout != "contiguous":
        x = x.contiguous(memory_format=torch.channels_last_3d)
    stem = FramesStem(conv, layout != "contiguous", 12 if layout == "padded" else None)
    with torch.no_grad():
        want, got = conv(x), stem(x)
    assert got.shape == want.shape
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    if layout != "contiguous":  # what the next channels-last stage reads without a copy
        assert got.is_contiguous(memory_format=torch.channels_last_3d)


@pytest.mark.parametrize("kernel,padding", [((5, 3, 3), (2, 1, 1)), ((3, 3, 3), (0, 1, 1)),
                                            ((1, 7, 7), (0, 3, 3))])
def test_other_temporal_kernels_and_paddings(kernel, padding):
    conv = _stem(kernel, (1, 1, 2), padding, cin=2)
    x = torch.randn(1, 2, 6, 9, 12, dtype=torch.float64)
    with torch.no_grad():
        torch.testing.assert_close(FramesStem(conv, False)(x), conv(x), rtol=0, atol=1e-12)


def test_frames_as_channels_orders_taps_then_channels_with_zero_ends():
    x = torch.arange(2 * 3 * 4 * 2 * 2, dtype=torch.float32).view(2, 3, 4, 2, 2)
    for cl in (True, False):
        y = frames_as_channels(x, 3, 1, cl)
        assert y.shape == (8, 9, 2, 2)
        y = y.unflatten(0, (2, 4))  # (B, T, taps * C, H, W)
        for t in range(4):
            for k in range(3):
                s = t - 1 + k
                want = x[:, :, s] if 0 <= s < 4 else torch.zeros(2, 3, 2, 2)
                assert torch.equal(y[:, t, 3 * k: 3 * k + 3], want), (cl, t, k)
    padded = frames_as_channels(x, 3, 1, True, 12)
    assert padded.shape == (8, 12, 2, 2) and not padded[:, 9:].any()
    assert torch.equal(padded[:, :9], frames_as_channels(x, 3, 1, False))
    for cl, n in ((False, 12), (True, 8)):
        with pytest.raises(ValueError, match="cannot be padded"):
            frames_as_channels(x, 3, 1, cl, n)


def test_a_temporally_strided_convolution_is_refused():
    with pytest.raises(ValueError, match="temporal stride 1"):
        FramesStem(_stem(stride=(2, 2, 2)), True)


@pytest.mark.parametrize("option", [
    pytest.param("stem_2d", marks=pytest.mark.slow),  # about 8 s each here: CI runs them
    pytest.param("stem_s2d", marks=pytest.mark.slow),  # (the stem's units stay above)
])
def test_scores_with_a_2d_stem_are_fp32_scores(vids, backbone, option):
    """The 2D stem, and the 2D stem over its stride phases (space-to-depth)."""
    ref = vids.smooth(3, 10, 40, 36)
    test = vids.distort(ref, seed=5)
    w = _random_weights("cgvqm-5", 1027, seed=9)
    plain = CGVQM("cgvqm-5", weights=w, backbone=backbone).score(ref, test, fps=8)
    for cl in (True, False):
        m = CGVQM("cgvqm-5", weights=w, backbone=backbone, channels_last=cl, **{option: True})
        stem = m.net.model.stem[0]
        assert isinstance(stem, FramesStem)
        assert isinstance(stem.conv2d, PhaseConv2d) == (option == "stem_s2d")
        detail = m.provenance()["precision_detail"]
        assert detail["stem_2d"] is True and detail[option] is True
        res = m.score(ref, test, fps=8)
        assert np.abs(res.msd - plain.msd).max() < 1e-5 * np.abs(plain.msd).max()
        assert abs(res.q - plain.q) < 1e-4


def test_2d_stem_rules(backbone):
    def fp(**kw):
        args = dict(fp32_stem=True, differences=False, fuse_bn=True, tf32_stem=False,
                    fused=None, pad_stem=None)
        return fast_path(CUDA, torch.float16, **(args | kw))

    assert not fp().stem_2d  # asked for only
    got = fp(stem_2d=True)
    assert (got.stem_2d, got.fused, got.pad_stem) == (True, True, False)
    assert fp(stem_2d=True, tf32_stem=True).pad_stem  # a TF32 2D stem is padded
    with pytest.raises(CGVQMError, match="differences"):
        fp(stem_2d=True, differences=True)
    both = fp(stem_2d=True, split_stem="int")
    assert (both.stem_2d, both.split_stem, both.pad_stem) == (True, "int", False)
    # the 16-byte padding of a 2D stem: the nine taps' channels to 12 in fp32
    net = FeatureNet(backbone, 3, stem_2d=True, pad_stem=True)
    assert net.model.stem[0].in_channels == 12 and net.pad_stem
    flat = FeatureNet(backbone, 3, stem_2d=True, pad_stem=True, channels_last=False)
    assert flat.model.stem[0].in_channels == 9 and not flat.pad_stem
    assert "pad_stem" not in flat.precision_info
    x = torch.randn(1, 3, 4, 16, 16)
    assert_same_levels(net, flat, x)
    # a split stem as a 2D stem: the split's 8 channels times 3 taps (times 4 stride phases
    # with space-to-depth), fp32's numbers still
    pixels = torch.randint(0, 256, (1, 4, 16, 16, 3), dtype=torch.uint8)
    for option, channels in (("stem_2d", 24), ("stem_s2d", 96)):
        split2d = FeatureNet(backbone, 3, split_stem="int", **{option: True})
        assert split2d.model.stem[0].in_channels == channels
        assert_same_levels(split2d, flat, split2d.to_input(pixels))
    # R(2+1)D's stem starts with a (1, 7, 7) convolution: one tap, a conv2d per frame
    r21 = random_backbone(0, arch="r2plus1d_18")
    two_d = FeatureNet(r21, 2, stem_2d=True)
    assert isinstance(two_d.model.stem[0], FramesStem)
    assert_same_levels(two_d, FeatureNet(r21, 2), x)


def test_the_stem_rewrite_pads_splits_or_leaves_the_convolution():
    """StemRewrite alone: which module replaces the stem's convolution, and its input."""
    conv = _stem().float()
    kw = dict(channels_last=True, mean=MEAN, std=STD)
    x = torch.randn(1, 3, 4, 12, 12).contiguous(memory_format=torch.channels_last_3d)
    plain = StemRewrite(conv, split=None, two_d=False, pad=False, **kw)
    assert plain.module is conv and not plain.rewritten and not plain.padded
    padded = StemRewrite(conv, split=None, two_d=False, pad=True, **kw)
    assert padded.padded and padded.rewritten and padded.module.in_channels == 4
    assert padded.input(x, torch.float32).shape[1] == 4
    two_d = StemRewrite(conv, split=None, two_d=True, pad=True, **kw)
    assert two_d.padded and not two_d.rewritten  # it builds its own input
    assert two_d.module.in_channels == 12
    split = StemRewrite(conv, split="3xtf32", two_d=False, pad=True, **kw)
    assert not split.padded and split.rewritten and split.input(x, torch.float32).shape[1] == 12
    with torch.no_grad():
        for r in (padded, two_d, split):
            torch.testing.assert_close(r.module(r.input(x, torch.float32)), conv(x),
                                       rtol=1e-5, atol=1e-5)
    # a stem that is not a plain 3D convolution: padding is left out, the rest refused
    assert StemRewrite(None, split=None, two_d=False, pad=True, **kw).module is None
    for bad in (dict(split="int", two_d=False), dict(split=None, two_d=True)):
        with pytest.raises(ValueError, match="plain 3D convolution"):
            StemRewrite(None, pad=False, **bad, **kw)
