"""The participant's app: window, screens, trials, rating, and the session around them.

One loop per screen: handle input, draw, flip, measure the flip. With vsync the driver paces
the flips; without it (e.g. a virtual X display) :class:`~study_app.clock.FlipPacer` paces
them on the monotonic clock at the configured refresh rate and the session records
``vsync: false``. Videos are uploaded to textures before a trial starts; the next trial's pair
is decoded in the background while the participant rates.
"""

from __future__ import annotations

import itertools
import logging
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stimuli_manifests import StimuliError, probe_video

from . import __version__
from .clock import FlipPacer, FlipStats, blank_refreshes, frame_index, refreshes_elapsed
from .decode import DecodedPair, Prefetcher, decode_pair, pair_bytes
from .errors import StudyError
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
from .schedule import make_schedule, participant_seed, pick_practice
from .session import PlannedTrial, SessionStore, TrialResult, utc_now
from .slider import Slider
from .study import Study

if TYPE_CHECKING:
    from .render import Renderer

log = logging.getLogger(__name__)

# Without vsync, a median flip interval below this means the driver is not waiting for the
# display (no real monitor refreshes faster than 250 Hz).
_MIN_VSYNC_INTERVAL_S = 1 / 250
LABEL_TEST = "Test video"
LABEL_REFERENCE = "Reference"
GREY_TEXT = (0.85, 0.85, 0.85, 1.0)
ACCENT = (0.98, 0.80, 0.20, 1.0)


@dataclass
class RunOptions:
    """Options of ``cgvq-study run``."""

    participant: str
    windowed: bool = False
    skip_preflight: bool = False
    seed: int | None = None
    sessions_dir: Path | None = None
    practice: int = 2
    refresh_hz: float | None = None
    max_dropped_frames: int = 10
    break_every: int = 40
    window_size: tuple[int, int] | None = None
    screenshots: Path | None = None
    force_pacer: bool = False


@dataclass
class RunOutcome:
    """How a run ended: ``finished``, ``quit`` (resumable) or ``declined`` (no consent)."""

    status: str
    session_path: Path | None
    answered: int = 0
    total: int = 0


class _QuitRequestedError(Exception):
    """The participant closed the window or chose to quit."""


# -- the window ---------------------------------------------------------------------------
class Display:
    """A Pygame OpenGL window with a ModernGL context and measured flips."""

    def __init__(self, *, windowed: bool, window_size: tuple[int, int] | None,
                 refresh_hz: float | None, force_pacer: bool = False,
                 min_window: tuple[int, int] = (800, 600)) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        import moderngl
        import pygame

        from .render import Renderer

        self.pg = pygame
        os.environ.setdefault("SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS", "0")
        pygame.display.init()
        for attr, value in ((pygame.GL_CONTEXT_MAJOR_VERSION, 3),
                            (pygame.GL_CONTEXT_MINOR_VERSION, 3),
                            (pygame.GL_CONTEXT_PROFILE_MASK, pygame.GL_CONTEXT_PROFILE_CORE),
                            (pygame.GL_DOUBLEBUFFER, 1)):
            pygame.display.gl_set_attribute(attr, value)
        sizes = pygame.display.get_desktop_sizes()
        self.screen_size = tuple(sizes[0]) if sizes else (0, 0)
        flags = pygame.OPENGL | pygame.DOUBLEBUF
        if windowed:
            w, h = window_size or min_window
            size = (min(w, self.screen_size[0] or w), min(h, self.screen_size[1] or h))
        else:
            flags |= pygame.FULLSCREEN
            size = self.screen_size
        self.vsync_requested = not force_pacer
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                pygame.display.set_mode(size, flags, vsync=0 if force_pacer else 1)
            except pygame.error:
                pygame.display.set_mode(size, flags)
                self.vsync_requested = False
        if any("vsync" in str(w.message).lower() for w in caught):
            self.vsync_requested = False
        pygame.display.set_caption("cgvq-study")
        pygame.mouse.set_visible(True)
        try:
            self.ctx = moderngl.create_context(require=330)
        except Exception as exc:
            raise StudyError(f"OpenGL 3.3 is not available ({exc}); update the graphics "
                             "driver") from None
        self.window_size = tuple(pygame.display.get_window_size())
        self.drawable_size = tuple(self.ctx.screen.viewport[2:])
        self.renderer = Renderer(self.ctx, self.window_size)
        self.configured_hz = refresh_hz
        self.vsync = False
        self.refresh_hz = refresh_hz or 60.0
        self.pacer: FlipPacer | None = None
        self.measured_intervals: list[float] = []

    @property
    def period(self) -> float:
        return 1.0 / self.refresh_hz

    def measure_refresh(self, n: int = 60) -> None:
        """Flip ``n`` times; decide whether vsync works and what the refresh rate is."""
        times = []
        for _ in range(n):
            self.renderer.clear()
            self.renderer.text("Checking the display...", self.window_size[0] / 2,
                               self.window_size[1] / 2, anchor="center")
            self.pg.display.flip()
            self.ctx.finish()
            times.append(time.perf_counter())
            self.pg.event.pump()
        intervals = [b - a for a, b in itertools.pairwise(times)]
        self.measured_intervals = intervals
        median = float(np.median(intervals)) if intervals else 0.0
        self.vsync = self.vsync_requested and median >= _MIN_VSYNC_INTERVAL_S
        if self.vsync:
            self.refresh_hz = self.configured_hz or 1.0 / median
            self.pacer = None
        else:
            self.refresh_hz = self.configured_hz or 60.0
            self.pacer = FlipPacer(self.refresh_hz)
        log.info("display %dx%d, window %dx%d, vsync %s, refresh %.2f Hz (%s)",
                 *self.screen_size, *self.window_size, self.vsync, self.refresh_hz,
                 "measured" if self.vsync and not self.configured_hz else "configured")

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

    def info(self) -> dict[str, Any]:
        return {
            "screen": list(self.screen_size), "window": list(self.window_size),
            "drawable": list(self.drawable_size), "vsync": self.vsync,
            "refresh_hz": round(self.refresh_hz, 3),
            "refresh_source": "measured" if self.vsync and not self.configured_hz
            else "configured",
            "gl_renderer": self.ctx.info.get("GL_RENDERER"),
            "gl_version": self.ctx.info.get("GL_VERSION"),
            "video_driver": self.pg.display.get_driver(),
        }

    def close(self) -> None:
        self.pg.display.quit()


# -- one trial ----------------------------------------------------------------------------
@dataclass
class TrialState:
    """Everything measured while one trial is on screen."""

    stats: FlipStats
    showing: str = "test"
    n: int = 0
    blank_until: int | None = None
    blank_target: str | None = None
    switch_key_t: float | None = None
    t_start: float | None = None
    presented_at: str | None = None
    n_toggles: int = 0
    switch_latencies_ms: list[float] = field(default_factory=list)
    blank_durations_ms: list[float] = field(default_factory=list)
    blank_started_t: float | None = None
    blank_started_n: int = 0
    blank_refreshes: list[int] = field(default_factory=list)
    blank_target_refreshes: int = 0
    cpu_start: float = 0.0
    flips: int = 0
    toggle_times_ms: list[float] = field(default_factory=list)
    ms_on: dict[str, float] = field(default_factory=lambda: {"test": 0.0, "reference": 0.0})
    viewing_s: float = 0.0
    last_content: str | None = None


@dataclass
class OnGpu:
    """A trial's two videos uploaded to textures (the decoded arrays are freed)."""

    stimulus: str
    tex: dict[str, Any]
    width: int
    height: int
    frames: int
    fps: float
    decode_seconds: float

    def release(self) -> None:
        for t in self.tex.values():
            t.release()


class App:
    """Runs one participant session of a study."""

    def __init__(self, study: Study, opts: RunOptions) -> None:
        self.study = study
        self.opts = opts
        self.m = study.manifest
        self.session_path = study.session_path(opts.participant, opts.sessions_dir)
        self.display: Display | None = None
        self.store: SessionStore | None = None
        self.prefetch = Prefetcher()
        self._shots_done: set[str] = set()
        self._practice_mode = False
        self._first_pair: DecodedPair | None = None

    # -- utilities --------------------------------------------------------------------
    def _state(self, name: str, **kw: Any) -> None:
        """Log a screen change (the end-to-end test follows these lines)."""
        extra = "".join(f" {k}={v}" for k, v in kw.items())
        log.debug("state: %s%s", name, extra)

    def _shot(self, name: str) -> bool:
        """Save the back buffer as ``<screenshots>/<name>.png`` once per name."""
        if self.opts.screenshots is None or name in self._shots_done:
            return False
        from PIL import Image

        self.opts.screenshots.mkdir(parents=True, exist_ok=True)
        Image.fromarray(self.display.renderer.read_pixels()).save(
            self.opts.screenshots / f"{name}.png")
        self._shots_done.add(name)
        return True

    def _paths(self, trial: PlannedTrial) -> tuple[Path, Path]:
        return (self.study.loaded.stimulus_path(trial.stimulus),
                self.study.loaded.reference_path(trial.reference))

    # -- entry point ------------------------------------------------------------------
    def run(self) -> RunOutcome:
        new = not self.session_path.exists()
        if not new:
            with SessionStore.open(self.session_path) as store:
                info = store.info
                if info.finished_at is not None:
                    raise StudyError(
                        f"the session of participant {self.opts.participant} is already "
                        f"finished ({self.session_path}); nothing left to do: send that file "
                        "to the experimenter")
                if info.manifest_sha256 and info.manifest_sha256 != self.study.loaded.sha256:
                    raise StudyError(
                        f"the study's manifest changed since this session started "
                        f"({self.session_path}); resume with the original study folder")
        self.display = Display(
            windowed=self.opts.windowed, window_size=self.opts.window_size or self._window_for(),
            refresh_hz=self.opts.refresh_hz, force_pacer=self.opts.force_pacer)
        try:
            return self._run(new)
        except _QuitRequestedError:
            answered, total = self.store.progress() if self.store else (0, 0)
            if self.store:
                self.store.log_event("quit", answered=answered)
            return RunOutcome("quit", self.session_path if self.store else None,
                              answered, total)
        finally:
            self.prefetch.close()
            if self.store is not None:
                self.store.close()
            self.display.close()

    def _window_for(self) -> tuple[int, int]:
        """Windowed mode: room for the largest reference video plus labels and hints."""
        w = h = 0
        for ref in self.m.references:
            if ref.width and ref.height:
                w, h = max(w, ref.width), max(h, ref.height)
            else:
                try:
                    info = probe_video(self.study.loaded.reference_path(str(ref.id)))
                except StimuliError:
                    continue
                w, h = max(w, info.width), max(h, info.height)
        return max(800, w + 320), max(600, h + 160)

    def _run(self, new: bool) -> RunOutcome:
        d = self.display
        d.measure_refresh()
        if new:
            if self.study.briefing:
                self._text_screen("briefing", "Welcome", self.study.briefing.splitlines(),
                                  {"continue": "Press Space to continue"})
            if self.study.consent is not None:
                choice = self._text_screen(
                    "consent", "Consent", self.study.consent.splitlines(),
                    {"accept": "Press A to accept and take part",
                     "decline": "Press Esc to decline (nothing is recorded)"})
                if choice == "decline":
                    return RunOutcome("declined", None)
            self.store = self._create_session()
        else:
            self.store = SessionStore.open(self.session_path)
            answered, total = self.store.progress()
            self._text_screen("welcome-back", "Welcome back",
                              [f"Your answers so far are saved. You continue at trial "
                               f"{answered + 1} of {total}."],
                              {"continue": "Press Space to continue"})
        self.store.log_event("resume" if not new else "created", pid=os.getpid())
        first = self.store.next_trial()
        self._first_pair = self._preflight(first)
        self.store.mark_started(display=d.info())
        if new and self.opts.practice > 0:
            self._practice()
        return self._main_loop()

    def _create_session(self) -> SessionStore:
        seed = self.opts.seed
        if seed is None:
            seed = participant_seed(self.m.study_id, self.opts.participant)
        plan = make_schedule(self.study.schedule_items(), self.m.protocol.repetitions, seed)
        settings = {
            "protocol": self.m.protocol.model_dump(mode="json"),
            "display_requirements": self.m.display.model_dump(mode="json"),
            "scale": self.m.scale.model_dump(mode="json"),
            "practice_trials": self.opts.practice,
            "max_dropped_frames": self.opts.max_dropped_frames,
            "seed_source": "option" if self.opts.seed is not None else "participant",
        }
        return SessionStore.create(
            self.session_path, participant=self.opts.participant, study_id=self.m.study_id,
            manifest_sha256=self.study.loaded.sha256, seed=seed, app_version=__version__,
            plan=plan, settings=settings)

    # -- pre-flight -------------------------------------------------------------------
    def _preflight(self, first: PlannedTrial | None) -> DecodedPair | None:
        d = self.display
        req = self.m.display
        checks: list[Check] = [
            check_screen(*d.screen_size, req),
            check_refresh(d.measured_intervals, req, vsync=d.vsync, paced_hz=d.refresh_hz),
        ]
        big = (0, 0, 0)
        pair: DecodedPair | None = None
        if first is not None:
            self._state("preflight")
            job = self._background(lambda: decode_pair(first.stimulus, *self._paths(first)),
                                   "Preparing the videos...")
            pair = job
            t, h, w = pair.test.shape[:3]
            big = (w, h, t)
        for ref in self.m.references:
            if ref.width and ref.height:
                big = (max(big[0], ref.width), max(big[1], ref.height),
                       max(big[2], ref.frames or big[2]))
        checks.append(check_pixel_mapping(d.window_size, d.drawable_size, big[:2]))
        checks.append(check_memory(2 * pair_bytes(*big), available_memory_bytes()))
        if pair is not None:
            checks.append(check_decode_speed(pair.seconds))
        if not self.opts.skip_preflight:
            checks.append(self._background(lambda: check_checksums(self.study),
                                           "Checking the study files..."))
        results = [c.as_dict() for c in checks]
        self.store.save_preflight(results, skipped=self.opts.skip_preflight)
        failed = [c for c in checks if not c.ok]
        for c in checks:
            log.info("pre-flight %s: %s: %s", c.name, "ok" if c.ok else "FAILED", c.message)
        if failed and not self.opts.skip_preflight:
            lines = [f"- {c.message}" for c in failed]
            self._text_screen("preflight-failed", "This computer cannot run the study yet",
                              [*lines, "", "Nothing was rated. Fix the above and start again."],
                              {"close": "Press Esc to close"})
            raise StudyError("pre-flight failed: " + " | ".join(
                f"{c.name}: {c.message}" for c in failed))
        if failed:
            self.store.log_event("preflight_skipped", failed=[c.name for c in failed])
        return pair

    def _background(self, fn: Callable[[], Any], message: str) -> Any:
        """Run ``fn`` in a worker thread while a waiting screen keeps the window alive."""
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=1) as pool:
            job = pool.submit(fn)
            while not job.done():
                self._poll_quit()
                r = self.display.renderer
                r.clear()
                r.text(message, self.display.window_size[0] / 2,
                       self.display.window_size[1] / 2, anchor="center")
                self.display.flip()
            return job.result()

    def _poll_quit(self) -> None:
        pg = self.display.pg
        for event in pg.event.get():
            if event.type == pg.QUIT:
                raise _QuitRequestedError

    # -- text screens -----------------------------------------------------------------
    def _text_screen(self, name: str, title: str, lines: list[str],
                     choices: dict[str, str]) -> str:
        """A screen of text; returns the key of ``choices`` the participant picked."""
        pg = self.display.pg
        keymap = {"continue": (pg.K_SPACE, pg.K_RETURN, pg.K_KP_ENTER), "accept": (pg.K_a,),
                  "decline": (pg.K_ESCAPE, pg.K_n), "close": (pg.K_ESCAPE, pg.K_RETURN),
                  "quit": (pg.K_q,), "resume": (pg.K_SPACE, pg.K_RETURN, pg.K_KP_ENTER)}
        self._state(name)
        r = self.display.renderer
        w, h = self.display.window_size
        width = min(1000, w - 80)
        x = (w - width) / 2
        cleaned = [ln.lstrip("#").strip() if ln.startswith("#") else ln for ln in lines]
        while True:
            for event in pg.event.get():
                if event.type == pg.QUIT:
                    if "decline" in choices:
                        return "decline"
                    raise _QuitRequestedError
                if event.type == pg.KEYDOWN:
                    for choice in choices:
                        if event.key in keymap[choice]:
                            self._state(f"{name}-done", choice=choice)
                            return choice
            r.clear((0.2, 0.2, 0.2, 1.0))
            r.text(title, w / 2, 40, px=44, anchor="center")
            y = r.paragraph(cleaned, x, 110, width, px=28, color=GREY_TEXT)
            y = max(y + 20, 0)
            for hint in choices.values():
                r.text(hint, w / 2, min(y, h - 60), px=30, color=ACCENT, anchor="center")
                y += 40
            self._shot(name)
            self.display.flip()

    # -- practice and main loop -------------------------------------------------------
    def _practice(self) -> None:
        items = pick_practice(self.study.schedule_items(), self.opts.practice,
                              self.store.info.seed)
        self._text_screen("practice-intro", "Practice",
                          [f"First {len(items)} practice trial(s) to get to know the controls. "
                           "They are not recorded."], {"continue": "Press Space to start"})
        self._practice_mode = True
        try:
            for k, item in enumerate(items):
                trial = PlannedTrial(-(k + 1), item.id, item.reference, 1,
                                     item.is_hidden_reference)
                pair = self._background(lambda t=trial: decode_pair(t.stimulus,
                                                                    *self._paths(t)),
                                        "Loading...")
                gpu = self._upload(pair)
                del pair
                try:
                    while self._trial_loop(trial, gpu, k + 1, len(items)) == "pause":
                        self._pause()
                finally:
                    gpu.release()
        finally:
            self._practice_mode = False
        self._text_screen("practice-done", "Practice done",
                          ["The real trials start now."], {"continue": "Press Space to start"})

    def _main_loop(self) -> RunOutcome:
        store = self.store
        pair, self._first_pair = self._first_pair, None
        since_break = 0
        while (trial := store.next_trial()) is not None:
            if pair is None or pair.stimulus != trial.stimulus:
                pair = self.prefetch.take(trial.index)
                if pair is None or pair.stimulus != trial.stimulus:
                    pair = self._background(
                        lambda t=trial: decode_pair(t.stimulus, *self._paths(t)), "Loading...")
            answered, total = store.progress()
            gpu = self._upload(pair)
            pair = None  # the frames live in textures now; free the decoded arrays
            try:
                while (outcome := self._trial_loop(trial, gpu, answered + 1, total)) == "pause":
                    store.log_event("pause", trial=trial.index)
                    self._pause()
            finally:
                gpu.release()
            result: TrialResult = outcome
            limit = self.opts.max_dropped_frames
            if needs_requeue(result.dropped_frames, limit, trial):
                log.warning("trial %d: %d dropped frames (limit %d); re-queued at the end",
                            trial.index, result.dropped_frames, limit)
                store.requeue(trial.index, result,
                              f"{result.dropped_frames} dropped frames > {limit}")
                self._state("requeued", trial=trial.index)
            else:
                store.record(trial.index, result)
                self._state("recorded", trial=trial.index, rating=f"{result.rating:.3f}")
            since_break += 1
            if (self.opts.break_every > 0 and since_break >= self.opts.break_every
                    and store.next_trial() is not None):
                since_break = 0
                answered, total = store.progress()
                self._pause(title="Time for a break",
                            text=f"{answered} of {total} trials done. Rest your eyes.")
        store.finish()
        answered, total = store.progress()
        self._state("end", answered=answered)
        self._text_screen(
            "end", "Thank you!",
            [f"All {total} trials are done.", "",
             "Your result file is:", str(self.session_path.resolve()), "",
             "Please send this file to the experimenter (or the .zip made by "
             f"'cgvq-study export {self.session_path}')."],
            {"close": "Press Enter or Esc to close"})
        return RunOutcome("finished", self.session_path, answered, total)

    def _pause(self, title: str = "Paused", text: str | None = None) -> None:
        choice = self._text_screen(
            "pause", title,
            [text or "Your answers so far are saved.",
             "If you continue, the current trial starts again."],
            {"resume": "Press Space to continue", "quit": "Press Q to quit and continue later"})
        if choice == "quit":
            raise _QuitRequestedError

    def _prefetch_following(self, trial: PlannedTrial) -> None:
        if self._practice_mode or self.store is None:
            return
        pending = self.store.pending()
        after = [p for p in pending if p.index != trial.index]
        if after:
            nxt = after[0]
            self.prefetch.start(nxt.index, nxt.stimulus, *self._paths(nxt))

    # -- the trial --------------------------------------------------------------------
    def _upload(self, pair: DecodedPair) -> OnGpu:
        """Both videos of a trial into textures, before its first frame."""
        r = self.display.renderer
        t, h, w = pair.test.shape[:3]
        tex = {"test": r.upload_video(pair.test), "reference": r.upload_video(pair.reference)}
        self.display.ctx.finish()
        return OnGpu(pair.stimulus, tex, w, h, t, pair.fps, pair.seconds)

    def _trial_loop(self, trial: PlannedTrial, gpu: OnGpu, k: int, total: int
                    ) -> TrialResult | str:
        """Show one trial until the rating is submitted; returns it, or ``"pause"``."""
        d = self.display
        pg = d.pg
        r = d.renderer
        proto = self.m.protocol
        frames = gpu.frames
        loop_s = frames / gpu.fps
        min_view = proto.min_view_seconds if proto.min_view_seconds is not None else loop_s
        blank_n = blank_refreshes(proto.blank_seconds, d.refresh_hz)
        st = TrialState(stats=FlipStats(d.period), blank_target_refreshes=blank_n)
        w = d.window_size[0]
        slider = self._make_slider()
        submit_rect = (w / 2 - 90, slider.y + 110, 180, 50)
        phase = "view"
        notice_until = 0.0
        prefix = "Practice: " if self._practice_mode else ""
        warm_up_viewing(r, d.window_size, gpu, f"{prefix}Trial {k} of {total}", min_view)
        if d.pacer is not None:
            d.pacer.reset()
        self._state("viewing", trial=trial.index, practice=int(self._practice_mode))

        def submit_ready() -> bool:
            return slider.is_set and st.viewing_s >= min_view

        while True:
            now = time.perf_counter()
            for event in pg.event.get():
                if event.type == pg.QUIT:
                    raise _QuitRequestedError
                if event.type == pg.KEYDOWN:
                    key = event.key
                    if key in (pg.K_p, pg.K_ESCAPE):
                        self._state("pause-request", trial=trial.index)
                        return "pause"
                    if phase == "view":
                        if key == pg.K_SPACE and st.blank_until is None:
                            target = "reference" if st.showing == "test" else "test"
                            st.n_toggles += 1
                            st.switch_key_t = now
                            if st.t_start is not None:
                                st.toggle_times_ms.append(1000 * (now - st.t_start))
                            if blank_n > 0:
                                st.blank_until = st.n + blank_n
                                st.blank_target = target
                            else:
                                st.showing = target
                            self._state("switch", to=target)
                        elif key in (pg.K_RETURN, pg.K_KP_ENTER):
                            if st.viewing_s >= min_view and st.blank_until is None:
                                phase = "rate"
                                st.stats.break_chain()
                                self._prefetch_following(trial)
                                x0, x1 = slider.x0, slider.x1
                                self._state("rating", trial=trial.index,
                                            slider=f"{x0:.0f},{x1:.0f},{slider.y:.0f}",
                                            submit=",".join(f"{v:.0f}" for v in submit_rect))
                            else:
                                notice_until = now + 2.0
                    else:
                        if key == pg.K_SPACE:
                            phase = "view"
                            if d.pacer is not None:
                                d.pacer.reset()
                            self._state("viewing", trial=trial.index, back=1)
                        elif key in (pg.K_LEFT, pg.K_RIGHT):
                            coarse = bool(event.mod & (pg.KMOD_SHIFT | pg.KMOD_CTRL))
                            slider.key_step(-1 if key == pg.K_LEFT else 1, coarse, now)
                            self._state("slider", value=f"{slider.value:.3f}")
                        elif key in (pg.K_PAGEUP, pg.K_PAGEDOWN):
                            slider.key_step(1 if key == pg.K_PAGEUP else -1, True, now)
                        elif key in (pg.K_RETURN, pg.K_KP_ENTER):
                            if submit_ready():
                                return self._result(st, slider, now, gpu, d)
                            notice_until = now + 2.0
                elif phase == "rate" and event.type == pg.MOUSEBUTTONDOWN and event.button == 1:
                    x, y = event.pos
                    if slider.press(x, y, now):
                        self._state("slider", value=f"{slider.value:.3f}")
                    elif _inside(submit_rect, x, y):
                        if submit_ready():
                            return self._result(st, slider, now, gpu, d)
                        notice_until = now + 2.0
                elif phase == "rate" and event.type == pg.MOUSEMOTION and slider.dragging:
                    slider.drag(event.pos[0])
                elif event.type == pg.MOUSEBUTTONUP and event.button == 1:
                    if slider.dragging:
                        self._state("slider", value=f"{slider.value:.3f}")
                    slider.release()

            r.clear()
            progress = f"{prefix}Trial {k} of {total}"
            if phase == "view":
                if st.blank_until is not None and st.n >= st.blank_until:
                    st.showing = st.blank_target or st.showing
                    st.blank_until = None
                content = "blank" if st.blank_until is not None else st.showing
                idx = frame_index(st.n, gpu.fps, d.refresh_hz, frames, loop=proto.loop)
                draw_viewing(r, d.window_size, gpu, content, idx, progress,
                             notice=now < notice_until, min_view=min_view)
                shot = self._shot(("practice-" if self._practice_mode else "")
                                  + ("blank" if content == "blank" else f"viewing-{content}"))
                t = d.flip()
                if shot:
                    st.stats.break_chain()
                interval = st.stats.add(t)
                st.flips += 1
                if st.t_start is None:
                    st.t_start = t
                    st.cpu_start = time.process_time()
                    st.presented_at = utc_now()
                if interval is not None and st.last_content is not None:
                    if st.last_content != "blank":
                        st.ms_on[st.last_content] += 1000 * interval
                    st.viewing_s += interval
                if content == "blank" and st.last_content != "blank":
                    st.blank_started_t = t
                    st.blank_started_n = st.n
                if content != "blank" and st.switch_key_t is not None and st.blank_until is None:
                    st.switch_latencies_ms.append(1000 * (t - st.switch_key_t))
                    if st.blank_started_t is not None:
                        st.blank_durations_ms.append(1000 * (t - st.blank_started_t))
                        st.blank_refreshes.append(st.n - st.blank_started_n)
                        st.blank_started_t = None
                    st.switch_key_t = None
                st.last_content = content
                st.n += refreshes_elapsed(interval, d.period) if interval is not None else 1
            else:
                self._draw_rating(slider, submit_rect, submit_ready(), progress,
                                  notice=now < notice_until, min_view=min_view)
                if slider.is_set and not self._practice_mode:
                    self._shot("rating")
                elif not self._practice_mode:
                    self._shot("rating-unset")
                d.flip()
                st.flips += 1
                st.last_content = None

    def _make_slider(self) -> Slider:
        w, h = self.display.window_size
        scale = self.m.scale
        labels = [(lab.position, lab.text) for lab in scale.labels]
        half = min(600, (w - 160) / 2)
        return Slider(x0=w / 2 - half, x1=w / 2 + half, y=h / 2, vmin=scale.min,
                      vmax=scale.max, labels=labels,
                      fine_step=(scale.max - scale.min) / 100,
                      coarse_step=(scale.max - scale.min) / 10)

    def _draw_rating(self, slider: Slider, submit_rect: tuple[float, ...], ready: bool,
                     progress: str, *, notice: bool, min_view: float) -> None:
        r = self.display.renderer
        w, h = self.display.window_size
        r.text(progress, w - 20, 16, px=26, color=GREY_TEXT, anchor="topright")
        r.text("Rate the quality of distortions in the shown video", w / 2, slider.y - 150,
               px=34, anchor="center")
        r.text("with respect to its reference", w / 2, slider.y - 115, px=34, anchor="center")
        r.rect(slider.x0, slider.y - 3, slider.x1 - slider.x0, 6, (0.15, 0.15, 0.15, 1.0))
        for i, (x, text) in enumerate(slider.label_positions()):
            r.rect(x - 1, slider.y - 14, 2, 28, (0.15, 0.15, 0.15, 1.0))
            y = slider.y + 22 + (i % 2) * 26  # alternate rows so long labels never overlap
            r.text(text, x, y, px=24, color=(0.05, 0.05, 0.05, 1.0), anchor="center")
        if slider.value is not None:
            mx = slider.x_of(slider.value)
            r.rect(mx - 7, slider.y - 18, 14, 36, (0.85, 0.1, 0.1, 1.0))
        x, y, bw, bh = submit_rect
        r.rect(x, y, bw, bh, (0.2, 0.45, 0.2, 1.0) if ready else (0.4, 0.4, 0.4, 1.0))
        r.text("Submit", x + bw / 2, y + 14, px=30,
               color=_submit_text_color(ready), anchor="center")
        if notice:
            hint = ("Set the slider first" if slider.value is None
                    else f"Please watch for at least {min_view:.1f} s")
        else:
            hint = ("Click or use the arrow keys (Shift: big steps)    Enter: submit    "
                    "Space: back to the videos    P: pause")
        r.text(hint, w / 2, h - 36, px=26, color=(0.1, 0.1, 0.1, 1.0), anchor="center")

    def _result(self, st: TrialState, slider: Slider, now: float, gpu: OnGpu,
                d: Display) -> TrialResult:
        t0 = st.t_start if st.t_start is not None else now
        stats = st.stats
        self._state("submitted", value=f"{slider.value:.3f}")
        return TrialResult(
            rating=float(slider.value),
            rt_ms=1000 * (now - t0),
            n_toggles=st.n_toggles,
            ms_on_reference=st.ms_on["reference"],
            ms_on_test=st.ms_on["test"],
            presented_at=st.presented_at or utc_now(),
            slider_first_move_ms=(1000 * (slider.first_touch - t0)
                                  if slider.first_touch is not None else None),
            frames_presented=stats.frames_presented,
            dropped_frames=stats.dropped_frames,
            max_flip_interval_ms=stats.max_interval_ms,
            switch_latencies_ms=st.switch_latencies_ms,
            details={
                "vsync": d.vsync, "refresh_hz": d.refresh_hz, "fps": gpu.fps,
                "p99_flip_interval_ms": stats.percentile_interval_ms(99),
                "blank_durations_ms": st.blank_durations_ms,
                "blank_refreshes": st.blank_refreshes,
                "blank_target_refreshes": st.blank_target_refreshes,
                "toggle_times_ms": st.toggle_times_ms, "viewing_ms": 1000 * st.viewing_s,
                "decode_seconds": gpu.decode_seconds,
                # CPU time of the whole process (all threads) per flip: what the machine needs
                # to keep up, independent of how loaded it was.
                "cpu_ms_per_flip": 1000 * (time.process_time() - st.cpu_start)
                / max(1, st.flips - 1),
            },
        )



# -- the viewing screen -------------------------------------------------------------------
def draw_viewing(r: Renderer, size: tuple[int, int], gpu: OnGpu, content: str, idx: int,
                 progress: str, *, notice: bool, min_view: float) -> None:
    """One refresh of the viewing screen: a video frame (or the blank), its label, hints."""
    w, h = size
    if content != "blank":
        vx, vy, _, _ = r.video_rect(gpu.width, gpu.height)
        r.draw_video(gpu.tex[content], idx)
        _draw_label(r, LABEL_TEST if content == "test" else LABEL_REFERENCE, vx, vy)
    r.text(progress, w - 20, 16, px=26, color=GREY_TEXT, anchor="topright")
    if notice:
        hint = f"Please watch for at least {min_view:.1f} s before rating"
    else:
        hint = "Space: switch test / reference    Enter: rate    P: pause"
    r.text(hint, w / 2, h - 36, px=26, color=GREY_TEXT, anchor="center")


def warm_up_viewing(r: Renderer, size: tuple[int, int], gpu: OnGpu, progress: str,
                    min_view: float) -> None:
    """Draw every variant of the viewing screen once into the back buffer, unshown.

    Drivers compile shader variants and make text textures on first use (Mesa's llvmpipe
    spends 10-50 ms per variant); doing it before the trial's first flip keeps that out of
    the timed presentation, where it showed up as dropped frames.
    """
    for content in ("test", "reference", "blank"):
        for notice in (False, True):
            r.clear()
            draw_viewing(r, size, gpu, content, gpu.frames - 1, progress, notice=notice,
                         min_view=min_view)
    r.ctx.finish()
    r.clear()


def _draw_label(r: Renderer, label: str, vx: int, vy: int) -> None:
    tw, th = r.text_size(label, 30)
    if vx >= tw + 24:  # room left of the video
        r.text(label, vx - 16, vy, px=30, color=ACCENT, anchor="topright")
    elif vy >= th + 8:
        r.text(label, vx, vy - th - 6, px=30, color=ACCENT)
    else:
        r.text(label, 12, 12, px=30, color=ACCENT)

def needs_requeue(dropped_frames: int, limit: int, trial: PlannedTrial) -> bool:
    """Re-queue a trial (once) when more than ``limit`` frames dropped; ``limit < 0`` never."""
    return 0 <= limit < dropped_frames and trial.requeue_of is None


def _submit_text_color(ready: bool) -> tuple[float, float, float, float]:
    return (1.0, 1.0, 1.0, 1.0) if ready else (0.75, 0.75, 0.75, 1.0)


def _inside(rect: tuple[float, ...], x: float, y: float) -> bool:
    rx, ry, rw, rh = rect
    return rx <= x <= rx + rw and ry <= y <= ry + rh


def run_study(study: Study, opts: RunOptions) -> RunOutcome:
    """Run (or resume) one participant's session of ``study``."""
    return App(study, opts).run()
