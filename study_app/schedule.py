"""The trial order of a session: seeded per participant, no stimulus twice in a row.

Each stimulus appears ``repetitions`` times. The order is drawn item by item from a seeded
generator; an item is only allowed when the rest can still be arranged without immediate
repeats (a multiset with counts ``c`` and ``R`` items left can follow item ``last`` iff every
``c[x] <= ceil(R / 2)``, and ``c[last] <= floor(R / 2)``), so the draw never dead-ends.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from session_store import PlannedTrial
from session_store.errors import StudyError
from stimuli_manifests import Manifest


@dataclass(frozen=True)
class ScheduleItem:
    """What the schedule needs to know about one stimulus."""

    id: str
    reference: str
    is_hidden_reference: bool


def schedule_items(manifest: Manifest) -> list[ScheduleItem]:
    """Every stimulus of a manifest (hidden references included) as a schedule item."""
    return [ScheduleItem(s.id, s.reference, s.is_hidden_reference) for s in manifest.stimuli()]


def participant_seed(study_id: str, participant: str) -> int:
    """The default seed of a participant: stable across runs, different between people."""
    digest = hashlib.sha256(f"{study_id}\0{participant}".encode()).digest()
    return int.from_bytes(digest[:4], "big")


def _feasible(counts: dict[str, int], last: str | None) -> bool:
    remaining = sum(counts.values())
    for key, c in counts.items():
        bound = remaining // 2 if key == last else (remaining + 1) // 2
        if c > bound:
            return False
    return True


def make_schedule(
    items: Sequence[ScheduleItem], repetitions: int, seed: int
) -> list[PlannedTrial]:
    """Every item ``repetitions`` times in a seeded random order without immediate repeats."""
    if repetitions < 1:
        raise StudyError(f"repetitions must be at least 1, got {repetitions}")
    ids = [it.id for it in items]
    if len(set(ids)) != len(ids):
        raise StudyError("stimulus ids in the schedule must be unique")
    if not items:
        raise StudyError("the study has no stimuli to schedule")
    if len(items) == 1 and repetitions > 1:
        raise StudyError(
            "a study with a single stimulus cannot avoid showing it twice in a row; add "
            "stimuli or set protocol.repetitions to 1"
        )
    by_id = {it.id: it for it in items}
    counts = dict.fromkeys(ids, repetitions)
    seen = dict.fromkeys(ids, 0)
    rng = np.random.default_rng(seed)
    order: list[PlannedTrial] = []
    last: str | None = None
    for index in range(len(ids) * repetitions):
        candidates = [k for k in ids if counts[k] > 0 and k != last]
        weights = np.array([counts[k] for k in candidates], dtype=float)
        for pick in rng.choice(len(candidates), size=len(candidates), replace=False,
                               p=weights / weights.sum()):
            key = candidates[int(pick)]
            counts[key] -= 1
            if _feasible(counts, key):
                break
            counts[key] += 1
        else:  # pragma: no cover - impossible by the feasibility invariant
            raise StudyError("internal error: no feasible next trial")
        seen[key] += 1
        it = by_id[key]
        order.append(PlannedTrial(index, key, it.reference, seen[key], it.is_hidden_reference))
        last = key
    return order


def pick_practice(items: Sequence[ScheduleItem], n: int, seed: int) -> list[ScheduleItem]:
    """``n`` distinct stimuli for practice trials (not recorded), drawn with the seed."""
    if n <= 0:
        return []
    rng = np.random.default_rng([seed, 0x5EED])
    picks = rng.choice(len(items), size=min(n, len(items)), replace=False)
    return [items[int(i)] for i in picks]
