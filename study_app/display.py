"""The participant's window: OpenGL context, DPI awareness, measured (vsync'd) flips.

Timing modes: ``vsync`` (the participant's mode: the driver waits for the display's refresh
at every flip, and the refresh rate is measured from those flips) and ``paced-pilot`` (an
experimenter's pilot/test mode for displays without vsync, e.g. a virtual X display: flips are
paced on the monotonic clock by :class:`~study_app.clock.FlipPacer`). The window is DPI-aware
(Windows per-monitor awareness; macOS high-DPI framebuffers are drawn in their own pixels), so
a video pixel is a physical pixel wherever the pre-flight passes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
import warnings
from typing import Any

from session_store.errors import StudyError

from .clock import FlipPacer
from .preflight import Monitor, PixelGeometry
from .vsync import MIN_FLIPS, RefreshEstimate, estimate_refresh

log = logging.getLogger(__name__)

VSYNC, PACED_PILOT = "vsync", "paced-pilot"
MIN_WINDOW = (800, 600)


# -- DPI ----------------------------------------------------------------------------------
# Windows DPI awareness levels (GetAwarenessFromDpiAwarenessContext).
DPI_UNAWARE, DPI_SYSTEM_AWARE, DPI_PER_MONITOR_AWARE = 0, 1, 2


def windows_stretches(awareness: int | None, monitor_scale: float | None,
                      system_scale: float | None) -> bool:
    """Whether Windows resamples a window of a process with this DPI awareness.

    Per-monitor aware windows are never scaled; a system-aware one is scaled where its
    monitor's scale differs from the system's; an unaware one wherever the scale is not 100%.
    """
    if awareness == DPI_PER_MONITOR_AWARE:
        return False
    scale = monitor_scale or 1.0
    if awareness == DPI_SYSTEM_AWARE:
        return abs(scale - (system_scale or 1.0)) > 1e-3
    return abs(scale - 1.0) > 1e-3


def enable_dpi_awareness() -> str:
    """Ask the OS for 1:1 pixels before the window opens; returns what was obtained."""
    if sys.platform == "darwin":
        # The app draws in the framebuffer's own pixels (twice the window size on a Retina
        # screen when SDL gives a high-DPI framebuffer); nothing to ask for.
        return "framebuffer-pixels"
    if sys.platform != "win32":
        return "not-needed"
    os.environ.setdefault("SDL_WINDOWS_DPI_AWARENESS", "permonitorv2")
    import ctypes

    try:
        # DPI_AWARENESS_CONTEXT_PER_MONITOR_AWARE_V2 = -4 (Windows 10 1703+).
        if ctypes.windll.user32.SetProcessDpiAwarenessContext(ctypes.c_void_p(-4)):
            return "per-monitor-v2"
    except (AttributeError, OSError):
        pass
    try:
        # PROCESS_PER_MONITOR_DPI_AWARE = 2 (Windows 8.1+); fails if already set.
        if ctypes.windll.shcore.SetProcessDpiAwareness(2) == 0:
            return "per-monitor"
    except (AttributeError, OSError):
        pass
    try:
        ctypes.windll.user32.SetProcessDPIAware()
        return "system"
    except (AttributeError, OSError):
        return "unknown"


def _windows_scale(hwnd: int) -> tuple[int | None, float | None, float | None]:
    """(awareness, the window's monitor scale, the system scale) on Windows."""
    import ctypes
    from ctypes import wintypes

    awareness = monitor_scale = system_scale = None
    user32 = ctypes.windll.user32
    with contextlib.suppress(AttributeError, OSError):
        user32.GetThreadDpiAwarenessContext.restype = ctypes.c_void_p
        user32.GetAwarenessFromDpiAwarenessContext.argtypes = [ctypes.c_void_p]
        awareness = int(user32.GetAwarenessFromDpiAwarenessContext(
            user32.GetThreadDpiAwarenessContext()))
    with contextlib.suppress(AttributeError, OSError):
        user32.MonitorFromWindow.restype = ctypes.c_void_p
        user32.MonitorFromWindow.argtypes = [wintypes.HWND, wintypes.DWORD]
        monitor = user32.MonitorFromWindow(hwnd, 2)  # MONITOR_DEFAULTTONEAREST
        dx, dy = wintypes.UINT(), wintypes.UINT()
        if ctypes.windll.shcore.GetDpiForMonitor(ctypes.c_void_p(monitor), 0,
                                                 ctypes.byref(dx), ctypes.byref(dy)) == 0:
            monitor_scale = dx.value / 96.0
    with contextlib.suppress(AttributeError, OSError):
        system_scale = user32.GetDpiForSystem() / 96.0
    return awareness, monitor_scale, system_scale


# -- the window ---------------------------------------------------------------------------
class Display:
    """A Pygame OpenGL window with a ModernGL context and measured flips."""

    def __init__(self, *, windowed: bool, window_size: tuple[int, int] | None,
                 refresh_hz: float | None = None, force_pacer: bool = False,
                 min_window: tuple[int, int] = MIN_WINDOW) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        os.environ.setdefault("SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS", "0")
        self.dpi_awareness = enable_dpi_awareness()
        self.priority: str | None = None  # what realtime.raise_priority() was granted
        import moderngl
        import pygame

        from .fonts import Fonts
        from .render import Renderer

        self.pg = pygame
        try:
            pygame.display.init()
        except pygame.error as exc:
            raise StudyError(f"cannot open a window ({exc}); run the study on a computer with "
                             "a screen and a desktop session") from None
        for attr, value in ((pygame.GL_CONTEXT_MAJOR_VERSION, 3),
                            (pygame.GL_CONTEXT_MINOR_VERSION, 3),
                            (pygame.GL_CONTEXT_PROFILE_MASK, pygame.GL_CONTEXT_PROFILE_CORE),
                            (pygame.GL_DOUBLEBUFFER, 1)):
            pygame.display.gl_set_attribute(attr, value)
        sizes = pygame.display.get_desktop_sizes()
        desktop = tuple(sizes[0]) if sizes else (0, 0)
        flags = pygame.OPENGL | pygame.DOUBLEBUF
        if windowed:
            w, h = window_size or min_window
            size = (min(w, desktop[0] or w), min(h, desktop[1] or h))
        else:
            flags |= pygame.FULLSCREEN
            size = desktop
        self.force_pacer = force_pacer
        self.vsync_requested = not force_pacer
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                pygame.display.set_mode(size, flags, vsync=0 if force_pacer else 1)
            except pygame.error:
                try:
                    pygame.display.set_mode(size, flags)
                except pygame.error as exc:
                    raise StudyError(f"cannot open an OpenGL window ({exc}); update the "
                                     "graphics driver") from None
                self.vsync_requested = False
        if any("vsync" in str(w.message).lower() for w in caught):
            self.vsync_requested = False
        pygame.display.set_caption("Video quality study")
        pygame.mouse.set_visible(True)
        try:
            self.ctx = moderngl.create_context(require=330)
        except Exception as exc:
            raise StudyError(f"OpenGL 3.3 is not available ({exc}); update the graphics "
                             "driver") from None
        self.window_size: tuple[int, int] = tuple(pygame.display.get_window_size())
        self.drawable_size: tuple[int, int] = tuple(self.ctx.screen.viewport[2:])
        self.size = self.drawable_size  # drawing happens in framebuffer pixels
        self.fonts = Fonts()
        self.renderer = Renderer(self.ctx, self.size, self.fonts)
        self.configured_hz = refresh_hz
        self.timing_mode = VSYNC
        self.vsync = False
        self.refresh_hz = refresh_hz or 60.0
        self.estimate: RefreshEstimate | None = None
        self.pacer: FlipPacer | None = None

    # -- geometry ---------------------------------------------------------------------
    @property
    def pixel_ratio(self) -> float:
        return self.drawable_size[0] / self.window_size[0] if self.window_size[0] else 1.0

    def to_pixels(self, pos: tuple[float, float]) -> tuple[float, float]:
        """Mouse position (window units) to framebuffer pixels."""
        r = self.pixel_ratio
        return pos[0] * r, pos[1] * r

    def geometry(self) -> PixelGeometry:
        """Where the window is and how its pixels reach the monitor."""
        from . import sdl

        pg = self.pg
        placement = sdl.window_placement()
        index, pos = placement if placement is not None else (None, None)
        bounds = sdl.display_bounds()
        if not bounds:
            sizes = pg.display.get_desktop_sizes()
            bounds = [(0, 0, w, h) for w, h in sizes]
        monitors = tuple(Monitor(i, sdl.display_name(i) or f"display {i + 1}", tuple(b))
                         for i, b in enumerate(bounds))
        os_scale = None
        stretches = False
        if sys.platform == "win32":
            with contextlib.suppress(Exception):
                hwnd = pg.display.get_wm_info()["window"]
                awareness, os_scale, system_scale = _windows_scale(hwnd)
                stretches = windows_stretches(awareness, os_scale, system_scale)
        elif sys.platform == "darwin":
            os_scale = self.pixel_ratio
        return PixelGeometry(self.window_size, self.drawable_size, monitors, pos, index,
                             os_scale, stretches)

    def monitor_pixels(self, geom: PixelGeometry) -> tuple[int, int]:
        """Resolution in pixels of the monitor the window is on."""
        mon = geom.monitor()
        if mon is None:
            return self.drawable_size
        r = geom.pixel_ratio
        return round(mon.bounds[2] * r), round(mon.bounds[3] * r)

    # -- timing -----------------------------------------------------------------------
    def measure_refresh(self, draw: Any = None, n: int = 90) -> RefreshEstimate:
        """Flip ``n`` times with vsync requested and estimate the refresh from the flips."""
        times = []
        for i in range(-3, max(n, MIN_FLIPS + 1)):  # 3 untimed flips: shaders, text textures
            if draw is not None:
                draw(i)
            else:
                self.renderer.clear()
            self.pg.display.flip()
            self.ctx.finish()
            if i >= 0:
                times.append(time.perf_counter())
            self.pg.event.pump()
        est = estimate_refresh(times)
        if not self.vsync_requested:
            # The driver refused vsync (or the experimenter turned it off): whatever pace
            # the flips had, it was not the display's.
            est = RefreshEstimate(est.n_intervals, False, 0.0, 0.0, 0.0, 0, 0)
        self.estimate = est
        return est

    def set_timing(self, *, pilot_allowed: bool) -> str:
        """Choose the timing mode after :meth:`measure_refresh`; returns it."""
        est = self.estimate
        if est is not None and est.vsync and not self.force_pacer:
            self.timing_mode, self.vsync, self.pacer = VSYNC, True, None
            self.refresh_hz = est.hz
        elif pilot_allowed or self.force_pacer:
            self.timing_mode, self.vsync = PACED_PILOT, False
            self.refresh_hz = self.configured_hz or 60.0
            self.pacer = FlipPacer(self.refresh_hz)
        else:  # no vsync and no pilot: the pre-flight fails; pace the failure screen
            self.timing_mode, self.vsync = VSYNC, False
            self.refresh_hz = 60.0
            self.pacer = FlipPacer(self.refresh_hz)
        log.info("display %dx%d (drawable %dx%d), timing %s, vsync %s, refresh %.2f Hz",
                 *self.window_size, *self.drawable_size, self.timing_mode, self.vsync,
                 self.refresh_hz)
        return self.timing_mode

    @property
    def period(self) -> float:
        return 1.0 / self.refresh_hz

    def flip(self) -> float:
        """Show the back buffer at the next refresh; returns the flip's monotonic time."""
        if self.pacer is not None:
            # Rasterise now (software renderers defer it to the swap), so the swap itself is
            # a short copy that lands right on the paced slot.
            self.ctx.finish()
            self.pacer.wait()
        self.pg.display.flip()
        if self.vsync:
            self.ctx.finish()
        return time.perf_counter()

    def info(self, geom: PixelGeometry | None = None) -> dict[str, Any]:
        mon = geom.monitor() if geom is not None else None
        return {
            "screen": list(self.monitor_pixels(geom)) if geom else list(self.drawable_size),
            "window": list(self.window_size), "drawable": list(self.drawable_size),
            "pixel_ratio": self.pixel_ratio, "vsync": self.vsync,
            "timing_mode": self.timing_mode, "refresh_hz": round(self.refresh_hz, 3),
            "refresh_source": "measured" if self.vsync else "configured",
            "refresh_estimate": self.estimate.as_dict() if self.estimate else None,
            "monitor": mon.name if mon else None,
            "monitor_index": mon.index if mon else None,
            "monitors": len(geom.monitors) if geom else None,
            "os_scale": geom.os_scale if geom else None,
            "dpi_awareness": self.dpi_awareness,
            "priority": self.priority,
            "gl_renderer": self.ctx.info.get("GL_RENDERER"),
            "gl_version": self.ctx.info.get("GL_VERSION"),
            "video_driver": self.pg.display.get_driver(),
        }

    def close(self) -> None:
        self.pg.display.quit()
