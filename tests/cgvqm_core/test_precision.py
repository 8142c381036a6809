"""Precisions: fp32 unchanged, bf16 on CPUs that have it (drift within measured bounds),
refusal with the reason elsewhere, and the precision and device in every result."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM, patch_channel_msd
from cgvqm_core import precision as prec
from cgvqm_core.cli import main
from cgvqm_core.errors import CGVQMError
from cgvqm_core.features import EPS, FeatureNet
from cgvqm_core.patch_scorer import PatchScorer
from cgvqm_core.weights import FeatureWeights

HAS_BF16 = prec.cpu_bf16().supported
needs_bf16 = pytest.mark.skipif(not HAS_BF16, reason=f"no bf16 on this CPU: "
                                f"{prec.cpu_bf16().reason()}")

# Per-level |omega| totals and alpha of the published weights (cgvqm-2.pickle, cgvqm-5.pickle),
# spread uniformly inside each level: q lands in the published weights' range without needing
# the files.
SHAPED = {"cgvqm-2": ([3, 64, 64], [9.4e-06, 0.776, 0.0624], 131543.4),
          "cgvqm-5": ([3, 64, 64, 128, 256, 512],
                      [1.7e-05, 0.1406, 3.2e-05, 0.00317, 0.0564, 0.0467], 583746.4)}
# |dq| bounds of bf16 against fp32 (0..100 scale). Measured on these inputs (4 seeds x 3 noise
# levels, 16x64x64, this AVX512-BF16 CPU): max 0.0075 (CGVQM-2) and 0.035 (CGVQM-5); on the
# demo study and real content (benchmarks/bench_precision.py, README) within the same range.
# CGVQM-2: measured x2.7 for other CPUs' kernels (AMX accumulates in another order); CGVQM-5:
# the acceptance bound 0.05.
DQ_BOUND = {"cgvqm-2": 0.02, "cgvqm-5": 0.05}


def shaped_weights(variant: str) -> FeatureWeights:
    ch, tot, alpha = SHAPED[variant]
    omega = np.concatenate([np.full(c, t / c, np.float32) for c, t in zip(ch, tot, strict=True)])
    return FeatureWeights(variant, omega, alpha, "test", "test-shaped", "test", {})


class OldFP32Net(FeatureNet):
    """FeatureNet.levels exactly as it was before precisions other than fp32 existed."""

    def levels(self, x):
        with torch.inference_mode():
            it = self.model.levels(x, self.n_levels)
            for li in range(self.n_levels):
                a = next(it).float()
                if li == 0:
                    yield a
                else:
                    yield a / torch.linalg.vector_norm(a, dim=1, keepdim=True).add_(EPS)


@pytest.mark.parametrize("n_levels", [3, 6])
def test_fp32_is_bit_identical_to_the_previous_path(vids, backbone, n_levels):
    ref = torch.from_numpy(vids.smooth(3, 6, 24, 24))
    tests = [torch.from_numpy(vids.distort(ref.numpy(), s)) for s in (4, 5)]
    new = PatchScorer(FeatureNet(backbone, n_levels), batch_size=2)(ref, tests)
    old = PatchScorer(OldFP32Net(backbone, n_levels), batch_size=2)(ref, tests)
    assert torch.equal(new.msd, old.msd)
    net = FeatureNet(backbone, n_levels)
    assert net.precision == "fp32" and net.precision_info["bit_exact"]
    assert all(p.dtype == torch.float32 for p in net.model.parameters())


def test_the_default_is_fp32_on_a_cpu_and_provenance_says_so(vids, backbone):
    m = CGVQM(weights=shaped_weights("cgvqm-2"), backbone=backbone)
    res = m.score(vids.smooth(1, 4, 16, 16), vids.smooth(2, 4, 16, 16), fps=4)
    p = res.provenance
    assert (p["device"], p["precision"]) == ("cpu", "fp32")
    assert p["precision_detail"] == {"precision": "fp32", "compute_dtype": "float32",
                                     "bit_exact": True, "requested": "auto"}
    strict = CGVQM(weights=shaped_weights("cgvqm-2"), backbone=backbone, precision="fp32")
    again = strict.score(vids.smooth(1, 4, 16, 16), vids.smooth(2, 4, 16, 16), fps=4)
    assert again.q == res.q and "requested" not in again.provenance["precision_detail"]
    assert p["device_name"].endswith(f"{torch.get_num_threads()} threads")
    assert "precision" not in res.to_dict()  # only reduced precisions are flagged


@needs_bf16
@pytest.mark.parametrize("variant", [  # cgvqm-5 (12 s) in the slow run after `make test`
    "cgvqm-2", pytest.param("cgvqm-5", marks=pytest.mark.slow)])
def test_bf16_drift_within_measured_bounds(vids, backbone, variant):
    w = shaped_weights(variant)
    m32 = CGVQM(variant, weights=w, backbone=backbone)
    m16 = CGVQM(variant, weights=w, backbone=backbone, precision="bf16")
    assert m16.net.stage_dtypes[0] == torch.float32  # stem kept in fp32
    assert set(m16.net.stage_dtypes[1:]) == {torch.bfloat16}
    dq = []
    for seed in (0, 1):
        ref = vids.smooth(seed, 16, 64, 64)
        tests = [vids.distort(ref, 10 + seed, s) for s in (2.0, 12.0)]
        for a, b in zip(m32.score_many(ref, tests, fps=16), m16.score_many(ref, tests, fps=16),
                        strict=True):
            assert 0 < a.q < 100  # the regime the bounds were measured in
            dq += [abs(a.quality(p) - b.quality(p)) for p in ("max", "mean")]
    assert max(dq) <= DQ_BOUND[variant]
    assert max(dq) > 0  # bf16 really ran


@needs_bf16
def test_bf16_keeps_input_and_stem_levels_fp32(vids, backbone):
    """Level 0 is the fp32 input and the stem runs in fp32: their columns match fp32's."""
    ref = vids.smooth(4, 8, 32, 32)
    test = vids.distort(ref, 3)
    a = patch_channel_msd(ref, [test], FeatureNet(backbone, 3), fps=8)[0].msd
    b = patch_channel_msd(ref, [test], FeatureNet(backbone, 3, precision="bf16"), fps=8)[0].msd
    assert np.array_equal(a[:, :3], b[:, :3])
    np.testing.assert_allclose(b[:, 3:67], a[:, 3:67], rtol=1e-5, atol=0)
    assert not np.array_equal(a[:, 67:], b[:, 67:])  # layer1 in bf16


@needs_bf16
def test_bf16_provenance_and_json(vids, backbone):
    m = CGVQM(weights=shaped_weights("cgvqm-2"), backbone=backbone, precision="bf16")
    res = m.score(vids.smooth(1, 4, 16, 16), vids.smooth(2, 4, 16, 16), fps=4)
    d = res.provenance["precision_detail"]
    assert res.provenance["precision"] == "bf16" and res.provenance["device"] == "cpu"
    assert d["cpu_isa"] == prec.cpu_bf16().isa and not d["bit_exact"]
    assert d["fp32_stem"] and d["accumulate"] == "fp32"
    out = json.loads(json.dumps(res.to_dict()))
    assert out["precision"] == "bf16 on cpu (not bit-exact)"
    assert out["provenance"]["precision"] == "bf16"


@needs_bf16
def test_reduced_precision_refuses_non_finite_features(vids, backbone, monkeypatch):
    net = FeatureNet(backbone, 3, precision="bf16")
    real = FeatureNet.pair_levels

    def poisoned(self, x, G, n, tape=None):
        for i, (r, t) in enumerate(real(self, x, G, n, tape)):
            yield (r, t.clone().fill_(float("inf"))) if i == 2 else (r, t)

    monkeypatch.setattr(FeatureNet, "pair_levels", poisoned)
    ref = torch.from_numpy(vids.smooth(1, 4, 16, 16))
    with pytest.raises(CGVQMError, match="overflowed in bf16"):
        PatchScorer(net)(ref, [ref])


NO_BF16 = prec.CpuBf16(amx_bf16=False, avx512_bf16=False, source="/proc/cpuinfo")


def test_bf16_refused_with_the_reason_without_hardware(monkeypatch, backbone):
    monkeypatch.setattr(prec, "cpu_bf16", lambda: NO_BF16)
    with pytest.raises(CGVQMError, match="neither AMX-BF16 nor AVX512-BF16"):
        FeatureNet(backbone, 3, precision="bf16")
    for p in ("fp16", "tf32"):
        with pytest.raises(CGVQMError, match="CUDA only"):
            FeatureNet(backbone, 3, precision=p)
    with pytest.raises(CGVQMError, match="precision must be one of"):
        FeatureNet(backbone, 3, precision="int8")


def test_cli_refusal_is_one_line_exit_2(monkeypatch, capsys, tmp_path, vids):
    monkeypatch.setattr(prec, "cpu_bf16", lambda: NO_BF16)
    ref, test = tmp_path / "r.npy", tmp_path / "t.npy"
    np.save(ref, vids.smooth(1, 4, 16, 16))
    np.save(test, vids.smooth(2, 4, 16, 16))
    code = main(["score", "--ref", str(ref), "--test", str(test), "--fps", "4",
                 "--random-backbone", "1", "--weights", "uniform", "--precision", "bf16"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    refusal = [ln for ln in err if "bf16" in ln]
    assert len(refusal) == 1 and "neither AMX-BF16 nor AVX512-BF16" in refusal[0]
    assert "Traceback" not in "\n".join(err)


@pytest.mark.parametrize(("flags", "probe", "expect"), [
    ("fpu avx512f avx512_bf16 amx_tile amx_bf16", None, ("amx_bf16", "/proc/cpuinfo")),
    ("fpu avx512f avx512_bf16", None, ("avx512_bf16", "/proc/cpuinfo")),
    ("fpu avx2 avx512f", None, ("", "/proc/cpuinfo")),
    ("fpu", {"avx512_bf16": True, "amx_bf16": False}, ("avx512_bf16", "torch-cpuinfo")),
])
def test_detection_reads_torch_then_proc_cpuinfo(monkeypatch, tmp_path, flags, probe, expect):
    info = tmp_path / "cpuinfo"
    info.write_text(f"processor\t: 0\nmodel name\t: Test CPU\nflags\t\t: {flags}\n\n"
                    f"processor\t: 1\nflags\t\t: {flags}\n")
    monkeypatch.setattr(prec, "CPUINFO", info)
    monkeypatch.setattr(prec, "_probe_torch", lambda: probe)
    prec.cpu_bf16.cache_clear()
    try:
        cap = prec.cpu_bf16()
        source = "/proc/cpuinfo" if cap.source == str(info) else cap.source
        assert (cap.isa, source) == expect
        assert cap.supported == bool(expect[0])
    finally:
        prec.cpu_bf16.cache_clear()


def test_detection_without_any_source(monkeypatch, tmp_path):
    monkeypatch.setattr(prec, "CPUINFO", tmp_path / "missing")
    monkeypatch.setattr(prec, "_probe_torch", lambda: None)
    prec.cpu_bf16.cache_clear()
    try:
        cap = prec.cpu_bf16()
        assert not cap.supported and "could not read" in cap.reason()
    finally:
        prec.cpu_bf16.cache_clear()


def test_tf32_switches_restored():
    before = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    with prec.tf32_mode(torch.device("cuda"), False):
        assert not torch.backends.cudnn.allow_tf32
        assert not torch.backends.cuda.matmul.allow_tf32
    assert (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32) == before
    with prec.tf32_mode(torch.device("cpu"), True):
        assert (torch.backends.cudnn.allow_tf32,
                torch.backends.cuda.matmul.allow_tf32) == before


def test_auto_means_what_upstream_computes_on_each_device():
    from cgvqm_core.errors import CGVQMError
    from cgvqm_core.precision import resolve

    assert resolve("auto", torch.device("cpu")) == "fp32"
    assert resolve("auto", torch.device("cuda")) == "tf32"  # PyTorch's defaults on CUDA
    for p in ("fp32", "tf32", "bf16", "fp16"):
        assert resolve(p, torch.device("cuda")) == p
    with pytest.raises(CGVQMError, match="precision must be one of"):
        resolve("fp64", torch.device("cpu"))


@pytest.mark.parametrize(("allow", "conv"), [(True, True), (False, False)])
def test_tf32_mode_sets_pytorchs_defaults_or_strict_fp32_and_restores(allow, conv):
    """On CUDA, tf32 is PyTorch's default (convolutions may use TF32, matrix products not);
    fp32 turns TF32 off. The switches are process-wide flags: no GPU needed to check them."""
    from cgvqm_core.precision import tf32_mode

    saved = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = (not conv, True)
    try:
        with tf32_mode(torch.device("cuda"), allow):
            assert torch.backends.cudnn.allow_tf32 is conv
            assert torch.backends.cuda.matmul.allow_tf32 is False
        assert (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32) == \
            (not conv, True)
        with tf32_mode(torch.device("cpu"), allow):  # nothing to switch on a CPU
            assert torch.backends.cudnn.allow_tf32 is (not conv)
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = saved
