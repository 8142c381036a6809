"""The one-line screens shown while the app waits: for the refresh measurement, and for work
in a worker thread (decoding, checksums, the last uploads) so that the window stays alive."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from .display import Display

T = TypeVar("T")

WAITING_BG = (0.14, 0.15, 0.17, 1.0)


def draw_checking_display(d: Display, i: int) -> None:
    """One frame of the refresh measurement (``i`` is the flip's number; unused)."""
    r = d.renderer
    r.clear(WAITING_BG)
    px = 24 if d.size[1] >= 900 else 20
    r.text("Checking your display...", d.size[0] / 2, d.size[1] / 2 - px, px=px,
           anchor="center")


def wait_for(d: Display, fn: Callable[[], T], message: str,
             on_close: Callable[[], None]) -> T:
    """Run ``fn`` in a worker thread while ``message`` keeps the window alive; the window's
    close button calls ``on_close`` (which stops the run by raising, or returns)."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        job = pool.submit(fn)
        while not job.done():
            for event in d.pg.event.get():
                if event.type == d.pg.QUIT:
                    on_close()
            r = d.renderer
            r.clear(WAITING_BG)
            r.text(message, d.size[0] / 2, d.size[1] / 2 - 12, px=22, anchor="center")
            d.flip()
        return job.result()

