"""The download bar says when no data has come for a while, and stops saying it when data
comes again (tqdm alone keeps showing the last speed over a stalled download)."""

from __future__ import annotations

import io
import re
import time

from tqdm import tqdm

from study_app.remote.stall_note import StallNote


class _Bar:
    def __init__(self) -> None:
        self.postfix: list[str] = []

    def set_postfix_str(self, text: str) -> None:
        self.postfix.append(text)


def test_quiet_seconds_are_told_and_cleared_when_data_comes():
    bar = _Bar()
    with StallNote(bar, quiet_s=0.3, every_s=0.05) as note:
        for _ in range(6):  # data every 0.1 s: never quiet long enough
            time.sleep(0.1)
            note.moved()
        assert bar.postfix == []
        time.sleep(0.6)
        assert bar.postfix and all(re.fullmatch(r"no data for \d+ s", t) for t in bar.postfix)
        note.moved()
        assert bar.postfix[-1] == ""
        seen = len(bar.postfix)
    time.sleep(0.5)  # the watcher has stopped with the download
    assert len(bar.postfix) == seen


def test_a_real_bar_shows_it():
    out = io.StringIO()
    with tqdm(total=100, file=out, mininterval=0) as bar, StallNote(bar, quiet_s=0.2,
                                                                     every_s=0.05) as note:
        bar.update(10)
        note.moved()
        time.sleep(1.3)
    assert "no data for 1 s" in out.getvalue()
