"""Flags are the experimenter's view of odd client behaviour: bounded per participant, each
logged once, and free of the participant's local folders (their account name)."""

from __future__ import annotations

import logging
from pathlib import Path

from study_app.remote.uploader import local_problems, without_paths
from study_server.ingest import Ingest
from study_server.storage import MAX_FLAGS, ServerStore

AT = "2026-01-01T00:00:00.000Z"


def test_distinct_flags_stop_at_the_cap_and_are_counted_after(tmp_path):
    store = ServerStore(tmp_path / "state.sqlite")
    try:
        news = [store.add_flag("P01", None, "local_edit", f"problem {i}", AT)
                for i in range(MAX_FLAGS + 50)]
        assert news == [True] * MAX_FLAGS + [False] * 50
        assert store.add_flag("P01", None, "local_edit", "problem 0", AT) is False  # repeat
        flags = store.flags("P01")
        assert len(flags) == MAX_FLAGS + 1
        extra = [f for f in flags if f.kind == "too_many_flags"]
        assert len(extra) == 1 and extra[0].count == 50
        assert next(f for f in flags if f.message == "problem 0").count == 2
        assert store.add_flag("P02", None, "local_edit", "problem 0", AT) is True  # per person
    finally:
        store.close()


def test_each_distinct_flag_is_logged_once(tmp_path, caplog):
    store = ServerStore(tmp_path / "state.sqlite")
    try:
        ingest = Ingest(store, "study")
        with caplog.at_level(logging.WARNING, logger="study_server.ingest"):
            for _ in range(5):
                ingest.flag("P01", None, "clock_skew", "off by 9 min")
            ingest.flag("P01", None, "clock_skew", "off by 10 min")
        logged = [r.getMessage() for r in caplog.records if "flag clock_skew" in r.getMessage()]
        assert len(logged) == 2
        assert next(f for f in store.flags("P01") if f.message == "off by 9 min").count == 5
    finally:
        store.close()


def test_the_session_files_folders_are_not_sent(tmp_path, monkeypatch):
    home = tmp_path / "home" / "jane.doe"
    session = home / ".local" / "share" / "cgvq-study" / "sessions" / "P01.sqlite"
    session.parent.mkdir(parents=True)
    session.write_bytes(b"not a database at all" * 10)
    monkeypatch.setenv("HOME", str(home))
    problems = local_problems(session)
    assert problems and "P01.sqlite" in problems[0]
    assert "jane.doe" not in problems[0] and str(tmp_path) not in problems[0]
    # a relative spelling of the same file is left out too
    monkeypatch.chdir(session.parent)
    text = without_paths(f"{session} and {Path('P01.sqlite').absolute()} and {home}/x",
                         Path("P01.sqlite"))
    assert "jane.doe" not in text and text.count("P01.sqlite") == 2 and "~/x" in text


def test_home_folders_an_altered_client_sends_are_not_kept():
    """The genuine app sends none; the server shows client text as sent, so it leaves out
    home folders itself (they name the participant's account)."""
    from study_server.ingest import without_home

    text = ("cannot read /home/jane.doe/.local/x.sqlite, C:\\Users\\Jane Doe\\AppData\\x "
            "and /Users/jdoe/Library; /srv/data stays")
    assert without_home(text) == ("cannot read ~/.local/x.sqlite, ~\\AppData\\x and "
                                  "~/Library; /srv/data stays")
