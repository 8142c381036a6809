"""Where the player's window is, asked without leaving a dangling pointer in SDL.

Pygame's ``_sdl2.video.Window.from_display_module()`` stores a pointer to itself in the SDL
window ("pg_window") but does not keep itself alive; once it was freed, every later key, mouse
or window event made ``pygame.event.get()`` take a reference to freed memory. That corrupted
the heap and crashed the preview at random. The real window under Xvfb, in a child process
(a crash there fails this test instead of killing pytest)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.gui

REPO = Path(__file__).resolve().parents[2]

CHILD = r"""
import ctypes, json, subprocess, sys, time
from study_app import sdl
from study_app.display import Display

d = Display(windowed=True, window_size=(320, 240))
geom = d.geometry()
lib = sdl._lib()
lib.SDL_GetWindowData.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
lib.SDL_GetWindowData.restype = ctypes.c_void_p
window_data = lib.SDL_GetWindowData(lib.SDL_GL_GetCurrentWindow(), b"pg_window")
# events for the window: every one of them asks SDL for "pg_window"
x, y = geom.window_pos or (0, 0)
windows = []
for i in range(40):
    subprocess.run(["xdotool", "mousemove", str(x + 10 + 5 * i), str(y + 10 + 3 * i)],
                   check=True)
    for event in d.pg.event.get():
        if hasattr(event, "window"):
            windows.append(repr(event.window))
    d.flip()
xid = d.pg.display.get_wm_info()["window"]
xdo = subprocess.run(["xdotool", "getwindowgeometry", "--shell", str(xid)],
                     capture_output=True, text=True, check=True).stdout
fields = dict(line.split("=", 1) for line in xdo.split())
print(json.dumps({"pos": geom.window_pos, "index": geom.monitor_index,
                  "monitors": len(geom.monitors), "window_data": window_data,
                  "event_windows": windows,
                  "xdotool_pos": [int(fields["X"]), int(fields["Y"])]}))
d.close()
"""


def test_geometry_matches_the_x_server_and_leaves_no_pointer_in_the_sdl_window(xvfb_factory):
    env = xvfb_factory((1280, 1024))
    proc = subprocess.run([sys.executable, "-c", CHILD], env={**env, "PYTHONPATH": str(REPO)},
                          capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    # the window's place as the X server reports it (no window manager: no decorations)
    assert out["pos"] == out["xdotool_pos"]
    assert out["index"] == 0 and out["monitors"] == 1
    # nothing of Python's stored in the SDL window, so events carry window=None
    assert out["window_data"] is None
    assert out["event_windows"] and set(out["event_windows"]) == {"None"}
