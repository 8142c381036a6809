"""One trial on screen: the looping test and reference, the switch after the blank, the
rating slider, until the rating is submitted (or the participant pauses or closes).

:class:`TrialScreen` runs the presentation loop under the real-time guard
(:mod:`.realtime`); the trial's logic is the state machine of :mod:`.trial`, the geometry
comes from :mod:`.layout`, the drawing from :mod:`.screens.draw`, and input events become
commands in :mod:`.input_map`. What the session does around a trial stays in :mod:`.app`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from session_store import PlannedTrial, TrialResult
from stimuli_manifests import Manifest

from . import realtime
from .decode import DecodedPair
from .display import Display
from .input_map import event_command
from .keys import RATING, VIEWING, Keymap
from .layout import RatingLayout, ViewingLayout, rating_layout, viewing_layout
from .render import VideoTexture
from .screens.draw import LABEL_REFERENCE, LABEL_TEST, draw_rating, draw_viewing, warm_up_viewing
from .slider import Slider
from .trial import RATE, VIEW, TrialMachine

NameKeys = Callable[[Keymap, str], str]


@dataclass
class OnGpu:
    """A trial's two videos uploaded to textures (the decoded arrays are freed)."""

    stimulus: str
    tex: dict[str, VideoTexture]
    width: int
    height: int
    frames: int
    fps: float
    decode_seconds: float

    def release(self) -> None:
        for t in self.tex.values():
            t.release()


def upload_pair(d: Display, pair: DecodedPair) -> OnGpu:
    """Both videos of a trial into textures, before its first frame."""
    r = d.renderer
    t, h, w = pair.test.shape[:3]
    tex = {"test": r.upload_video(pair.test), "reference": r.upload_video(pair.reference)}
    d.ctx.finish()
    return OnGpu(pair.stimulus, tex, w, h, t, pair.fps, pair.seconds)


def viewing_layout_for(d: Display, k: NameKeys, video: tuple[int, int], progress: str,
                       min_view: float) -> ViewingLayout:
    """The viewing screen's geometry with this participant's key names."""
    hints = [f"{k(VIEWING, 'switch')}: switch test / reference",
             f"{k(VIEWING, 'rate')}: rate", f"{k(VIEWING, 'pause')}: pause"]
    notice = ["Please watch for at least", f"{min_view:.1f} s before rating"]
    return viewing_layout(d.size, video, d.fonts, labels=[LABEL_TEST, LABEL_REFERENCE],
                          progress=progress, hints=hints, notice=notice)


def rating_layout_for(d: Display, k: NameKeys, manifest: Manifest, progress: str,
                      min_view: float) -> RatingLayout:
    """The rating screen's geometry: the manifest's scale and labels, the key names."""
    scale = manifest.scale
    span = scale.max - scale.min
    labels = [((lab.position - scale.min) / span, lab.text) for lab in scale.labels]
    hints = [f"Click the scale or use {k(RATING, 'left')} {k(RATING, 'right')} "
             "(with Shift: bigger steps)", f"{k(RATING, 'submit')}: submit",
             f"{k(RATING, 'back')}: back to the videos", f"{k(RATING, 'pause')}: pause"]
    return rating_layout(d.size, d.fonts, question=scale.shown_question, labels=labels,
                         progress=progress, hints=hints,
                         notice=f"Please watch for at least {min_view:.1f} s",
                         buttons=[("back", "Back to the videos"), ("submit", "Submit")])


@dataclass
class TrialScreen:
    """Presents trials on ``display`` for the session around them (the app)."""

    display: Display
    manifest: Manifest
    name_keys: NameKeys
    state: Callable[..., None]
    """Logs a screen change (``state(name, **details)``; the end-to-end tests follow it)."""
    shot: Callable[[str], bool]
    """Saves the back buffer once per name when screenshots were asked for."""
    rating_opened: Callable[[PlannedTrial], None]
    """Called when the rating screen opens (the app prefetches the next trial then)."""
    min_view_seconds: Callable[[], float]
    """The minimum viewing time the rating screen names (the manifest's, else one loop)."""
    overlay: Callable[[Any, ViewingLayout, TrialMachine], None] | None = None
    """Draws over the viewing screen after each frame (the preview's timing overlay); it
    must keep off the video and the screen's texts."""
    machine: TrialMachine | None = field(default=None, init=False, repr=False)
    """The state of the trial on screen (or of the last one): its flip timing stays readable
    after a pause (the preview sums it up)."""

    def run(self, trial: PlannedTrial, gpu: OnGpu, k: int, total: int, *,
            practice: bool = False) -> TrialResult | str:
        """Show one trial until its rating is submitted; returns it, ``pause`` or
        ``close``. No garbage-collector pause interrupts it (see :mod:`.realtime`)."""
        with realtime.presentation_guard():
            return self._present(trial, gpu, k, total, practice)

    def _layouts(self, gpu: OnGpu, progress: str, min_view: float
                 ) -> tuple[ViewingLayout, RatingLayout]:
        return (viewing_layout_for(self.display, self.name_keys, (gpu.width, gpu.height),
                                   progress, min_view),
                rating_layout_for(self.display, self.name_keys, self.manifest, progress,
                                  self.min_view_seconds()))

    def _slider(self, rlay: RatingLayout) -> Slider:
        scale = self.manifest.scale
        return Slider(x0=rlay.track_x0, x1=rlay.track_x1, y=rlay.track_y, vmin=scale.min,
                      vmax=scale.max, labels=[(lab.position, lab.text) for lab in scale.labels],
                      fine_step=(scale.max - scale.min) / 100,
                      coarse_step=(scale.max - scale.min) / 10)

    def _present(self, trial: PlannedTrial, gpu: OnGpu, k: int, total: int,
                 practice_mode: bool) -> TrialResult | str:
        d = self.display
        pg, r = d.pg, d.renderer
        proto = self.manifest.protocol
        min_view = proto.min_view_seconds if proto.min_view_seconds is not None else (
            gpu.frames / gpu.fps)
        progress = f"{'Practice: ' if practice_mode else ''}Trial {k} of {total}"
        vlay, rlay = self._layouts(gpu, progress, min_view)
        slider = self._slider(rlay)
        m = TrialMachine(fps=gpu.fps, refresh_hz=d.refresh_hz, frames=gpu.frames,
                         slider=slider, blank_seconds=proto.blank_seconds, loop=proto.loop,
                         min_view_s=min_view, vsync=d.vsync,
                         details={"decode_seconds": gpu.decode_seconds,
                                  "timing_mode": d.timing_mode})
        self.machine = m
        warm_up_viewing(r, vlay, gpu.tex)
        if d.pacer is not None:
            d.pacer.reset()
        practice = int(practice_mode)
        self.state("viewing", trial=trial.index, practice=practice)
        hover = None
        ratio = d.pixel_ratio
        while True:
            now = time.perf_counter()
            for event in pg.event.get():
                if event.type == pg.QUIT:
                    return "close"
                if event.type == pg.MOUSEMOTION and m.phase == RATE:
                    x, y = d.to_pixels(event.pos)
                    hover = next((b.action for b in rlay.buttons
                                  if b.rect.contains_point(x, y)), None)
                cmd = event_command(pg, event, m.phase, rlay, d.to_pixels)
                if cmd is None:
                    continue
                for action in m.command(cmd, now):
                    if action.name == "log":
                        info = dict(action.info)
                        self.state(info.pop("state"), **info)
                    elif action.name == "pause":
                        self.state("pause-request", trial=trial.index)
                        return "pause"
                    elif action.name == "rating_opened":
                        self.rating_opened(trial)
                        sb = rlay.button("submit").rect
                        self.state(
                            "rating", trial=trial.index,
                            slider=f"{rlay.track_x0 / ratio:.0f},{rlay.track_x1 / ratio:.0f},"
                                   f"{rlay.track_y / ratio:.0f}",
                            submit=",".join(f"{v / ratio:.0f}" for v in sb.as_tuple()))
                    elif action.name == "viewing_resumed":
                        if d.pacer is not None:
                            d.pacer.reset()
                        self.state("viewing", trial=trial.index, practice=practice, back=1)
                    elif action.name == "submitted":
                        self.state("submitted", value=f"{slider.value:.3f}")
                        return action.result
            notice = m.notice_active(now)
            if m.phase == VIEW:
                content_now, idx = m.next_frame()
                r.clear()
                draw_viewing(r, vlay, gpu.tex.get(content_now), content_now, idx,
                             notice=notice)
                if self.overlay is not None:
                    self.overlay(r, vlay, m)
                name = content_now if not practice_mode else "practice-trial"
                shot = self.shot(name)
            else:
                value_x = slider.x_of(slider.value) if slider.is_set else None
                draw_rating(r, rlay, value_x, ready=m.may_submit,
                            notice=m.notice_text() if notice else None, hover=hover)
                shot = False if practice_mode else self.shot(
                    "rating-after-click" if slider.is_set else "rating-before-click")
            m.flipped(d.flip(), chained=not shot)
