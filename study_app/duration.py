"""How long a session will take, told to the participant before it starts (pure)."""

from __future__ import annotations

import math

from session_store.schedule import schedule_items
from stimuli_manifests import Manifest

# Per trial, a participant watches the test video about 1-2 times and the reference about
# 1-2 times (each switch adds a blank), then rates and the next pair loads. The range below
# brackets that: the CGVQM+D design (240 trials of 3 s loops) gives about 50-90 minutes,
# the paper's reported 60-90 minutes falling inside.
LOW_LOOPS, HIGH_LOOPS = 2.5, 4.0
LOW_BLANKS, HIGH_BLANKS = 1, 3
LOW_OVERHEAD_S, HIGH_OVERHEAD_S = 5.0, 8.0


def estimate_minutes(n_trials: int, loop_s: float, blank_s: float) -> tuple[int, int]:
    """(low, high) estimate in whole minutes, rounded outwards to 5 min above 10 min."""
    if n_trials <= 0:
        return 0, 0
    low = n_trials * (LOW_LOOPS * loop_s + LOW_BLANKS * blank_s + LOW_OVERHEAD_S) / 60
    high = n_trials * (HIGH_LOOPS * loop_s + HIGH_BLANKS * blank_s + HIGH_OVERHEAD_S) / 60
    return _rounded(low, high)


# The panel around the trials, per item (seconds, low and high): a colour plate is read at
# a glance or after a look; the acuity check is the card (about a minute) and some 40 rings;
# a question is read and answered.
PLATE_S = (3.0, 8.0)
PLATES = 8
ACUITY_S = (120.0, 240.0)
QUESTION_S = (8.0, 20.0)


def panel_seconds(panel: object | None) -> tuple[float, float, list[str]]:
    """(low, high) seconds of a study's vision checks and questionnaires, and their names in
    the participant's words (what the announced time includes besides the trials)."""
    if panel is None:
        return 0.0, 0.0, []
    low = high = 0.0
    parts = []
    vs = getattr(panel, "vision_screening", None)
    if vs is not None and vs.colour:
        low, high = low + PLATES * PLATE_S[0], high + PLATES * PLATE_S[1]
        parts.append("a colour vision check")
    if vs is not None and vs.acuity:
        low, high = low + ACUITY_S[0], high + ACUITY_S[1]
        parts.append("a sharpness check")
    n = sum(len(page.questions) for qn in panel.questionnaires for page in qn.pages)
    if n:
        low, high = low + n * QUESTION_S[0], high + n * QUESTION_S[1]
        parts.append(f"{n} question{'s' if n != 1 else ''}")
    return low, high, parts


def describe_duration(n_trials: int, loop_s: float, blank_s: float,
                      panel: object | None = None) -> str:
    """'about 50-90 minutes (240 trials), plus the breaks you take'; with a ``panel``, its
    checks and questions are counted and named ('(240 trials, a colour vision check and 12
    questions)')."""
    low, high = estimate_minutes(n_trials, loop_s, blank_s)
    extra_low, extra_high, parts = panel_seconds(panel)
    if parts:  # the trials' span in seconds, the panel's added, rounded as the trials' are
        t_low = 0 if n_trials <= 0 else n_trials * (
            LOW_LOOPS * loop_s + LOW_BLANKS * blank_s + LOW_OVERHEAD_S)
        t_high = 0 if n_trials <= 0 else n_trials * (
            HIGH_LOOPS * loop_s + HIGH_BLANKS * blank_s + HIGH_OVERHEAD_S)
        low, high = _rounded((t_low + extra_low) / 60, (t_high + extra_high) / 60)
    span = f"{low}" if low == high else f"{low}-{high}"
    unit = "minute" if high == 1 else "minutes"
    what = [f"{n_trials} {'trial' if n_trials == 1 else 'trials'}", *parts]
    listed = what[0] if len(what) == 1 else ", ".join(what[:-1]) + " and " + what[-1]
    return f"about {span} {unit} ({listed}), plus the breaks you take"


def _rounded(low: float, high: float) -> tuple[int, int]:
    """Whole minutes rounded outwards, to 5 min above 10 min (as :func:`estimate_minutes`)."""
    if high > 10:
        return max(1, 5 * math.floor(low / 5)), 5 * math.ceil(high / 5)
    return max(1, math.floor(low)), max(1, math.ceil(high))


def later_block_trials(manifest: Manifest, done: int) -> int:
    """Trials in the blocks still to come after ``done`` blocks (0 in a full design)."""
    settings = manifest.protocol.adaptive_settings()
    if settings is None:
        return 0
    per_block = settings.trials_per_block(len(schedule_items(manifest)))
    return max(settings.blocks - done, 0) * per_block


def session_trials(manifest: Manifest) -> int:
    """Rated trials in a participant's whole session (practice aside): every stimulus
    ``repetitions`` times, or, in an adaptive study, every block."""
    items = len(schedule_items(manifest))
    if manifest.protocol.allocation == "adaptive":
        return items + later_block_trials(manifest, 1)
    return items * manifest.protocol.repetitions
