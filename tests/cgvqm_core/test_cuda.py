"""The CUDA path of the scoring pipeline (skipped without a GPU; benchmarks/gpu/run.sh tests
runs it on a lent machine): pinned clips decoded ahead, patches cut on the GPU, several
positions per pass and one transfer per clip compute what the CPU computes."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM
from cgvqm_core.stage_clock import StageClock

from .test_parity import _random_weights

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


@pytest.fixture
def pair(vids):
    ref = vids.smooth(40, 13, 70, 90)  # 2 clips at 8 fps, a grid that does not divide
    return ref, vids.distort(ref, seed=41)


def test_strict_fp32_on_the_gpu_equals_the_cpu(pair, backbone):
    ref, test = pair
    w = _random_weights("cgvqm-2", 131, seed=42)
    cpu = CGVQM(weights=w, backbone=backbone).score(ref, test, fps=8, emap=True)
    gpu_metric = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp32")
    assert gpu_metric.scorer.positions_per_pass(1, 8 * 17 * 22) > 1  # several per pass
    clock = StageClock("cuda")
    gpu = gpu_metric.score(ref, test, fps=8, emap=True, clock=clock)
    assert abs(gpu.quality("max") - cpu.quality("max")) <= 1e-4
    assert abs(gpu.quality("mean") - cpu.quality("mean")) <= 1e-4
    np.testing.assert_allclose(gpu.patch_errors, cpu.patch_errors, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(gpu.emap, cpu.emap, rtol=1e-3, atol=1e-3 * np.abs(cpu.emap).max())
    s = clock.seconds()
    assert clock.overlapped and s["backbone"] > 0 and s["copy"] > 0
    assert s["copy"] + s["backbone"] + s["pooling"] + s["idle"] >= s["wall"] * 0.999


def test_reference_reuse_and_batches_agree_on_the_gpu(pair, vids, backbone):
    ref, _ = pair
    tests = [vids.distort(ref, seed=50 + i) for i in range(4)]
    w = _random_weights("cgvqm-2", 131, seed=43)
    runs = [CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp32",
                  batch_size=bs, prefetch=pf).score_many(ref, tests, fps=8)
            for bs, pf in ((None, True), (2, False), (5, True), (40, True))]
    for other in runs[1:]:
        for a, b in zip(runs[0], other, strict=True):
            np.testing.assert_allclose(b.patch_errors, a.patch_errors, rtol=1e-5, atol=1e-6)


def test_default_on_cuda_gives_upstreams_numbers(pair, backbone):
    """auto (tf32, batch norm separate) against the benchmarks' stand-in for the authors'
    run_cgvqm with PyTorch's defaults: |dq| <= 1e-3 (the issue's bound)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    try:
        from upstream_as_run import UpstreamAsRun
    finally:
        sys.path.pop(0)
    ref, test = pair
    w = _random_weights("cgvqm-2", 131, seed=44)
    ours = CGVQM(weights=w, backbone=backbone, device="cuda").score(ref, test, fps=8)
    assert ours.provenance["precision"] == "tf32"
    up = UpstreamAsRun(backbone, w, device="cuda").score(ref, test, fps=8)
    assert abs(ours.quality("max") - up.q_max) <= 1e-3
    assert abs(ours.quality("mean") - up.q_mean) <= 1e-3


@pytest.mark.parametrize("precision", ["bf16", "fp16"])
def test_reduced_precisions_drift_within_the_bound(pair, backbone, precision):
    ref, test = pair
    w = _random_weights("cgvqm-2", 131, seed=45)
    exact = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp32")
    fast = CGVQM(weights=w, backbone=backbone, device="cuda", precision=precision)
    a, b = exact.score(ref, test, fps=8), fast.score(ref, test, fps=8)
    assert abs(a.quality("max") - b.quality("max")) <= 0.05


def test_bf16_differences_on_cuda_compute_the_plain_numbers_in_fp32(pair, backbone):
    """The difference path's algebra on the GPU's kernels: asked for in strict fp32 it gives
    the plain path's patch errors."""
    ref, test = pair
    w = _random_weights("cgvqm-5", 1027, seed=46)
    plain = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp32")
    diff = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp32",
                 differences=True)
    a, b = plain.score(ref, test, fps=8), diff.score(ref, test, fps=8)
    np.testing.assert_allclose(b.msd, a.msd, rtol=2e-4, atol=1e-9)


@pytest.mark.parametrize("precision", ["fp32", "fp16"])
def test_fused_stages_and_the_padded_stem_on_cuda(pair, backbone, precision):
    """cuDNN's fused convolution (bias, residual and ReLU in the epilogue) and the zero-padded
    stem compute the plain network's numbers: to 1e-4 in strict fp32, within fp16's own
    rounding in fp16. The fused operation must actually run (not fall back)."""
    ref, test = pair
    w = _random_weights("cgvqm-5", 1027, seed=47)
    plain = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision=precision,
                  fused=False, pad_stem=False, tf32_stem=False).score(ref, test, fps=8)
    fast = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision=precision,
                 fused=True, pad_stem=True, tf32_stem=False)
    got = fast.score(ref, test, fps=8)
    detail = fast.net.precision_info
    assert detail["fused"] is True and detail["pad_stem"] is True
    assert fast.net.model.stem[0].in_channels == 4  # the stem runs in fp32 either way
    bound = 1e-4 if precision == "fp32" else 5e-3
    assert abs(got.quality("max") - plain.quality("max")) <= bound
    assert abs(got.quality("mean") - plain.quality("mean")) <= bound


def test_a_tf32_stem_stays_within_the_drift_bound(pair, backbone):
    ref, test = pair
    w = _random_weights("cgvqm-2", 131, seed=48)
    exact = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp32")
    fast = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp16", tf32_stem=True,
                 fused=True, pad_stem=True)
    a, b = exact.score(ref, test, fps=8), fast.score(ref, test, fps=8)
    assert fast.net.precision_info["tf32_stem"] is True
    assert abs(a.quality("max") - b.quality("max")) <= 0.05


def test_fp16_on_cuda_takes_the_fast_path_by_default(pair, backbone):
    """fp16's default on CUDA: fused stages really running, the stem in exact fp32; with the
    TF32 stem asked for, the stem padded too."""
    ref, test = pair
    w = _random_weights("cgvqm-2", 131, seed=49)
    m = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp16")
    m.score(ref, test, fps=8)
    d = m.provenance()["precision_detail"]
    assert d["fused"] is True and "pad_stem" not in d and "tf32_stem" not in d
    assert m.net._fused_proven
    fast = CGVQM(weights=w, backbone=backbone, device="cuda", precision="fp16", tf32_stem=True)
    d = fast.provenance()["precision_detail"]
    assert d["fused"] is True and d["pad_stem"] is True and d["tf32_stem"] is True


#: the stem rewrites that keep fp32's numbers: split operands in TF32 kernels, and the stem
#: as one conv2d over frames (in both layouts)
EXACT_STEMS = {"split-int": {"split_stem": "int"}, "split-3xtf32": {"split_stem": "3xtf32"},
               "2d": {"stem_2d": True}, "2d-channels-last": {"stem_2d": True,
                                                             "channels_last": True},
               "s2d": {"stem_s2d": True},
               "split-int-s2d": {"split_stem": "int", "stem_s2d": True}}


@pytest.mark.parametrize("stem", EXACT_STEMS.values(), ids=EXACT_STEMS.keys())
def test_a_rewritten_stem_on_cuda_computes_the_fp32_stem(pair, backbone, stem):
    """cuDNN's TF32 kernels on the split operands, or its 2D kernels (over the stride phases
    too): strict fp32's numbers (the 1e-4 of CPU parity), fused, in strict fp32; under fp16
    within fp16's own rounding of its exact-stem default."""
    ref, test = pair
    w = _random_weights("cgvqm-5", 1027, seed=50)
    exact = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp32")
    m = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp32",
              **stem)
    a, b = exact.score(ref, test, fps=8), m.score(ref, test, fps=8)
    d = m.provenance()["precision_detail"]
    option = {k: v for k, v in stem.items() if k != "channels_last"}
    assert all(d[k] == v for k, v in option.items())
    assert d["fused"] is True and m.net._fused_proven
    for pool in ("max", "mean"):
        assert abs(a.quality(pool) - b.quality(pool)) <= 1e-4
    np.testing.assert_allclose(b.patch_errors, a.patch_errors, rtol=1e-4, atol=1e-6)
    plain16 = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp16")
    m16 = CGVQM("cgvqm-5", weights=w, backbone=backbone, device="cuda", precision="fp16",
                **option)
    c, e = plain16.score(ref, test, fps=8), m16.score(ref, test, fps=8)
    assert abs(c.quality("max") - e.quality("max")) <= 5e-3
