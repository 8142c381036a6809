"""What the player continues (findings 3 and 4 of the session audit), checked through
:func:`study_app.resume_check.check_resumable` and the App's own resume check, no window:
a damaged file (broken rating chain, tables that differ from the change log), another
participant's file or another study's file is refused in one line; a sound one resumes."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.sessions import bare_plan, plain_result

from session_store import SessionStore
from session_store.errors import StudyError
from study_app.app import App, RunOptions
from study_app.resume_check import check_resumable

MANIFEST = "ab" * 32


def _session(path: Path, participant: str = "P01", study: str = "s", answered: int = 2
             ) -> Path:
    with SessionStore.create(path, participant=participant, study_id=study,
                             manifest_sha256=MANIFEST, seed=1, app_version="t",
                             plan=bare_plan(6)) as store:
        for i in range(answered):
            store.record(i, plain_result(10.0 * (i + 1)))
    return path


def _check(path: Path, participant: str = "P01", study: str = "s", seed: int | None = None,
           manifest: str = MANIFEST) -> None:
    check_resumable(path, participant=participant, study_id=study, manifest_sha256=manifest,
                    seed=seed)


def _edit(path: Path, sql: str) -> None:
    con = sqlite3.connect(path)
    con.execute(sql)
    con.commit()
    con.close()


def test_a_sound_session_resumes(tmp_path):
    _check(_session(tmp_path / "P01.sqlite"))


def test_a_broken_rating_chain_is_not_resumed(tmp_path):
    path = _session(tmp_path / "P01.sqlite")
    _edit(path, "UPDATE ratings SET rating = rating + 1 WHERE seq = 1")
    with pytest.raises(StudyError) as caught:
        _check(path)
    message = str(caught.value)
    assert "\n" not in message and "is damaged" in message
    assert "cgvq-study export" in message and "send" in message and "fresh session" in message


def test_tables_that_differ_from_the_change_log_are_not_resumed(tmp_path):
    path = _session(tmp_path / "P01.sqlite")
    _edit(path, "UPDATE session SET display = '{\"w\": 1}'")  # not covered by the rating chain
    with pytest.raises(StudyError, match=r"is damaged .*change log"):
        _check(path)


def test_an_unreadable_change_log_is_not_resumed(tmp_path):
    path = _session(tmp_path / "P01.sqlite")
    _edit(path, "UPDATE outbox SET body = 'not json' WHERE seq = 2")
    with pytest.raises(StudyError, match="is damaged"):
        _check(path)


def test_another_participants_file_is_not_resumed(tmp_path):
    path = _session(tmp_path / "P01.sqlite", participant="P02")
    with pytest.raises(StudyError, match="holds the session of participant P02, not P01"):
        _check(path)


def test_another_studys_file_is_not_resumed(tmp_path):
    path = _session(tmp_path / "P01.sqlite", study="other")
    with pytest.raises(StudyError, match="session of study other, not of this study"):
        _check(path, manifest="cd" * 32)  # named by its study, not as a changed manifest


def test_the_refusals_kept_from_before(tmp_path):
    path = _session(tmp_path / "P01.sqlite")
    with pytest.raises(StudyError, match="manifest changed"):
        _check(path, manifest="cd" * 32)
    with pytest.raises(StudyError, match="--seed 99"):
        _check(path, seed=99)
    with SessionStore.open(path) as store:
        store.withdraw()
    with pytest.raises(StudyError, match="withdrew"):
        _check(path)


def test_the_app_refuses_before_any_window(tmp_path):
    """App._check_existing runs before the display is made; it uses the same check."""
    path = _session(tmp_path / "P01.sqlite", participant="P02")
    study = SimpleNamespace(manifest=SimpleNamespace(study_id="s"),
                            loaded=SimpleNamespace(sha256=MANIFEST),
                            session_path=lambda *_: path)
    app = App(study, RunOptions(participant="P01"))
    with pytest.raises(StudyError, match="participant P02, not P01"):
        app._check_existing()
    assert app.display is None
    damaged = _session(tmp_path / "damaged" / "P01.sqlite")
    _edit(damaged, "UPDATE ratings SET rating = rating + 1 WHERE seq = 1")
    study.session_path = lambda *_: damaged
    with pytest.raises(StudyError, match="is damaged"):
        App(study, RunOptions(participant="P01"))._check_existing()
    good = _session(tmp_path / "good" / "P01.sqlite")
    study.session_path = lambda *_: good
    assert App(study, RunOptions(participant="P01"))._check_existing() is True


def test_a_new_session_has_its_consent_from_the_first_transaction(tmp_path, monkeypatch):
    """App._create_session writes session, pre-flight and consent in the creation transaction:
    no later write (which a kill could prevent) is needed for the consent record."""
    path = tmp_path / "P01.sqlite"
    study = SimpleNamespace(
        manifest=SimpleNamespace(
            study_id="s", protocol=SimpleNamespace(model_dump=lambda **_: {}),
            display=SimpleNamespace(model_dump=lambda **_: {}),
            scale=SimpleNamespace(model_dump=lambda **_: {})),
        loaded=SimpleNamespace(sha256=MANIFEST), consent="Do you agree?",
        text_sha256=lambda name: "cc" * 32, session_path=lambda *_: path)
    app = App(study, RunOptions(participant="P01", seed=1))
    app.display = SimpleNamespace(timing_mode="vsync")

    def no_later_write(*_a, **_k):
        raise AssertionError("written after the creation transaction")

    monkeypatch.setattr(SessionStore, "_change", no_later_write)
    store = app._create_session(bare_plan(3), [{"name": "screen", "ok": True, "message": ""}])
    store.close()
    with SessionStore.open(path) as reopened:
        events = reopened.events()
    assert [e["kind"] for e in events] == ["preflight", "consent", "created"]
    assert events[1]["asked"] is True


@pytest.mark.parametrize("damage", ["broken-chain", "truncated", "empty"])
def test_the_advice_for_a_damaged_file_is_one_that_works(tmp_path, damage, capsys):
    """The refusal told everyone to export the file; ``export`` cannot read a file SQLite
    cannot open, and wrote nothing."""
    from cgvq_cli.study_cli import main

    path = _session(tmp_path / "P01.sqlite")
    if damage == "broken-chain":
        _edit(path, "UPDATE ratings SET rating = rating + 1 WHERE seq = 1")
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:3000])
    else:
        path.write_bytes(b"")
    with pytest.raises(StudyError) as caught:
        _check(path)
    message = str(caught.value)
    out = tmp_path / "out"
    out.mkdir()
    main(["export", str(path), "--out", str(out)])
    capsys.readouterr()
    exported = list(out.iterdir())
    if "cgvq-study export" in message:
        assert damage == "broken-chain" and len(exported) == 1  # the zip, damage and all
    else:
        assert damage != "broken-chain" and not exported
        assert f"send the file {path} as it is" in message and "P01.sqlite" in message
