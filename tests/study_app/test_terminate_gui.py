"""A run ended from outside (system shutdown: SIGTERM; Ctrl+C in the terminal: SIGINT; the
terminal closed: SIGHUP) is the participant's confirmed "stop and continue later": the app
exits by itself with the saved-session message, records a "quit" naming the signal, frees
its lock, and a later run resumes where it stopped. Before, SDL turned SIGTERM into a
window-close that waited for a confirmation nobody gave, SIGINT raised a traceback and SIGHUP
killed the app without a word. A participant who stops before the practice gets it
when they come back (it used to count as done once the session existed)."""

from __future__ import annotations

import os
import signal

import pytest

from session_store import SessionStore, read_ratings

pytestmark = pytest.mark.gui

PILOT = "--pilot-no-vsync"


def _events(path) -> list[dict]:
    with SessionStore.open(path) as store:
        return store.events()


@pytest.mark.slow  # about 26 s here: CI runs it after `make test` (.ci/run)
def test_signals_end_the_run_as_a_confirmed_quit(tmp_path, xdisplay, study_factory,
                                                  app_driver):
    study = study_factory(tmp_path / "study")
    session = study / "sessions" / "P01.sqlite"
    lock = study / "sessions" / "P01.sqlite.lock"
    args = [str(study), "--participant", "P01", "--seed", "3", "--max-dropped-frames", "-1",
            "--practice", "1", PILOT]

    # SIGTERM on the practice's first screen: the practice comes again on the return
    app = app_driver(xdisplay, args)
    app.through_consent()
    app.wait("practice")
    os.kill(app.proc.pid, signal.SIGTERM)
    code, out = app.finish(timeout=20)
    assert code == 0 and "Session saved (0 of 3 trials answered)" in out, out
    assert "practice" not in [e["kind"] for e in _events(session)]

    # SIGTERM while a video plays (trial 1, after the practice and one answer)
    app = app_driver(xdisplay, args)
    app.resume()
    app.practice()
    app.rate(1)
    app.wait("viewing trial=1")
    os.kill(app.proc.pid, signal.SIGTERM)
    code, out = app.finish(timeout=20)
    assert code == 0, out
    assert "Session saved (1 of 3 trials answered)" in out
    assert not lock.exists()
    assert not any("Traceback" in line for line in app.lines)
    quit_ = _events(session)[-1]
    assert quit_["kind"] == "quit" and quit_["signal"] == "SIGTERM" and quit_["answered"] == 1
    assert [e["kind"] for e in _events(session)].count("practice") == 1  # not on later returns

    # SIGINT on the pause screen: a text screen, not the trial's event loop
    app = app_driver(xdisplay, args)
    app.resume()
    app.wait("viewing trial=1")
    app.key("p")
    app.wait("pause")
    os.kill(app.proc.pid, signal.SIGINT)
    code, out = app.finish(timeout=20)
    assert code == 0 and "Session saved (1 of 3 trials answered)" in out, out
    assert not any("Traceback" in line for line in app.lines)
    events = _events(session)
    assert [e["kind"] for e in events[-2:]] == ["pause", "quit"]
    assert events[-1]["signal"] == "SIGINT"

    # SIGHUP before the returning session reopens: nothing new is written to it
    n_events = len(events)
    app = app_driver(xdisplay, args)
    app.wait("preflight-passed")
    os.kill(app.proc.pid, signal.SIGHUP)
    code, out = app.finish(timeout=20)
    assert code == 1 and "Closed before the session continued" in out, out
    assert str(session) in out and not lock.exists()
    assert len(_events(session)) == n_events

    # a finished session's end screen closes as usual: a signal there is no "quit"
    app = app_driver(xdisplay, args)
    app.resume()
    app.rate(2)
    app.wait("end")
    os.kill(app.proc.pid, signal.SIGTERM)
    code, out = app.finish(timeout=20)
    assert code == 0 and "Session finished: 3 trials" in out, out
    rows, problems = read_ratings(session)
    assert problems == [] and [r["trial"] for r in rows] == [0, 1, 2]
    kinds = [e["kind"] for e in _events(session)]
    assert kinds.count("quit") == 3 and kinds[-1] != "quit"
