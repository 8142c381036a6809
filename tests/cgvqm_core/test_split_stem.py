"""The split stems: fp32's stem from one TF32 convolution of split operands. Their operands
are TF32 numbers, so a CPU's fp32 convolution computes what a GPU's TF32 kernel does (up to
summation order); the references here are float64 convolutions and the TF32-rounded stem."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cgvqm_core import CGVQM
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import MEAN, STD, FeatureNet
from cgvqm_core.precision import fast_path
from cgvqm_core.stem import SPLITS, SplitStem, round_tf32

from .test_fast_paths import _folded
from .test_parity import _random_weights

CUDA, CPU = torch.device("cuda"), torch.device("cpu")


def _normalised(pixels: torch.Tensor) -> torch.Tensor:
    """uint8 (B, 3, T, H, W) -> the stem's fp32 input, as FeatureNet.to_input makes it."""
    m = torch.tensor(MEAN).view(1, 3, 1, 1, 1)
    s = torch.tensor(STD).view(1, 3, 1, 1, 1)
    return pixels.float().div(255).sub(m).div(s)


def test_round_tf32_is_round_to_nearest_at_ten_mantissa_bits():
    """Away from ties, TF32 and fp16 keep the same 10 mantissa bits: fp16's own rounding is
    the oracle inside its range; ties round away from zero."""
    x = torch.randn(100_000) * 30
    ties = (x.view(torch.int32) & 0x1FFF) == 0x1000
    torch.testing.assert_close(round_tf32(x)[~ties], x.half().float()[~ties], rtol=0, atol=0)
    one = torch.tensor([1 + 2**-11, -(1 + 2**-11), 1 + 2**-12, 1e30])
    got = round_tf32(one)
    assert got[:3].tolist() == [1 + 2**-10, -(1 + 2**-10), 1.0]
    assert abs(got[3].item() / 1e30 - 1) < 2**-11


@pytest.mark.parametrize("split", SPLITS)
@pytest.mark.parametrize("channels_last", [True, False])
def test_a_split_stem_computes_the_fp32_stem(split, channels_last):
    conv = _folded(depth=0).stem[0]
    with torch.no_grad():
        conv.bias.mul_(3)
    pixels = torch.randint(0, 256, (2, 3, 5, 22, 22), dtype=torch.uint8)
    pixels[..., :4] = 255  # saturated borders, where the int split's ones channel matters
    x = _normalised(pixels)
    fmt = torch.channels_last_3d if channels_last else torch.contiguous_format
    stem = SplitStem(split, MEAN, STD)
    wide = stem.conv(conv, channels_last)
    xs = stem.input(x.contiguous(memory_format=fmt), channels_last, check=True)
    assert wide.in_channels == {"int": 8, "3xtf32": 12}[split]  # 16-byte multiples
    assert xs.is_contiguous(memory_format=fmt)
    # every operand a TF32 number: a TF32 kernel rounds none of them
    assert torch.equal(round_tf32(wide.weight.contiguous()), wide.weight.contiguous())
    assert torch.equal(round_tf32(xs.contiguous()), xs.contiguous())
    args = conv.stride, conv.padding
    exact = F.conv3d(x.double(), conv.weight.double(), conv.bias.double(), *args)
    scale = exact.abs().max()
    with torch.inference_mode():
        fp32 = (conv(x).double() - exact).abs().max() / scale
        got = (wide(xs).double() - exact).abs().max() / scale
        tf32 = F.conv3d(round_tf32(x), round_tf32(conv.weight), conv.bias, *args)
        tf32 = (tf32.double() - exact).abs().max() / scale
    assert got < 4 * fp32 + 1e-7  # fp32's error, give or take summation order
    assert tf32 > 50 * got  # what the split is for


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_scores_with_a_split_stem_are_fp32_scores(vids, backbone):
    """Whole scores: each split stem within fp32 rounding of the plain network; the TF32
    stem it replaces visibly not."""
    ref = vids.smooth(3, 10, 40, 36)
    test = vids.distort(ref, seed=5)
    w = _random_weights("cgvqm-5", 1027, seed=9)
    plain = CGVQM("cgvqm-5", weights=w, backbone=backbone).score(ref, test, fps=8)
    tf32 = CGVQM("cgvqm-5", weights=w, backbone=backbone)
    stem = tf32.net.model.stem[0]
    stem.forward = lambda x: F.conv3d(round_tf32(x), round_tf32(stem.weight), stem.bias,
                                      stem.stride, stem.padding)
    tf32_dev = np.abs(tf32.score(ref, test, fps=8).msd - plain.msd).max()
    for split in SPLITS:
        m = CGVQM("cgvqm-5", weights=w, backbone=backbone, split_stem=split)
        assert m.provenance()["precision_detail"]["split_stem"] == split
        assert "pad_stem" not in m.provenance()["precision_detail"]
        dev = np.abs(m.score(ref, test, fps=8).msd - plain.msd).max()
        assert dev < 1e-5 * np.abs(plain.msd).max()
        assert tf32_dev > 20 * dev


def test_split_stem_rules(backbone):
    def fp(**kw):
        args = dict(fp32_stem=True, differences=False, fuse_bn=True, tf32_stem=False,
                    fused=None, pad_stem=None)
        return fast_path(CUDA, torch.float16, **(args | kw))

    assert fp(split_stem="int") == fp(pad_stem=False, split_stem="int")
    got = fp(split_stem="3xtf32", pad_stem=True)
    assert (got.split_stem, got.pad_stem, got.fused, got.tf32_stem) == ("3xtf32", False, True,
                                                                        False)
    assert fp().split_stem is None  # asked for only
    for kw, why in ((dict(split_stem="int", tf32_stem=True), "exclude each other"),
                    (dict(split_stem="hilo"), "one of int, 3xtf32"),
                    (dict(split_stem="int", fp32_stem=False), "fp32 stem"),
                    (dict(split_stem="int", differences=True), "differences")):
        with pytest.raises(CGVQMError, match=why):
            fp(**kw)
    with pytest.raises(CGVQMError, match="fp32 stem"):  # tf32 keeps upstream's TF32 stem
        fast_path(CUDA, torch.float32, fp32_stem=False, differences=False, fuse_bn=False,
                  tf32_stem=False, fused=None, pad_stem=None, split_stem="int", tf32_net=True)
    # strict fp32 may have it (an exact stem either way)
    got = fast_path(CPU, torch.float32, fp32_stem=False, differences=False, fuse_bn=True,
                    tf32_stem=False, fused=None, pad_stem=None, split_stem="int")
    assert got.split_stem == "int"
    with pytest.raises(CGVQMError, match="split stem must be"):
        FeatureNet(backbone, 3, split_stem="half")


def test_the_int_split_refuses_input_that_is_not_normalised_pixels(backbone):
    """Its exactness rests on integer pixels: any other input is an error, never a silently
    rounded one; the 3xtf32 split takes any input."""
    x = torch.randn(1, 3, 4, 16, 16)
    net = FeatureNet(backbone, 3, split_stem="int")
    for _ in range(2):  # a refused first pass leaves the next one checked too
        with pytest.raises(CGVQMError, match="uint8 pixels"):
            list(net.levels(x))
    ok = FeatureNet(backbone, 3, split_stem="3xtf32")
    plain = FeatureNet(backbone, 3)
    for a, b in zip(ok.levels(x), plain.levels(x), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
    pixels = torch.randint(0, 256, (1, 3, 4, 16, 16), dtype=torch.uint8)
    assert len(list(net.levels(_normalised(pixels)))) == 3
