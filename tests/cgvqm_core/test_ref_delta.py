"""Test features carried as differences from the reference's (cgvqm_core.ref_delta).

In fp32 the difference path must compute the plain path's numbers (the algebra: bias-free
convolutions, batch norm as a scale, the ReLU rule, residual sums, the tape); in bf16 it
must remove the rounding bias that the plain path adds, measured against fp32."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core import precision as prec
from cgvqm_core.backbone import build_backbone
from cgvqm_core.features import FeatureNet
from cgvqm_core.hub import from_state_dict
from cgvqm_core.patch_scorer import PatchScorer

from .test_parity import _random_weights

needs_bf16 = pytest.mark.skipif(not prec.cpu_bf16().supported,
                                reason=f"no bf16 on this CPU: {prec.cpu_bf16().reason()}")


def _backbone(arch: str, seed: int):
    """A random network of ``arch`` whose batch norms do something (random statistics)."""
    torch.manual_seed(seed)
    model = build_backbone(arch)
    g = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm3d):
            c = m.num_features
            m.running_mean.copy_(torch.randn(c, generator=g) * 0.1)
            m.running_var.copy_(torch.rand(c, generator=g) + 0.5)
            m.weight.data.copy_(torch.rand(c, generator=g) + 0.5)
            m.bias.data.copy_(torch.randn(c, generator=g) * 0.1)
    return from_state_dict(model.state_dict(), arch=arch, label=f"test-{arch}")


def _msd(net: FeatureNet, ref: np.ndarray, tests: list[np.ndarray], batch: int) -> torch.Tensor:
    scorer = PatchScorer(net, batch_size=batch)
    return scorer(torch.from_numpy(ref), [torch.from_numpy(t) for t in tests]).msd


@pytest.mark.parametrize(("arch", "fuse_bn", "fp32_stem"), [
    ("r3d_18", True, True), ("r3d_18", False, False), ("mc3_18", True, False),
    ("r2plus1d_18", False, True)])
def test_differences_in_fp32_compute_the_plain_numbers(vids, arch, fuse_bn, fp32_stem):
    """Every level of every architecture, folded or separate batch norm, the stem inside or
    outside the difference path, one pass or chunks replayed from the tape (batch 2 for
    three tests; batch 1 records the reference alone)."""
    bb = _backbone(arch, seed=3)
    ref = vids.smooth(5, 6, 24, 24)
    tests = [vids.distort(ref, seed=6 + i, sigma=s) for i, s in enumerate((1.0, 4.0, 12.0))]
    kw = dict(fuse_bn=fuse_bn, fp32_stem=fp32_stem)
    plain = _msd(FeatureNet(bb, 6, differences=False, **kw), ref, tests, batch=4)
    net = FeatureNet(bb, 6, differences=True, **kw)
    assert net.differences and net.precision == "fp32"
    for batch in (4, 2, 1):
        got = _msd(net, ref, tests, batch)
        assert got.shape == plain.shape == (3, 3 + 64 + 64 + 128 + 256 + 512)
        np.testing.assert_allclose(got.numpy(), plain.numpy(), rtol=2e-4, atol=1e-9)


def test_differences_in_fp32_compute_the_plain_numbers_with_halos(vids, backbone):
    """Seamless tiling crops every level to the patch's core: the same numbers either way."""
    ref = vids.smooth(7, 4, 64, 64)
    test = vids.distort(ref, seed=8, sigma=5.0)
    w = _random_weights("cgvqm-5", 1027, seed=9)
    kw = dict(weights=w, backbone=backbone, seamless=True, patch_scale=2)
    a = CGVQM("cgvqm-5", **kw).score(ref, test, fps=4)
    b = CGVQM("cgvqm-5", differences=True, **kw).score(ref, test, fps=4)
    np.testing.assert_allclose(b.msd, a.msd, rtol=2e-4, atol=1e-9)
    assert b.q == pytest.approx(a.q, rel=1e-5)


def test_the_default_follows_the_precision(backbone):
    assert not FeatureNet(backbone, 3).differences
    assert "differences" not in FeatureNet(backbone, 3).precision_info
    if prec.cpu_bf16().supported:
        net = FeatureNet(backbone, 3, precision="bf16")
        assert net.differences
        assert net.precision_info["differences"] == "propagated from the reference"
        assert not FeatureNet(backbone, 3, precision="bf16", differences=False).differences


@needs_bf16
def test_bf16_differences_remove_the_rounding_bias(vids, backbone):
    """Near-identical videos (noise sigma 1-3 grey levels), CGVQM-5's six levels: the plain
    bf16 path rounds reference and test independently and inflates every layer's mean
    squared difference; carried as differences, the error against fp32 shrinks tenfold
    and has no sign of its own (measured here: +2 to +56 % plain, within 1.1 % as differences)."""
    ref = vids.smooth(21, 8, 48, 48)
    tests = [vids.distort(ref, seed=22 + i, sigma=s) for i, s in enumerate((1.0, 2.0, 3.0))]
    exact = _msd(FeatureNet(backbone, 6), ref, tests, batch=4).double()
    plain = _msd(FeatureNet(backbone, 6, precision="bf16", differences=False), ref, tests,
                 batch=4).double()
    diff = _msd(FeatureNet(backbone, 6, precision="bf16"), ref, tests, batch=4).double()
    cuts = np.cumsum([0, 3, 64, 64, 128, 256, 512])
    for lo, hi in itertools.pairwise(cuts[2:]):  # layer1..layer4 (the bf16 levels)
        e = exact[:, lo:hi].sum(1)
        bias_plain = (plain[:, lo:hi].sum(1) / e - 1).numpy()
        bias_diff = (diff[:, lo:hi].sum(1) / e - 1).numpy()
        assert (bias_plain > 0).all()  # independent rounding only ever adds
        assert np.abs(bias_diff).max() < np.abs(bias_plain).max() / 10
    # the stem level is fp32 in both: identical to fp32 up to float rounding
    np.testing.assert_allclose(diff[:, 3:67], exact[:, 3:67], rtol=1e-4)


@needs_bf16
def test_bf16_differences_in_chunks_equal_one_pass(vids, backbone):
    """Four tests sharing a reference: the reference replayed from the tape (batch 2, three
    passes) gives what one pass of all five videos gives."""
    ref = vids.smooth(31, 6, 32, 32)
    tests = [vids.distort(ref, seed=32 + i, sigma=2.0 + 3 * i) for i in range(4)]
    net = FeatureNet(backbone, 6, precision="bf16")
    one = _msd(net, ref, tests, batch=5)
    chunks = _msd(net, ref, tests, batch=2)
    np.testing.assert_allclose(chunks.numpy(), one.numpy(), rtol=1e-5, atol=1e-12)
