"""Session files that do not belong are refused and named; duplicates, withdrawals, zips,
partial sessions: every choice documented and independent of the order of the files."""

from __future__ import annotations

import hashlib
import shutil
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main
from analysis.inputs import load_ratings
from analysis.quality import drop_incomplete
from analysis.synthetic import synthetic_study
from stimuli_manifests import load_manifest, save_manifest

from .conftest import write_session

pytest.importorskip("session_store")


def _trials(manifest) -> list[tuple[str, str, int, bool]]:
    return [(s.id, s.reference, rep, s.is_hidden_reference)
            for rep in range(1, manifest.protocol.repetitions + 1) for s in manifest.stimuli()]


@pytest.fixture
def panel(tmp_path: Path):
    """5 raters of study 'synthetic' as session files, the manifest and its sha256."""
    st = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=5, repetitions=2,
                         noise_sd=4, seed=8)
    mpath = save_manifest(st.manifest.manifest, tmp_path / "manifest.json")
    sha = load_manifest(mpath).sha256
    folder = tmp_path / "sessions"
    folder.mkdir()
    for rater, rows in st.ratings.groupby("participant"):
        write_session(folder / f"{rater}.sqlite", rows, study_id="synthetic",
                      manifest_sha256=sha, all_trials=_trials(st.manifest.manifest))
    return st, mpath, sha, folder


def test_foreign_sessions_are_refused_listed_and_named(panel, tmp_path: Path, capsys) -> None:
    st, mpath, sha, folder = panel
    # Another study's participant "P01" in a file that sorts first, with other ratings.
    other = synthetic_study(n_scenes=3, methods=("blur",), levels=2, n_raters=1,
                            repetitions=2, noise_sd=4, seed=99, study_id="other-study")
    write_session(folder / "A_other.sqlite", other.ratings, study_id="other-study",
                  manifest_sha256=sha)
    # Same study id, but run with another manifest.
    p02 = st.ratings[st.ratings["participant"] == "P02"].assign(participant="P06")
    write_session(folder / "B_old_manifest.sqlite", p02, study_id="synthetic",
                  manifest_sha256="0" * 64)
    rs = load_ratings(mpath, sessions=[folder])
    refused = {Path(x.who).name: x for x in rs.exclusions if x.kind == "refused session"}
    assert set(refused) == {"A_other.sqlite", "B_old_manifest.sqlite"}
    assert "other-study" in refused["A_other.sqlite"].reason
    assert "another manifest" in refused["B_old_manifest.sqlite"].reason
    assert rs.raters == ["P01", "P02", "P03", "P04", "P05"]
    # P01's ratings are the real ones, not the other study's.
    real = st.ratings[st.ratings["participant"] == "P01"]
    s = rs.raters.index("P01")
    for r in real.itertuples():
        e = rs.stimulus_ids.index(r.stimulus)
        assert rs.scores[e, s, r.repetition - 1] == pytest.approx(r.rating)
    # The command line names them on stderr, one line each, and in the report's first screen.
    out = tmp_path / "rep"
    assert main(["report", "--manifest", str(mpath), "--sessions", str(folder), "--model",
                 "mos", "--bootstrap", "20", "--splits", "20", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert sum("excluded: refused session" in line and "A_other.sqlite" in line
               for line in err.splitlines()) == 1
    assert "B_old_manifest.sqlite" in err
    html = (out / "report.html").read_text()
    glance = html[html.index("At a glance"): html.index("</div>", html.index("At a glance"))]
    assert "A_other.sqlite" in glance and "B_old_manifest.sqlite" in glance


def test_withdrawn_session_is_never_used(panel) -> None:
    st, mpath, sha, folder = panel
    rows = st.ratings[st.ratings["participant"] == "P03"].assign(participant="P09")
    write_session(folder / "P09.sqlite", rows, study_id="synthetic", manifest_sha256=sha,
                  withdraw=True)
    rs = load_ratings(mpath, sessions=[folder])
    assert "P09" not in rs.raters
    (x,) = [x for x in rs.exclusions if "P09" in x.who]
    assert x.kind == "refused session" and "withdrew" in x.reason


def test_duplicates_are_resolved_the_same_whatever_the_file_order(panel, tmp_path) -> None:
    st, mpath, sha, folder = panel
    shutil.copy(folder / "P02.sqlite", folder / "P02_copy.sqlite")
    # A second session of P04 (started later) that re-rates some trials differently.
    later = st.ratings[st.ratings["participant"] == "P04"].head(6).assign(rating=1.0)
    write_session(tmp_path / "P04_second.sqlite", later, study_id="synthetic",
                  manifest_sha256=sha, created_at="2099-01-01T00:00:00Z",
                  session_id="p04-second")
    files = [*sorted(folder.glob("*.sqlite")), tmp_path / "P04_second.sqlite"]
    a = load_ratings(mpath, sessions=files)
    b = load_ratings(mpath, sessions=files[::-1])
    np.testing.assert_array_equal(a.scores, b.scores)
    assert a.raters == b.raters and sorted(map(str, a.exclusions)) == sorted(map(str, b.exclusions))
    (dup,) = [x for x in a.exclusions if x.kind == "duplicate session"]
    assert "P02" in dup.reason and dup.who.endswith("P02_copy.sqlite")
    # The earlier session's ratings win; the re-rated trials are reported.
    s = a.raters.index("P04")
    first = st.ratings[st.ratings["participant"] == "P04"]
    for r in first.head(6).itertuples():
        assert a.scores[a.stimulus_ids.index(r.stimulus), s, r.repetition - 1] == \
            pytest.approx(r.rating)
    dups = [p for p in a.problems if "duplicate rating" in p.message]
    assert len(dups) == 6 and all("earlier session" in p.message for p in dups)


def test_zips_and_folders_are_accepted(panel, tmp_path: Path) -> None:
    _, mpath, _, folder = panel
    archive = tmp_path / "returned.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for f in sorted(folder.glob("P0[1-3].sqlite")):
            zf.write(f, f"export/{f.name}")
    rest = tmp_path / "rest"
    rest.mkdir()
    for f in sorted(folder.glob("P0[4-5].sqlite")):
        shutil.copy(f, rest / f.name)
    both = load_ratings(mpath, sessions=[archive, rest])
    direct = load_ratings(mpath, sessions=[folder])
    assert both.raters == direct.raters
    np.testing.assert_array_equal(both.scores, direct.scores)


def test_partial_sessions_follow_min_completeness(panel) -> None:
    st, mpath, sha, folder = panel
    trials = _trials(st.manifest.manifest)
    part = st.ratings[st.ratings["participant"] == "P05"].assign(participant="P07").head(5)
    write_session(folder / "P07.sqlite", part, study_id="synthetic", manifest_sha256=sha,
                  all_trials=trials, finish=False)
    rs = load_ratings(mpath, sessions=[folder])
    info = rs.rater_info
    assert info.loc["P07", "n_ratings"] == 5 and info.loc["P07", "n_planned"] == len(trials)
    assert info.loc["P07", "completeness"] == pytest.approx(5 / len(trials))
    assert info.loc["P01", "completeness"] == 1.0
    used = drop_incomplete(rs, 0.5)
    assert "P07" not in used.raters and used.n_raters == 5
    (x,) = [x for x in used.exclusions if x.kind == "partial rater"]
    assert x.who == "P07" and f"5 of {len(trials)} planned trials" in x.reason
    assert "--min-completeness" in x.reason
    kept = drop_incomplete(rs, 0.0)
    assert "P07" in kept.raters


def test_missing_paths_and_empty_folders(tmp_path: Path, panel) -> None:
    _, mpath, _, _ = panel
    from analysis.errors import AnalysisError

    (tmp_path / "empty").mkdir()
    with pytest.raises(AnalysisError, match="no session files"):
        load_ratings(mpath, sessions=[tmp_path / "empty"])
    with pytest.raises(AnalysisError, match="does not exist"):
        load_ratings(mpath, sessions=[tmp_path / "nope"])


def test_a_zip_member_altered_in_transit_is_refused(panel, tmp_path: Path) -> None:
    _, mpath, _, folder = panel
    archive = tmp_path / "export.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        zf.write(folder / "P01.sqlite", "P01.sqlite")
        zf.write(folder / "P02.sqlite", "P02.sqlite")
        good = hashlib.sha256((folder / "P02.sqlite").read_bytes()).hexdigest()
        zf.writestr("SHA256SUMS", f"{'0' * 64}  P01.sqlite\n{good}  P02.sqlite\n")
    rs = load_ratings(mpath, sessions=[archive, folder / "P03.sqlite", folder / "P04.sqlite"])
    (x,) = [x for x in rs.exclusions if x.kind == "refused session"]
    assert "P01.sqlite" in x.who and "checksum mismatch" in x.reason
    assert "P01" not in rs.raters and "P02" in rs.raters


def _damage_member(archive: Path, member: str) -> None:
    """Overwrite 16 bytes in the middle of ``member``'s compressed data (a zip damaged in
    transit: a broken deflate stream or a CRC mismatch)."""
    with zipfile.ZipFile(archive) as zf:
        info = zf.getinfo(member)
    data = bytearray(archive.read_bytes())
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:
                                                    info.header_offset + 30])
    at = info.header_offset + 30 + name_len + extra_len + info.compress_size // 2
    data[at:at + 16] = b"\xff" * 16
    archive.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["member", "truncated"])
def test_a_damaged_zip_is_one_line_exit_2_and_writes_nothing(damage, panel, tmp_path: Path,
                                                             capsys) -> None:
    """A zip damaged inside a member used to escape as a zlib.error traceback (exit 1), a
    truncated one was called 'not a readable SQLite session file'."""
    _, mpath, _, folder = panel
    archive = tmp_path / "P01_export.zip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.write(folder / "P01.sqlite", "P01.sqlite")
    if damage == "member":
        _damage_member(archive, "P01.sqlite")
    else:
        archive.write_bytes(archive.read_bytes()[:300])
    out = tmp_path / "dmos.csv"
    assert main(["dmos", "--sessions", str(archive), "--manifest", str(mpath),
                 "--bootstrap", "10", "--splits", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("cgvq-analyze: error: "), err
    assert f"{archive}: damaged zip" in err[0] and "SQLite" not in err[0]
    assert not out.exists()
    # beside readable sessions the damaged zip is left out and named, never used silently
    rs = load_ratings(mpath, sessions=[archive, *sorted(folder.glob("P0[2-5].sqlite"))])
    assert "P01" not in rs.raters
    assert any(p.source == str(archive) and "damaged zip" in p.message for p in rs.problems)
