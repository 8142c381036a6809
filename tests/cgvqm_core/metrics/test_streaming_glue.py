"""Each peer's streamed, pooled score equals its library called directly on whole decoded
videos: the streaming, alignment, conversion and pooling glue is right."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cgvqm_core.metrics import MetricOptions, build_scorers, score_reference
from cgvqm_core.metrics.cvvdp_entry import load_cvvdp
from cgvqm_core.metrics.flip_entry import flip_frame
from stimuli_manifests import read_video, write_video

from .conftest import as_batch, blurred, noisy, real_video
from .piq_loader import load_piq

FPS = 8
PIQ_NAMES = {"psnr": "psnr", "ssim": "ssim", "ms-ssim": "multi_scale_ssim",
             "iw-ssim": "information_weighted_ssim", "vif": "vif_p", "fsim": "fsim",
             "sr-sim": "srsim", "gmsd": "gmsd", "ms-gmsd": "multi_scale_gmsd", "vsi": "vsi",
             "dss": "dss", "haarpsi": "haarpsi", "mdsi": "mdsi"}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("glue")
    ref = real_video(6, 168, 184)
    tests = [noisy(ref, 10), blurred(ref, 1.5)]
    r = write_video(d / "ref.mkv", ref, FPS)
    ts = [write_video(d / f"t{i}.mkv", t, FPS) for i, t in enumerate(tests)]
    return r, ts


# about 10 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_piq_family_streamed_equals_piq_on_whole_videos(files):
    piq = load_piq()
    ref_path, test_paths = files
    scorers = build_scorers(list(PIQ_NAMES), MetricOptions())
    results = score_reference(ref_path, test_paths, scorers)
    ref = as_batch(read_video(ref_path))
    for path, per_test in zip(test_paths, results, strict=True):
        test = as_batch(read_video(path))
        for m in per_test:
            fn = getattr(piq, PIQ_NAMES[m.metric])
            if m.metric == "sr-sim":  # PIQ normalises SR-SIM's saliency over its batch
                frames = torch.cat([fn(test[i:i + 1], ref[i:i + 1], reduction="none")
                                    for i in range(len(test))])
            else:
                frames = fn(test, ref, reduction="none")
            assert m.score == pytest.approx(float(frames.double().mean()), rel=2e-5), m.metric
            assert len(m.per_frame) == len(test)


def test_flip_streamed_equals_flip_evaluator(files):
    pytest.importorskip("flip_evaluator")
    ref_path, test_paths = files
    opts = MetricOptions()
    (scorer,) = build_scorers(["flip"], opts)
    results = score_reference(ref_path, test_paths, [scorer])
    ref = read_video(ref_path).astype(np.float32) / 255
    ppd = opts.viewing.pixels_per_degree
    for path, (m,) in zip(test_paths, results, strict=True):
        test = read_video(path).astype(np.float32) / 255
        direct = np.mean([flip_frame(ref[i], test[i], ppd) for i in range(len(ref))])
        assert m.score == pytest.approx(direct, rel=1e-9)
    assert results[0][0].score < results[1][0].score or results[0][0].score > 0


def test_cvvdp_streamed_equals_cvvdp_predict(files):
    try:
        cls, _, _ = load_cvvdp()
    except Exception as exc:  # not installed
        pytest.skip(str(exc))
    ref_path, test_paths = files
    (scorer,) = build_scorers(["cvvdp"], MetricOptions())
    results = score_reference(ref_path, test_paths, [scorer])
    metric = cls(display_name="standard_4k", device=torch.device("cpu"), quiet=True)
    ref = read_video(ref_path)
    for path, (m,) in zip(test_paths, results, strict=True):
        jod, _ = metric.predict(read_video(path), ref, dim_order="FHWC", frames_per_second=FPS)
        assert m.score == pytest.approx(float(jod), abs=1e-5)
    assert 0 < results[0][0].score < 10


# about 9 s: CI runs it after `make test` (.ci/run), as `make test-slow` does
@pytest.mark.slow
def test_cgvqm_entry_equals_cgvqm(files):
    from cgvqm_core import CGVQM

    ref_path, test_paths = files
    opts = MetricOptions(random_backbone=3, weights="uniform", pools=("max", "mean"))
    (scorer,) = build_scorers(["cgvqm-2"], opts)
    results = score_reference(ref_path, test_paths, [scorer])
    direct = CGVQM("cgvqm-2", random_backbone=3, weights="uniform").score_many(
        ref_path, test_paths)
    for res, (mx, mn) in zip(direct, results, strict=True):
        assert mx.metric == "cgvqm-2-uniform" and mx.pooling == "max"
        assert mx.score == pytest.approx(res.quality("max"), abs=1e-9)
        assert mn.score == pytest.approx(res.quality("mean"), abs=1e-9)
        assert mx.extra["backbone"] == "random-seed-3"


def test_test_video_of_another_size_is_aligned_like_cgvqm(tmp_path):
    """A test video of another size and length is resized and resampled to the reference
    exactly as for CGVQM; the image metrics see the aligned frames."""
    from cgvqm_core.stream import resize_frame, time_index

    ref = real_video(6, 64, 80)
    small = np.stack([resize_frame(f, 48, 60) for f in noisy(ref, 8)])[:4]
    r = write_video(tmp_path / "r.mkv", ref, FPS)
    t = write_video(tmp_path / "t.mkv", small, FPS)
    (scorer,) = build_scorers(["psnr"], MetricOptions())
    ((m,),) = score_reference(r, [t], [scorer])
    aligned = np.stack([resize_frame(small[j], 64, 80) for j in time_index(4, 6)])
    from cgvqm_core.metrics import iqa

    expected = iqa.psnr(as_batch(aligned), as_batch(ref)).double().mean()
    assert m.score == pytest.approx(float(expected), rel=1e-9)


def test_results_come_in_the_order_the_metrics_were_asked_for(tmp_path):
    """At 48x48 MS-SSIM does not apply; its note used to come first, so a caller matching
    results by position gave PSNR's number MS-SSIM's name (and resume key)."""
    from cgvqm_core.metrics import iqa

    ref = real_video(4, 48, 48)
    test = noisy(ref, 8)
    r = write_video(tmp_path / "r.mkv", ref, FPS)
    t = write_video(tmp_path / "t.mkv", test, FPS)
    scorers = build_scorers(["psnr", "ms-ssim"], MetricOptions())
    ((first, second),) = score_reference(r, [t], scorers)
    assert (first.metric, second.metric) == ("psnr", "ms-ssim")
    assert second.score is None and second.note
    expected = iqa.psnr(as_batch(test), as_batch(ref)).double().mean()
    assert first.score == pytest.approx(float(expected), rel=1e-9)
