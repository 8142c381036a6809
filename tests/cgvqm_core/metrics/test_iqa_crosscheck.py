"""The image metrics against PIQ itself and, where they overlap, scikit-image,
pytorch-msssim, torchmetrics and sewar, on real photographs with real distortions."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cgvqm_core.metrics import iqa

from .conftest import as_batch, blurred, noisy, real_video
from .piq_loader import load_piq

# (our function, PIQ function name, relative tolerance achieved with margin: float32 sums in
# another order; DSS and HaarPSI sort/threshold float32 maps, about 2e-6)
PAIRS = [
    ("psnr", "psnr", 1e-6), ("ssim", "ssim", 1e-6), ("ms_ssim", "multi_scale_ssim", 1e-6),
    ("iw_ssim", "information_weighted_ssim", 1e-5), ("vif_p", "vif_p", 1e-5),
    ("fsim", "fsim", 1e-5), ("srsim", "srsim", 1e-5), ("gmsd", "gmsd", 1e-5),
    ("ms_gmsd", "multi_scale_gmsd", 1e-5), ("vsi", "vsi", 1e-5), ("dss", "dss", 1e-5),
    ("haarpsi", "haarpsi", 1e-5), ("mdsi", "mdsi", 1e-5),
]


def _frames(h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    ref = real_video(3, h, w)
    test = np.concatenate([noisy(ref[:1], 12), blurred(ref[1:2], 1.5), ref[2:3] // 2 + 60])
    return as_batch(test), as_batch(ref)


@pytest.mark.parametrize("size", [(176, 208), (517, 389)], ids=["176x208", "517x389"])
@pytest.mark.parametrize(("ours", "theirs", "rtol"), PAIRS, ids=[p[0] for p in PAIRS])
def test_matches_piq(ours, theirs, rtol, size):
    piq = load_piq()
    t, r = _frames(*size)
    mine = getattr(iqa, ours)(t, r).double()
    # PIQ one frame at a time: the paper's per-frame protocol (PIQ's SR-SIM normalises its
    # saliency over a whole batch)
    ref = torch.cat([getattr(piq, theirs)(t[i:i + 1], r[i:i + 1], reduction="none")
                     for i in range(len(t))]).double()
    assert mine.shape == (3,)
    np.testing.assert_allclose(mine.numpy(), ref.numpy(), rtol=rtol, atol=1e-7)


def test_batch_equals_frame_by_frame():
    t, r = _frames(176, 176)
    for name, _, _ in PAIRS:
        f = getattr(iqa, name)
        whole = f(t, r)
        one = torch.cat([f(t[i:i + 1], r[i:i + 1]) for i in range(len(t))])
        # batched float32 linear algebra (IW-SSIM) rounds differently: 1e-5
        np.testing.assert_allclose(whole.numpy(), one.numpy(), rtol=1e-5, err_msg=name)


def test_identical_images_give_the_perfect_score():
    _, r = _frames(176, 176)
    best = {"psnr": 80.0, "gmsd": 0.0, "ms_gmsd": 0.0, "mdsi": 0.0}
    for name, _, _ in PAIRS:
        v = getattr(iqa, name)(r, r)
        np.testing.assert_allclose(v.numpy(), best.get(name, 1.0), atol=2e-5, err_msg=name)


@pytest.mark.parametrize("name", ["ms_ssim", "iw_ssim"])
def test_multiscale_refuses_small_images(name):
    t, r = _frames(160, 300)
    with pytest.raises(ValueError, match="161x161"):
        getattr(iqa, name)(t, r)


def test_psnr_equals_numpy():
    ref = real_video(4, 64, 80)
    test = noisy(ref, 9)
    mse = ((test.astype(np.float64) - ref) / 255.0) ** 2
    expected = -10 * np.log10(mse.mean(axis=(1, 2, 3)) + 1e-8)
    def f64(v: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(v).permute(0, 3, 1, 2).double() / 255.0

    got = iqa.psnr(f64(test), f64(ref)).numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    tm = pytest.importorskip("torchmetrics.functional.image")
    one = tm.peak_signal_noise_ratio(as_batch(test[:1]), as_batch(ref[:1]), data_range=1.0)
    assert float(one) == pytest.approx(expected[0], abs=1e-4)


def test_ssim_against_scikit_image():
    """With matching settings (Gaussian window sigma 1.5, population covariance, no
    down-sampling) scikit-image's SSIM equals ours up to float32 rounding: scikit-image
    filters the whole frame with reflection and drops a 5-pixel border, which is exactly the
    valid region our unpadded 11x11 window sees. What differs by default: scikit-image uses
    a 7x7 uniform window with sample covariance, and does not down-sample large frames
    (PIQ and we average-pool by round(min(H, W)/256), the authors' recommendation)."""
    metrics = pytest.importorskip("skimage.metrics")
    ref = real_video(1, 200, 240)
    test = noisy(ref, 10)
    ours = float(iqa.ssim(as_batch(test), as_batch(ref), downsample=False))
    sk = metrics.structural_similarity(ref[0].astype(np.float32) / 255,
                                       test[0].astype(np.float32) / 255, data_range=1.0,
                                       gaussian_weights=True, sigma=1.5,
                                       use_sample_covariance=False, channel_axis=-1)
    assert ours == pytest.approx(sk, abs=5e-5)
    default = metrics.structural_similarity(ref[0], test[0], channel_axis=-1)
    assert abs(default - ours) > 1e-3  # the default settings are a different SSIM


def test_ms_ssim_against_pytorch_msssim():
    pm = pytest.importorskip("pytorch_msssim")
    ref = real_video(2, 256, 256)
    test = blurred(ref, 1.2)
    a = iqa.ms_ssim(as_batch(test), as_batch(ref))
    b = pm.ms_ssim(as_batch(test), as_batch(ref), data_range=1.0, size_average=False)
    np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=2e-5)


def test_vif_against_sewar():
    sewar = pytest.importorskip("sewar.full_ref")
    ref = real_video(1, 160, 200)
    test = noisy(ref, 12)
    w = np.array([0.299, 0.587, 0.114])
    # sewar on the same float32-rounded luma
    luma = [(as_batch(v)[0].permute(1, 2, 0).double().numpy() @ w) * 255 for v in (ref, test)]
    expected = sewar.vifp(luma[0], luma[1], sigma_nsq=2)
    assert float(iqa.vif_p(as_batch(test), as_batch(ref))) == pytest.approx(expected, rel=5e-5)
