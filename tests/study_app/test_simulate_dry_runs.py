"""Dry runs that a researcher trusts: a lower-is-better scale is rated the right way round
(the analysis mirrors it back), ``--overwrite`` replaces the whole earlier simulation, and
simulated sessions mixed with real ones are named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from analysis.inputs import load_ratings
from analysis.quality import quality_table
from analysis.scores import dmos_table, fit_scores
from stimuli_manifests import parse_manifest, save_manifest
from study_app.simulate import SimulationOptions, simulate_panel

from .test_simulate import METHODS


def _manifest(folder: Path, **scale) -> Path:
    refs = [{"id": f"SRC0{i}", "path": f"s{i}.mkv", "scene": f"scene{i}"} for i in (1, 2)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_{m}{lv}.mkv", "method": m, "level": lv}
             for r in refs for m in METHODS for lv in (1, 2, 3, 4)]
    data = {"format": "cgvq-manifest/1", "study_id": "simtest", "references": refs,
            "conditions": conds}
    if scale:
        data["scale"] = scale
    folder.mkdir(parents=True, exist_ok=True)
    return save_manifest(parse_manifest(data), folder / "manifest.json")


def test_a_lower_is_better_scale_is_rated_the_right_way_round(tmp_path):
    labels = [{"position": v, "text": t} for v, t in
              ((0, "Imperceptible"), (25, "Perceptible"), (50, "Slightly annoying"),
               (75, "Annoying"), (100, "Very annoying"))]
    mpath = _manifest(tmp_path / "m", min=0, max=100, direction="lower_is_better",
                      labels=labels)
    out = tmp_path / "sim"
    truth = json.loads(simulate_panel(mpath, out, SimulationOptions(raters=8, seed=0),
                                      progress=False).read_text())
    assert truth["scale"]["direction"] == "lower_is_better"
    # The slider: hidden references (true quality 97) sit near the "Imperceptible" end.
    from session_store import read_ratings

    rows, _ = read_ratings(out / "sim01.sqlite")
    refs = [r["rating"] for r in rows if r["is_hidden_reference"]]
    assert np.mean(refs) < 20
    rs = load_ratings(mpath, sessions=[out])
    d = dmos_table(rs, fit_scores(rs, "mos", n_boot=5))
    d = d.set_index("stimulus") if "stimulus" in d.columns else d
    q = {s["id"]: s["true_quality"] for s in truth["stimuli"] if not s["is_hidden_reference"]}
    ids = sorted(q)
    assert stats.spearmanr([d.loc[i, "dmos"] for i in ids], [q[i] for i in ids])[0] > 0.9
    assert d["dmos"].max() <= 100 + 1e-9


def test_overwrite_replaces_the_whole_earlier_simulation(tmp_path):
    mpath = _manifest(tmp_path / "m")
    out = tmp_path / "sim"
    simulate_panel(mpath, out, SimulationOptions(raters=6, outliers=3, seed=0), progress=False)
    simulate_panel(mpath, out, SimulationOptions(raters=3, seed=5), progress=False,
                   overwrite=True)
    assert sorted(p.name for p in out.glob("*.sqlite")) == [
        "sim01.sqlite", "sim02.sqlite", "sim03.sqlite"]
    assert load_ratings(mpath, sessions=[out]).raters == ["sim01", "sim02", "sim03"]


def test_simulated_raters_are_flagged_and_named_among_real_ones(tmp_path):
    mpath = _manifest(tmp_path / "m")
    out = tmp_path / "sim"
    simulate_panel(mpath, out, SimulationOptions(raters=3, seed=1), progress=False)
    alone = load_ratings(mpath, sessions=[out])
    assert not any("simulated rater" in p.message for p in alone.problems)
    # A "real" session: a simulated one whose settings say vsync (as the app writes them).
    import sqlite3

    real = out / "sim03.sqlite"
    with sqlite3.connect(real) as con:
        settings = json.loads(con.execute("SELECT settings FROM session").fetchone()[0])
        settings["timing_mode"] = "vsync"
        con.execute("UPDATE session SET settings=?", (json.dumps(settings),))
    mixed = load_ratings(mpath, sessions=[out])
    named = [p for p in mixed.problems if "simulated rater(s)" in p.message]
    assert len(named) == 1 and "2 simulated rater(s) (sim01, sim02)" in named[0].message
    flags = quality_table(mixed)["flags"]
    assert "simulated rater" in flags["sim01"] and "simulated" not in flags["sim03"]
    assert not quality_table(alone)["flags"].str.contains("simulated").any()


@pytest.mark.parametrize("methods", [("vrs",), ("path_tracing", "vrs")])
def test_the_demo_notes_name_the_families_it_simulated(methods):
    import importlib.util

    repo = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location("run_demo", repo / "scripts" / "run_demo.py")
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    truth = {"stimuli": [{"is_hidden_reference": False, "method": m, "level": lv}
                         for m in methods for lv in (1, 2, 3)]
             + [{"is_hidden_reference": True, "method": None, "level": None}]}
    text = demo._families(truth)
    assert text.startswith(f"{len(methods)} distortion famil") and "at 3 levels each" in text
    assert ("path tracing" in text) == ("path_tracing" in methods)
