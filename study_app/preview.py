"""``cgvq-study preview``: the experimenter watches a study exactly as a participant will, and
nothing is recorded.

The same display, pre-loading, trial screen (looping test and reference, the blank on each
switch, the slider) and timing as a participant's run, composed without a session: no session
file, no run lock, nothing written into the study folder. On request a small timing overlay
sits in free space beside the video; at the end every stimulus's frames shown, dropped frames
and worst frame interval are printed, so the experimenter can tell whether a computer shows
the study cleanly before inviting anyone.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from session_store import PlannedTrial, TrialResult
from session_store.errors import StudyError
from session_store.study_folder import Study

from .decode import decode_pair
from .display import MIN_WINDOW, PACED_PILOT, Display
from .keys import Keymap
from .layout import Rect, ViewingLayout, ui_px
from .schedule import make_schedule, participant_seed, schedule_items
from .screens import preview_content
from .screens.draw import ON_GREY
from .text_screen import TextScreen
from .trial import TrialMachine
from .trial_screen import TrialScreen, upload_pair
from .waiting_screen import draw_checking_display, wait_for

log = logging.getLogger(__name__)
OVERLAY_MARGIN = 12


@dataclass
class PreviewOptions:
    """What ``cgvq-study preview`` was asked for."""

    stimulus: str | None = None
    windowed: bool = False
    window_size: tuple[int, int] | None = None
    refresh_hz: float | None = None
    force_pacer: bool = False
    timing_overlay: bool = False
    screenshots: Path | None = None


@dataclass
class PreviewRow:
    """One stimulus as previewed: how it was presented, and the rating given (not stored)."""

    stimulus: str
    frames_presented: int = 0
    dropped_frames: int = 0
    max_interval_ms: float = 0.0
    rating: float | None = None

    def line(self) -> str:
        rated = f"rated {self.rating:.1f} (not stored)" if self.rating is not None else \
            "not rated"
        return (f"{self.stimulus}: {self.frames_presented} frames shown, "
                f"{self.dropped_frames} dropped, worst interval {self.max_interval_ms:.1f} ms; "
                f"{rated}")


@dataclass
class PreviewResult:
    """Every stimulus previewed, in order, and the timing it ran with."""

    timing_mode: str
    refresh_hz: float
    rows: list[PreviewRow] = field(default_factory=list)
    total: int = 0

    @property
    def dropped(self) -> int:
        return sum(r.dropped_frames for r in self.rows)

    def lines(self) -> list[str]:
        head = (f"timing: {'vsync' if self.timing_mode != PACED_PILOT else 'paced (no vsync)'}"
                f" at {self.refresh_hz:.2f} Hz; {len(self.rows)} of {self.total} stimuli "
                f"previewed; {self.dropped} dropped frame(s) in all")
        return [head, *(r.line() for r in self.rows)]


def preview_trials(study: Study, stimulus: str | None) -> list[PlannedTrial]:
    """The stimuli to preview: one, or every stimulus once in a participant-like order."""
    items = schedule_items(study.manifest)
    if stimulus is not None:
        match = [i for i in items if i.id == stimulus]
        if not match:
            known = ", ".join(i.id for i in items[:5])
            raise StudyError(f"--stimulus {stimulus!r} is not a stimulus of study "
                             f"{study.manifest.study_id} (e.g. {known}"
                             f"{', ...' if len(items) > 5 else ''})")
        items = match
    seed = participant_seed(study.manifest.study_id, "preview")
    return make_schedule(items, 1, seed) if len(items) > 1 else [
        PlannedTrial(0, items[0].id, items[0].reference, 1, items[0].is_hidden_reference)]


def overlay_box(lay: ViewingLayout, size: tuple[int, int], window: tuple[int, int]
                ) -> Rect | None:
    """A corner of the window for a box of ``size`` that keeps off the video and every text
    of the viewing screen (None when no corner is free)."""
    w, h = size
    taken = [lay.video, *lay.text_rects()]
    if lay.label is not None:
        taken.append(lay.label)
    m = OVERLAY_MARGIN
    for x, y in ((m, m), (window[0] - w - m, m), (m, window[1] - h - m),
                 (window[0] - w - m, window[1] - h - m)):
        box = Rect(x, y, w, h)
        if box.inside(*window) and not any(box.intersects(t) for t in taken):
            return box
    return None


class TimingOverlay:
    """Draws the frame interval, the dropped frames so far and the refresh rate."""

    def __init__(self, display: Display) -> None:
        self.display = display
        self.px = max(12, ui_px(display.size) - 6)

    def text(self, m: TrialMachine) -> list[str]:
        iv = m.stats.intervals
        last = 1000.0 * iv[-1] if iv else 0.0
        return [f"frame {last:5.1f} ms (max {m.stats.max_interval_ms:.1f})",
                f"dropped {m.stats.dropped_frames} of {m.stats.frames_presented}",
                f"{self.display.refresh_hz:.1f} Hz {'vsync' if self.display.vsync else 'paced'}"]

    def __call__(self, r: Any, lay: ViewingLayout, m: TrialMachine) -> None:
        lines = self.text(m)
        sizes = [r.text_size(t, self.px) for t in lines]
        w = max(s[0] for s in sizes) + 16
        h = sum(s[1] for s in sizes) + 12
        box = overlay_box(lay, (w, h), self.display.size)
        if box is None:
            return
        r.rect(box.x, box.y, box.w, box.h, (0.0, 0.0, 0.0, 0.55))
        y = box.y + 6
        for text, (_, th) in zip(lines, sizes, strict=True):
            r.text(text, box.x + 8, y, px=self.px, color=ON_GREY)
            y += th


class Preview:
    """The preview on one display; :meth:`run` returns the :class:`PreviewResult`."""

    def __init__(self, study: Study, opts: PreviewOptions) -> None:
        self.study = study
        self.opts = opts
        self.trials = preview_trials(study, opts.stimulus)
        self.display: Display | None = None
        self._shots: set[str] = set()

    @staticmethod
    def _name_keys(keys: Keymap, action: str) -> str:
        from . import sdl

        return keys.label(action, sdl.layout_key_name)

    def _window_for(self) -> tuple[int, int]:
        """Windowed: room for the largest reference plus labels and hints (as a run)."""
        refs = self.study.manifest.references
        w = max((r.width or 0 for r in refs), default=0)
        h = max((r.height or 0 for r in refs), default=0)
        return max(MIN_WINDOW[0], w + 640), max(MIN_WINDOW[1], h + 120)

    def _state(self, name: str, **kw: Any) -> None:
        log.debug("state: %s%s", name, "".join(f" {k}={v}" for k, v in kw.items()))

    def _shot(self, name: str) -> bool:
        if self.opts.screenshots is None or name in self._shots or self.display is None:
            return False
        from PIL import Image

        self.opts.screenshots.mkdir(parents=True, exist_ok=True)
        file = name if name.startswith("preview") else f"preview-{name}"
        Image.fromarray(self.display.renderer.read_pixels()).save(
            self.opts.screenshots / f"{file}.png")
        self._shots.add(name)
        return True

    def _screen(self, spec: Any) -> str:
        def closed() -> None:
            raise _StopPreviewError

        return TextScreen(self.display, self._state, self._shot, closed).show(spec)

    def run(self) -> PreviewResult:
        d = self.display = Display(
            windowed=self.opts.windowed or self.opts.window_size is not None,
            window_size=self.opts.window_size or self._window_for(),
            refresh_hz=self.opts.refresh_hz, force_pacer=self.opts.force_pacer)
        try:
            self._state("checking-display")
            d.measure_refresh(draw=lambda i: draw_checking_display(d, i))
            d.set_timing(pilot_allowed=True)  # a preview paces flips where vsync is missing
            result = PreviewResult(d.timing_mode, d.refresh_hz, total=len(self.trials))
            try:
                if self._screen(preview_content.intro(
                        self.study.manifest.study_id, len(self.trials),
                        "vsync" if d.vsync else f"paced at {d.refresh_hz:g} Hz (no vsync)",
                        self.opts.timing_overlay, self._name_keys)) == "go":
                    self._trials(result)
                self._screen(preview_content.summary(result.lines(), self._name_keys))
            except _StopPreviewError:
                pass
            return result
        finally:
            d.close()

    def _trials(self, result: PreviewResult) -> None:
        overlay = TimingOverlay(self.display) if self.opts.timing_overlay else None
        proto = self.study.manifest.protocol
        loaded = self.study.loaded
        for k, trial in enumerate(self.trials, start=1):
            pair = wait_for(self.display, lambda t=trial: decode_pair(
                t.stimulus, loaded.stimulus_path(t.stimulus), loaded.reference_path(t.reference)),
                "Loading...", _raise_stop)
            gpu = upload_pair(self.display, pair)
            del pair
            min_view = proto.min_view_seconds if proto.min_view_seconds is not None else (
                gpu.frames / gpu.fps)
            screen = TrialScreen(
                self.display, self.study.manifest, self._name_keys, self._state, self._shot,
                lambda _trial: None, lambda v=min_view: v, overlay)
            row = PreviewRow(trial.stimulus)
            try:
                while True:
                    outcome = screen.run(trial, gpu, k, len(self.trials))
                    if isinstance(outcome, TrialResult):
                        break
                    if outcome == "close" or self._screen(preview_content.paused(
                            k - 1, len(self.trials), self._name_keys)) == "stop":
                        return
            finally:
                gpu.release()
            row.frames_presented = outcome.frames_presented
            row.dropped_frames = outcome.dropped_frames
            row.max_interval_ms = outcome.max_flip_interval_ms
            row.rating = outcome.rating
            self._state("previewed", stimulus=trial.stimulus,
                        dropped=outcome.dropped_frames)
            result.rows.append(row)


class _StopPreviewError(Exception):
    """The window was closed: stop the preview (nothing to save)."""


def _raise_stop() -> None:
    raise _StopPreviewError


def run_preview(study: Study, opts: PreviewOptions) -> PreviewResult:
    """Preview ``study`` (see the module doc)."""
    return Preview(study, opts).run()
