"""Issue 22, item 3.6: `cgvq-study verify` checks an exported zip as a whole (every member
against SHA256SUMS) and its ratings CSV against the session file inside, which stays the
authority: each tampering below is reported as damage to the copy (exit 2), an untouched
export stays intact and complete (exit 0)."""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from pathlib import Path

import pytest
from support.sessions import bare_session, plain_result
from support.tamper import edit_csv_cell, rewrite_zip

from cgvq_cli.study_cli import main
from study_app.export import export_session, verify_file

RATINGS = (10.0, 20.0, 30.0)
AUTHORITY = "the copy is damaged; the session file is intact and authoritative"


@pytest.fixture
def exported(tmp_path: Path) -> Path:
    """A finished session of three ratings, exported to a zip."""
    path = tmp_path / "P01.sqlite"
    with bare_session(path, "P01", n=len(RATINGS)) as store:
        for i, rating in enumerate(RATINGS):
            store.record(i, plain_result(rating))
        store.finish()
    return export_session(path, tmp_path / "back.zip")


def _csv_name(zip_path: Path) -> str:
    with zipfile.ZipFile(zip_path) as zf:
        (name,) = [n for n in zf.namelist() if n.endswith("_ratings.csv")]
    return name


def _verify(capsys: pytest.CaptureFixture[str], zip_path: Path) -> tuple[int, str]:
    code = main(["verify", str(zip_path)])
    out = capsys.readouterr().out
    return code, out


def test_untouched_export_is_intact_and_complete(exported, capsys):
    code, out = _verify(capsys, exported)
    assert code == 0 and "intact and complete" in out and "DAMAGED" not in out
    assert verify_file(exported).problems == []


def test_same_numbers_written_another_way_are_not_damage(exported, capsys):
    """'20' for '20.0' is the same rating: only a changed value is damage."""
    name = _csv_name(exported)
    rewrite_zip(exported, lambda m: m.update({name: edit_csv_cell(m[name], 2, "rating", "20")}),
                resum=True)
    code, out = _verify(capsys, exported)
    assert code == 0 and "intact and complete" in out


def _edit_rating(name: str) -> Callable[[dict[str, bytes]], None]:
    return lambda m: m.update({name: edit_csv_cell(m[name], 2, "rating", "55")})


@pytest.mark.parametrize("case", ["csv edited", "csv edited, sums recomputed", "sums removed",
                                  "member added", "member removed"])
def test_each_tampering_is_damage_to_the_copy(exported, capsys, case):
    name = _csv_name(exported)
    # the session's second rating (data row 2, trial 1) is RATINGS[1], written as a float
    mismatch = (f"{name} does not match the session inside the zip (row 2 (trial 1): rating 55 "
                f"in the CSV vs {RATINGS[1]} in the session)")
    expected: list[str]
    if case == "csv edited":
        rewrite_zip(exported, _edit_rating(name))
        expected = [f"{name}: sha256", "differs from its SHA256SUMS entry", mismatch]
    elif case == "csv edited, sums recomputed":
        rewrite_zip(exported, _edit_rating(name), resum=True)
        expected = [mismatch]
    elif case == "sums removed":
        rewrite_zip(exported, lambda m: m.pop("SHA256SUMS"))
        expected = ["no SHA256SUMS in the zip"]
    elif case == "member added":
        rewrite_zip(exported, lambda m: m.update({"notes.txt": b"hello"}))
        expected = ["notes.txt is in the zip but not listed in SHA256SUMS"]
    else:
        rewrite_zip(exported, lambda m: m.pop(name))
        expected = [f"{name} is listed in SHA256SUMS but missing from the zip"]
    code, out = _verify(capsys, exported)
    assert code == 2 and "DAMAGED" in out, out
    for text in expected:
        assert text in out, (text, out)
    report = verify_file(exported)
    assert report.state == "damaged" and report.exit_code == 2
    messages = [p.message for p in report.problems]
    assert messages and all(m.endswith(AUTHORITY) for m in messages), messages
    if case != "csv edited":  # the sums still cover the edit: one problem, not two
        assert len(messages) == 1, messages
    if case == "csv edited, sums recomputed":
        assert "SHA256SUMS" not in out


def test_csv_removed_with_sums_recomputed_is_still_damage(exported, capsys):
    name = _csv_name(exported)
    rewrite_zip(exported, lambda m: m.pop(name), resum=True)
    code, out = _verify(capsys, exported)
    assert code == 2 and f"holds no ratings CSV {name}" in out and AUTHORITY in out


def test_a_forged_session_is_not_called_authoritative(exported, capsys):
    """An edit of the session member itself fails its checksum: then the session is not
    claimed intact and authoritative."""
    def flip(m: dict[str, bytes]) -> None:
        (member,) = [n for n in m if n.endswith(".sqlite")]
        m[member] = m[member][:-1] + bytes([m[member][-1] ^ 1])
    rewrite_zip(exported, flip)
    code, out = _verify(capsys, exported)
    assert code == 2 and "checksum mismatch" in out
    assert "intact and authoritative" not in out


def test_the_error_line_of_a_damaged_member_names_the_damage_not_a_missing_file(exported,
                                                                               capsys):
    name = _csv_name(exported)
    rewrite_zip(exported, _edit_rating(name))
    code = main(["verify", str(exported)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "not found;" not in err[0] and "differs from its SHA256SUMS entry" in err[0], err[0]


def _as_version_1_0(data: bytes) -> bytes:
    """The CSV as a toolkit before cgvq-ratings/1.1 wrote it: no manifest_sha256 column."""
    import csv
    import io

    rows = list(csv.reader(io.StringIO(data.decode())))
    drop = rows[0].index("manifest_sha256")
    out = io.StringIO()
    writer = csv.writer(out)
    for r in rows:
        r = r[:drop] + r[drop + 1:]
        writer.writerow(["cgvq-ratings/1" if v == "cgvq-ratings/1.1" else v for v in r])
    return out.getvalue().encode()


def test_an_export_written_before_version_1_1_still_verifies(exported, capsys):
    name = _csv_name(exported)
    rewrite_zip(exported, lambda m: m.update({name: _as_version_1_0(m[name])}), resum=True)
    code, out = _verify(capsys, exported)
    assert code == 0 and "intact and complete" in out
    # ... and an edited rating in such a file is still damage
    rewrite_zip(exported, _edit_rating(name), resum=True)
    code, out = _verify(capsys, exported)
    assert code == 2 and "rating 55" in out
