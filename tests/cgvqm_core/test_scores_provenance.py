"""What a scores row says about how it was computed, and what a batch checks before it
starts: resuming after adding a permission (--allow-resample) keeps the rows written, keys of
older files still count, every pair's frame rate and readability are probed before any work,
a resized or resampled test says so in its row, and ``score --csv`` rows record their
inputs' sha256 and device as batch rows do."""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

from cgvqm_core.batch import scorer_identity
from cgvqm_core.metrics import MetricOptions, build_scorers
from stimuli_manifests import fill_checksums, load_manifest, save_manifest, write_video

from .metrics.conftest import real_video
from .metrics.test_cli_batch import FPS, _run, _study


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _replace(manifest: Path, name: str, frames, fps: float) -> None:
    """Re-render one test video of the study and record its new checksum."""
    write_video(manifest.parent / "videos" / name, frames, fps)
    save_manifest(fill_checksums(load_manifest(manifest)), manifest)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_adding_allow_resample_to_resume_keeps_the_rows_written(tmp_path, capsys):
    """The flag was hashed into every row's key, so the rerun its own error message asks for
    was refused as "computed with other settings" for every row already there."""
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    assert _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr")[0] == 0
    before = out.read_bytes()
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr",
                      "--allow-resample", "--allow-convert")
    assert rc == 0, err
    assert out.read_bytes() == before  # every row counted as done, none added


def test_rows_keyed_the_old_way_count_as_done(tmp_path, capsys):
    """Files written before keys left the permissions out: their rows are not scored again
    and do not clash (the old key is computed here from its published recipe)."""
    manifest = _study(tmp_path)
    out = tmp_path / "s.csv"
    assert _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr")[0] == 0
    options = MetricOptions()
    (scorer,) = build_scorers(["psnr"], options)
    ident = scorer_identity(scorer, options)
    rows = _rows(out)
    for r in rows:
        doc = {**ident, "pooling": "", "reference": r["reference"],
               "reference_sha256": r["reference_sha256"], "stimulus": r["stimulus"],
               "stimulus_sha256": r["stimulus_sha256"],
               "alignment": {"allow_resample": False, "on_conversion": "error"}}
        r["key"] = hashlib.sha256(json.dumps(doc, sort_keys=True, separators=(",", ":"),
                                             default=str).encode()).hexdigest()
    with out.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    before = out.read_bytes()
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr")
    assert rc == 0, err
    assert out.read_bytes() == before


def test_a_frame_rate_mismatch_is_refused_before_any_work(tmp_path, capsys):
    """The first mismatched pair used to stop the batch when its turn came, after the
    references before it had been scored; now every pair is probed first and all are named."""
    manifest = _study(tmp_path)
    frames = real_video(6, 48, 48, image="coffee")
    _replace(manifest, "src1_d1.mkv", frames, FPS * 2)
    _replace(manifest, "src1_d2.mkv", frames, FPS * 2)
    out = tmp_path / "s.csv"
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr",
                      "--group-size", "1")
    assert rc == 2
    lines = [ln for ln in err.splitlines() if "error" in ln]
    assert len(lines) == 1, err
    assert "2 test video(s) differ from their reference in frame rate" in lines[0]
    assert "SRC02_HRC03" in lines[0] and "SRC02_HRC04" in lines[0]
    assert not out.exists() or len(_rows(out)) == 0  # nothing scored before the refusal
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr",
                      "--allow-resample")
    assert rc == 0, err
    assert len(_rows(out)) == 4


def test_unreadable_videos_are_named_before_any_work(tmp_path, capsys):
    manifest = _study(tmp_path)
    for name in ("src0_d2.mkv", "src1_d2.mkv"):
        (tmp_path / "videos" / name).write_bytes(b"not a video" * 50)
    save_manifest(fill_checksums(load_manifest(manifest)), manifest)
    out = tmp_path / "s.csv"
    rc, _, err = _run(capsys, "batch", "--manifest", manifest, "--out", out, "--metric", "psnr")
    assert rc == 2
    assert "2 video(s) of the manifest cannot be scored" in err
    assert "src0_d2.mkv" in err and "src1_d2.mkv" in err
    assert not out.exists() or len(_rows(out)) == 0


def test_a_resized_and_resampled_test_says_so_in_its_row(tmp_path, capsys):
    """Such a score is not the score of the file as rendered; the row's note said nothing
    (and a note still reads as "does not apply" only where there is no score)."""
    manifest = _study(tmp_path)
    small = real_video(6, 48, 48, image="coffee")[:4, ::2, ::2].copy()  # 4 frames, 24x24
    _replace(manifest, "src1_d1.mkv", small, FPS)
    out = tmp_path / "s.csv"
    rc, stdout, err = _run(capsys, "batch", "--manifest", manifest, "--out", out,
                           "--metric", "psnr")
    assert rc == 0, err
    assert "not applicable" not in stdout + err
    by_stim = {r["stimulus"]: r for r in _rows(out)}
    note = by_stim["SRC02_HRC03"]["note"]
    assert "resized from 24x24 to the reference's 48x48" in note
    # 4 frames to 6: indices floor(k * 4 / 6) = 0 0 1 2 2 3, so 2 repeated, none dropped
    assert "test's 4 frames resampled in time to the reference's 6 (2 repeated, 0 dropped)" \
        in note
    assert float(by_stim["SRC02_HRC03"]["score"]) > 0
    assert all(by_stim[s]["note"] == "" for s in by_stim if s != "SRC02_HRC03")


def test_score_csv_rows_record_inputs_and_device_as_batch_rows_do(tmp_path, capsys):
    manifest = _study(tmp_path)
    videos = tmp_path / "videos"
    ref, test = videos / "src0.mkv", videos / "src0_d1.mkv"
    batch_csv, single_csv = tmp_path / "batch.csv", tmp_path / "single.csv"
    common = ["--random-backbone", "0", "--weights", "uniform"]
    assert _run(capsys, "batch", "--manifest", manifest, "--out", batch_csv, "--metric",
                "cgvqm-2,psnr", *common)[0] == 0
    for metric, extra in (("cgvqm-2", common), ("psnr", [])):
        rc, _, err = _run(capsys, "score", "--ref", ref, "--test", test, "--metric", metric,
                          "--csv", single_csv, *extra)
        assert rc == 0, err
    batch = {r["metric"]: r for r in _rows(batch_csv) if r["stimulus"] == "SRC01_HRC01"}
    for r in _rows(single_csv):
        assert r["reference_sha256"] == _sha(ref) and r["stimulus_sha256"] == _sha(test)
        assert json.loads(r["settings"])["device_type"] == "cpu"
        twin = batch[r["metric"]]
        for column in ("settings", "versions", "backbone", "backbone_sha256", "weights_sha256",
                       "note", "score"):
            assert r[column] == twin[column], column
        assert r["key"] == ""  # a single pair is not resumed


def test_score_json_of_a_peer_names_its_device_and_alignment(tmp_path, capsys):
    ref, test = tmp_path / "ref.mkv", tmp_path / "test.mkv"
    frames = real_video(6, 48, 48)
    write_video(ref, frames, FPS)
    write_video(test, frames[:, ::2, ::2].copy(), FPS)
    rc, out, err = _run(capsys, "score", "--ref", ref, "--test", test, "--metric", "psnr",
                        "--json")
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["settings"]["device_type"] == "cpu"
    assert doc["note"].startswith("test resized from 24x24 to the reference's 48x48")
    assert "resampled in time" not in doc["note"]  # same frame count: only resized
