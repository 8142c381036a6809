"""Published cross-check values on the real SUREAL datasets (spec), and safe parsing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.errors import AnalysisError
from analysis.exports import rating_matrix
from analysis.scores import fit_scores
from analysis.screening import screen_raters
from analysis.sureal_io import load_sureal, parse_sureal_py, write_sureal_json


def test_nflx_mos_and_dmos(sureal_dir: Path) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw.py")
    assert (rs.n_stimuli, rs.n_raters) == (79, 26)
    assert rs.hidden_reference_mask.sum() == 9
    assert rs.ref_score == 5.0
    res = fit_scores(rs, "mos")
    assert res.quality[0] == pytest.approx(4.884615384615385, abs=1e-12)
    assert res.quality[10] == pytest.approx(2.0769230769230771, abs=1e-12)
    assert res.quality.mean() == pytest.approx(3.544790652385589, abs=1e-12)
    assert res.dmos[10] == pytest.approx(2.1923076923076921, abs=1e-12)
    assert res.dmos.mean() == pytest.approx(3.7731256085686473, abs=1e-12)


def test_nflx_p910_mle(sureal_dir: Path) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw.py")
    res = fit_scores(rs, "p910")
    assert res.quality[0] == pytest.approx(4.918072566018977, abs=1e-9)
    assert res.quality[-2] == pytest.approx(4.258802804871559, abs=1e-9)
    assert res.rater_inconsistency[0] == pytest.approx(0.5823933134761798, abs=1e-9)


def test_nflx_outliers_bt500(sureal_dir: Path) -> None:
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw_last4outliers.py")
    assert rs.n_raters == 30
    res = fit_scores(rs, "bt500")
    assert res.rejected == ["26", "28", "29"]
    assert res.quality[0] == pytest.approx(1.3333333333333333, abs=1e-12)
    assert res.quality[-2] == pytest.approx(4.555555555555555, abs=1e-12)
    screen = screen_raters(rs, "bt500")
    assert screen.removed_names == ["26", "28", "29"]
    assert all(r.statistic > 0.05 for r in screen.removed)


def test_repetitions_as_lists(sureal_dir: Path) -> None:
    rs = load_sureal(sureal_dir / "test_dataset_os_as_list_with_repetitions.py")
    # os of the second dis_video: [[2, 2], 1, [3, 3, 1]] -> rater 2 voted three times.
    assert rs.scores.shape == (3, 3, 3)
    np.testing.assert_array_equal(rs.scores[1, 2], [3, 3, 1])
    np.testing.assert_array_equal(rs.scores[1, 1, :1], [1])
    assert np.isnan(rs.scores[1, 1, 1:]).all()
    res = fit_scores(rs, "mos")
    assert res.quality[0] == pytest.approx(np.mean([3, 2, 4, 1]))
    assert res.quality[1] == pytest.approx(np.mean([2, 2, 1, 3, 3, 1]))


def test_p910_matrix_matches_the_p910_demo_csv(sureal_dir: Path) -> None:
    """The P.910 demo CSV is the NFLX matrix with raters 0..4 corrupted and one NaN: our
    rating matrix of the NFLX dataset must equal it in the untouched columns."""
    rs = load_sureal(sureal_dir / "NFLX_dataset_public_raw.py")
    ours = rating_matrix(rs).to_numpy()
    demo = pd.read_csv(sureal_dir / "p910_demo_sample_data.csv", header=None).to_numpy()
    assert demo.shape == ours.shape
    same = np.isfinite(demo[:, 5:])
    assert same.sum() >= demo[:, 5:].size - 1
    np.testing.assert_array_equal(ours[:, 5:][same], demo[:, 5:][same])


def test_json_export_reads_back_in_sureal(sureal_dir: Path, tmp_path: Path) -> None:
    """Our SUREAL JSON is read by SUREAL itself and gives the same MOS."""
    from sureal.dataset_reader import RawDatasetReader
    from sureal.subjective_model import MosModel
    from sureal.tools.misc import import_json_file

    rs = load_sureal(sureal_dir / "test_dataset_os_as_list_with_repetitions.py")
    path = write_sureal_json(rs, tmp_path / "ds.json")
    data = json.loads(path.read_text())
    assert isinstance(next(iter(data["dis_videos"][1]["os"].values())), list)
    mos = MosModel(RawDatasetReader(import_json_file(str(path)))).run_modeling()
    expected = np.nanmean(rs.scores.reshape(3, -1), axis=1)
    np.testing.assert_allclose(mos["quality_scores"], expected)
    back = load_sureal(path)
    np.testing.assert_allclose(np.sort(back.scores[np.isfinite(back.scores)]),
                               np.sort(rs.scores[np.isfinite(rs.scores)]))


def test_sureal_py_is_parsed_not_executed(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.py"
    evil.write_text(f"import os\nos.system('touch {marker}')\nref_videos = []\n")
    with pytest.raises(AnalysisError, match="plain assignments"):
        load_sureal(evil)
    assert not marker.exists()
    with pytest.raises(AnalysisError, match="not plain data"):
        parse_sureal_py("x = open('/etc/passwd').read()\n")
    env = parse_sureal_py("d = 'a'\nx = [d + '/b', float('nan'), -1.5]\n")
    assert env["x"][0] == "a/b" and np.isnan(env["x"][1]) and env["x"][2] == -1.5


def test_bad_sureal_files(tmp_path: Path) -> None:
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(AnalysisError, match=r"\.py or \.json"):
        load_sureal(tmp_path / "x.txt")
    (tmp_path / "e.py").write_text("ref_videos = []\ndis_videos = []\n")
    with pytest.raises(AnalysisError, match="non-empty list"):
        load_sureal(tmp_path / "e.py")
    with pytest.raises(AnalysisError, match="does not exist"):
        load_sureal(tmp_path / "missing.py")
