"""The participant's app: the order of screens around the trials (orchestration only).

Flow of a new session: the display check (pre-flight) on the participant's screen, a short
"your display passed" screen with the figures and the expected duration, the briefing, the
consent; only then the session file is created (with the pre-flight results and a consent
event carrying the sha256 of both texts), then practice and the rated trials with breaks. A
failed pre-flight or a declined consent stores nothing. A resumed session repeats the display
check and says where it continues.

What each part does lives elsewhere: :mod:`.display` (window, DPI, vsync'd flips),
:mod:`.vsync` (refresh estimate), :mod:`.preflight` (the checks), :mod:`.trial_screen` (one
trial on screen, under the real-time guard) with :mod:`.trial` (its state machine),
:mod:`.text_screen` and :mod:`.waiting_screen` (the screens between trials), :mod:`.input_map`
and :mod:`.keys` (events as actions, keyboard layouts), :mod:`.layout` and :mod:`.screens`
(what goes where, what screens say, how they are drawn), :mod:`session_store.run_lock` (one run
per participant), :mod:`.run_options` (the run's options and how it ended).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from session_store import PlannedTrial, SessionStore, TrialResult
from session_store.answers import ENDED_BY_VISION_CHECK
from session_store.errors import StudyError
from session_store.run_lock import RunLock
from session_store.schedule import (
    block_trials,
    make_schedule,
    participant_seed,
    pick_practice,
    schedule_items,
    uniform_block,
)
from session_store.study_folder import BRIEFING_NAME, CONSENT_NAME, Study
from stimuli_manifests import StimuliError, probe_video

from . import __version__, realtime
from .acuity_check_screen import AcuityCheckScreen, optotype_room
from .breaks import break_due
from .colour_check_screen import ColourCheckScreen, plate_size
from .decode import DecodedPair, Prefetcher, decode_pair, pair_bytes
from .display import MIN_WINDOW, PACED_PILOT, Display
from .duration import describe_duration, later_block_trials
from .form_screen import FormScreen
from .keys import RATING, VIEWING, Keymap
from .panel_progress import QUESTIONNAIRE_EVENT, panel_progress
from .preflight import (
    Check,
    PixelGeometry,
    available_memory_bytes,
    check_checksums,
    check_decode_speed,
    check_memory,
    check_pixel_mapping,
    check_refresh,
    check_screen,
)
from .remote.uploader import WITHDRAWN
from .resume_check import check_resumable
from .reveal import reveal_in_file_manager
from .run_options import RunOptions, RunOutcome
from .screens import content
from .termination import Termination, termination_watch
from .text_screen import TextScreen
from .trial_screen import OnGpu, TrialScreen, upload_pair, viewing_layout_for
from .vision.acuity_plan import acuity_plan
from .vision.acuity_scoring import score_acuity
from .vision.isochromatic import plate_series
from .vision.scoring import score_colour
from .waiting_screen import draw_checking_display, wait_for

__all__ = ["RunOptions", "RunOutcome", "needs_requeue", "run_study"]

log = logging.getLogger(__name__)

class _QuitRequestedError(Exception):
    """The participant confirmed that they stop now (and may continue later)."""


class _WithdrawnError(Exception):
    """The participant confirmed that they withdraw from the study."""


class _ClosedError(Exception):
    """The window was closed before a session existed (nothing recorded)."""


class _EndedByServerError(Exception):
    """The study server no longer accepts this session (the participant was withdrawn); the
    argument says so in the participant's words."""


class _ScreenedOutError(Exception):
    """A failed vision check ends the session (the manifest's ``on_fail: end``)."""


def needs_requeue(missed_refreshes: int, limit: int, trial: PlannedTrial) -> bool:
    """Re-queue a trial (once) when more than ``limit`` refreshes passed without a new frame
    (each late flip counted by its length, so one long freeze weighs what it hid);
    ``limit < 0`` never."""
    return 0 <= limit < missed_refreshes and trial.requeue_of is None


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
        self._loop_s = 1.0
        self._termination = Termination()

    # -- utilities --------------------------------------------------------------------
    def _state(self, name: str, **kw: Any) -> None:
        """Log a screen change (the end-to-end tests follow these lines)."""
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

    def _name_keys(self, keys: Keymap, action: str) -> str:
        from . import sdl

        def layout_name(scancode: int) -> str | None:
            return sdl.layout_key_name(scancode)

        return keys.label(action, layout_name)

    # -- entry point ------------------------------------------------------------------
    def run(self) -> RunOutcome:
        self.opts.validate()
        folder = self.session_path.parent
        created_folder = not folder.exists()
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)  # a person's answers
        lock = RunLock(self.session_path, self.opts.participant)
        try:
            lock.acquire()
            if lock.took_over:
                log.info("took over the lock of an ended run (process %s)",
                         lock.took_over.get("pid"))
            resume = self._check_existing()
            with termination_watch(self._post_close) as self._termination:
                self.display = Display(
                    windowed=self.opts.windowed or self.opts.window_size is not None,
                    window_size=self.opts.window_size or self._window_for(),
                    refresh_hz=self.opts.refresh_hz, force_pacer=self.opts.force_pacer)
                self.display.priority = realtime.raise_priority()
                try:
                    return self._run(resume)
                except _QuitRequestedError:
                    return self._quit_outcome()
                except _ClosedError:  # before the session (re)opened: nothing new in it
                    return RunOutcome("closed", self.session_path if resume else None)
        finally:
            self.prefetch.close()
            if self.store is not None:
                self._close_store()
            if self.display is not None:
                self.display.close()
            lock.release()
            if created_folder and not self.session_path.exists():
                with contextlib.suppress(OSError):
                    folder.rmdir()

    def _check_existing(self) -> bool:
        """True when the participant's session exists and can be resumed; a file that is
        someone else's, of another study, closed or damaged is refused (one line) before
        any window opens (see :mod:`.resume_check`)."""
        self._refuse_other_case()
        if not self.session_path.exists():
            return False
        check_resumable(self.session_path, participant=self.opts.participant,
                        study_id=self.m.study_id, manifest_sha256=self.study.loaded.sha256,
                        seed=self.opts.seed)
        return True

    def _refuse_other_case(self) -> None:
        """``p07`` where ``P07.sqlite`` exists: on Linux it would start a second session with
        another trial order, on Windows and macOS open P07's file; refused alike everywhere."""
        folder, wanted = self.session_path.parent, self.session_path.name
        if not folder.is_dir():
            return
        for other in folder.glob("*.sqlite"):
            if other.name != wanted and other.name.lower() == wanted.lower():
                raise StudyError(
                    f"a session of participant {other.stem} exists in {folder}; participant "
                    f"ids are case-sensitive: give --participant {other.stem} to continue it")

    def _close_store(self) -> None:
        """Close the session file. A checkpoint that fails there (a full disk) is raised
        unless an error is already on its way out (which says the same or matters more)."""
        on_its_way = sys.exc_info()[1]  # called from a ``finally``: the error propagating
        try:
            self.store.close()
        except StudyError:
            if on_its_way is None:
                raise
            log.warning("closing %s failed as well", self.session_path, exc_info=True)

    def _window_for(self) -> tuple[int, int]:
        """Windowed mode: room for the largest reference video plus labels and hints."""
        w, h = self._largest_video()
        return max(MIN_WINDOW[0], w + 640), max(MIN_WINDOW[1], h + 120)

    def _largest_video(self) -> tuple[int, int]:
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
        return w, h

    # -- the session ------------------------------------------------------------------
    def _run(self, resume: bool) -> RunOutcome:
        d = self.display
        self._state("checking-display")
        d.measure_refresh(draw=lambda i: draw_checking_display(d, i))
        timing = d.set_timing(pilot_allowed=self.opts.pilot_allowed)
        plan: list[PlannedTrial] | None = None
        if resume:
            with SessionStore.open(self.session_path) as store:
                first = store.next_trial() or store.plan()[0]  # between two blocks: any pair
                answered, total = store.progress()
                total += self._later_blocks(store.blocks_done())
                settings = store.info.settings
            started = settings.get("timing_mode")
            if started == "vsync" and timing == PACED_PILOT:
                raise StudyError(
                    f"this session was started with vsync timing; it cannot continue in the "
                    f"pilot mode without vsync ({self.session_path})")
            n_left = total - answered
        else:
            seed = self._seed()
            reps = 1 if self.m.protocol.allocation == "adaptive" else \
                self.m.protocol.repetitions  # adaptive: block 1 holds every stimulus once
            plan = make_schedule(schedule_items(self.m), reps, seed)
            first = plan[0]
            answered, total = 0, len(plan) + self._later_blocks(1)
            n_left = total
        checks, geom = self._preflight(first)
        duration = describe_duration(n_left, self._loop_s, self.m.protocol.blank_seconds,
                                     None if resume else self.m.panel)
        failed = [c for c in checks if not c.ok]
        for c in checks:
            log.info("pre-flight %s: %s: %s", c.name, "ok" if c.ok else "FAILED", c.message)
        if failed and not self.opts.skip_preflight:
            self._screen(content.preflight_failed(failed, self._name_keys,
                                                  (answered, total) if resume else None))
            raise StudyError("pre-flight failed: " + " | ".join(
                f"{c.name}: {c.message}" for c in failed))
        if not self.opts.skip_preflight:
            self._screen(content.preflight_passed(checks, duration, resume, self._name_keys))
        results = [c.as_dict() for c in checks]
        if resume:
            self.store = SessionStore.open(self.session_path)
            self._screen(content.welcome_back(answered, total, self._name_keys,
                                              self._next_part(answered, total)))
            self.store.save_preflight(results, skipped=self.opts.skip_preflight)
            self.store.log_event("resume", pid=os.getpid(), timing_mode=timing)
        else:
            # Without a briefing the duration was on the "display passed" screen already.
            if self.study.briefing is not None:
                self._screen(content.welcome(self.study.briefing, duration, self._name_keys))
            if self.study.consent is not None:
                choice = self._screen(content.consent(self.study.consent, self._name_keys))
                if choice != "accept":
                    return RunOutcome("declined", None)
            self.store = self._create_session(plan, results)
        if failed:
            self.store.log_event("preflight_skipped", failed=[c.name for c in failed])
        self.store.mark_started(display=d.info(geom))
        try:
            self._panel("before")
            distance = self.m.protocol.viewing_distance_cm
            answered, total = self.store.progress()
            if distance is not None and answered < total:  # not when only questions are left
                self._screen(content.seating(distance, self._name_keys, again=resume))
            if self.opts.practice > 0 and not self._practised():
                self._practice()
            return self._main_loop()
        except _EndedByServerError as exc:
            return self._ended_by_server(str(exc))
        except _WithdrawnError:
            self.store.withdraw()
            answered, total = self.store.progress()
            self._state("finishing", withdrawn=1)
            self._end_screen(total, withdrawn=True)
            return RunOutcome("withdrawn", self.session_path, answered, total)
        except _ScreenedOutError as e:
            test = str(e)
            self.store.log_event(ENDED_BY_VISION_CHECK, test=test)
            self.store.finish(allow_incomplete=True)
            answered, total = self.store.progress()
            self._state("finishing", screened_out=1)
            self._end_screen(total, withdrawn=False, screened_out=test)
            return RunOutcome("screened-out", self.session_path, answered, total,
                              screened_by=test)

    def _seed(self) -> int:
        if self.opts.seed is not None:
            return self.opts.seed
        return participant_seed(self.m.study_id, self.opts.participant)

    def _create_session(self, plan: list[PlannedTrial], preflight: list[dict[str, Any]]
                        ) -> SessionStore:
        d = self.display
        settings = {
            "protocol": self.m.protocol.model_dump(mode="json"),
            "display_requirements": self.m.display.model_dump(mode="json"),
            "scale": self.m.scale.model_dump(mode="json"),
            "practice_trials": self.opts.practice,
            "max_dropped_frames": self.opts.max_dropped_frames,
            "break_every": self.opts.break_every,
            "seed_source": "option" if self.opts.seed is not None else "participant",
            "timing_mode": d.timing_mode,
        }
        consent = {"consent_sha256": self.study.text_sha256(CONSENT_NAME),
                   "briefing_sha256": self.study.text_sha256(BRIEFING_NAME),
                   "asked": self.study.consent is not None}
        # one transaction: a session never exists without its pre-flight and consent
        return SessionStore.create(
            self.session_path, participant=self.opts.participant, study_id=self.m.study_id,
            manifest_sha256=self.study.loaded.sha256, seed=self._seed(),
            app_version=__version__, plan=plan, settings=settings, preflight=preflight,
            preflight_skipped=self.opts.skip_preflight,
            events=[("consent", consent), ("created", {"pid": os.getpid()})])

    # -- pre-flight -------------------------------------------------------------------
    def _preflight(self, first: PlannedTrial | None
                   ) -> tuple[list[Check], PixelGeometry]:
        d = self.display
        req = self.m.display
        geom = d.geometry()
        mon = geom.monitor()
        checks: list[Check] = [
            check_screen(*d.monitor_pixels(geom), req, monitor=mon.name if mon else None),
            check_refresh(d.estimate, req, paced_pilot=d.timing_mode == PACED_PILOT,
                          paced_hz=d.refresh_hz),
        ]
        w, h = self._largest_video()
        frames = max((ref.frames or 0) for ref in self.m.references)
        self._state("preflight")
        files: Check | None = None
        if not self.opts.skip_preflight:  # first: a missing first video is its finding
            files = self._background(lambda: check_checksums(
                self.study, from_server=self.opts.files_from_server,
                known_sha256=self.opts.files_verified),
                "Checking the study files...")
        pair: DecodedPair | None = None
        if first is not None and (files is None or files.ok):
            pair = self._background(lambda: decode_pair(first.stimulus, *self._paths(first)),
                                    "Preparing the videos...")
            t, ph, pw = pair.test.shape[:3]
            w, h, frames = max(w, pw), max(h, ph), max(frames, t)
            self._loop_s = t / pair.fps
        lay = viewing_layout_for(self.display, self._name_keys, (w, h), "Trial 1 of 1",
                                 1.0)
        checks.append(check_pixel_mapping(geom, (w, h), fits_with_label=lay.label is not None))
        checks.append(check_memory(2 * pair_bytes(w, h, frames), available_memory_bytes()))
        if pair is not None:
            checks.append(check_decode_speed(pair.seconds))
        if files is not None:
            checks.append(files)
        self._first_pair = pair
        return checks, geom

    def _background(self, fn: Callable[[], Any], message: str) -> Any:
        """Run ``fn`` in a worker thread while a waiting screen keeps the window alive."""
        return wait_for(self.display, fn, message, self._on_close)

    def _quit_outcome(self) -> RunOutcome:
        """A confirmed stop (or a signal, see :mod:`.termination`), recorded as the event
        the dashboard and the analysis read as "stopped, to continue later"."""
        answered, total = self.store.progress() if self.store else (0, 0)
        if self.store:
            signal = ({"signal": self._termination.name} if self._termination.requested
                      else {})
            self.store.log_event("quit", answered=answered, **signal)
        return RunOutcome("quit", self.session_path if self.store else None, answered, total)

    def _post_close(self) -> None:
        """From the signal handler: wake the screen showing now with a window-close event."""
        d = self.display
        if d is not None and d.pg.display.get_init():
            d.pg.event.post(d.pg.event.Event(d.pg.QUIT))

    def _stop_if_terminated(self) -> None:
        """A signal asked the run to end: stop as a confirmed quit (no session open yet:
        closed; a session already finished or withdrawn: its end screen closes as usual)."""
        if not self._termination.requested:
            return
        if self.store is None:
            raise _ClosedError
        info = self.store.info
        if info.finished_at is None and not info.withdrawn:
            raise _QuitRequestedError

    def _on_close(self) -> None:
        """The window's close button outside a text screen: confirm, or nothing stored yet."""
        self._stop_if_terminated()
        if self.store is None:
            raise _ClosedError
        answered, total = self.store.progress()
        if self._screen(content.confirm_quit(answered, total, self._name_keys)) == "yes":
            raise _QuitRequestedError

    def _next_part(self, answered: int, total: int) -> str:
        """What a resumed session goes on with, in the participant's words ('' for a trial):
        a vision check or the questions before the videos, or the questions after them."""
        if self.m.panel is None:
            return ""
        rec = self.store.snapshot()
        left = panel_progress(self.m.panel, rec.answers, rec.screenings, rec.events)
        if left.vision_todo:
            return "the " + {"colour": "colour vision check",
                             "acuity": "sharpness and contrast check"}[left.vision_todo[0]]
        if left.before:
            return f"the questions \u201c{left.before[0].questionnaire.title}\u201d"
        if answered >= total and left.after:
            return f"the last questions \u201c{left.after[0].questionnaire.title}\u201d"
        return ""

    # -- the panel: questionnaires (and vision checks) ----------------------------------
    def _panel(self, when: str) -> None:
        """The questionnaires shown ``when`` (before the first trial or after the last),
        resumed on the page a killed run was on; every answer is stored as it is given."""
        panel = self.m.panel
        if panel is None:
            return
        rec = self.store.snapshot()
        progress = panel_progress(panel, rec.answers, rec.screenings, rec.events)
        if when == "before":
            checks = {"colour": self._colour_check, "acuity": self._acuity_check}
            for test in progress.vision_todo:
                if checks[test]() == "failed" and panel.vision_screening.on_fail == "end":
                    raise _ScreenedOutError(test)
        screen = FormScreen(self.display, self._state, self._shot, self._on_close,
                            lambda: self._pause_outside_trials("questions"))
        for item in progress.before if when == "before" else progress.after:
            qn = item.questionnaire

            def store_answer(page: int, question: str, value: Any, qid: str = qn.id) -> None:
                self.store.record_answer(qid, question, value, page=page)

            outcome = screen.run(qn, answered=item.answered, start_page=item.start_page,
                                 on_answer=store_answer)
            self.store.log_event(QUESTIONNAIRE_EVENT, questionnaire=qn.id, outcome=outcome)

    def _colour_check(self) -> str:
        """The generated plates (seeded by the session), scored and stored; the outcome."""
        plates = plate_series(self.store.info.seed, size=plate_size(self.display.size))
        ends = self.m.panel.vision_screening.on_fail == "end"
        self._screen(content.colour_check_intro(len(plates), self._name_keys, ends_study=ends))
        self.display.pg.key.start_text_input()
        try:
            answers = ColourCheckScreen(self.display, self._state, self._shot,
                                        self._on_close,
                                        lambda: self._pause_outside_trials("check")).run(plates)
        finally:
            self.display.pg.key.stop_text_input()
        outcome, result = score_colour(answers)
        self.store.record_screening("colour", outcome, result)
        self._state("colour-check-done")
        return outcome

    def _acuity_check(self) -> str:
        """The card calibration and the optotypes (orientations seeded by the session),
        scored and stored; the outcome."""
        vs = self.m.panel.vision_screening
        distance = vs.viewing_distance_cm
        screen = AcuityCheckScreen(self.display, self._state, self._shot, self._on_close,
                                   lambda: self._pause_outside_trials("check"))
        self._screen(content.acuity_check_intro(distance, self._name_keys,
                                                ends_study=vs.on_fail == "end"))
        geometry, card_px = screen.calibrate(distance)
        try:
            plan = acuity_plan(geometry, self.store.info.seed, kind=vs.optotype,
                               max_size_px=optotype_room(self.display.size))
        except ValueError as e:  # nothing this display can draw at this distance
            result = {"test": "acuity", "outcome": "inconclusive", "passed": False,
                      "reason": str(e), "geometry": geometry.to_dict(), "card_px": card_px}
            self.store.record_screening("acuity", "inconclusive", result)
            return "inconclusive"
        self._screen(content.acuity_trials_intro(distance, self._name_keys))
        answers = screen.run(plan, geometry)
        outcome, result = score_acuity(plan, answers, geometry,
                                       criterion_logmar=vs.acuity_logmar,
                                       criterion_contrast=vs.contrast_weber)
        result["card_px"] = card_px
        result["window"] = list(self.display.size)
        self.store.record_screening("acuity", outcome, result)
        self._state("acuity-check-done")
        return outcome

    # -- text screens -----------------------------------------------------------------
    def _screen(self, spec: content.ScreenSpec) -> str:
        """Show a text screen until one of its actions is chosen; returns the action."""
        self._stop_if_terminated()
        choice = TextScreen(self.display, self._state, self._shot, self._on_close).show(spec)
        self._stop_if_terminated()  # closed by a signal: not the screen's close action
        return choice

    # -- practice and main loop -------------------------------------------------------
    def _practice(self) -> None:
        items = pick_practice(schedule_items(self.m), self.opts.practice,
                              self.store.info.seed,
                              levels={str(c.id): c.level for c in self.m.conditions})
        min_view = self._min_view()
        self._screen(content.practice_intro(len(items), VIEWING, RATING, min_view,
                                            self._name_keys))
        self.store.log_event("practice", stimuli=[it.id for it in items])  # once begun
        self._practice_mode = True
        try:
            for k, item in enumerate(items):
                trial = PlannedTrial(-(k + 1), item.id, item.reference, 1,
                                     item.is_hidden_reference)
                pair = self._background(lambda t=trial: decode_pair(t.stimulus,
                                                                    *self._paths(t)),
                                        "Loading...")
                gpu = upload_pair(self.display, pair)
                del pair
                try:
                    while True:
                        outcome = self._trial_loop(trial, gpu, k + 1, len(items))
                        if isinstance(outcome, TrialResult):
                            break
                        self._interrupt(outcome)
                finally:
                    gpu.release()
        finally:
            self._practice_mode = False
        self._screen(content.practice_done(self._name_keys))

    def _practised(self) -> bool:
        """The practice was shown, or rating began: a participant who stopped before it (on
        the seating screen, in a questionnaire) still gets it when they come back."""
        return self.store.progress()[0] > 0 or any(
            e["kind"] == "practice" for e in self.store.events())

    def _min_view(self) -> float:
        mv = self.m.protocol.min_view_seconds
        return mv if mv is not None else self._loop_s

    def _interrupt(self, outcome: str) -> None:
        """A trial was left for the pause screen (``pause``) or by closing the window."""
        if outcome == "close":
            self._on_close()
            return
        answered, total = self.store.progress()
        self.store.log_event("pause", answered=answered)
        self._pause_menu(content.pause(answered, total, self._name_keys))

    def _pause_outside_trials(self, during: str) -> None:
        """Esc (or P) in a questionnaire or a vision check: the pause menu a trial has, so a
        participant can stop or withdraw there too (full screen has no close button)."""
        answered, total = self.store.progress()
        self.store.log_event("pause", answered=answered, during=during)
        self._pause_menu(content.pause(answered, total, self._name_keys, during=during))

    def _pause_menu(self, spec: content.ScreenSpec) -> None:
        """Pause or break: continue, stop (confirmed) or withdraw (confirmed)."""
        while True:
            choice = self._screen(spec)
            if choice == "resume":
                return
            answered, total = self.store.progress()
            confirm = (content.confirm_quit(answered, total, self._name_keys) if choice == "quit"
                       else content.confirm_withdraw(
                           self._name_keys, served=self.opts.upload_report is not None))
            if self._screen(confirm) == "yes":
                raise _QuitRequestedError if choice == "quit" else _WithdrawnError

    def _main_loop(self) -> RunOutcome:
        store = self.store
        pair, self._first_pair = self._first_pair, None
        since_break = 0
        while (trial := store.next_trial()) is not None or self._next_block():
            if trial is None:
                continue
            self._check_server()
            if pair is None or pair.stimulus != trial.stimulus:
                pair = self.prefetch.take(trial.index)
                if pair is None or pair.stimulus != trial.stimulus:
                    pair = self._background(
                        lambda t=trial: decode_pair(t.stimulus, *self._paths(t)), "Loading...")
            answered, total = self._progress()
            gpu = upload_pair(self.display, pair)
            pair = None  # the frames live in textures now; free the decoded arrays
            try:
                while not isinstance(
                        outcome := self._trial_loop(trial, gpu, answered + 1, total),
                        TrialResult):
                    self._interrupt(outcome)
            finally:
                gpu.release()
            result: TrialResult = outcome
            limit = self.opts.max_dropped_frames
            missed = int(result.details.get("missed_refreshes", result.dropped_frames))
            if needs_requeue(missed, limit, trial):
                log.warning("trial %d: %d refreshes without a new frame (limit %d); re-queued "
                            "at the end", trial.index, missed, limit)
                store.requeue(trial.index, result,
                              f"{missed} refreshes without a new frame > {limit}")
                self._state("requeued", trial=trial.index)
            else:
                store.record(trial.index, result)
                self._state("recorded", trial=trial.index, rating=f"{result.rating:.3f}")
            if self.opts.on_commit is not None:
                self.opts.on_commit()
            since_break += 1
            answered, total = self._progress()
            if break_due(since_break, self.opts.break_every, total - answered):
                since_break = 0
                store.log_event("break", answered=answered)
                self._pause_menu(content.break_screen(
                    answered, total, self._name_keys, self.m.protocol.viewing_distance_cm))
        self._panel("after")
        store.finish()
        answered, total = store.progress()
        self._state("finishing", answered=answered)
        self._end_screen(total, withdrawn=False)
        return RunOutcome("finished", self.session_path, answered, total)

    def _check_server(self) -> None:
        """Raise :class:`_EndedByServerError` when the study server refused the session."""
        why = self.opts.ended_by_server() if self.opts.ended_by_server else None
        if why:
            raise _EndedByServerError(why)

    def _ended_by_server(self, why: str) -> RunOutcome:
        """The server refused the session for good: say so, and stop asking for ratings
        that nobody would keep (the session file stays as it is)."""
        answered, total = self.store.progress()
        self.store.log_event("ended_by_server", reason=why, answered=answered)
        self._state("server-ended", answered=answered)
        self._screen(content.ended_by_server(answered, why, self._name_keys))
        return RunOutcome("ended", self.session_path, answered, total)

    # -- adaptive allocation: the blocks after the first -------------------------------
    def _later_blocks(self, done: int) -> int:
        """Trials in the blocks still to come after ``done`` blocks (0 in a full design)."""
        return later_block_trials(self.m, done)

    def _progress(self) -> tuple[int, int]:
        """(answered, trials of the whole session, blocks to come included)."""
        answered, total = self.store.progress()
        return answered, total + self._later_blocks(self.store.blocks_done())

    def _next_block(self) -> bool:
        """Add the next block of an adaptive session to the plan: from the study server
        (retried, or the session finished early, when it cannot be reached), or uniform
        when the study runs without one. False when the session has all its blocks."""
        settings = self.m.protocol.adaptive_settings()
        store = self.store
        done = store.blocks_done()
        if settings is None or done >= settings.blocks:
            return False
        block = done + 1
        plan = store.plan()
        last = plan[-1].stimulus if plan else None
        items = schedule_items(self.m)
        if self.opts.next_block is None:
            stimuli = uniform_block(items, settings.trials_per_block(len(items)),
                                    store.info.seed, block, last)
            block_id, issued_by = f"local-b{block}", "session"
        else:
            answer = self._ask_for_block(block, last)
            if answer is None:
                store.log_event("blocks_incomplete", blocks=done, of=settings.blocks)
                return False
            stimuli, block_id, issued_by = list(answer["stimuli"]), str(answer["id"]), "server"
        trials = block_trials(items, stimuli, plan)
        store.add_block(block, block_id, trials, issued_by=issued_by)
        self._state("block", number=block, trials=len(trials), issued_by=issued_by)
        return True

    def _ask_for_block(self, block: int, last: str | None) -> dict[str, Any] | None:
        """The server's next block; None when the participant chose to finish without it."""
        assert self.opts.next_block is not None
        sid = self.store.info.session_id
        while True:
            try:
                answer = self._background(lambda: self.opts.next_block(sid, block, last),
                                          "Getting the next part of the study...")
                known = {it.id for it in schedule_items(self.m)}
                stimuli = answer.get("stimuli") if isinstance(answer, dict) else None
                if not isinstance(stimuli, list) or answer.get("block") != block or \
                        not stimuli or not set(stimuli) <= known:
                    raise StudyError("the study server's block does not fit this study")
                return answer
            except StudyError as exc:
                if getattr(exc, "status", None) == 410:  # the server's "withdrawn"
                    raise _EndedByServerError(WITHDRAWN) from None
                self._check_server()
                log.warning("block %d not received: %s", block, exc)
                answered, _ = self.store.progress()
                if self._screen(content.block_unavailable(answered, self._name_keys)) \
                        == "finish":
                    return None

    def _end_screen(self, total: int, *, withdrawn: bool, screened_out: str = "") -> None:
        in_two_files = False
        try:  # the end screen tells what to send, so the file must be whole before it shows
            self.store.save_to_file()
        except StudyError as exc:
            log.warning("%s", exc)
            in_two_files = True
        upload = None
        if self.opts.upload_report is not None:
            upload = self._background(self.opts.upload_report,
                                      "Sending your last answers to the study server...")
            self._state("uploaded", arrived=int(upload[0]))
        spec = content.end(self.session_path, total, withdrawn, self._name_keys, upload=upload,
                           screened_out=screened_out, in_two_files=in_two_files)
        while self._screen(spec) == "show":
            reveal_in_file_manager(self.session_path)

    def _prefetch_following(self, trial: PlannedTrial) -> None:
        if self._practice_mode or self.store is None:
            return
        pending = self.store.pending()
        after = [p for p in pending if p.index != trial.index]
        if after:
            nxt = after[0]
            self.prefetch.start(nxt.index, nxt.stimulus, *self._paths(nxt))

    # -- the trial --------------------------------------------------------------------
    def _trial_loop(self, trial: PlannedTrial, gpu: OnGpu, k: int, total: int
                    ) -> TrialResult | str:
        """Show one trial until its rating is submitted (see :mod:`.trial_screen`)."""
        screen = TrialScreen(self.display, self.m, self._name_keys, self._state, self._shot,
                             self._prefetch_following, self._min_view)
        return screen.run(trial, gpu, k, total, practice=self._practice_mode)


def run_study(study: Study, opts: RunOptions) -> RunOutcome:
    """Run (or resume) one participant's session of ``study``."""
    return App(study, opts).run()
