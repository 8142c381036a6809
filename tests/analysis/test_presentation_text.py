"""The paper's presentation paragraph: the player's protocol and the required display as
the manifest sets them, the timing the session files recorded, and nothing for ratings from
a CSV (another tool may have shown them)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from analysis.inputs import load_ratings
from analysis.presentation_text import _sessions, presentation_paragraph
from stimuli_manifests import parse_manifest, save_manifest
from study_app.simulate import SimulationOptions, run_simulation


def _study(folder):
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "scene": f"scene{i}"} for i in range(3)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(3) for lv in (1, 2)]
    manifest = parse_manifest({
        "study_id": "shown", "references": refs, "conditions": conds,
        "protocol": {"repetitions": 1, "blank_seconds": 0.25, "min_view_seconds": 4},
        "display": {"min_width": 1280, "min_height": 720, "min_refresh_hz": 119.5}})
    return save_manifest(manifest, folder / "manifest.json")


def test_the_protocol_and_display_are_the_manifests(tmp_path):
    path = _study(tmp_path)
    run_simulation(path, tmp_path / "sessions", SimulationOptions(raters=4, seed=1),
                   progress=False)
    rs = load_ratings(path, sessions=[tmp_path / "sessions"])
    text = presentation_paragraph(rs, None, list(rs.raters))
    assert "every switch showed a 0.25 s grey blank" in text
    assert "The rating could be given after 4 s" in text
    assert "at least 1280x720 pixels at 119.5 Hz or more" in text
    assert "hidden reference" in text
    # from a CSV of the same ratings (another tool may have shown them): nothing
    rows = [{"participant": r, "stimulus": s, "rating": float(v)}
            for j, r in enumerate(rs.raters) for i, s in enumerate(rs.stimulus_ids)
            for v in rs.scores[i, j] if np.isfinite(v)]
    pd.DataFrame(rows).to_csv(tmp_path / "ratings.csv", index=False)
    from_csv = load_ratings(path, ratings_csv=tmp_path / "ratings.csv")
    assert presentation_paragraph(from_csv, None, list(from_csv.raters)) == ""


def test_the_session_timing_is_counted_from_the_quality_table():
    quality = pd.DataFrame({"timing_mode": ["vsync", "vsync", "paced-60"],
                            "vsync": [True, True, False], "presentations": [40, 40, 20],
                            "trials_with_drops": [1, 0, 3]}, index=["P1", "P2", "P3"])
    assert _sessions(quality, ["P1", "P2", "P3"]) == (
        " 2 of the 3 sessions ran with vsync; 4 of 100 presentations (4.0%) dropped a frame "
        "or more.")
    assert _sessions(quality, ["P1", "P2"]).startswith(" All 2 sessions ran with vsync; 1 of 80")
    simulated = quality.assign(timing_mode="simulated")
    assert "simulated" in _sessions(simulated, ["P1", "P2", "P3"])
