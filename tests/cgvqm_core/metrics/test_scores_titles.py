"""The scores file's ``title`` (cgvq-scores/1.1): what ``batch`` and ``score --csv`` write, and
a run resumed on a file of the layout before it (1.0), which keeps that file's layout."""

from __future__ import annotations

import csv
from pathlib import Path

from cgvqm_core.batch import SCORE_COLUMNS
from cgvqm_core.cli import main
from stimuli_manifests import write_video
from stimuli_manifests.tables import SCORES, SCORES_1_0, read_table

from .conftest import noisy, real_video
from .test_cli_batch import FPS, _study


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def test_batch_writes_each_metrics_title(capsys, tmp_path):
    manifest = _study(tmp_path)
    out = tmp_path / "scores.csv"
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metrics",
                      "psnr,flip,cgvqm-2", "--random-backbone", "0", "--weights", "uniform")
    assert rc == 0, err
    header, rows = _rows(out)
    assert tuple(header) == SCORE_COLUMNS and "title" in header
    titles = {r["metric"]: r["title"] for r in rows}
    # the registry's titles; a CGVQM with other weights keeps its suffix, so the uniform
    # variant never passes for the published CGVQM-2 in prose
    assert titles == {"psnr": "PSNR", "flip": "FLIP (LDR)", "cgvqm-2-uniform": "CGVQM-2-uniform"}
    assert {r["format"] for r in rows} == {"cgvq-scores/1.1"}


def test_score_csv_writes_the_title(capsys, tmp_path):
    ref = real_video(4, 40, 48)
    r = write_video(tmp_path / "r.mkv", ref, FPS)
    t = write_video(tmp_path / "t.mkv", noisy(ref, 10), FPS)
    out = tmp_path / "one.csv"
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "gmsd", "--csv", out)
    assert rc == 0, err
    (row,) = read_table(out, SCORES)
    assert row["metric"] == "gmsd" and row["title"] == "GMSD"


def test_a_run_resumed_on_a_file_without_titles_keeps_its_layout(capsys, tmp_path):
    """A scores file written before the title column (1.0): the resumed run neither refuses it
    nor rescores what it holds (the title is not part of a row's key), and appends its new
    rows in the file's own columns and version, so the file stays one readable table."""
    manifest = _study(tmp_path)
    out = tmp_path / "scores.csv"
    assert _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metrics", "psnr")[0] == 0
    header, rows = _rows(out)
    old_header = [c for c in header if c != "title"]
    with out.open("w", newline="", encoding="utf-8") as fh:  # as the toolkit wrote it before
        w = csv.DictWriter(fh, old_header, extrasaction="ignore")
        w.writeheader()
        w.writerows({**r, "format": "cgvq-scores/1"} for r in rows)
    before = out.read_bytes()

    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out,
                           "--metrics", "psnr,gmsd")
    assert rc == 0, err
    assert out.read_bytes().startswith(before)  # nothing rewritten, psnr not scored again
    header, rows = _rows(out)
    assert header == old_header
    assert [r["metric"] for r in rows] == ["psnr"] * 4 + ["gmsd"] * 4
    assert {r["format"] for r in rows} == {"cgvq-scores/1"}
    assert len(read_table(out, SCORES_1_0)) == 8


def test_score_csv_rows_can_carry_the_manifests_ids(capsys, tmp_path):
    """Two scenes rendered to the same file names (as `cgvq-study init` lays them out): with
    --id and --reference-id each row names its manifest ids, so neither clashes with the
    other and the analysis can join them; without --csv the ids are refused."""
    out = tmp_path / "rows.csv"
    for n, scene in enumerate(("colonnade", "lattice"), start=1):
        ref = real_video(4, 40, 48, image="astronaut" if n == 1 else "coffee")
        r = write_video(tmp_path / scene / "reference.mkv", ref, FPS)
        t = write_video(tmp_path / scene / "blur_L1.mkv", noisy(ref, 8), FPS)
        rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "psnr",
                          "--csv", out, "--id", f"SRC0{n}_HRC01", "--reference-id", f"SRC0{n}")
        assert rc == 0, err
    rows = read_table(out, SCORES)
    assert [(r["stimulus"], r["reference"]) for r in rows] == [("SRC01_HRC01", "SRC01"),
                                                               ("SRC02_HRC01", "SRC02")]
    rc, _, err = _run(capsys, "score", "--ref", r, "--test", t, "--metric", "psnr",
                      "--id", "SRC02_HRC01")
    assert rc == 2 and "give --csv too" in err and len(err.strip().splitlines()) == 1
