"""The trial order of a session: seeded per participant, no stimulus twice in a row.

Each stimulus appears ``repetitions`` times. The order is drawn item by item from a seeded
generator; an item is only allowed when the rest can still be arranged without immediate
repeats (a multiset with counts ``c`` and ``R`` items left can follow item ``last`` iff every
``c[x] <= ceil(R / 2)``, and ``c[last] <= floor(R / 2)``), so the draw never dead-ends.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from stimuli_manifests import Manifest

from .errors import StudyError
from .records import PlannedTrial


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
    if len(items) == 1 and repetitions > 1:
        raise StudyError(
            "a study with a single stimulus cannot avoid showing it twice in a row; add "
            "stimuli or set protocol.repetitions to 1"
        )
    return order_trials(items, {it.id: repetitions for it in items}, seed)


def order_trials(items: Sequence[ScheduleItem], counts: dict[str, int], seed: int, *,
                 start_index: int = 0, seen: dict[str, int] | None = None,
                 last: str | None = None) -> list[PlannedTrial]:
    """Each item ``counts[id]`` times in a seeded random order without immediate repeats
    (as far as the counts allow: when one item holds more than half of them, its extra
    trials come at the end). ``start_index``, ``seen`` (repetitions already planned per
    item) and ``last`` (the trial before) continue an earlier plan: a block of an adaptive
    study."""
    ids = [it.id for it in items]
    if len(set(ids)) != len(ids):
        raise StudyError("stimulus ids in the schedule must be unique")
    if not items:
        raise StudyError("the study has no stimuli to schedule")
    by_id = {it.id: it for it in items}
    left = {k: int(counts.get(k, 0)) for k in ids}
    if any(c < 0 for c in left.values()) or not sum(left.values()):
        raise StudyError("a schedule needs non-negative counts and at least one trial")
    done = dict.fromkeys(ids, 0) if seen is None else {k: int(seen.get(k, 0)) for k in ids}
    rng = np.random.default_rng(seed)
    order: list[PlannedTrial] = []
    for index in range(start_index, start_index + sum(left.values())):
        candidates = [k for k in ids if left[k] > 0 and k != last] or \
            [k for k in ids if left[k] > 0]
        weights = np.array([left[k] for k in candidates], dtype=float)
        key = candidates[0]
        for pick in rng.choice(len(candidates), size=len(candidates), replace=False,
                               p=weights / weights.sum()):
            key = candidates[int(pick)]
            left[key] -= 1
            if _feasible(left, key):
                break
            left[key] += 1
        else:  # no candidate keeps the rest arrangeable: take the largest count
            key = max(candidates, key=lambda k: left[k])
            left[key] -= 1
        done[key] += 1
        it = by_id[key]
        order.append(PlannedTrial(index, key, it.reference, done[key], it.is_hidden_reference))
        last = key
    return order


def pick_practice(items: Sequence[ScheduleItem], n: int, seed: int,
                  levels: Mapping[str, int] | None = None) -> list[ScheduleItem]:
    """``n`` distinct stimuli for practice trials (not recorded), drawn with the seed: test
    videos before hidden references (a practice should show a distortion), and with
    ``levels`` (test id -> distortion level; 1 is the strongest) one of the strongest level
    and then one of the mildest first, so that the practice spans the range the participant
    will rate, starting with a distortion nobody can miss."""
    if n <= 0:
        return []
    rng = np.random.default_rng([seed, 0x5EED])
    tests = [it for it in items if not it.is_hidden_reference]
    refs = [it for it in items if it.is_hidden_reference]
    picks: list[ScheduleItem] = []
    known = {int(levels[it.id]) for it in tests if it.id in levels} if levels else set()
    if n >= 2 and len(known) >= 2:
        assert levels is not None
        for level in (min(known), max(known)):  # strongest, then mildest
            at = [it for it in tests if levels.get(it.id) == level and it not in picks]
            other_scene = [it for it in at if all(it.reference != p.reference for p in picks)]
            pool = other_scene or at
            picks.append(pool[int(rng.integers(len(pool)))])
    for pool in (tests, refs):
        rest = [it for it in pool if it not in picks]
        take = min(n - len(picks), len(rest))
        if take > 0:
            picks += [rest[int(i)] for i in rng.choice(len(rest), size=take, replace=False)]
    return picks


def block_seed(session_seed: int, block: int) -> int:
    """The seed of the trial order of block ``block`` (2, 3, ...) of an adaptive session:
    from the session's seed, so the server and an audit derive the same order."""
    digest = hashlib.sha256(f"{session_seed}\0block\0{block}".encode()).digest()
    return int.from_bytes(digest[:4], "big")


def uniform_counts(ids: Sequence[str], size: int, seed: int, *,
                   last: str | None = None) -> dict[str, int]:
    """``size`` trials spread evenly over ``ids``, the block an adaptive study uses before it
    can adapt. When ``size`` does not divide, the stimuli that get one more are drawn with the
    block's ``seed``: taking the first ones would give every participant's block the same
    stimuli (the hidden references, listed last, never an extra rating). ``last`` (the trial
    before the block) gets no extra one where that would put it twice in a row: a block of
    one trial after ``last`` is another stimulus."""
    base, extra = divmod(size, len(ids))
    rng = np.random.default_rng([seed, 0xB10C])
    lucky = set(rng.choice(len(ids), size=extra, replace=False).tolist()) if extra else set()
    if last in ids and ids.index(last) in lucky and base + 1 > size // 2:
        others = [k for k in range(len(ids)) if k not in lucky and ids[k] != last]
        lucky.remove(ids.index(last))
        lucky.add(others[int(rng.integers(len(others)))])
    return {s: base + (k in lucky) for k, s in enumerate(ids)}


def block_trials(items: Sequence[ScheduleItem], stimuli: Sequence[str],
                 plan: Sequence[PlannedTrial]) -> list[tuple[str, str, int, bool]]:
    """A block's stimuli as trials to append to ``plan``: (stimulus, reference, repetition,
    is_hidden_reference), repetitions counting on from the plan (re-queued trials aside)."""
    by_id = {it.id: it for it in items}
    unknown = sorted(set(stimuli) - set(by_id))
    if unknown:
        raise StudyError(f"the block names stimuli this study does not have: {unknown[:3]}")
    seen: dict[str, int] = {}
    for p in plan:
        if p.requeue_of is None:
            seen[p.stimulus] = seen.get(p.stimulus, 0) + 1
    out = []
    for sid in stimuli:
        seen[sid] = seen.get(sid, 0) + 1
        it = by_id[sid]
        out.append((sid, it.reference, seen[sid], it.is_hidden_reference))
    return out


def uniform_block(items: Sequence[ScheduleItem], size: int, session_seed: int, block: int,
                  last: str | None) -> list[str]:
    """The stimuli of a uniform block (an adaptive study run without its study server)."""
    seed = block_seed(session_seed, block)
    order = order_trials(items, uniform_counts([it.id for it in items], size, seed, last=last),
                         seed, last=last)
    return [t.stimulus for t in order]
