"""Whether every scene has every (method, level) the study has elsewhere.

One render exported under another name (``ours-64spp.mp4`` among ``ours_4spp.mp4``...) is
left out by the naming patterns with a one-line warning, and the study then compares "ours at
level 64" over two scenes with "baseline at level 64" over three: the design is unbalanced
and nothing else says so. Read by ``cgvq-study init`` (with the files it left out, to name
the likely one) and by ``cgvq-study check`` (from the manifest)."""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import PurePosixPath


@dataclass(frozen=True)
class Cell:
    """One test condition's place in the design, in one scene."""

    scene: str
    method: str
    level: int | None
    """A level's setting ("4 spp") may differ between scenes; the level is the design's."""

    @property
    def condition(self) -> str:
        """``method 'ours' level 64``: the condition, worded as the other design warnings
        (``method ...`` keeps a warning whole where init groups warnings by file)."""
        return f"method {self.method!r}" + (f" level {self.level}" if self.level is not None
                                            else "")


def _tokens(text: str) -> set[str]:
    """Words and numbers, lower case: ``sponza/ours-64spp`` -> sponza, ours, 64, spp (the
    extension is cut off before: ``mp4`` would read as a level 4)."""
    return set(re.findall(r"[a-z]+|\d+", text.lower()))


def _likely_file(cell: Cell, left_out: Iterable[str]) -> str | None:
    """A left-out file whose path names the cell's scene, method and level."""
    want = _tokens(cell.scene) | _tokens(cell.method) | (
        {str(cell.level)} if cell.level is not None else set())
    return next((p for p in left_out
                 if want <= _tokens(str(PurePosixPath(p).with_suffix("")))), None)


def missing_cells(cells: Iterable[Cell], left_out: Iterable[str] = ()) -> list[str]:
    """One warning per condition that some scenes with test videos lack, naming them (and a
    left-out file that looks like the missing one); empty for a complete design."""
    cells = list(cells)
    scenes = sorted({c.scene for c in cells})
    if len(scenes) < 2:
        return []
    have: dict[tuple, set[str]] = {}
    for c in cells:
        have.setdefault((c.method, c.level), set()).add(c.scene)
    left = [str(p) for p in left_out]
    out = []
    for key in sorted(have, key=lambda k: (k[0], -1 if k[1] is None else k[1])):
        missing = [s for s in scenes if s not in have[key]]
        if not missing:
            continue
        hints = [f for s in missing if (f := _likely_file(Cell(s, *key), left)) is not None]
        out.append(f"{Cell(missing[0], *key).condition} is in {len(have[key])} of {len(scenes)} "
                   f"scenes (missing in {', '.join(missing)}): its mean would rest on other "
                   "scenes than the other conditions'"
                   + (f"; a file left out may be it: {', '.join(hints)}" if hints else ""))
    return out
