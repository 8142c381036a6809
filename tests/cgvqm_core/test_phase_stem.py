"""Space-to-depth: a strided conv2d as a stride-1 one over its input's stride phases, and the
2D stem run that way. Checked against ``F.conv2d`` and the 3D stem in float64 (where they
must agree to summation order), element by element on a small input, and through whole
scores (test_frames_stem.py)."""

from __future__ import annotations

import itertools

import pytest
import torch
import torch.nn.functional as F

from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import MEAN, STD, FeatureNet
from cgvqm_core.hub import random_backbone
from cgvqm_core.precision import fast_path
from cgvqm_core.stem import FramesStem, PhaseConv2d, StemRewrite, phase_weight, phases_as_channels
from cgvqm_core.stem.frames import frames_as_channels, frames_phases_as_channels
from cgvqm_core.stem.windows import span

from .test_frames_stem import assert_same_levels

GEOMETRIES = [  # kernel, stride, padding, image
    ((7, 7), (2, 2), (3, 3), (23, 18)),  # the stem's, odd and even sides
    ((7, 7), (2, 2), (3, 3), (16, 16)),
    ((3, 5), (3, 2), (1, 2), (11, 9)),  # unequal strides, a kernel shorter than 2 strides
    ((4, 4), (2, 2), (0, 0), (9, 10)),  # no padding: the last rows are never read
    ((5, 5), (1, 1), (2, 2), (6, 7)),  # stride 1: one phase
    ((2, 2), (2, 2), (3, 3), (5, 5)),  # padding wider than the kernel
]


@pytest.mark.parametrize("kernel,stride,padding,size", GEOMETRIES)
@pytest.mark.parametrize("layout", ["channels_last", "padded", "contiguous"])
def test_the_phase_convolution_is_the_strided_one(kernel, stride, padding, size, layout):
    torch.manual_seed(1)
    x = torch.randn(2, 3, *size, dtype=torch.float64)
    w = torch.randn(5, 3, *kernel, dtype=torch.float64)
    b = torch.randn(5, dtype=torch.float64)
    cl = layout != "contiguous"
    if cl:
        x = x.contiguous(memory_format=torch.channels_last)
    n = 3 * stride[0] * stride[1]
    conv = PhaseConv2d(w, b, stride, padding, cl, n + 3 if layout == "padded" else None)
    assert conv.weight.shape == (5, n + 3 * (layout == "padded"), -(-kernel[0] // stride[0]),
                                 -(-kernel[1] // stride[1]))
    got, want = conv(x), F.conv2d(x, w, b, stride, padding)
    assert got.shape == want.shape
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    if cl:
        assert got.is_contiguous(memory_format=torch.channels_last)


def test_phases_hold_the_padded_image_pixel_by_pixel():
    """Channel (i*sw + j)*C + c of pixel (a, b) is padded pixel (sh*a + i, sw*b + j) of
    channel c; zeros outside the image. Checked one element at a time."""
    x = torch.arange(1, 1 + 2 * 2 * 5 * 6, dtype=torch.float32).view(2, 2, 5, 6)
    (sh, sw), (ph, pw), kernel = (2, 3), (1, 2), (3, 4)
    for cl in (True, False):
        y = phases_as_channels(x, (sh, sw), (ph, pw), kernel, cl)
        h2, w2 = y.shape[2:]
        # (5 + 2 - 3) // 2 + 1 = 3 outputs, 2 more phase rows; (6 + 4 - 4) // 3 + 1 = 3, 1 more
        assert y.shape == (2, sh * sw * 2, 3 + 1, 3 + 1), cl
        for n, i, j, c, a, b in itertools.product(range(2), range(sh), range(sw), range(2),
                                                  range(h2), range(w2)):
            r, s = sh * a + i - ph, sw * b + j - pw
            want = x[n, c, r, s] if 0 <= r < 5 and 0 <= s < 6 else 0.0
            assert y[n, (i * sw + j) * 2 + c, a, b] == want, (cl, n, i, j, c, a, b)
    with pytest.raises(ValueError, match="cannot be padded"):
        phases_as_channels(x, (sh, sw), (ph, pw), kernel, False, 13)
    with pytest.raises(ValueError, match="does not fit"):
        phases_as_channels(x, (2, 2), (0, 0), (7, 7), True)


def test_the_phase_weight_moves_each_tap_to_its_phase():
    w = torch.randn(4, 3, 7, 7)
    p = phase_weight(w, (2, 2))
    assert p.shape == (4, 12, 4, 4)
    for o, i, j, c, a, b in itertools.product(range(4), range(2), range(2), range(3),
                                              range(4), range(4)):
        u, v = 2 * a + i, 2 * b + j
        want = w[o, c, u, v] if u < 7 and v < 7 else 0.0
        assert p[o, (i * 2 + j) * 3 + c, a, b] == want


def test_a_span_is_the_rows_inside_the_source():
    """Against a brute-force list of the destination rows whose source row exists."""
    for size, out, offset, step in itertools.product(range(1, 9), range(8), range(-7, 8),
                                                     (1, 2, 3)):
        lo, hi, start, st = span(size, out, offset, step)
        inside = [a for a in range(out) if 0 <= step * a + offset < size]
        assert (lo, hi) == ((inside[0], inside[-1] + 1) if inside else (lo, lo))
        assert st == step and (not inside or start == step * lo + offset)


@pytest.mark.parametrize("taps,pad", [(3, 1), (1, 0), (2, 0)])
def test_frames_and_phases_in_one_copy_are_the_two_copies(taps, pad):
    x = torch.randn(2, 3, 5, 11, 8)
    for cl, channels in ((True, None), (True, 40), (False, None)):
        xs = x.contiguous(memory_format=torch.channels_last_3d) if cl else x
        want = phases_as_channels(frames_as_channels(xs, taps, pad, cl), (2, 2), (3, 3),
                                  (7, 7), cl)
        got = frames_phases_as_channels(xs, taps, pad, (2, 2), (3, 3), (7, 7), cl, channels)
        assert torch.equal(got[:, : want.shape[1]], want), (cl, channels)
        assert not got[:, want.shape[1]:].any()
        if cl:
            assert got.is_contiguous(memory_format=torch.channels_last)
    with pytest.raises(ValueError, match="fewer than"):
        frames_phases_as_channels(x[:, :, :1], 3, 0, (2, 2), (3, 3), (7, 7), True)


@pytest.mark.parametrize("frames", [1, 2, 7])
@pytest.mark.parametrize("cl", [True, False])
def test_the_space_to_depth_stem_is_the_3d_stem(frames, cl):
    torch.manual_seed(4)
    conv = torch.nn.Conv3d(3, 16, (3, 7, 7), stride=(1, 2, 2), padding=(1, 3, 3)).double()
    x = torch.randn(2, 3, frames, 23, 18, dtype=torch.float64)
    if cl:
        x = x.contiguous(memory_format=torch.channels_last_3d)
    stem = FramesStem(conv, cl, space_to_depth=True)
    assert stem.in_channels == 36  # 3 taps x 3 channels x 4 phases
    with torch.no_grad():
        want, got = conv(x), stem(x)
    assert got.shape == want.shape
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    if cl:
        assert got.is_contiguous(memory_format=torch.channels_last_3d)


def test_space_to_depth_rules(backbone, monkeypatch):
    def fp(**kw):
        args = dict(fp32_stem=True, differences=False, fuse_bn=True, tf32_stem=False,
                    fused=None, pad_stem=None)
        return fast_path(torch.device("cuda"), torch.float16, **(args | kw))

    assert not fp().stem_s2d and not fp(stem_2d=True).stem_s2d  # asked for only
    got = fp(stem_s2d=True)
    assert (got.stem_2d, got.stem_s2d, got.pad_stem) == (True, True, False)  # implies 2D
    with pytest.raises(CGVQMError, match="differences"):
        fp(stem_s2d=True, differences=True)
    # padding to 16-byte voxels pads the phases' channels: 36 in fp32 are 144 bytes already;
    # a 16-bit stem rounds 36 up to 40
    assert FeatureNet(backbone, 3, stem_s2d=True, pad_stem=True).model.stem[0].in_channels \
        == 36
    # the layout, not the speed: a CPU without bf16 hardware would refuse to run it
    import cgvqm_core.precision as precision

    monkeypatch.setattr(precision, "cpu_bf16", lambda: precision.CpuBf16(True, False, "test"))
    low = FeatureNet(backbone, 3, precision="bf16", fp32_stem=False, differences=False,
                     stem_s2d=True, pad_stem=True)
    assert low.model.stem[0].in_channels == 40 and low.pad_stem
    # with the int split: test_frames_stem.py
    # R(2+1)D's one-tap stem: 3 channels x 4 phases
    r21 = random_backbone(0, arch="r2plus1d_18")
    s2d = FeatureNet(r21, 2, stem_s2d=True)
    assert s2d.model.stem[0].in_channels == 12
    x = torch.randn(1, 3, 4, 16, 16)
    assert_same_levels(s2d, FeatureNet(r21, 2), x)
    with pytest.raises(ValueError, match="2D stem only"):
        StemRewrite(torch.nn.Conv3d(3, 4, 3), split=None, two_d=False, pad=False,
                    channels_last=True, mean=MEAN, std=STD, space_to_depth=True)
