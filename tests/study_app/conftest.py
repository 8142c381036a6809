"""Fixtures of the study-app tests: a tiny study folder made on the fly; private Xvfb
displays and a driver of the real app for the GUI tests."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from stimuli_manifests import (
    fill_checksums,
    load_manifest,
    parse_manifest,
    save_manifest,
    write_video,
)


def reference_frames(size: int, frames: int, seed: int) -> np.ndarray:
    """A moving pattern whose every frame differs (so frame indices are visible)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size]
    base = rng.integers(0, 256, size=3)
    out = np.empty((frames, size, size, 3), dtype=np.uint8)
    for t in range(frames):
        for c in range(3):
            out[t, :, :, c] = (base[c] + 4 * xx + 2 * yy + 7 * t * (c + 1)) % 256
    return out


def make_study(folder: Path, *, size: int = 64, fps: float = 30, seconds: float = 1.0,
               refs: int = 1, repetitions: int = 1, min_display=(640, 480),
               briefing: bool = True, consent: bool = True) -> Path:
    """A study folder: ``refs`` references, each with two noisy conditions (levels 1, 2)."""
    folder.mkdir(parents=True, exist_ok=True)
    n = round(fps * seconds)
    references, conditions = [], []
    for r in range(refs):
        ref = reference_frames(size, n, seed=r)
        write_video(folder / "videos" / f"ref{r}.mkv", ref, fps)
        references.append({"path": f"ref{r}.mkv", "scene": f"scene{r}", "width": size,
                           "height": size, "fps": fps, "frames": n})
        rng = np.random.default_rng(100 + r)
        for level, sigma in ((1, 40), (2, 10)):
            noisy = np.clip(ref + rng.normal(0, sigma, ref.shape), 0, 255).astype(np.uint8)
            write_video(folder / "videos" / f"ref{r}_noise{level}.mkv", noisy, fps)
            conditions.append({"reference": f"SRC{r + 1:02d}", "method": "noise",
                               "level": level, "path": f"ref{r}_noise{level}.mkv"})
    manifest = parse_manifest({
        "study_id": "tiny-study", "root": "videos",
        "protocol": {"repetitions": repetitions, "blank_seconds": 0.5},
        "display": {"min_width": min_display[0], "min_height": min_display[1],
                    "min_refresh_hz": 59},
        "references": references, "conditions": conditions,
    })
    if briefing:
        (folder / "briefing.md").write_text(
            "# Welcome\n\nYou will see short videos and rate their quality.\n", encoding="utf-8")
    if consent:
        (folder / "consent.md").write_text("I agree that my ratings are stored.\n",
                                           encoding="utf-8")
    save_manifest(manifest, folder / "manifest.json")
    save_manifest(fill_checksums(load_manifest(folder / "manifest.json")),
                  folder / "manifest.json")
    return folder


@pytest.fixture
def study_factory():
    """``make_study`` for tests that need their own variant of the tiny study."""
    return make_study


@pytest.fixture
def tiny_study(tmp_path: Path) -> Path:
    return make_study(tmp_path / "study")


# -- GUI tests: private Xvfb displays and a driver for `cgvq-study run` ---------------------
REPO = Path(__file__).resolve().parents[2]
# Put first on PYTHONPATH, this folder makes torch, scipy, pandas ... unimportable (the
# participant's base install): every GUI run of the app proves it needs none of them.
LEAN_SITE = REPO / "tests" / "support" / "lean_site"


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
                 command: list[str] | None = None) -> None:
        """``command`` runs the app (default: this Python, in a process where the research
        stack cannot be imported, as in the participant's base install)."""
        self.env = env
        if command is None:
            command = [sys.executable, "-m", "cgvq_cli.study_cli"]
            env = {**env, "PYTHONPATH": f"{LEAN_SITE}{os.pathsep}{REPO}"}
        self.proc = subprocess.Popen(
            [*command, "-v", "run", *args], env=env, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self._pos = 0
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stderr:
            if "state:" in line or "error" in line.lower() or "Traceback" in line:
                self.lines.append(line.strip())

    def wait(self, state: str, timeout: float = 30.0, *, required: bool = True) -> str | None:
        """Wait for the next ``state: <state>`` line; returns it (None when not
        ``required`` and it did not come in time)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            while self._pos < len(self.lines):
                line = self.lines[self._pos]
                self._pos += 1
                if re.search(rf"state: {re.escape(state)}(\s|$)", line):
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
