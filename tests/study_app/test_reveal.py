"""Showing the session file in the file manager: the command per system, and the environment
it gets in the frozen app (PyInstaller's loader puts the bundle's libraries first in
LD_LIBRARY_PATH and keeps the participant's own value in LD_LIBRARY_PATH_ORIG, as its manual
says; a system file manager started with the bundle's libraries can fail to start)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from study_app import reveal
from study_app.reveal import reveal_command, system_environment


def test_the_command_per_system(tmp_path):
    f = tmp_path / "p01.sqlite"
    assert reveal_command(f, "win32") == ["explorer", f"/select,{f.resolve()}"]
    assert reveal_command(f, "darwin") == ["open", "-R", str(f.resolve())]
    assert reveal_command(f, "linux") == ["xdg-open", str(tmp_path.resolve())]


def test_outside_the_frozen_app_the_environment_is_left_alone():
    env = {"LD_LIBRARY_PATH": "/opt/lib", "LD_LIBRARY_PATH_ORIG": "/x", "HOME": "/h"}
    assert system_environment(env, frozen=False) == env


def test_in_the_frozen_app_the_participants_library_path_is_restored():
    env = {"LD_LIBRARY_PATH": "/tmp/_MEI123:/opt/lib", "LD_LIBRARY_PATH_ORIG": "/opt/lib",
           "HOME": "/h"}
    assert system_environment(env, frozen=True) == {"LD_LIBRARY_PATH": "/opt/lib", "HOME": "/h"}


def test_in_the_frozen_app_a_path_the_participant_did_not_have_is_removed():
    env = {"LD_LIBRARY_PATH": "/tmp/_MEI123", "LIBPATH": "/tmp/_MEI123", "HOME": "/h"}
    assert system_environment(env, frozen=True) == {"HOME": "/h"}


def test_the_file_manager_is_started_with_that_environment(tmp_path, monkeypatch):
    started: list[dict] = []

    class FakePopen:
        def __init__(self, cmd, **kwargs):
            started.append({"cmd": cmd, **kwargs})

    monkeypatch.setattr(subprocess, "Popen", FakePopen)
    monkeypatch.setattr(sys, "frozen", True, raising=False)
    monkeypatch.setenv("LD_LIBRARY_PATH", "/tmp/_MEI9")
    monkeypatch.setenv("LD_LIBRARY_PATH_ORIG", "/usr/local/lib")
    assert reveal.reveal_in_file_manager(Path(tmp_path / "p01.sqlite"))
    (call,) = started
    assert call["env"]["LD_LIBRARY_PATH"] == "/usr/local/lib"
    assert "LD_LIBRARY_PATH_ORIG" not in call["env"]
    assert call["start_new_session"] is True
