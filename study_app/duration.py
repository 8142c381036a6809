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
    if high > 10:
        return max(1, 5 * math.floor(low / 5)), 5 * math.ceil(high / 5)
    return max(1, math.floor(low)), max(1, math.ceil(high))


def describe_duration(n_trials: int, loop_s: float, blank_s: float) -> str:
    """'about 50-90 minutes (240 trials), plus the breaks you take'."""
    low, high = estimate_minutes(n_trials, loop_s, blank_s)
    span = f"{low}" if low == high else f"{low}-{high}"
    unit = "minute" if high == 1 else "minutes"
    trials = "trial" if n_trials == 1 else "trials"
    return f"about {span} {unit} ({n_trials} {trials}), plus the breaks you take"


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
