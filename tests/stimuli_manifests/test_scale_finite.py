"""A rating scale with an infinite bound is refused (it would turn every DMOS into inf)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from stimuli_manifests import ManifestError, load_manifest, parse_manifest


def _doc(scale: dict) -> dict:
    return {
        "format": "cgvq-manifest/1", "study_id": "s1", "scale": scale,
        "references": [{"path": "a.mkv"}],
        "conditions": [{"reference": "SRC01", "path": "b.mkv", "method": "blur", "level": 1}],
    }


@pytest.mark.parametrize("scale", [
    {"min": 0, "max": math.inf, "labels": []},
    {"min": -math.inf, "max": 100, "labels": []},
    {"min": 0, "max": math.nan, "labels": []},
    {"min": 0, "max": 100, "labels": [{"position": math.inf, "text": "x"}]},
])
def test_non_finite_scale_values_are_refused(scale: dict) -> None:
    with pytest.raises(ManifestError, match="finite"):
        parse_manifest(_doc(scale))


def test_json_1e400_reads_as_inf_and_is_refused(tmp_path: Path) -> None:
    # Python's json turns 1e400 into inf; the manifest loader must not accept it.
    text = json.dumps(_doc({"min": 0, "max": 100, "labels": []})).replace('"max": 100',
                                                                          '"max": 1e400')
    path = tmp_path / "manifest.json"
    path.write_text(text)
    assert json.loads(text)["scale"]["max"] == math.inf
    with pytest.raises(ManifestError, match="finite"):
        load_manifest(path)


def test_study_check_says_error_not_ok(tmp_path: Path, capsys) -> None:
    pytest.importorskip("cgvq_cli.study_cli")
    from cgvq_cli.study_cli import main

    (tmp_path / "manifest.json").write_text(
        json.dumps(_doc({"min": 0, "max": 100, "labels": []})).replace('"max": 100',
                                                                       '"max": 1e400'))
    assert main(["check", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    assert "OK" not in captured.out
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "finite" in err[0]
