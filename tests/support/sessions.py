"""Session files in tests: bare ones made in a line, and whole files read for comparisons."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from session_store import PlannedTrial, SessionStore, TrialResult
from session_store.outbox import OutboxEntry, read_entries
from session_store.replica import _dump
from session_store.schema import open_existing


@contextmanager
def _read_only(path: Path) -> Iterator[sqlite3.Connection]:
    con = open_existing(path, readonly=True)
    try:
        yield con
    finally:
        con.close()


def blur_manifest(folder: Path, study_id: str) -> Path:
    """``folder/manifest.json``: two references (R0, R1), each blurred at levels 1 and 2, one
    repetition; no video files (the analysis reads the manifest only)."""
    from stimuli_manifests import parse_manifest, save_manifest

    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "width": 256, "height": 144, "fps": 30,
             "frames": 90} for i in range(2)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(2) for lv in (1, 2)]
    return save_manifest(parse_manifest({
        "study_id": study_id, "references": refs, "conditions": conds,
        "protocol": {"repetitions": 1}}), folder / "manifest.json")


def session_tables(path: Path) -> dict[str, list[tuple]]:
    """Every table of a session file as rows (what two copies of a session must share)."""
    with _read_only(path) as con:
        return _dump(con)


def session_entries(path: Path) -> list[OutboxEntry]:
    """The change log (outbox) of a session file, entry by entry, as the uploader sends it."""
    with _read_only(path) as con:
        return read_entries(con)


def bare_plan(n: int) -> list[PlannedTrial]:
    """``n`` trials over three stimuli of one reference, no hidden references."""
    return [PlannedTrial(i, f"S{i % 3}", "R", i // 3 + 1, False) for i in range(n)]


def plain_result(rating: float) -> TrialResult:
    """A trial result in which only the rating matters."""
    return TrialResult(rating=rating, rt_ms=1000.0, n_toggles=1, ms_on_reference=1.0,
                       ms_on_test=2.0, presented_at="2026-01-01T00:00:00.000Z")


def bare_session(path: Path, participant: str = "P01", n: int = 6) -> SessionStore:
    """A new session file of study "s" (no manifest) with ``n`` planned trials, open."""
    return SessionStore.create(path, participant=participant, study_id="s", manifest_sha256=None,
                               seed=1, app_version="t", plan=bare_plan(n))


def player_session(folder: Path, loaded, participant: str, *, screen=(1920, 1080),
                   hz: float = 60.0, card_px: float | None = None, seed: int = 1,
                   timing: str = "vsync", practice: int | None = None,
                   break_every: int | None = None, withdraw: bool = False,
                   name: str | None = None) -> Path:
    """A participant's finished session as the player writes it: the protocol in force, the
    display the pre-flight measured (``timing``: vsync, or paced-pilot for an experimenter's
    pilot) and, with ``card_px``, the acuity check's card geometry (measured at the check's
    60 cm, not at the seating distance). Ratings: 20, 50, 80 in turn over the trials.
    ``practice``/``break_every``: the run's settings; ``withdraw``: the participant withdraws
    after the first trial; ``name``: the file's name (a second session of a participant)."""
    from session_store.schedule import make_schedule, schedule_items
    from study_app.vision.acuity import card_calibration

    m = loaded.manifest
    plan = make_schedule(schedule_items(m), m.protocol.repetitions, seed)
    settings = {"protocol": m.protocol.model_dump(mode="json"), "timing_mode": timing}
    if practice is not None:
        settings["practice_trials"] = practice
    if break_every is not None:
        settings["break_every"] = break_every
    path = folder / f"{name or participant}.sqlite"
    with SessionStore.create(path, participant=participant, study_id=m.study_id,
                             manifest_sha256=loaded.sha256, seed=seed, app_version="t",
                             plan=plan, settings=settings) as store:
        store.mark_started(display={"screen": list(screen), "refresh_hz": hz,
                                    "vsync": timing == "vsync"})
        if card_px is not None:
            store.record_screening("acuity", "passed",
                                   {"geometry": card_calibration(card_px, 60).to_dict()})
        for k, trial in enumerate(plan[:1] if withdraw else plan):
            store.record(trial.index, plain_result(20.0 + 30 * (k % 3)))
        if withdraw:
            store.withdraw()
        else:
            store.finish()
    return path
