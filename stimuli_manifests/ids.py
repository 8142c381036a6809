"""VQEG-style identifiers: SRCnn for sources, SRCnn_HRCmm for processed sequences.

An HRC (hypothetical reference circuit) is one processing chain, so the same (method, level)
gets the same HRC number for every source, as in VQEG test plans.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol


class _Source(Protocol):
    """What id assignment reads and sets on a reference (the manifest's ``Reference``)."""

    id: str | None


class _Processed(Protocol):
    """What id assignment reads and sets on a condition (the manifest's ``Condition``)."""

    id: str | None
    reference: str
    method: str
    level: int


def src_id(index: int) -> str:
    """1-based source number -> ``SRC01``."""
    return f"SRC{index:02d}"


def pvs_id(src: str, hrc_index: int) -> str:
    """Source id and 1-based HRC number -> ``SRC01_HRC03``."""
    return f"{src}_HRC{hrc_index:02d}"


def hrc_numbers(pairs: list[tuple[str, int]]) -> dict[tuple[str, int], int]:
    """Number each distinct (method, level) in order of first appearance, from 1."""
    numbers: dict[tuple[str, int], int] = {}
    for pair in pairs:
        numbers.setdefault(pair, len(numbers) + 1)
    return numbers


def assign_missing_ids(references: Sequence[_Source], conditions: Sequence[_Processed]
                       ) -> None:
    """Fill in ids the user left out; ids the user gave are kept as they are.

    References without an id become ``SRCnn`` (numbered by position). A condition's
    ``reference`` may name a reference by id or, when references have no ids, by its
    1-based position as ``"SRCnn"``; conditions without an id become ``<SRC>_HRCmm``.
    Ids are set with ``object.__setattr__``, without re-running the models' validation.
    """
    taken = {r.id for r in references if r.id is not None}
    for i, ref in enumerate(references, start=1):
        if ref.id is None:
            candidate = src_id(i)
            while candidate in taken:
                candidate += "x"
            object.__setattr__(ref, "id", candidate)
            taken.add(candidate)
    hrcs = hrc_numbers([(c.method, c.level) for c in conditions])
    taken |= {c.id for c in conditions if c.id is not None}
    for cond in conditions:
        if cond.id is None:
            candidate = pvs_id(cond.reference, hrcs[(cond.method, cond.level)])
            while candidate in taken:
                candidate += "x"
            object.__setattr__(cond, "id", candidate)
            taken.add(candidate)
