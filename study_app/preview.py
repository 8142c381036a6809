"""``cgvq-study preview``: the experimenter watches a study's trials as a participant will, and
nothing is recorded.

The same display, refresh measurement, real-time guard, pre-loading (the next stimulus decodes
in the background while the current one is rated), trial screen (looping test and reference,
the blank on each switch, the slider) and timing as a participant's run, composed without a
session: no session file, no ``sessions/`` folder, no run lock, nothing written into the study
folder. The display checks of the pre-flight run and are reported (on the first screen and in
the summary) but do not stop the preview, as with ``run --skip-preflight``; the only refusal
is a screen or window too small to show the videos at 1:1 pixels. Without vsync the flips are
paced on the clock (the pilot mode of ``run``), which the summary says.

On request a small overlay (the stimulus's id and its timing) sits in free space off the video
and the screen's texts; at
the end (or when stopped early) every stimulus's frames shown, dropped frames, worst frame
interval and the rating given (not stored) are listed, so the experimenter can tell whether
this computer shows the study cleanly before inviting anyone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from session_store import PlannedTrial, TrialResult
from session_store.errors import StudyError
from session_store.schedule import make_schedule, participant_seed, schedule_items
from session_store.study_folder import Study

from . import realtime
from .app import RunOptions
from .clock import FlipStats
from .decode import DecodedPair, Prefetcher, decode_pair, pair_bytes
from .display import MIN_WINDOW, PACED_PILOT, Display
from .duration import estimate_minutes, session_trials
from .keys import Keymap
from .layout import GAP, Rect, ViewingLayout, ui_px
from .preflight import (
    Check,
    available_memory_bytes,
    check_checksums,
    check_decode_speed,
    check_memory,
    check_pixel_mapping,
    check_refresh,
    check_screen,
)
from .screens import preview_content
from .screens.draw import ON_GREY
from .text_screen import TextScreen
from .trial import TrialMachine
from .trial_screen import TrialScreen, upload_pair, viewing_layout_for
from .waiting_screen import draw_checking_display, wait_for

__all__ = ["PreviewOptions", "PreviewResult", "PreviewRow", "overlay_box", "preview_trials",
           "run_preview"]

log = logging.getLogger(__name__)
OVERLAY_MARGIN = 12
OVERLAY_UPDATE_S = 0.25
"""The overlay's figures change four times a second: readable, and few new text textures."""
OVERLAY_TEMPLATE = ("scene_method_L0", "frame 000.0 ms, worst 000.0",
                    "dropped 0000 (0000 in all), missed 0000", "000.00 Hz paced (no vsync)")
"""The widest the overlay's lines get: its box keeps this size while the figures change."""
REQUEUE_LIMIT = RunOptions.max_dropped_frames
"""A participant's run re-queues a trial with more dropped frames than this (its default)."""


@dataclass
class PreviewOptions:
    """What ``cgvq-study preview`` was asked for."""

    stimulus: str | None = None
    windowed: bool = False
    window_size: tuple[int, int] | None = None
    refresh_hz: float | None = None
    force_pacer: bool = False
    pilot_no_vsync: bool = False
    """Accepted as in ``run``; a preview paces flips on the clock wherever vsync is missing."""
    timing_overlay: bool = False
    screenshots: Path | None = None

    def validate(self) -> None:
        """The window size and pacing rate are refused as ``run`` refuses them."""
        RunOptions(participant="preview", windowed=self.windowed, window_size=self.window_size,
                   refresh_hz=self.refresh_hz, force_pacer=self.force_pacer,
                   pilot_no_vsync=True).validate()


@dataclass
class PreviewRow:
    """One stimulus as previewed: how it was presented, and the rating given (not stored).

    A stimulus continued after a pause starts again; its figures add up over the starts."""

    stimulus: str
    frames_presented: int = 0
    dropped_frames: int = 0
    """Late flips."""
    missed_refreshes: int = 0
    """Refreshes those flips hid (a 1 s freeze at 60 Hz: one late flip, 59 missed): what a
    participant's run re-queues a trial by."""
    max_interval_ms: float = 0.0
    rating: float | None = None
    seconds: float = 0.0
    """From the stimulus's start to its rating (pauses aside): the experimenter's pace."""

    def add(self, stats: FlipStats) -> None:
        self.frames_presented += stats.frames_presented
        self.dropped_frames += stats.dropped_frames
        self.missed_refreshes += stats.missed_refreshes
        self.max_interval_ms = max(self.max_interval_ms, stats.max_interval_ms)

    @property
    def would_requeue(self) -> bool:
        return self.missed_refreshes > REQUEUE_LIMIT

    def line(self) -> str:
        rated = (f"rated {self.rating:.1f} (not stored)" if self.rating is not None else
                 "stopped before rating")
        n = self.missed_refreshes
        missed = (f" ({n} refresh{'es' if n != 1 else ''} missed"
                  + ("; a run would re-queue it" if self.would_requeue else "") + ")"
                  if self.dropped_frames else "")
        return (f"{self.stimulus}: {self.frames_presented} frames shown, "
                f"{self.dropped_frames} dropped{missed}, worst interval "
                f"{self.max_interval_ms:.1f} ms; {rated}")


@dataclass
class PreviewResult:
    """Every stimulus previewed, in order, the timing it ran with and the display checks."""

    timing_mode: str
    refresh_hz: float
    rows: list[PreviewRow] = field(default_factory=list)
    total: int = 0
    checks: list[Check] = field(default_factory=list)
    overlay_note: str | None = None
    failure: str | None = None
    """Why the preview stopped before its end (a video that would not decode), if it did."""
    session_trials: int = 0
    """Rated trials in a participant's whole session, for the pace line."""
    told: str = ""
    """The duration a participant is told before the session starts."""

    @property
    def dropped(self) -> int:
        return sum(r.dropped_frames for r in self.rows)

    @property
    def paced(self) -> bool:
        return self.timing_mode == PACED_PILOT

    def timing(self) -> str:
        return "paced on the clock (no vsync)" if self.paced else "vsync"

    def verdict(self) -> str:
        """Can this computer show the study? One sentence."""
        rows = [r for r in self.rows if r.frames_presented]
        if self.failure is not None:
            return (f"verdict: stopped, {self.failure}; a participant's run would refuse this "
                    "study: run 'cgvq-study check'")
        if not rows:
            return "verdict: no stimulus was shown"
        if self.dropped:
            bad = [r for r in rows if r.dropped_frames]
            worst = max(r.max_interval_ms for r in rows)
            requeued = [r.stimulus for r in rows if r.would_requeue]
            run = (f"a run would re-queue {', '.join(requeued)} (more than {REQUEUE_LIMIT} "
                   "refreshes missed)" if requeued else
                   f"a run re-queues a trial with more than {REQUEUE_LIMIT} refreshes missed")
            return (f"verdict: {self.dropped} dropped frame(s) in {len(bad)} of {len(rows)} "
                    f"stimuli (worst interval {worst:.1f} ms): close other programs or use a "
                    f"faster computer before inviting participants ({run})")
        if self.paced:
            return ("verdict: no dropped frames, but the flips were paced on the clock without "
                    "vsync, as in run's pilot mode: a participant's run needs vsync on this "
                    "computer")
        return (f"verdict: no dropped frames with vsync at {self.refresh_hz:.2f} Hz: this "
                "computer shows the study cleanly")

    def pace(self) -> str | None:
        """The experimenter's time per stimulus, and what a whole session takes at it next to
        what a participant is told: a first check of the duration in the invitation."""
        times = sorted(r.seconds for r in self.rows if r.rating is not None)
        if not times:
            return None
        mid = len(times) // 2
        median = times[mid] if len(times) % 2 else (times[mid - 1] + times[mid]) / 2
        minutes = self.session_trials * median / 60
        took = f"about {round(minutes)} min" if minutes >= 1 else "under a minute"
        whole = (f"; a participant's session of {self.session_trials} trials takes {took} "
                 f"at this pace, breaks aside (participants are "
                 f"told {self.told})" if self.session_trials and self.told else "")
        return (f"pace: median {median:.1f} s per stimulus from its start to the rating "
                f"({len(times)} rated){whole}")

    def lines(self) -> list[str]:
        rated = sum(1 for r in self.rows if r.rating is not None)
        stopped = len(self.rows) - rated
        head = (f"timing: {self.timing()} at {self.refresh_hz:.2f} Hz; {rated} of {self.total} "
                f"stimuli previewed{f', {stopped} stopped early' if stopped else ''}; "
                f"{self.dropped} dropped frame(s) in all")
        checks = [f"pre-flight {c.name}: {_check_state(c)}: {c.message}" for c in self.checks]
        note = [self.overlay_note] if self.overlay_note else []
        pace = [p] if (p := self.pace()) else []
        return [head, *(r.line() for r in self.rows), *pace, *checks, *note, self.verdict()]


def _check_state(c: Check) -> str:
    return "not met (reported only)" if not c.ok else "ok, with a warning" if c.warning else "ok"


def preview_trials(study: Study, stimulus: str | None) -> list[PlannedTrial]:
    """The stimuli to preview: one, or every stimulus once (hidden references included) in a
    seeded participant-like order (no stimulus twice in a row, no repetitions)."""
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
    """A place for a box of ``size`` that keeps off the video (and the gap the layout keeps
    free around it) and every text of the viewing screen: a corner of the window where one
    is free, else the first free spot from the top; None when there is none."""
    w, h = size
    vid = lay.video
    taken = [Rect(vid.x - GAP, vid.y - GAP, vid.w + 2 * GAP, vid.h + 2 * GAP),
             *lay.text_rects()]
    if lay.label is not None:
        taken.append(lay.label)
    m = OVERLAY_MARGIN

    def free(box: Rect) -> bool:
        return box.inside(*window) and not any(box.intersects(t) for t in taken)

    for x, y in ((m, m), (window[0] - w - m, m), (m, window[1] - h - m),
                 (window[0] - w - m, window[1] - h - m)):
        if free(box := Rect(x, y, w, h)):
            return box
    step = 8
    for y in range(m, window[1] - h - m + 1, step):
        for x in range(m, window[0] - w - m + 1, step):
            if free(box := Rect(x, y, w, h)):
                return box
    return None


class TimingOverlay:
    """Draws the frame interval, the dropped frames so far and the refresh rate beside the
    video (:class:`TrialScreen`'s overlay hook).

    It reads the trial's flip times incrementally and renews its text four times a second,
    so that it costs the presentation loop next to nothing; its box keeps one size and one
    place per trial."""

    def __init__(self, display: Display, result: PreviewResult) -> None:
        self.display = display
        self.result = result
        self.px = max(12, ui_px(display.size) - 6)
        self._machine: TrialMachine | None = None
        self._layout: ViewingLayout | None = None
        self._box: Rect | None = None
        self._width = 0
        self._lines: list[str] = []
        self.never_fitted = True
        self.missing = False
        self.stimulus = ""
        """The stimulus on screen, named on the overlay's first line (the preview is the
        experimenter's: which video it is matters when judging the levels)."""

    def _start(self, m: TrialMachine) -> None:
        self._machine = m
        self._seen = 0
        self._dropped = 0
        self._missed = 0
        self._worst = 0.0
        self._recent = 0.0
        self._next = 0.0

    def _read(self, m: TrialMachine) -> None:
        iv = m.stats.intervals
        for d in iv[self._seen:]:
            missed = m.stats.missed_by(d)
            self._dropped += missed > 0
            self._missed += missed
            self._worst = max(self._worst, d)
            self._recent = max(self._recent, d)
        self._seen = len(iv)

    def text(self, m: TrialMachine) -> list[str]:
        """The overlay's lines now (and forget the interval of the period just shown)."""
        d = self.display
        before = sum(r.dropped_frames for r in self.result.rows)
        lines = [self.stimulus,
                 f"frame {1000 * self._recent:.1f} ms, worst {1000 * self._worst:.1f}",
                 f"dropped {self._dropped} ({before + self._dropped} in all), "
                 f"missed {self._missed}",
                 f"{d.refresh_hz:.2f} Hz {'vsync' if d.vsync else 'paced (no vsync)'}"]
        self._recent = 0.0
        return lines

    def _place(self, r: Any, lay: ViewingLayout) -> None:
        """Find the box's place when the layout changes (or its text outgrows it), never
        on every refresh: the search is not for the presentation loop."""
        sizes = [r.text_size(t, self.px) for t in (*OVERLAY_TEMPLATE, *self._lines)]
        w = max(s[0] for s in sizes) + 16
        h = sum(s[1] for s in sizes[:len(OVERLAY_TEMPLATE)]) + 12
        if self._layout is lay and w <= self._width:
            return
        self._layout, self._width = lay, w
        self._box = overlay_box(lay, (w, h), self.display.size)
        if self._box is None:
            self.missing = True
            log.info("timing overlay: no free %dx%d place beside the video", w, h)
        else:
            self.never_fitted = False

    def __call__(self, r: Any, lay: ViewingLayout, m: TrialMachine) -> None:
        if m is not self._machine:
            self._start(m)
        self._read(m)
        now = time.perf_counter()
        if now >= self._next or not self._lines:
            self._lines = self.text(m)
            self._next = now + OVERLAY_UPDATE_S
            self._place(r, lay)
        elif self._layout is not lay:
            self._place(r, lay)
        box = self._box
        if box is None:
            return
        r.rect(box.x, box.y, box.w, box.h, (0.0, 0.0, 0.0, 0.55))
        y = box.y + 6
        for text in self._lines:
            h = r.text(text, box.x + 8, y, px=self.px, color=ON_GREY)[1]
            y += h


class _StopPreviewError(Exception):
    """The window was closed: stop the preview (nothing to save)."""


class Preview:
    """The preview on one display; :meth:`run` returns the :class:`PreviewResult`."""

    def __init__(self, study: Study, opts: PreviewOptions) -> None:
        opts.validate()
        self.study = study
        self.m = study.manifest
        self.opts = opts
        self.trials = preview_trials(study, opts.stimulus)
        self.display: Display | None = None
        self.prefetch = Prefetcher()
        self.closed = False
        self._first: DecodedPair | None = None
        self._shots: set[str] = set()

    # -- utilities (as the app's) -----------------------------------------------------
    @staticmethod
    def _name_keys(keys: Keymap, action: str) -> str:
        from . import sdl

        return keys.label(action, sdl.layout_key_name)

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

    def _on_close(self) -> None:
        self.closed = True
        raise _StopPreviewError

    def _screen(self, spec: Any) -> str:
        return TextScreen(self.display, self._state, self._shot, self._on_close).show(spec)

    def _paths(self, trial: PlannedTrial) -> tuple[Path, Path]:
        loaded = self.study.loaded
        return loaded.stimulus_path(trial.stimulus), loaded.reference_path(trial.reference)

    def _window_for(self) -> tuple[int, int]:
        """Windowed: room for the largest reference plus labels and hints (as a run)."""
        w, h = self._manifest_video()[:2]
        return max(MIN_WINDOW[0], w + 640), max(MIN_WINDOW[1], h + 120)

    def _manifest_video(self) -> tuple[int, int, int]:
        refs = self.m.references
        return (max((r.width or 0 for r in refs), default=0),
                max((r.height or 0 for r in refs), default=0),
                max((r.frames or 0 for r in refs), default=0))

    # -- the preview --------------------------------------------------------------------
    def run(self) -> PreviewResult:
        d = self.display = Display(
            windowed=self.opts.windowed or self.opts.window_size is not None,
            window_size=self.opts.window_size or self._window_for(),
            refresh_hz=self.opts.refresh_hz, force_pacer=self.opts.force_pacer)
        try:
            d.priority = realtime.raise_priority()
            self._state("checking-display")
            d.measure_refresh(draw=lambda i: draw_checking_display(d, i))
            d.set_timing(pilot_allowed=True)  # a preview paces flips where vsync is missing
            result = PreviewResult(d.timing_mode, d.refresh_hz, total=len(self.trials),
                                   session_trials=session_trials(self.m))
            try:
                self._first, checksums = wait_for(d, lambda: (
                    decode_pair(self.trials[0].stimulus, *self._paths(self.trials[0])),
                    check_checksums(self.study)), "Preparing the videos...", self._on_close)
                result.checks = [*self._preflight(self._first), checksums]
                timing = "vsync" if d.vsync else f"paced at {d.refresh_hz:g} Hz (no vsync)"
                if self._screen(preview_content.intro(
                        self.m.study_id, len(self.trials), timing, self.opts.timing_overlay,
                        result.checks, self._name_keys)) == "go":
                    self._trials(result)
                    if not self.closed:
                        self._screen(preview_content.summary(
                            result.verdict(), result.lines(), self._name_keys,
                            stopped=len(result.rows) < result.total
                            or any(r.rating is None for r in result.rows)))
            except _StopPreviewError:
                pass
            return result
        finally:
            self._first = None
            self.prefetch.close()
            d.close()

    def _preflight(self, first: DecodedPair) -> list[Check]:
        """The display checks of a run's pre-flight, reported only; refuses (StudyError) only
        when the videos cannot be shown at 1:1 pixels at all."""
        d = self.display
        req = self.m.display
        geom = d.geometry()
        mon = geom.monitor()
        t, ph, pw = first.test.shape[:3]
        mw, mh, mf = self._manifest_video()
        w, h, frames = max(mw, pw), max(mh, ph), max(mf, t)
        self._refuse_unshowable(w, h)
        lay = viewing_layout_for(d, self._name_keys, (w, h), "Trial 1 of 1", 1.0)
        checks = [
            check_screen(*d.monitor_pixels(geom), req, monitor=mon.name if mon else None),
            check_refresh(d.estimate, req, paced_pilot=d.timing_mode == PACED_PILOT,
                          paced_hz=d.refresh_hz),
            check_pixel_mapping(geom, (w, h), fits_with_label=lay.label is not None),
            check_memory(2 * pair_bytes(w, h, frames), available_memory_bytes()),
            check_decode_speed(first.seconds),
        ]
        for c in checks:
            log.info("pre-flight %s: %s (reported only): %s", c.name,
                     "ok" if c.ok else "not met", c.message)
        return checks

    def _refuse_unshowable(self, w: int, h: int) -> None:
        dw, dh = self.display.drawable_size
        if w <= dw and h <= dh:
            return
        windowed = self.opts.windowed or self.opts.window_size is not None
        fix = ("give a larger --window-size or leave out --windowed" if windowed else
               "set the screen to its highest resolution and display scaling to 100%, or use "
               "a larger monitor")
        raise StudyError(f"the videos ({w}x{h} pixels) do not fit into the "
                         f"{'window' if windowed else 'screen'} ({dw}x{dh} pixels) at 1:1, so "
                         f"they cannot be previewed: {fix}")

    def _pair(self, index: int) -> DecodedPair:
        """The ``index``-th stimulus's decoded pair: from the background decode started
        while the one before was rated, else decoded now behind a waiting screen."""
        trial = self.trials[index]
        return wait_for(self.display, lambda: self.prefetch.take(index) or decode_pair(
            trial.stimulus, *self._paths(trial)), "Loading...", self._on_close)

    def _prefetch_after(self, index: int) -> None:
        """The rating screen of stimulus ``index`` opened: decode the next one meanwhile (as
        a run does)."""
        if index + 1 < len(self.trials):
            nxt = self.trials[index + 1]
            self.prefetch.start(index + 1, nxt.stimulus, *self._paths(nxt))

    def _min_view(self, frames: int, fps: float) -> float:
        mv = self.m.protocol.min_view_seconds
        return mv if mv is not None else frames / fps

    def _trials(self, result: PreviewResult) -> None:
        d = self.display
        overlay = TimingOverlay(d, result) if self.opts.timing_overlay else None
        n = len(self.trials)
        try:
            for i, trial in enumerate(self.trials):
                try:
                    pair = self._first if i == 0 else self._pair(i)
                except StudyError as exc:  # the summary so far is kept, and says so
                    result.failure = f"cannot decode stimulus {trial.stimulus} ({exc})"
                    return
                self._first = None  # the frames go into textures; free the decoded arrays
                self._refuse_unshowable(pair.test.shape[2], pair.test.shape[1])
                gpu = upload_pair(d, pair)
                del pair
                min_view = self._min_view(gpu.frames, gpu.fps)
                if overlay is not None:
                    overlay.stimulus = trial.stimulus
                screen = TrialScreen(d, self.m, self._name_keys, self._state, self._shot,
                                     lambda _t, i=i: self._prefetch_after(i),
                                     lambda v=min_view: v, overlay)
                row = PreviewRow(trial.stimulus)
                result.rows.append(row)
                if not result.told:
                    low, high = estimate_minutes(result.session_trials, gpu.frames / gpu.fps,
                                                 self.m.protocol.blank_seconds)
                    result.told = f"about {low}-{high} min" if low != high else f"about {low} min"
                try:
                    while True:
                        started = time.perf_counter()
                        outcome = screen.run(trial, gpu, i + 1, n)
                        row.seconds += time.perf_counter() - started
                        if screen.machine is not None:
                            row.add(screen.machine.stats)
                        if isinstance(outcome, TrialResult):
                            row.rating = outcome.rating
                            break
                        if outcome == "close":
                            self.closed = True
                            return
                        if self._screen(preview_content.paused(
                                i, n, self._name_keys)) == "stop":
                            return
                finally:
                    gpu.release()
                self._state("previewed", stimulus=trial.stimulus, dropped=row.dropped_frames)
        finally:
            if overlay is not None and overlay.missing:
                result.overlay_note = ("timing overlay: " + (
                    "no free place beside the video on this screen, so it was not shown" if
                    overlay.never_fitted else "not shown for some stimuli (no free place)"))


def missing_videos(study: Study, trials: list[PlannedTrial]) -> list[Path]:
    """The video files of ``trials`` that are not there, checked before any window opens (a
    missing one would otherwise stop the preview when it is reached, maybe after 40)."""
    loaded = study.loaded
    paths = dict.fromkeys(p for t in trials for p in (loaded.stimulus_path(t.stimulus),
                                                      loaded.reference_path(t.reference)))
    return [p for p in paths if not p.exists()]


def run_preview(study: Study, opts: PreviewOptions) -> PreviewResult:
    """Preview ``study`` (see the module doc); refuses before opening a window when a video
    is missing."""
    missing = missing_videos(study, preview_trials(study, opts.stimulus))
    if missing:
        shown = ", ".join(str(p) for p in missing[:3]) + (
            f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        raise StudyError(f"{len(missing)} video file(s) of the study are missing: {shown}; "
                         "run 'cgvq-study check'")
    return Preview(study, opts).run()
