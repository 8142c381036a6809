"""The participant's app under a private Xvfb display (OpenGL 3.3 through Mesa), driven by X
input: the displays, a driver of ``cgvq-study run`` that follows its ``state:`` log lines, and
their fixtures. Tests skip when Xvfb, xdotool or OpenGL are missing."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from support.lean_install import lean_pythonpath


def _free_display() -> int:
    for n in range(90, 200):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    pytest.skip("no free X display number between :90 and :199")


_GL_PROBE = (
    "import pygame, moderngl; pygame.display.init();"
    "[pygame.display.gl_set_attribute(a, v) for a, v in ("
    "(pygame.GL_CONTEXT_MAJOR_VERSION, 3), (pygame.GL_CONTEXT_MINOR_VERSION, 3),"
    "(pygame.GL_CONTEXT_PROFILE_MASK, pygame.GL_CONTEXT_PROFILE_CORE))];"
    "pygame.display.set_mode((64, 64), pygame.OPENGL | pygame.DOUBLEBUF);"
    "moderngl.create_context(require=330)")


def start_xvfb(size: tuple[int, int]):
    """Start a private Xvfb of ``size`` with OpenGL 3.3 through Mesa: (process, env).

    Skips the test when Xvfb, xdotool or OpenGL are missing."""
    for tool in ("Xvfb", "xdotool"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (make test installs it as root)")
    n = _free_display()
    proc = subprocess.Popen(["Xvfb", f":{n}", "-screen", "0", f"{size[0]}x{size[1]}x24",
                             "-nolisten", "tcp"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 10
    while not Path(f"/tmp/.X11-unix/X{n}").exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            pytest.skip("Xvfb did not start")
        time.sleep(0.05)
    env = {**os.environ, "DISPLAY": f":{n}", "SDL_VIDEODRIVER": "x11",
           "SDL_AUDIODRIVER": "dummy", "PYGAME_HIDE_SUPPORT_PROMPT": "1"}
    probe = subprocess.run([sys.executable, "-c", _GL_PROBE], env=env, capture_output=True,
                           text=True, timeout=60)
    if probe.returncode != 0:
        proc.kill()
        pytest.skip(f"no OpenGL 3.3 on Xvfb: {probe.stderr.strip().splitlines()[-1:]}")
    return proc, env


@pytest.fixture(scope="module")
def xdisplay():
    """A private 1280x1024 Xvfb display with OpenGL 3.3 through Mesa, for a test module."""
    proc, env = start_xvfb((1280, 1024))
    yield env
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture
def xvfb_factory():
    """``start(size) -> env`` for private Xvfb displays, stopped after the test."""
    procs = []

    def start(size: tuple[int, int]) -> dict[str, str]:
        proc, env = start_xvfb(size)
        procs.append(proc)
        return env

    yield start
    for proc in procs:
        proc.terminate()
        proc.wait(timeout=10)


class AppDriver:
    """Runs ``cgvq-study run`` in a subprocess and follows its ``state:`` log lines."""

    def __init__(self, env: dict[str, str], args: list[str], *,
                 command: list[str] | None = None, subcommand: str = "run") -> None:
        """``command`` runs the app (default: this Python, in a process where the research
        stack cannot be imported, as in the participant's base install)."""
        self.env = env
        if command is None:
            command = [sys.executable, "-m", "cgvq_cli.study_cli"]
            # the research stack unimportable: every GUI run proves the app needs none of it
            env = {**env, "PYTHONPATH": lean_pythonpath()}
        self.proc = subprocess.Popen(
            [*command, "-v", subcommand, *args], env=env, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self._pos = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            if "state:" in line or "error" in line.lower() or "Traceback" in line:
                self.lines.append(line.strip())

    def wait(self, state: str, timeout: float = 30.0, *, required: bool = True,
             or_else: tuple[str, ...] = ()) -> str | None:
        """Wait for the next ``state: <state>`` line (or one of ``or_else``'s states);
        returns it (None when not ``required`` and it did not come in time)."""
        deadline = time.monotonic() + timeout
        wanted = "|".join(re.escape(s) for s in (state, *or_else))
        while time.monotonic() < deadline:
            while self._pos < len(self.lines):
                line = self.lines[self._pos]
                self._pos += 1
                if re.search(rf"state: ({wanted})(\s|$)", line):
                    return line
            if self.proc.poll() is not None and self._pos >= len(self.lines):
                break
            time.sleep(0.02)
        if not required:
            return None
        pytest.fail(f"app never reached state {state!r}; log: {self.lines[-15:]}")

    def key(self, *keys: str) -> None:
        for k in keys:
            subprocess.run(["xdotool", "key", k], env=self.env, check=True)
            time.sleep(0.12)

    def through_consent(self, timeout: float = 30.0) -> None:
        """A new participant: past the display check, the welcome and the consent."""
        self.wait("preflight-passed", timeout=timeout)
        self.key("space")
        self.wait("welcome")
        self.key("space")
        self.wait("consent")
        self.key("a")

    def practice(self) -> None:
        """One practice trial from its first screen: view, rate, and on to the study."""
        self.wait("practice")
        self.key("space")
        self.wait("viewing trial=-1 practice=1")
        self.open_rating()
        self.key("Right", "Return")
        self.wait("practice-end")
        self.key("space")

    def resume(self) -> None:
        """A returning participant: past the display check and the welcome-back screen."""
        self.wait("preflight-passed")
        self.key("space")
        self.wait("welcome-back")
        self.key("space")

    def switch_to_reference(self, trial: int) -> None:
        """Once ``trial`` shows its test video, switch to the reference (a blank comes first)."""
        self.wait(f"viewing trial={trial}")
        time.sleep(0.3)
        self.key("space")
        self.wait("switch to=reference")

    def quit_confirmed(self) -> tuple[int, str]:
        """From the pause screen: quit, confirm, and wait for the app to exit (as finish)."""
        self.key("q")
        self.wait("confirm-quit")
        self.key("y")
        return self.finish()

    def leave_failed_preflight(self, key: str) -> int:
        """Wait for the failed display check, leave it with ``key``; the app's exit code."""
        self.wait("preflight-failed")
        self.key(key)
        code, _ = self.finish()
        return code

    def open_rating(self, min_view_s: float = 1.0) -> str:
        """Enter until the rating screen opens (returns its state line). It needs
        ``min_view_s`` of presented viewing time, which a loaded machine (and a screenshot's
        read-back) can stretch; an early Enter only shows a notice."""
        time.sleep(min_view_s + 0.15)
        for _ in range(30):
            self.key("Return")
            line = self.wait("rating", timeout=1.0, required=False)
            if line:
                return line
        return self.wait("rating", timeout=1.0)

    def rate(self, trials: int = 1) -> None:
        """Rate the next ``trials`` trials: wait for each, open its rating, one step right of
        the middle, Enter, and wait until it is recorded."""
        for _ in range(trials):
            self.wait("viewing")
            self.open_rating()
            self.key("Right", "Return")
            self.wait("recorded")

    def click(self, x: float, y: float) -> None:
        subprocess.run(["xdotool", "mousemove", str(round(x)), str(round(y)), "click", "1"],
                       env=self.env, check=True)

    def finish(self, timeout: float = 30) -> tuple[int, str]:
        """Wait for the app to exit; returns its exit code and stdout."""
        self.proc.wait(timeout=timeout)
        self._reader.join(timeout=5)
        out = self.proc.stdout.read()
        self.proc.stdout.close()
        self.proc.stderr.close()
        return self.proc.returncode, out


@pytest.fixture
def app_driver():
    """The :class:`AppDriver` class (tests start one per ``cgvq-study run``)."""
    return AppDriver
