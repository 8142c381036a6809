"""Fixtures of the analysis tests: generated studies (known truth) and the SUREAL data."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis.synthetic import SyntheticStudy, synthetic_study


@pytest.fixture
def sureal_dir(shared_data: Path) -> Path:
    """../shared/data/sureal (skipped when absent)."""
    path = shared_data / "sureal"
    if not path.is_dir():
        pytest.skip("../shared/data/sureal is not present")
    return path


@pytest.fixture(scope="session")
def study() -> SyntheticStudy:
    """20 raters x 3 repetitions x 70 stimuli, one random (outlier) rater, P01."""
    return synthetic_study(n_scenes=10, methods=("blur", "noise", "alias"), levels=2,
                           n_raters=20, n_outliers=1, noise_sd=6.0, bias_sd=4.0, seed=3)


def write_session(path: Path, rows, *, study_id: str, manifest_sha256: str | None,
                  all_trials=None, settings: dict | None = None, display: dict | None = None,
                  preflight_skipped: bool = False, requeue: tuple[int, ...] = (),
                  dropped: dict[int, int] | None = None, viewing_ms: float = 4000.0,
                  withdraw: bool = False, finish: bool = True, session_id: str | None = None,
                  created_at: str | None = None) -> Path:
    """A real session file (through session_store) holding ``rows`` of one participant.

    ``all_trials``: (stimulus, reference, repetition, is_hidden) of the whole plan; the rows
    answered come first, the rest stay unanswered (a partial session). ``requeue``: answer
    positions whose first attempt is re-queued; ``dropped``: position -> dropped frames.
    """
    session = pytest.importorskip("session_store")
    answered = [(r.stimulus, r.reference, int(r.repetition), bool(r.is_hidden_reference))
                for r in rows.itertuples()]
    rest = [t for t in (all_trials or []) if (t[0], t[2]) not in {(a[0], a[2])
                                                                    for a in answered}]
    plan = [session.PlannedTrial(index=i, stimulus=s, reference=ref, repetition=rep,
                                 is_hidden_reference=hid)
            for i, (s, ref, rep, hid) in enumerate(answered + rest)]
    participant = str(rows["participant"].iloc[0])
    store = session.SessionStore.create(
        path, participant=participant, study_id=study_id, manifest_sha256=manifest_sha256,
        seed=0, app_version="test", plan=plan, settings=settings or {"timing_mode": "vsync"},
        session_id=session_id, created_at=created_at, durable=False)
    try:
        store.save_preflight([], skipped=preflight_skipped)
        store.mark_started(display=display or {"vsync": True, "refresh_hz": 60})
        later = []
        for k, r in enumerate(rows.itertuples()):
            result = session.TrialResult(
                rating=float(r.rating), rt_ms=900.0, n_toggles=2,
                ms_on_reference=viewing_ms / 2, ms_on_test=viewing_ms / 2,
                presented_at="2026-01-01T00:00:00Z",
                dropped_frames=int((dropped or {}).get(k, 0)), frames_presented=300,
                details={"viewing_ms": viewing_ms, "toggle_times_ms": [100.0, 900.0],
                         "vsync": (display or {}).get("vsync", True)})
            if k in requeue:  # this attempt dropped frames: answered again at the end
                bad = session.TrialResult(**{**result.__dict__, "dropped_frames": 30})
                later.append((store.requeue(k, bad, "too many dropped frames").index, result))
                continue
            store.record(k, result)
        for index, result in later:
            store.record(index, result)
        if withdraw:
            store.withdraw()
        elif finish:
            store.finish(allow_incomplete=True)
    finally:
        store.close()
    return path
