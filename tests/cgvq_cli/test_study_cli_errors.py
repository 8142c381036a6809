"""Inputs that used to end in a traceback or be accepted: one line on stderr, exit 2."""

from __future__ import annotations

import pytest

from cgvq_cli.study_cli import main


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_simulate_out_pointing_at_a_file(tiny_study, tmp_path, capsys):
    target = tmp_path / "afile"
    target.write_text("")
    code = main(["simulate", "--manifest", str(tiny_study / "manifest.json"), "--raters", "2",
                 "--out", str(target), "--no-progress"])
    assert code == 2
    assert "is a file" in _one_line_error(capsys)


@pytest.mark.parametrize("seconds", ["nan", "inf", "-1"])
def test_synth_non_finite_or_negative_seconds(tmp_path, capsys, seconds):
    code = main(["synth", "--out", str(tmp_path / "s"), "--seconds", seconds, "--no-progress"])
    assert code == 2
    assert "--seconds" in _one_line_error(capsys)
    assert not (tmp_path / "s").exists()
