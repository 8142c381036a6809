"""``cgvq-study run`` refuses bad input in one line on stderr (exit 2) before it creates
anything: no sessions folder, no session file, no lock, no window."""

from __future__ import annotations

import pytest

from cgvq_cli.study_cli import main


def _refused(capsys, study, *args: str) -> str:
    code = main(["run", str(study), *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert not (study / "sessions").exists()
    return err


@pytest.mark.parametrize("participant, words", [
    ("P" * 300, "300 characters"),
    ("../x", "not valid"),
    ("a b", "not valid"),
    (".hidden", "not valid"),
    ("", "not valid"),
])
def test_invalid_participant_ids(tiny_study, capsys, participant, words):
    err = _refused(capsys, tiny_study, "--participant", participant, "--pilot-no-vsync")
    assert words in err


def test_sessions_dir_that_is_a_file(tiny_study, tmp_path, capsys):
    target = tmp_path / "afile"
    target.write_text("not a folder")
    err = _refused(capsys, tiny_study, "--participant", "P01", "--sessions-dir", str(target))
    assert "is a file" in err
    assert target.read_text() == "not a folder"


@pytest.mark.parametrize("size, words", [
    ("0x0", "too small"),
    ("100x100", "too small"),
    ("799x600", "too small"),
    ("800x", "WIDTHxHEIGHT"),
    ("abc", "WIDTHxHEIGHT"),
    ("-800x600", "WIDTHxHEIGHT"),
    ("99999x99999", "larger than any screen"),
])
def test_invalid_window_sizes(tiny_study, capsys, size, words):
    err = _refused(capsys, tiny_study, "--participant", "P01", "--windowed",
                   f"--window-size={size}")
    assert words in err


@pytest.mark.parametrize("args, words", [
    (["--refresh-hz", "60"], "--pilot-no-vsync"),
    (["--data-dir", "downloads"], "a local study folder keeps its sessions in --sessions-dir"),
    (["--pilot-no-vsync", "--refresh-hz", "nan"], "between 20 and 500"),
    (["--pilot-no-vsync", "--refresh-hz", "0"], "between 20 and 500"),
    (["--practice", "-1"], "--practice"),
    (["--break-every", "-2"], "--break-every"),
    (["--max-dropped-frames", "-5"], "--max-dropped-frames"),
])
def test_invalid_options(tiny_study, capsys, args, words):
    err = _refused(capsys, tiny_study, "--participant", "P01", *args)
    assert words in err


@pytest.mark.parametrize("seed", ["-1", str(2**63)])
def test_seed_out_of_range(tiny_study, capsys, seed):
    err = _refused(capsys, tiny_study, "--participant", "P01", "--pilot-no-vsync",
                   "--seed", seed)
    assert "--seed must be a whole number from 0" in err
