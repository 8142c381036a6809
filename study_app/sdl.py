"""A few SDL2 queries Pygame does not expose (monitor names and bounds, the layout's key at a
scancode), through ctypes on the SDL library Pygame itself loaded.

Everything here is best effort: when the library cannot be found or a call fails, the
functions return None and the app falls back to what Pygame tells (display numbers, US key
names). Only call them after ``pygame.display.init()``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import logging
import sys
from pathlib import Path

log = logging.getLogger(__name__)


class _Rect(ctypes.Structure):
    _fields_ = [("x", ctypes.c_int), ("y", ctypes.c_int), ("w", ctypes.c_int),
                ("h", ctypes.c_int)]


def _candidates() -> list[str]:
    import pygame

    here = Path(pygame.__file__).resolve().parent
    out: list[str] = []
    if sys.platform.startswith("linux"):
        try:  # the exact library this process loaded
            with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
                for line in fh:
                    path = line.split()[-1] if "/" in line else ""
                    if "libSDL2-2" in path or path.endswith("libSDL2.so") or "libSDL2-2.0" in path:
                        out.append(path)
        except OSError:
            pass
        out += [str(p) for p in sorted((here.parent / "pygame.libs").glob("libSDL2-2*"))]
    elif sys.platform == "darwin":
        out += [str(p) for p in sorted((here / ".dylibs").glob("libSDL2*.dylib"))]
    elif sys.platform == "win32":
        out.append(str(here / "SDL2.dll"))
    found = ctypes.util.find_library("SDL2")
    if found:
        out.append(found)
    return list(dict.fromkeys(out))


@functools.cache
def _lib() -> ctypes.CDLL | None:
    for path in _candidates():
        try:
            lib = ctypes.CDLL(path)
            lib.SDL_GetNumVideoDisplays.restype = ctypes.c_int
            lib.SDL_GetDisplayName.restype = ctypes.c_char_p
            lib.SDL_GetDisplayName.argtypes = [ctypes.c_int]
            lib.SDL_GetDisplayBounds.argtypes = [ctypes.c_int, ctypes.POINTER(_Rect)]
            lib.SDL_GetDisplayBounds.restype = ctypes.c_int
            lib.SDL_GetKeyFromScancode.argtypes = [ctypes.c_int]
            lib.SDL_GetKeyFromScancode.restype = ctypes.c_int32
            lib.SDL_GetKeyName.argtypes = [ctypes.c_int32]
            lib.SDL_GetKeyName.restype = ctypes.c_char_p
            lib.SDL_GL_GetCurrentWindow.restype = ctypes.c_void_p
            lib.SDL_GL_GetCurrentWindow.argtypes = []
            lib.SDL_GetWindowDisplayIndex.argtypes = [ctypes.c_void_p]
            lib.SDL_GetWindowDisplayIndex.restype = ctypes.c_int
            lib.SDL_GetWindowPosition.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int),
                                                  ctypes.POINTER(ctypes.c_int)]
            lib.SDL_GetWindowPosition.restype = None
            return lib
        except (OSError, AttributeError) as exc:
            log.debug("SDL library %s unusable: %s", path, exc)
    return None


def display_name(index: int) -> str | None:
    """The monitor's name as the OS gives it (e.g. "DELL U2720Q"), or None."""
    lib = _lib()
    if lib is None:
        return None
    try:
        name = lib.SDL_GetDisplayName(int(index))
    except (OSError, ValueError):
        return None
    return name.decode("utf-8", "replace") if name else None


def display_bounds() -> list[tuple[int, int, int, int]] | None:
    """Each monitor's (x, y, w, h) on the desktop, in the OS's window coordinates."""
    lib = _lib()
    if lib is None:
        return None
    out = []
    try:
        for i in range(lib.SDL_GetNumVideoDisplays()):
            r = _Rect()
            if lib.SDL_GetDisplayBounds(i, ctypes.byref(r)) != 0:
                return None
            out.append((r.x, r.y, r.w, r.h))
    except (OSError, ValueError):
        return None
    return out


def window_placement() -> tuple[int, tuple[int, int]] | None:
    """The OpenGL window's monitor index and its position on the desktop, or None.

    Asked of SDL directly: Pygame's ``_sdl2.video.Window.from_display_module()`` would answer
    too, but it stores a pointer to itself in the SDL window without keeping itself alive, so
    once that object is freed every later window, key or mouse event makes Pygame take a
    reference to freed memory (the heap corruption that crashed the player at random)."""
    lib = _lib()
    if lib is None:
        return None
    try:
        window = lib.SDL_GL_GetCurrentWindow()
        if not window:
            return None
        index = lib.SDL_GetWindowDisplayIndex(window)
        x, y = ctypes.c_int(), ctypes.c_int()
        lib.SDL_GetWindowPosition(window, ctypes.byref(x), ctypes.byref(y))
    except (OSError, ValueError):
        return None
    if index < 0:
        return None
    return index, (x.value, y.value)


def layout_key_name(scancode: int) -> str | None:
    """What the current keyboard layout types with the key at ``scancode`` (e.g. "q" on
    AZERTY for the US "A" position), or None."""
    lib = _lib()
    if lib is None:
        return None
    try:
        name = lib.SDL_GetKeyName(lib.SDL_GetKeyFromScancode(int(scancode)))
    except (OSError, ValueError):
        return None
    text = name.decode("utf-8", "replace") if name else ""
    return text or None
