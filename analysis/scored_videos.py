"""Whether a scores file scored this study's videos.

A ``cgvq-scores/1`` row written by ``cgvqm batch`` or ``score --csv`` records the sha256 of
its test and reference; a manifest records each video's sha256 too (the names are not
compared: ``score --csv`` names its videos by their file names). Scores are
joined to the DMOS by stimulus id alone, and two studies (or two renders of one study) share
ids, so a scores file of other videos would give a plausible metric table for the wrong
videos. Here every row that records what it scored is compared with the manifest; files
without those columns (other labs' CSVs) pass unchecked.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import pandas as pd

from stimuli_manifests import Stimulus

from .errors import AnalysisError
from .metrics import MetricScores

SHOWN = 3
"""Examples named in the refusal."""


@dataclass(frozen=True)
class _Video:
    sha256: str | None
    reference_sha256: str | None


def _cell(value: object) -> str:
    return value.strip() if isinstance(value, str) else ""


def _videos(stimuli: Iterable[Stimulus]) -> dict[str, _Video]:
    items = list(stimuli)
    refs = {s.id: s.sha256 for s in items if s.is_hidden_reference}
    return {s.id: _Video(s.sha256, refs.get(str(s.reference))) for s in items}


def _row_mismatch(row: pd.Series, video: _Video) -> str | None:
    """Why one row scored another video than the manifest's (None when it may be this one)."""
    sha = _cell(row.get("stimulus_sha256"))
    if sha and video.sha256 and sha != video.sha256:
        return "stimulus_sha256 differs"
    ref_sha = _cell(row.get("reference_sha256"))
    if ref_sha and video.reference_sha256 and ref_sha != video.reference_sha256:
        return "reference_sha256 differs"
    return None


def check_scored_videos(scores: MetricScores, stimuli: Iterable[Stimulus],
                        manifest: str) -> None:
    """Refuse, in one line, score rows that record another video than the manifest's under
    the same id (another study's file, an earlier render): their statistics would look valid.
    ``stimuli`` are the manifest's, hidden references included; rows of ids the manifest does
    not have are left to the analysis (it names them)."""
    videos = _videos(stimuli)
    bad: dict[str, list[tuple[str, str]]] = {}
    for _, row in scores.frame.iterrows():
        video = videos.get(str(row["stimulus"]))
        why = None if video is None else _row_mismatch(row, video)
        if why is not None:
            bad.setdefault(str(row["_source"]), []).append((str(row["stimulus"]), why))
    if not bad:
        return
    source, rows = next(iter(bad.items()))
    total = sum(len(r) for r in bad.values())
    examples = ", ".join(f"{sid} ({why})" for sid, why in rows[:SHOWN])
    raise AnalysisError(
        f"metric scores file {source}: {total} score row(s) scored other videos than {manifest} "
        f"names under the same ids, e.g. {examples}; these are scores of another study or "
        "of other renders: score this study's videos (cgvqm batch --manifest "
        f"{manifest}), or give the manifest they were scored from")
