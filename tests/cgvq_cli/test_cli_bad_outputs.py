"""Outputs that would destroy a command's own inputs are refused in one line (exit 2), devices
PyTorch cannot use give one line, a mis-saved invites CSV gives one line, and an interrupted
report or simulation leaves nothing that passes for finished."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from support.studies import make_study

from analysis.cli import main as analyze
from cgvq_cli.study_cli import main as study
from cgvqm_core.cli import main as cgvqm
from stimuli_manifests import write_video


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line(capsys, code: int, says: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and says in err[0], err


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """A tiny study with 4 simulated raters' session files."""
    root = tmp_path_factory.mktemp("cli")
    folder = make_study(root / "study", size=32, seconds=0.5, fps=8)
    assert study(["simulate", "--manifest", str(folder / "manifest.json"), "--raters", "4",
                  "--seed", "1", "--out", str(folder / "sessions"), "--no-progress"]) == 0
    return folder


def test_dmos_out_never_replaces_an_input(simulated, tmp_path, capsys):
    manifest, sessions = simulated / "manifest.json", simulated / "sessions"
    victim = sessions / "sim03.sqlite"
    for out in (victim, manifest):
        before = _sha(out)
        code = analyze(["dmos", "--manifest", str(manifest), "--sessions", str(sessions),
                        "--model", "mos", "--out", str(out)])
        _one_line(capsys, code, "is not a DMOS CSV")
        assert _sha(out) == before
    # a DMOS CSV written before is replaced, as it always was
    out = tmp_path / "dmos.csv"
    for _ in range(2):
        assert analyze(["dmos", "--manifest", str(manifest), "--sessions", str(sessions),
                        "--model", "mos", "--out", str(out)]) == 0


def test_error_maps_are_never_written_over_the_videos_scored(tmp_path, capsys):
    frames = np.random.default_rng(0).integers(0, 255, (8, 32, 32, 3), dtype=np.uint8)
    ref, test = tmp_path / "ref.mkv", tmp_path / "test.mkv"
    write_video(ref, frames, 8)
    write_video(test, np.clip(frames.astype(int) + 9, 0, 255).astype(np.uint8), 8)
    png = tmp_path / "ref_png"
    png.mkdir()
    from PIL import Image

    for i, f in enumerate(frames):
        Image.fromarray(f).save(png / f"{i:06d}.png")
    before = {p: _sha(p) for p in (ref, test, png / "000000.png")}
    base = ["score", "--ref", str(ref), "--test", str(test), "--random-backbone", "0"]
    for extra, says in ((["--emap", str(ref)], "is an input of this run"),
                        (["--emap", str(test)], "is an input of this run")):
        _one_line(capsys, cgvqm([*base, *extra]), says)
    code = cgvqm(["score", "--ref", str(png), "--test", str(test), "--random-backbone", "0",
                  "--fps", "8", "--emap-png", str(png)])
    _one_line(capsys, code, "is the frame folder of an input")
    assert {p: _sha(p) for p in before} == before


@pytest.mark.parametrize("device", ["mps", "xpu", "meta"])
def test_cgvqm_refuses_a_device_pytorch_cannot_use_in_one_line(tmp_path, capsys, device):
    frames = np.zeros((8, 32, 32, 3), dtype=np.uint8)
    ref = tmp_path / "ref.mkv"
    write_video(ref, frames, 8)
    code = cgvqm(["score", "--ref", str(ref), "--test", str(ref), "--random-backbone", "0",
                  "--device", device])
    _one_line(capsys, code, "is not supported; use cpu or cuda")


def test_calibrate_out_never_replaces_a_dataset_manifest(simulated, tmp_path, capsys):
    manifest = simulated / "manifest.json"
    dmos = tmp_path / "dmos.csv"
    assert analyze(["dmos", "--manifest", str(manifest), "--sessions",
                    str(simulated / "sessions"), "--model", "mos", "--out", str(dmos)]) == 0
    capsys.readouterr()
    before = _sha(manifest)
    code = cgvqm(["calibrate", "--dataset", f"s={manifest}:{dmos}", "--random-backbone", "0",
                  "--cache", str(tmp_path / "cache"), "--steps", "5", "--no-validation",
                  "--quiet", "--out", str(manifest)])
    _one_line(capsys, code, "is not a CGVQM weights file")
    assert _sha(manifest) == before


def test_an_invites_csv_saved_as_utf16_gives_one_line(simulated, tmp_path, capsys):
    invites = tmp_path / "invites.csv"
    invites.write_text("participant,token,server\nP01,abc,http://127.0.0.1:9\n",
                       encoding="utf-16")
    code = study(["simulate", "--manifest", str(simulated / "manifest.json"), "--raters", "1",
                  "--out", str(tmp_path / "s"), "--server", "http://127.0.0.1:9",
                  "--invites", str(invites), "--no-progress"])
    _one_line(capsys, code, "is not a UTF-8 invites CSV")


def test_an_interrupted_report_leaves_no_finished_looking_folder(simulated, tmp_path,
                                                                monkeypatch):
    from analysis import report

    out = tmp_path / "report"
    args = ["report", "--manifest", str(simulated / "manifest.json"), "--sessions",
            str(simulated / "sessions"), "--model", "mos", "--out", str(out),
            "--bootstrap", "20", "--splits", "5"]
    assert analyze(args) == 0 and (out / "report.html").exists()

    def stop(*_a, **_k):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "write_tables", stop)
    assert analyze(args) == 130
    assert (out / "dmos.csv").exists()  # the rerun got this far ...
    assert not (out / "report.html").exists() and not (out / "summary.json").exists()


def test_an_interrupted_simulation_leaves_no_sessions(simulated, tmp_path, monkeypatch):
    from study_app import simulate

    real = simulate._simulate_rater
    calls = []

    def rater(panel, opts, k, *args):
        calls.append(k)
        if k == 2:
            raise KeyboardInterrupt
        return real(panel, opts, k, *args)

    monkeypatch.setattr(simulate, "_simulate_rater", rater)
    out = tmp_path / "sim"
    assert study(["simulate", "--manifest", str(simulated / "manifest.json"), "--raters",
                  "4", "--out", str(out), "--no-progress"]) == 130
    assert calls == [0, 1, 2]
    assert not list(out.glob("*.sqlite*")) and not (out / "ground_truth.json").exists()
