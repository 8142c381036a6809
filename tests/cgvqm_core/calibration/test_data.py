"""Reading a study (manifest + DMOS CSV) for calibration; direction of the scores."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from cgvqm_core.calibration import DatasetSpec, load_dataset
from cgvqm_core.errors import CGVQMError


def write_study(tmp_path, dmos_rows=None):
    """A manifest of 2 scenes x 2 conditions (videos need not exist to be listed)."""
    man = {
        "format": "cgvq-manifest/1", "study_id": "t", "root": "videos",
        "references": [{"id": "SRC01", "path": "a.mkv", "scene": "Bistro"},
                       {"id": "SRC02", "path": "b.mkv", "scene": "Sponza"}],
        "conditions": [
            {"id": f"{r}_HRC0{k}", "reference": r, "path": f"{r}_{k}.mkv",
             "method": "blur", "level": k} for r in ("SRC01", "SRC02") for k in (1, 2)],
    }
    mpath = tmp_path / "manifest.json"
    mpath.write_text(json.dumps(man))
    if dmos_rows is None:
        dmos_rows = [(f"{r}_HRC0{k}", r, 40.0 + 20 * k + (r == "SRC02")) for r in
                     ("SRC01", "SRC02") for k in (1, 2)] + [("SRC01", "SRC01", 100.0)]
    df = pd.DataFrame(dmos_rows, columns=["stimulus", "reference", "dmos"])
    df["method"], df["level"], df["model"] = "x", 1, "mle"
    dpath = tmp_path / "dmos.csv"
    df.to_csv(dpath, index=False)
    return DatasetSpec("t", mpath, dpath)


def test_rows_join_the_manifest_and_carry_scenes(tmp_path):
    spec = write_study(tmp_path)
    df = load_dataset(spec)
    assert len(df) == 4  # the hidden reference is left out
    assert dict(zip(df.stimulus, df.scene, strict=True))["SRC02_HRC01"] == "Sponza"
    assert df.set_index("stimulus").loc["SRC01_HRC02", "test_path"].endswith("videos/SRC01_2.mkv")
    assert df.set_index("stimulus").loc["SRC01_HRC02", "ref_path"].endswith("videos/a.mkv")
    assert (df.target == df.dmos.clip(0, 100)).all()
    assert len(load_dataset(spec, include_references=True)) == 5


def test_including_references_needs_a_dmos_csv_that_rates_them(tmp_path):
    rows = [(f"{r}_HRC0{k}", r, 50.0 + k) for r in ("SRC01", "SRC02") for k in (1, 2)]
    spec = write_study(tmp_path, rows)
    assert len(load_dataset(spec)) == 4
    with pytest.raises(CGVQMError, match="rates no hidden references"):
        load_dataset(spec, include_references=True)


def test_impairment_scale_is_turned_around_and_clipped(tmp_path):
    rows = [("SRC01_HRC01", "SRC01", 120.0), ("SRC01_HRC02", "SRC01", 30.0),
            ("SRC02_HRC01", "SRC02", -5.0), ("SRC02_HRC02", "SRC02", 50.0)]
    spec = write_study(tmp_path, rows)
    q = load_dataset(spec).set_index("stimulus").target
    imp = load_dataset(spec, dmos_scale="impairment").set_index("stimulus").target
    assert q.to_dict() == {"SRC01_HRC01": 100.0, "SRC01_HRC02": 30.0, "SRC02_HRC01": 0.0,
                           "SRC02_HRC02": 50.0}
    assert imp.to_dict() == {"SRC01_HRC01": 0.0, "SRC01_HRC02": 70.0, "SRC02_HRC01": 100.0,
                             "SRC02_HRC02": 50.0}


def test_unknown_stimuli_and_missing_values(tmp_path, caplog):
    spec = write_study(tmp_path, [("SRC01_HRC01", "SRC01", 50.0), ("NOPE", "SRC01", 50.0)])
    with pytest.raises(CGVQMError, match="NOPE"):
        load_dataset(spec)
    spec = write_study(tmp_path, [("SRC01_HRC01", "SRC01", 50.0), ("SRC01_HRC02", "SRC01", None),
                                  ("SRC02_HRC01", "SRC02", 60.0), ("SRC02_HRC02", "SRC02", 70.0)])
    assert len(load_dataset(spec)) == 3
    assert "without a DMOS" in caplog.text


def test_non_numeric_and_constant_dmos_are_refused(tmp_path):
    spec = write_study(tmp_path, [("SRC01_HRC01", "SRC01", "abc"), ("SRC01_HRC02", "SRC01", 40),
                                  ("SRC02_HRC01", "SRC02", 60), ("SRC02_HRC02", "SRC02", 70)])
    with pytest.raises(CGVQMError, match=r"1 DMOS value\(s\) are not numbers \(SRC01_HRC01: "
                                         r"'abc'\)"):
        load_dataset(spec)
    # no correlation with constant scores (after clipping to 0..100, as the fit sees them)
    for high in (50.0, 130.0):
        rows = [(f"{r}_HRC0{k}", r, high) for r in ("SRC01", "SRC02") for k in (1, 2)]
        spec = write_study(tmp_path, rows)
        with pytest.raises(CGVQMError, match=f"every usable DMOS .* is {min(high, 100):g}"):
            load_dataset(spec)


def test_dataset_argument_parsing(tmp_path):
    s = DatasetSpec.parse("mine=study/manifest.json:out/dmos.csv")
    assert (s.name, str(s.manifest), str(s.dmos_csv)) == ("mine", "study/manifest.json",
                                                          "out/dmos.csv")
    w = DatasetSpec.parse(r"w=C:\data\m.json:D:\out\dmos.csv")
    assert (str(w.manifest), str(w.dmos_csv)) == (r"C:\data\m.json", r"D:\out\dmos.csv")
    for bad in ("nodelimiter", "x=only.json", "=a:b", "bad name=a:b"):
        with pytest.raises(CGVQMError, match="NAME=MANIFEST:DMOS_CSV"):
            DatasetSpec.parse(bad)
