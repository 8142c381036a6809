"""Returning results: exports of many participants have unique names and unzip into one
folder, verify takes files, folders and zips at once, hostile zips and files edited into bad
ids or bad JSON are refused."""

from __future__ import annotations

import zipfile

import pytest
from support.sessions import bare_session, plain_result
from support.tamper import edit_database

from cgvq_cli.study_cli import main
from session_store import read_session
from study_app.export import export_session, verify_many


def test_exports_of_many_participants_unzip_into_one_folder(tmp_path, monkeypatch):
    paths = []
    for pid in ("P01", "P02"):
        path = tmp_path / "sessions" / f"{pid}.sqlite"
        with bare_session(path, pid) as store:
            store.record(0, plain_result(50.0))
        paths.append(path)
    returns = tmp_path / "returns"
    returns.mkdir()
    monkeypatch.chdir(returns)  # the default: the current folder, as the README says
    zips = [export_session(p) for p in paths]
    assert [z.parent for z in zips] == [returns, returns] and len(set(zips)) == 2
    unpacked = tmp_path / "unpacked"
    for z in zips:
        with zipfile.ZipFile(z) as zf:
            zf.extractall(unpacked)
    sqlites = sorted(unpacked.glob("*.sqlite"))
    assert len(sqlites) == 2
    assert {read_session(p).info.participant for p in sqlites} == {"P01", "P02"}


def test_verify_takes_files_folders_and_zips_at_once(tmp_path, capsys):
    done = tmp_path / "in" / "P01.sqlite"
    with bare_session(done, "P01", n=2) as store:
        store.record(0, plain_result(1.0))
        store.record(1, plain_result(2.0))
        store.finish()
    with bare_session(tmp_path / "in" / "P02.sqlite", "P02") as store:
        store.record(0, plain_result(1.0))
    z = export_session(done, tmp_path / "zips")
    broken = tmp_path / "broken.sqlite"
    broken.write_bytes(b"garbage")
    code = main(["verify", str(tmp_path / "in"), str(z), str(broken)])
    out = capsys.readouterr().out
    assert code == 2
    assert "P01.sqlite: intact and complete" in out
    assert "P02.sqlite: intact but INCOMPLETE" in out
    assert f"{z}:P01_" in out and "broken.sqlite: DAMAGED" in out
    assert "4 session files: 2 complete, 1 incomplete, 1 damaged" in out
    sid = read_session(done).info.session_id  # the file and its zip are one session
    (copies,) = [ln for ln in out.splitlines() if "copies of one session" in ln]
    assert copies.startswith(f"2 files are copies of one session ({sid[:12]}..., "
                             "participant P01): the analysis uses the copy with the most ratings")
    assert main(["verify", str(tmp_path / "in" / "P01.sqlite"), str(z)]) == 0
    capsys.readouterr()


def test_hostile_zip_members_stay_in_their_folder(tmp_path):
    path = tmp_path / "P01.sqlite"
    bare_session(path).close()
    evil = tmp_path / "evil.zip"
    with zipfile.ZipFile(evil, "w") as zf:
        zf.write(path, "../../escaped.sqlite")
    reports = verify_many([evil])
    assert len(reports) == 1 and reports[0].state == "damaged"  # no SHA256SUMS, no CSV
    messages = [p.message for p in reports[0].problems]
    assert any(m.startswith("no SHA256SUMS") for m in messages)
    assert all(m.endswith("the session file is intact and authoritative") for m in messages)
    assert not (tmp_path.parent / "escaped.sqlite").exists()


def test_export_refuses_files_edited_into_bad_ids_or_bad_json(tmp_path, capsys):
    path = tmp_path / "P01.sqlite"
    bare_session(path).close()
    edit_database(path, "UPDATE session SET participant='../../x'")
    assert main(["export", str(path), "--out", str(tmp_path / "z")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'../../x' is not valid" in err
    assert not (tmp_path.parent / "x").exists() and not list(tmp_path.glob("*.zip"))
    path2 = tmp_path / "P02.sqlite"
    bare_session(path2, "P02").close()
    edit_database(path2, "UPDATE session SET settings='{not json'")
    assert main(["export", str(path2)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "settings is not valid JSON" in err
    assert main(["verify", str(path2)]) == 2
    capsys.readouterr()


@pytest.mark.parametrize("what, says", [
    ("missing", "not found"),
    ("empty folder", "holds no session file"),
    ("text file", "not a readable SQLite session file"),
    ("truncated", "not a readable SQLite session file"),
])
def test_verify_of_unusable_input_also_says_so_on_stderr(tmp_path, capsys, what, says):
    good = tmp_path / "P01.sqlite"
    with bare_session(good, "P01", n=2) as store:
        store.record(0, plain_result(1.0))
    target = tmp_path / "input"
    if what == "empty folder":
        target.mkdir()
    elif what == "text file":
        target.write_text("just some text\n")
    elif what == "truncated":
        target.write_bytes(good.read_bytes()[:2048])
    code = main(["verify", str(target)])
    out, err = capsys.readouterr()
    assert code == 2
    # the verdict stays on stdout; a missing path or an empty folder is not a damaged file
    unchecked = what in ("missing", "empty folder")
    assert ("NOT CHECKED" in out) == unchecked and ("DAMAGED" in out) != unchecked, out
    assert err.count("\n") == 1 and err.startswith("cgvq-study verify: error:"), err
    assert says in err


def test_verify_of_a_pull_with_no_sessions_says_the_server_had_none(tmp_path, capsys):
    from study_app.remote.admin import LISTING_FILE

    pulled = tmp_path / "pulled"
    pulled.mkdir()
    (pulled / LISTING_FILE).write_text('{"participants": []}\n')
    good = tmp_path / "P01.sqlite"
    with bare_session(good, "P01", n=1) as store:
        store.record(0, plain_result(1.0))
    code = main(["verify", str(pulled), str(good)])
    out, err = capsys.readouterr()
    assert code == 2 and "DAMAGED" not in out, out
    assert "the server had received no session" in out
    assert "2 inputs: 1 incomplete, 1 not checked" in out
    assert "1 of 2 inputs hold no session file" in err and err.count("\n") == 1


def test_export_refuses_outputs_it_would_clobber_or_misname(tmp_path, capsys):
    session = tmp_path / "P01.sqlite"
    with bare_session(session, "P01", n=2) as store:
        store.record(0, plain_result(1.0))
    notes = tmp_path / "notes.csv"
    notes.write_text("my own notes\n")
    cases = [
        (["--out", str(tmp_path / "foo.tar")], "give a path ending in .zip"),
        (["--out", str(tmp_path / "z"), "--csv", str(notes)], "is not a ratings CSV"),
        (["--out", str(notes)], "existing file"),
    ]
    for args, says in cases:
        code = main(["export", str(session), *args])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not (tmp_path / "foo.tar").exists() and not (tmp_path / "z").exists()
    assert notes.read_text() == "my own notes\n"
    # a ratings CSV and a zip written by an earlier export may be replaced
    again = ["export", str(session), "--out", str(tmp_path / "a.zip"), "--csv",
             str(tmp_path / "r.csv")]
    assert main(again) == 0 and main(again) == 0
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["export", str(empty)]) == 2
    assert "holds no session file" in capsys.readouterr().err
