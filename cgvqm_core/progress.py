"""Progress of a long run: a bar on a terminal, plain lines in a log.

tqdm redraws its bar with carriage returns, which fill a scheduler's log file with hundreds
of half-lines. Where stderr is not a terminal the command line asks for ``"lines"``: one
line at most every half minute, and one at the end.
"""

from __future__ import annotations

import sys
from time import monotonic
from typing import Literal, TextIO

from tqdm.auto import tqdm

#: True: a tqdm bar; "lines": plain lines for logs; False: nothing
Progress = bool | Literal["lines"]

LINE_EVERY_S = 30.0


def for_stderr() -> Progress:
    """What the command line shows: a bar on a terminal, lines when stderr goes to a file."""
    return True if sys.stderr.isatty() else "lines"


class LineProgress:
    """tqdm's ``update``/``close`` as whole lines: ``<desc>: 8 of 27 videos (30 %), 2 min``."""

    def __init__(self, total: int, desc: str, unit: str, *, initial: int = 0,
                 every_s: float = LINE_EVERY_S, file: TextIO | None = None) -> None:
        self.total, self.desc, self.unit, self.n = total, desc, unit, initial
        self.every_s, self.file = every_s, file
        self.start = self.last = monotonic()
        self.shown = initial

    def update(self, n: int = 1) -> None:
        self.n += n
        if monotonic() - self.last >= self.every_s:
            self._line()

    def close(self) -> None:
        if self.n != self.shown:
            self._line()

    def _line(self) -> None:
        self.last, self.shown = monotonic(), self.n
        share = f" ({100 * self.n / self.total:.0f} %)" if self.total else ""
        print(f"{self.desc}: {self.n} of {self.total} {self.unit}s{share}, "
              f"{_elapsed(self.last - self.start)}", file=self.file or sys.stderr, flush=True)


def _elapsed(seconds: float) -> str:
    minutes, s = divmod(int(seconds), 60)
    return f"{minutes} min {s} s" if minutes else f"{s} s"


def progress_bar(total: int, desc: str, unit: str, progress: Progress, *,
                 initial: int = 0) -> tqdm | LineProgress:
    """The progress display ``progress`` asks for (see :data:`Progress`)."""
    if progress == "lines":
        return LineProgress(total, desc, unit, initial=initial)
    return tqdm(total=total, desc=desc, unit=unit, initial=initial, disable=not progress)
