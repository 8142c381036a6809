"""benchmarks/gpu/stem_kernels.py: every way it times the stem computes the stem.

The candidates are timed on a GPU only when one is lent; a candidate that computed another
function would waste that lease, or worse, be wired in. Here each is checked against the
stem in float64 (a second computation), with a real stem's shapes.
"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F


@pytest.fixture(scope="module")
def sk(session):
    return session.stem_kernels_mod


@pytest.fixture(scope="module")
def net(sk):
    n = sk.stem_net("cpu", seed=3)
    with torch.no_grad():  # a bias that is not zero, so that every kind must add it
        n.model.stem[0].bias.copy_(torch.linspace(-0.5, 0.5, 64))
    return n


@pytest.fixture(scope="module")
def conv(net):
    return net.model.stem[0]


def test_every_kind_computes_the_float64_stem_to_fp32_precision(sk, net, conv):
    x = sk.pixels(net, (7, 30, 26, 3), 2, seed=5)  # odd sizes: borders on every side
    ref = sk.exact(conv, x)
    assert ref.shape == (2, 64, 7, 15, 13)
    with torch.inference_mode():
        for kind in sk.KINDS:
            out = sk.make(kind, conv)(x)
            assert out.shape == ref.shape, kind
            assert sk.error(out, ref) < 5e-6, kind
    # and a wrong stem is caught by the same measure
    assert sk.error(F.conv3d(x, conv.weight, None, conv.stride, conv.padding), ref) > 1e-3


def test_measure_times_every_kind_and_the_report_says_which_keep_fp32s_numbers(sk, net):
    ticks = iter(range(10_000))
    res = sk.measure(net, 2, (4, 16, 16, 3), 2, check_shape=(4, 16, 16, 3),
                     clock=lambda: float(next(ticks)))  # each timed call takes 1 "s"
    assert list(res) == list(sk.KINDS)
    for r in res.values():
        assert r["s_per_pass"] == 1.0
        assert r["s_per_pair"] == sk.PATCH_VIDEOS_PER_PAIR / 2
        assert r["tflops"] == pytest.approx(2 * 2 * 4 * 8 * 8 * 64 * 3 * 3 * 7 * 7 / 1e12)
        assert r["error_vs_fp64"] < 5e-6
    fake = {"fp32": {"s_per_pass": 0.01, "s_per_pair": 0.1, "tflops": 16.0,
                     "error_vs_fp64": 1e-7},
            "tf32-pad": {"s_per_pass": 0.002, "s_per_pair": 0.03, "tflops": 60.0,
                         "error_vs_fp64": 3e-4},
            "split-int": {"s_per_pass": 0.003, "s_per_pair": 0.035, "tflops": 50.0,
                          "error_vs_fp64": 2e-7}}
    assert sk.fastest_exact(fake) == "split-int"
    assert sk.fastest_exact({}) is None
    lines = sk.report(fake)
    assert "(fp32's numbers)" in lines[0]
    assert "NOT fp32's numbers, within 0.04 s/pair" in lines[1]
    assert "(fp32's numbers, within 0.04 s/pair)" in lines[2]


def test_unknown_kinds_are_refused(sk, conv):
    with pytest.raises(ValueError, match="unknown stem"):
        sk.make("fp8", conv)
