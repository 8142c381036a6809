"""Inputs that used to give a plausible but wrong number from the Python API: image metrics
fed another range, NaN or half precision, 10-bit samples in uint16 arrays, a fractional
patch scale, a variant the weights file is not, and DSS below its smallest defined size.
Each is now a clear error (or, for rounding past a metric's range, held to the range)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cgvqm_core import CGVQM, CGVQMError
from cgvqm_core.metrics import iqa
from cgvqm_core.metrics.engine import score_reference
from cgvqm_core.metrics.registry import MetricOptions, build_scorers, get_entry
from cgvqm_core.weights import uniform_weights
from stimuli_manifests import VideoError, read_video

RNG = np.random.default_rng(5)
REF = torch.from_numpy(RNG.random((2, 3, 48, 48))).float()
TEST = (REF + 0.05 * torch.from_numpy(RNG.standard_normal((2, 3, 48, 48))).float()).clamp(0, 1)
FUNCTIONS = ["psnr", "ssim", "ms_ssim", "iw_ssim", "vif_p", "fsim", "srsim", "gmsd",
             "ms_gmsd", "vsi", "dss", "haarpsi", "mdsi"]


@pytest.mark.parametrize("name", FUNCTIONS)
def test_every_image_metric_refuses_another_range_nan_and_half(name):
    fn = getattr(iqa, name)
    if name in ("ms_ssim", "iw_ssim", "ms_gmsd", "srsim", "vif_p"):
        ref, test = (torch.nn.functional.interpolate(x, size=(176, 176)) for x in (REF, TEST))
    else:
        ref, test = REF, TEST
    assert torch.isfinite(fn(test, ref)).all()
    with pytest.raises(ValueError, match=r"spans [0-9.e-]+\.\.2[0-9.]+; image metrics take"):
        fn(test * 255, ref * 255)
    bad = test.clone()
    bad[0, 0, 3, 3] = float("nan")
    with pytest.raises(ValueError, match="NaN or infinite"):
        fn(bad, ref)
    with pytest.raises(ValueError, match="float32 or float64"):
        fn(test.half(), ref.half())
    with pytest.raises(ValueError, match="both of one type"):
        fn(test, ref.double())
    with pytest.raises(ValueError, match="channels last"):
        fn(test.permute(0, 2, 3, 1), ref.permute(0, 2, 3, 1))


def test_psnr_on_the_refused_range_would_have_been_wrong():
    """Why the range check: 0..255 through the [0, 1] formula is a different number."""
    right = iqa.psnr(TEST, REF)
    mse = ((TEST - REF) ** 2).mean(dim=(1, 2, 3)).double()
    assert torch.allclose(right.double(), -10 * torch.log10(mse + 1e-8), atol=1e-4)
    assert (-10 * torch.log10(mse * 255**2 + 1e-8) < 0).all()  # what 0..255 gave: negative dB


def test_ten_bit_samples_in_uint16_are_refused(tmp_path):
    frames = RNG.integers(0, 1024, (4, 16, 16, 3)).astype(np.uint16)
    np.save(tmp_path / "ten.npy", frames)
    with pytest.raises(VideoError, match=r"reach only \d+: 10-bit samples\?.*x << 6"):
        read_video(tmp_path / "ten.npy")
    np.save(tmp_path / "sixteen.npy", frames << 6)  # the same picture as 16-bit
    got = read_video(tmp_path / "sixteen.npy")
    assert np.array_equal(got, ((frames << 6) >> 8).astype(np.uint8))


def test_dss_is_not_applicable_below_its_pooling_size():
    spec = get_entry("dss").spec
    assert spec.min_size == 32
    with pytest.raises(ValueError, match="too small"):
        iqa.dss(TEST[..., :24, :24], REF[..., :24, :24])
    assert torch.isfinite(iqa.dss(TEST[..., :32, :32], REF[..., :32, :32])).all()
    frames = (RNG.random((3, 24, 24, 3)) * 255).astype(np.uint8)
    scorers = build_scorers(["psnr", "dss"], MetricOptions())
    [results] = score_reference(frames, [frames], scorers)
    by_name = {r.metric: r for r in results}
    assert by_name["psnr"].score == pytest.approx(80.0)  # the other metric is not lost
    assert by_name["dss"].score is None and "24x24" in by_name["dss"].note


def test_rounding_past_the_range_is_held_to_it():
    frames = (RNG.random((2, 64, 64, 3)) * 255).astype(np.uint8)
    raw = iqa.dss(torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255,
                  torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255)
    assert (raw > 1).any()  # float rounding: 17 sub-band epsilons
    [[dss]] = score_reference(frames, [frames], build_scorers(["dss"], MetricOptions()))
    assert dss.score == 1.0


def test_patch_scale_must_be_whole_and_the_variant_must_be_the_weights(backbone):
    with pytest.raises(CGVQMError, match="whole number"):
        CGVQM(weights=uniform_weights("cgvqm-2"), backbone=backbone, patch_scale=2.7)
    with pytest.raises(CGVQMError, match="cgvqm-5 asked for, but the weights are cgvqm-2's"):
        CGVQM("cgvqm-5", weights=uniform_weights("cgvqm-2"), backbone=backbone)
    assert CGVQM(weights=uniform_weights("cgvqm-5"), backbone=backbone).variant == "cgvqm-5"


def test_one_test_video_is_one_video_and_a_nan_q_has_no_label(backbone):
    from cgvqm_core import patch_channel_msd, quality_label

    ref = (RNG.random((8, 64, 64, 3)) * 255).astype(np.uint8)
    test = np.clip(ref.astype(int) + RNG.integers(-20, 21, ref.shape), 0, 255).astype(np.uint8)
    metric = CGVQM(weights=uniform_weights("cgvqm-2"), backbone=backbone)
    [as_list] = metric.score_many(ref, [test])
    [alone] = metric.score_many(ref, test)  # one array: one video, not 8 frame "videos"
    assert alone.q == as_list.q
    with pytest.raises(CGVQMError, match="not a CGVQM; with a CGVQM object call its channel_msd"):
        patch_channel_msd(ref, test, metric)
    [msd] = metric.channel_msd(ref, test)
    assert msd.msd.shape[1] == 131
    with pytest.raises(CGVQMError, match="finite"):
        quality_label(float("nan"))
    assert quality_label(100.0) == metric.score(ref, ref).label
