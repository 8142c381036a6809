"""What the experimenter's preview screens say (``cgvq-study preview``): nothing of it is a
participant's screen, and every one says that nothing is recorded."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ..keys import Keymap, keymap
from ..preflight import Check
from .content import ScreenSpec

NameKeys = Callable[[Keymap, str], str]
START_KEYS = keymap(go=["space", "enter"], stop=["esc", "q"])
PAUSE_KEYS = keymap(resume=["space", "enter"], stop=["q", "esc"])
END_KEYS = keymap(close=["space", "enter", "esc"])


def _buttons(keys: Keymap, items: list[tuple[str, str]], name_keys: NameKeys
             ) -> tuple[tuple[str, str], ...]:
    return tuple((a, f"{t}  ({name_keys(keys, a)})") for a, t in items)


CHECK_LABELS = {"screen_size": "Screen", "refresh_rate": "Refresh", "pixel_mapping": "Pixels",
                "memory": "Memory", "decode_speed": "Video loading"}


def _checks(checks: Sequence[Check]) -> str:
    if not checks:
        return ""
    items = "\n".join(
        f"- **{CHECK_LABELS.get(c.name, c.name)}:** "
        f"{'' if c.ok else 'NOT MET (a run would stop here): '}{c.message}" for c in checks)
    return ("\n\n## This computer\n\nThe display checks of a participant's pre-flight, "
            "reported only:\n\n" + items)


def intro(study_id: str, n: int, timing: str, overlay: bool, checks: Sequence[Check],
          name_keys: NameKeys) -> ScreenSpec:
    body = (f"**Preview of study {study_id}: nothing is recorded.** No session file is "
            "written and nothing in the study folder changes.\n\n"
            f"You will see {n} {'stimulus' if n == 1 else 'stimuli'} exactly as a participant "
            "does: the test and "
            "reference videos looping, the blank on every switch, the rating scale. Ratings "
            "you give are shown in the summary at the end and then forgotten.\n\n"
            f"Timing: {timing}."
            + (" The timing overlay beside the video shows the frame interval, the dropped "
               "frames so far and the refresh rate." if overlay else "")
            + "\n\nPause with P or Esc during a trial to stop the preview early."
            + _checks(checks))
    return ScreenSpec("preview-intro", "Preview (nothing is recorded)", body,
                      _buttons(START_KEYS, [("stop", "Stop"), ("go", "Start")], name_keys),
                      START_KEYS, close_action="stop", primary="go")


def paused(done: int, total: int, name_keys: NameKeys) -> ScreenSpec:
    body = (f"{done} of {total} stimuli previewed. Nothing is recorded.\n\n"
            "- **Continue**: the stimulus starts again from its beginning.\n"
            "- **Stop the preview**: print the timing summary and close.")
    return ScreenSpec("preview-pause", "Preview paused", body,
                      _buttons(PAUSE_KEYS, [("stop", "Stop the preview"),
                                            ("resume", "Continue")], name_keys),
                      PAUSE_KEYS, close_action="stop", primary="resume")


def summary(verdict: str, lines: Sequence[str], name_keys: NameKeys, *, stopped: bool = False
            ) -> ScreenSpec:
    """The verdict first (it must not need scrolling), then the summary's other lines."""
    body = (f"**{verdict[0].upper()}{verdict[1:]}.**\n\n"
            "The same summary is printed in the terminal:\n\n"
            + "\n".join(f"- {line}" for line in lines if line != verdict))
    return ScreenSpec("preview-end", "Preview stopped" if stopped else "Preview finished", body,
                      _buttons(END_KEYS, [("close", "Close")], name_keys), END_KEYS,
                      close_action="close", primary="close")
