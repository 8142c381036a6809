"""The GPU speed-ups that change how, not what, the network computes: fused convolution
stages, the zero-padded stem and the leaner unit normalisation. Checked on the CPU against
the plain modules (the cuDNN kernels themselves are checked in test_cuda.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import cgvqm_core.features as features
from cgvqm_core import CGVQM
from cgvqm_core.backbone import build_backbone
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import FeatureNet, _fuse_batchnorm
from cgvqm_core.fused_conv import REFERENCE, fusable, fused_stage
from cgvqm_core.precision import fast_path
from cgvqm_core.stem import pad_stem_conv, padded_channels, padded_input
from cgvqm_core.unit_norm import EPS, unit_norm_fp32

from .conftest import random_state_dict
from .test_parity import _random_weights


def _folded(arch: str = "r3d_18", depth: int = 2) -> torch.nn.Module:
    model = build_backbone(arch, depth=depth, classifier=False)
    sd = random_state_dict(7, arch)
    model.load_state_dict({k: v for k, v in sd.items() if k in model.state_dict()})
    model.eval()
    _fuse_batchnorm(model)
    return model


def test_fused_stages_compute_the_stages():
    """Stem, a layer without and a layer with a downsampling shortcut: the fused walk (with
    ordinary operators in place of cuDNN's) equals the modules' own forward."""
    model = _folded(depth=2)
    x = torch.randn(2, 3, 4, 16, 16)
    with torch.inference_mode():
        for stage in model.stages():
            assert fusable(stage)
            want = stage(x.clone())
            got = fused_stage(stage, x.clone(), REFERENCE)
            torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
            x = want
        assert model.layer2[0].downsample is not None  # the shortcut path was covered


def test_what_is_not_fused():
    """R(2+1)D's factorised convolutions and batch norm left in place are not fused."""
    assert not fusable(_folded("r2plus1d_18", 1).stem)
    assert not fusable(_folded("r2plus1d_18", 1).layer1)
    plain = build_backbone("r3d_18", depth=1, classifier=False).eval()
    assert not fusable(plain.stem) and not fusable(plain.layer1)


@pytest.mark.parametrize("channels_last", [True, False])
def test_a_padded_stem_computes_the_stem(channels_last):
    conv = _folded(depth=0).stem[0]
    fmt = torch.channels_last_3d if channels_last else torch.contiguous_format
    conv = conv.to(memory_format=fmt)
    x = torch.randn(2, 3, 5, 20, 20).contiguous(memory_format=fmt)
    c = padded_channels(torch.float32)
    wide = pad_stem_conv(conv, c, channels_last)
    xp = padded_input(x, c, torch.float32, channels_last)
    assert (c, padded_channels(torch.float16), padded_channels(torch.bfloat16)) == (4, 8, 8)
    assert xp.shape[1] == 4 and xp[:, 3].abs().max() == 0 and torch.equal(xp[:, :3], x)
    assert xp.is_contiguous(memory_format=fmt)
    assert torch.equal(wide.weight[:, :3], conv.weight) and wide.weight[:, 3:].abs().max() == 0
    with torch.inference_mode():
        torch.testing.assert_close(wide(xp), conv(x), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16, torch.float32])
def test_unit_norm_reads_low_precision_directly(dtype):
    """Same numbers as copying to fp32 first, then dividing by the norm plus EPS."""
    a = torch.randn(2, 8, 3, 5, 6).to(dtype).contiguous(memory_format=torch.channels_last_3d)
    a[0, :, 0, 0, 0] = 0  # a dead voxel stays at zero
    f = a.float()
    want = f / (torch.linalg.vector_norm(f, dim=1, keepdim=True) + EPS)
    got = unit_norm_fp32(a)
    assert got.dtype == torch.float32
    assert got.is_contiguous(memory_format=torch.channels_last_3d)
    torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-7)
    assert got[0, :, 0, 0, 0].abs().max() == 0


@pytest.mark.slow  # about 11 s here: CI runs it after `make test` (.ci/run)
def test_scores_with_a_padded_stem_and_fused_stages(vids, backbone, monkeypatch):
    """Whole scores through FeatureNet: the padded stem, and fused stages (cuDNN's operation
    stood in for by ordinary operators), against the plain network."""
    ref = vids.smooth(3, 10, 40, 36)
    test = vids.distort(ref, seed=5)
    w = _random_weights("cgvqm-5", 1027, seed=9)
    plain = CGVQM("cgvqm-5", weights=w, backbone=backbone).score(ref, test, fps=8)
    padded = CGVQM("cgvqm-5", weights=w, backbone=backbone, pad_stem=True)
    assert padded.net.model.stem[0].in_channels == 4
    assert padded.provenance()["precision_detail"]["pad_stem"] is True
    np.testing.assert_allclose(padded.score(ref, test, fps=8).msd, plain.msd, rtol=1e-4,
                               atol=1e-9)
    monkeypatch.setattr(features, "fused_stage", lambda st, h: fused_stage(st, h, REFERENCE))
    fused = CGVQM("cgvqm-5", weights=w, backbone=backbone)
    fused.net.fused = True
    np.testing.assert_allclose(fused.score(ref, test, fps=8).msd, plain.msd, rtol=1e-4,
                               atol=1e-9)
    assert fused.net._fused_proven


def test_a_cudnn_without_the_fused_operation_falls_back_once(vids, backbone, monkeypatch):
    """The first fused call failing turns fusion off for the network and says why; the
    scores are the plain ones."""
    ref = vids.smooth(4, 8, 24, 24)
    test = vids.distort(ref, seed=6)
    w = _random_weights("cgvqm-2", 131, seed=10)
    plain = CGVQM(weights=w, backbone=backbone).score(ref, test, fps=8)

    def refuse(stage, h):
        raise RuntimeError("cuDNN error: CUDNN_STATUS_NOT_SUPPORTED\nmore")

    monkeypatch.setattr(features, "fused_stage", refuse)
    m = CGVQM(weights=w, backbone=backbone)
    m.net.fused = True
    got = m.score(ref, test, fps=8)
    assert not m.net.fused
    assert m.net.precision_info["fused"] == \
        "unavailable: cuDNN error: CUDNN_STATUS_NOT_SUPPORTED"
    np.testing.assert_allclose(got.msd, plain.msd, rtol=1e-6)


def test_fast_path_refusals(backbone):
    with pytest.raises(CGVQMError, match="cuDNN"):
        FeatureNet(backbone, 3, fused=True)
    with pytest.raises(CGVQMError, match="TF32 stem"):
        FeatureNet(backbone, 3, tf32_stem=True)
    with pytest.raises(CGVQMError, match="differences"):
        FeatureNet(backbone, 3, pad_stem=True, differences=True)


CUDA, CPU = torch.device("cuda"), torch.device("cpu")


@pytest.mark.parametrize("device, dtype, fp32_stem, differences, fuse_bn, want", [
    # fp16 on CUDA: fused, its fp32 stem exact and unpadded (the TF32 stem is opt-in)
    (CUDA, torch.float16, True, False, True, (False, True, False)),
    # fp16 with its stem in fp16: fused, padded to 8 channels, no TF32 stem
    (CUDA, torch.float16, False, False, True, (False, True, True)),
    # bf16 carries tests as differences: none apply
    (CUDA, torch.bfloat16, True, True, True, (False, False, False)),
    # bf16 without differences: fused only (the fp32 stem padded ran slower)
    (CUDA, torch.bfloat16, True, False, True, (False, True, False)),
    # strict fp32: fused (exact), stem left as it is
    (CUDA, torch.float32, False, False, True, (False, True, False)),
    # tf32 (auto on CUDA) keeps batch norm apart, as upstream rounds it: nothing
    (CUDA, torch.float32, False, False, False, (False, False, False)),
    # a CPU: nothing
    (CPU, torch.bfloat16, True, False, True, (False, False, False)),
    (CPU, torch.float32, False, False, True, (False, False, False)),
])
def test_fast_path_defaults(device, dtype, fp32_stem, differences, fuse_bn, want):
    got = fast_path(device, dtype, fp32_stem=fp32_stem, differences=differences,
                    fuse_bn=fuse_bn, tf32_stem=False, fused=None, pad_stem=None)
    assert (got.tf32_stem, got.fused, got.pad_stem) == want


def test_explicit_fast_path_choices_win():
    got = fast_path(CUDA, torch.float16, fp32_stem=True, differences=False, fuse_bn=True,
                    tf32_stem=False, fused=False, pad_stem=True)
    assert (got.tf32_stem, got.fused, got.pad_stem) == (False, False, True)
    # asking for the TF32 stem pads it too: the pair measured fastest
    got = fast_path(CUDA, torch.float16, fp32_stem=True, differences=False, fuse_bn=True,
                    tf32_stem=True, fused=None, pad_stem=None)
    assert (got.tf32_stem, got.fused, got.pad_stem) == (True, True, True)
    with pytest.raises(CGVQMError, match="batch norm folded"):
        fast_path(CUDA, torch.float32, fp32_stem=False, differences=False, fuse_bn=False,
                  tf32_stem=None, fused=True, pad_stem=None)


def test_running_out_of_memory_is_not_taken_for_a_missing_operation(vids, backbone,
                                                                    monkeypatch):
    ref = vids.smooth(4, 8, 24, 24)

    def oom(stage, h):
        raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB")

    monkeypatch.setattr(features, "fused_stage", oom)
    m = CGVQM(weights=_random_weights("cgvqm-2", 131, seed=11), backbone=backbone)
    m.net.fused = True
    with pytest.raises(torch.OutOfMemoryError):
        m.score(ref, vids.distort(ref, seed=7), fps=8)
    assert m.net.fused and "fused" not in m.net.precision_info
