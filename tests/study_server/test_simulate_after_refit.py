"""``simulate --after-refit``: the raters after the adaptive warm-up arrive only once the
server has refit its model (a simulation at full speed would otherwise finish before the
first refit, and every block would be uniform). The server's answers are scripted here; the
demo's adaptive run (``tests/scripts``) goes through a real server."""

from __future__ import annotations

import argparse
import threading

import pytest

import study_app.remote.admin as admin
from cgvq_cli.study_commands import simulate
from session_store.errors import StudyError
from study_app.remote.http import ServerRefused, ServerUnavailable

from .conftest import make_adaptive_study, make_served_study

SETTINGS = {"blocks": 3, "warmup_participants": 2, "refit_seconds": 1, "bootstrap": 50}


def _args(manifest) -> argparse.Namespace:
    return argparse.Namespace(manifest=manifest, server="http://127.0.0.1:9")


def _scripted(monkeypatch, answers: list) -> list[int]:
    """server_refits answers these in turn (an exception is raised); returns the call log."""
    calls: list[int] = []

    def refits(server: str, token: str):
        calls.append(1)
        answer = answers.pop(0)
        if isinstance(answer, BaseException):
            raise answer
        return answer

    monkeypatch.setattr(admin, "server_refits", refits)
    monkeypatch.setattr("time.sleep", lambda s: None)
    return calls


def test_warm_up_raters_start_at_once_the_others_wait_for_the_first_refit(tmp_path,
                                                                           monkeypatch):
    study = make_adaptive_study(tmp_path / "s", SETTINGS)
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", "x" * 32)
    calls = _scripted(monkeypatch, [ServerUnavailable("restarting"), 0, 0, 2])
    gate = simulate._refit_gate(_args(study / "manifest.json"))
    gate(0)
    gate(1)  # the two warm-up raters never ask
    assert calls == []
    gate(2)  # asks until the server has refit: down, 0, 0, then 2
    assert len(calls) == 4
    gate(3)  # the refit is known: no more questions
    assert len(calls) == 4


def test_a_refused_token_a_full_design_and_a_missing_token_are_named(tmp_path, monkeypatch):
    study = make_adaptive_study(tmp_path / "s", SETTINGS)
    monkeypatch.setenv("CGVQ_ADMIN_TOKEN", "x" * 32)
    _scripted(monkeypatch, [ServerRefused("403", 403, "wrong admin token")])
    with pytest.raises(StudyError, match="refused the admin token"):
        simulate._refit_gate(_args(study / "manifest.json"))(2)
    _scripted(monkeypatch, [None])
    with pytest.raises(StudyError, match="serves a full design"):
        simulate._refit_gate(_args(study / "manifest.json"))(2)
    full = make_served_study(tmp_path / "full", refs=2, conds=2, repetitions=1)
    with pytest.raises(StudyError, match="is a full design"):
        simulate._refit_gate(_args(full / "manifest.json"))
    monkeypatch.delenv("CGVQ_ADMIN_TOKEN")
    with pytest.raises(StudyError, match=r"set \$CGVQ_ADMIN_TOKEN"):
        simulate._refit_gate(_args(study / "manifest.json"))


def test_a_gate_that_fails_stops_the_simulation_with_its_error(tmp_path):
    """The gate's error reaches the caller (the CLI prints it in one line)."""
    from study_app.simulate import SimulationOptions, UploadOptions, run_simulation

    study = make_adaptive_study(tmp_path / "s", SETTINGS)
    seen = threading.Event()

    def gate(k: int) -> None:
        seen.set()
        raise StudyError("--after-refit: the server did not refit")

    # rater 0 fails at its gate before it asks the (absent) server anything
    with pytest.raises(StudyError, match="did not refit"):
        run_simulation(study / "manifest.json", tmp_path / "out",
                       SimulationOptions(raters=1, seed=1), progress=False,
                       upload=UploadOptions("http://127.0.0.1:9", {"P01": "t" * 32},
                                            start_gate=gate, timeout_s=1))
    assert seen.is_set()
