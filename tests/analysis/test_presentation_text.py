"""The paper's presentation paragraph: the player's protocol and the required display as
the manifest sets them, the timing the session files recorded, and nothing for ratings from
a CSV (another tool may have shown them)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from support.sessions import player_session

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
        " The sessions of 2 of the 3 participants ran with vsync; 4 of the 100 presentations "
        "in their session files (4.0%) dropped a frame or more; 1 of them ran paced on the "
        "clock without vsync (pilots: P3).")
    assert _sessions(quality, ["P1", "P2"]).startswith(
        " The sessions of all 2 participants ran with vsync; 1 of the 80")
    simulated = quality.assign(timing_mode="simulated")
    assert "simulated" in _sessions(simulated, ["P1", "P2", "P3"])


def _seated_study(folder):
    """A study whose player tells participants to sit 90 cm away: (manifest path, tests)."""
    refs = [{"id": "R0", "path": "r0.mkv"}]
    conds = [{"id": f"R0_blur_L{lv}", "reference": "R0", "path": f"r0_{lv}.mkv",
              "method": "blur", "level": lv} for lv in (1, 2)]
    path = save_manifest(parse_manifest({
        "study_id": "seated", "references": refs, "conditions": conds,
        "protocol": {"repetitions": 1, "viewing_distance_cm": 90}}), folder / "manifest.json")
    return path, conds


def test_the_seating_distance_screens_and_pixels_per_degree_are_the_sessions(tmp_path):
    from stimuli_manifests import load_manifest

    path, _ = _seated_study(tmp_path)
    loaded = load_manifest(path)
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    player_session(sessions, loaded, "P1", screen=(1920, 1080), hz=60.0, card_px=300)
    player_session(sessions, loaded, "P2", screen=(2560, 1440), hz=143.9, card_px=420)
    player_session(sessions, loaded, "P3", screen=(2560, 1440), hz=59.94)
    rs = load_ratings(path, sessions=[sessions])
    from analysis.quality import quality_table

    text = presentation_paragraph(rs, quality_table(rs), ["P1", "P2", "P3"])
    assert ("The participants' screens had 1920x1080 to 2560x1440 pixels (2560x1440 most "
            "often) and refreshed at 60-144 Hz.") in text
    assert "asked to sit with their eyes about 90 cm from the screen" in text
    # the check measured at 60 cm; at the 90 cm seating distance a degree spans 1.5x the
    # pixels: the acuity module's own geometry at 90 cm is the independent value
    from study_app.vision.acuity import card_calibration

    lo, hi = (card_calibration(px, 90).px_per_degree for px in (300, 420))
    assert (f"the screens of 2 of the 3 participants, whose pixel size the vision screening "
            f"measured with a bank card, showed {lo:.0f}-{hi:.0f} pixels per visual degree "
            f"(median {(lo + hi) / 2:.0f})") in text
    # without the instruction: neither the distance nor pixels per degree
    rs.presentation = {**rs.presentation, "viewing_distance_cm": None}
    text = presentation_paragraph(rs, quality_table(rs), ["P1", "P2", "P3"])
    assert "sit" not in text and "per visual degree" not in text
    assert "1920x1080 to 2560x1440" in text


def test_the_metrics_pixels_per_degree_are_set_against_the_panels(tmp_path):
    """FLIP's and ColorVideoVDP's scores name their pixels per degree in their settings; the
    report compares them with what the measured participants' screens showed at the seating
    distance, and names a metric no participant saw the stimuli like."""
    from analysis.metrics import load_metric_scores
    from analysis.presentation_text import metric_viewing_text, viewing_summary
    from analysis.quality import quality_table
    from stimuli_manifests import load_manifest
    from study_app.vision.acuity import card_calibration

    path, conds = _seated_study(tmp_path)
    sessions = tmp_path / "sessions"
    sessions.mkdir()
    for k, card in enumerate((300, 360, 420)):
        player_session(sessions, load_manifest(path), f"P{k}", screen=(1920, 1080), hz=60.0,
                 card_px=card, seed=k + 1)
    rs = load_ratings(path, sessions=[sessions])
    settings = {"flip": '{"frames": "mean", "ppd": 100.0, "range": "LDR"}',
                "cvvdp": '{"display": "standard_4k", "ppd": 62.0}', "psnr": "{}"}
    rows = [{"stimulus": c["id"], "reference": "R0", "metric": m, "score": 1.0 + i,
             "direction": "higher-better", "settings": s}
            for m, s in settings.items() for i, c in enumerate(conds)]
    pd.DataFrame(rows).to_csv(tmp_path / "scores.csv", index=False)
    scores = load_metric_scores([tmp_path / "scores.csv"])
    assert scores.ppd == {"flip": 100.0, "cvvdp": 62.0}  # psnr takes no viewing condition

    viewing = viewing_summary(rs, quality_table(rs), list(rs.raters), scores.ppd)
    lo, mid, hi = (card_calibration(px, 90).px_per_degree for px in (300, 360, 420))
    assert viewing["seating_cm"] == 90 and viewing["panel_ppd"]["n"] == 3
    assert np.allclose([viewing["panel_ppd"][k] for k in ("min", "median", "max")],
                       [lo, mid, hi])
    text, advice = metric_viewing_text(viewing)
    assert "flip was computed at 100 pixels per visual degree" in text
    assert "cvvdp was computed at 62 pixels per visual degree" in text
    assert ("at the instructed 90 cm, the 3 participants whose screens the card calibration "
            f"measured saw {lo:.0f}-{hi:.0f} (median {mid:.0f}).") in text
    # 100 ppd is beyond every participant's; 62 is within
    assert text.endswith("No measured participant saw the stimuli at the pixels per degree "
                         "of flip.")  # the paper's text says so too
    assert advice == (f"Rescore with --ppd {mid:.0f} to compare under the panel's viewing "
                      "condition.")
    assert "--ppd" not in text  # the paper's sentence states facts
    # nothing measured: said so, no advice
    text, advice = metric_viewing_text({**viewing, "panel_ppd": None})
    assert advice == "" and "were not measured" in text
    assert metric_viewing_text({**viewing, "metric_ppd": {}}) == ("", "")
