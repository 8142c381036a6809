"""Simulated participants: the generative model, the truth file and the session files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from cgvq_cli.study_cli import main
from session_store import read_info, read_ratings, read_session, verify_session
from session_store.errors import StudyError
from session_store.schedule import ScheduleItem, make_schedule
from stimuli_manifests import parse_manifest, save_manifest
from study_app.simulate import SimulationOptions, simulate_panel

METHODS = ("path_tracing", "vrs")


@pytest.fixture(scope="module")
def manifest(tmp_path_factory):
    """2 scenes x 2 methods x 4 levels, hidden references on (videos are never read)."""
    refs = [{"id": f"SRC0{i}", "path": f"s{i}.mkv", "scene": f"scene{i}"} for i in (1, 2)]
    conds = [{"reference": r["id"], "path": f"{r['id']}_{m}{lv}.mkv", "method": m, "level": lv}
             for r in refs for m in METHODS for lv in (1, 2, 3, 4)]
    m = parse_manifest({"format": "cgvq-manifest/1", "study_id": "simtest",
                        "references": refs, "conditions": conds})
    return save_manifest(m, tmp_path_factory.mktemp("sim") / "manifest.json")


def _ratings(folder, n):
    out = {}
    for k in range(1, n + 1):
        rows, problems = read_ratings(folder / f"sim{k:02d}.sqlite")
        assert not problems
        out[f"sim{k:02d}"] = rows
    return out


def test_noise_free_panel_rates_the_documented_truth(manifest, tmp_path):
    opts = SimulationOptions(raters=2, seed=1, bias_sd=0.0, inconsistency_range=(0.0, 0.0),
                             ambiguity_range=(0.0, 0.0))
    truth_path = simulate_panel(manifest, tmp_path, opts, progress=False)
    truth = json.loads(truth_path.read_text())
    q = {s["id"]: s["true_quality"] for s in truth["stimuli"]}
    # the documented curve: Q = 100 - A * ((5 - level) / 4) ** gamma, A/gamma 75/1.3 and 40/1.4
    assert q["SRC01_HRC01"] == pytest.approx(25.0)  # path tracing, level 1
    assert q["SRC01_HRC04"] == pytest.approx(100 - 75 * 0.25**1.3)
    assert q["SRC02_HRC05"] == pytest.approx(60.0)  # vrs, level 1
    assert q["SRC01"] == q["SRC02"] == pytest.approx(97.0)  # hidden references
    for rows in _ratings(tmp_path, 2).values():
        assert len(rows) == 18 * 3
        for r in rows:
            assert r["rating"] == pytest.approx(q[r["stimulus"]])


def test_sample_count_levels_step_as_evenly_as_their_ranks(tmp_path):
    """Levels 4, 16, 64 (sample counts) made the truth jump: severities 1, 0.8, 0.02."""
    refs = [{"id": "SRC01", "path": "s1.mkv", "scene": "scene1"}]
    conds = [{"reference": "SRC01", "path": f"pt{lv}.mkv", "method": "path_tracing",
              "level": lv} for lv in (4, 16, 64)]
    m = save_manifest(parse_manifest({"format": "cgvq-manifest/1", "study_id": "spp",
                                      "references": refs, "conditions": conds}),
                      tmp_path / "manifest.json")
    opts = SimulationOptions(raters=1, seed=1, bias_sd=0.0, inconsistency_range=(0.0, 0.0),
                             ambiguity_range=(0.0, 0.0))
    truth = json.loads(simulate_panel(m, tmp_path / "sim", opts, progress=False).read_text())
    q = [s["true_quality"] for s in truth["stimuli"] if s["id"] != "SRC01"]
    # the documented curve over ranks 1..3: Q = 100 - 75 * ((4 - rank) / 3) ** 1.3
    assert q == pytest.approx([100 - 75 * (k / 3) ** 1.3 for k in (3, 2, 1)])


def test_bias_only_panel_shifts_each_rater_by_their_bias(manifest, tmp_path):
    opts = SimulationOptions(raters=3, seed=2, bias_sd=6.0, inconsistency_range=(0.0, 0.0),
                             ambiguity_range=(0.0, 0.0))
    truth = json.loads(simulate_panel(manifest, tmp_path, opts, progress=False).read_text())
    q = {s["id"]: s["true_quality"] for s in truth["stimuli"]}
    bias = {r["participant"]: r["bias"] for r in truth["raters"]}
    assert len(set(bias.values())) == 3
    assert all(abs(b) <= 2 * 6.0 for b in bias.values())  # truncated at 2 sd
    for p, rows in _ratings(tmp_path, 3).items():
        for r in rows:
            assert r["rating"] == pytest.approx(float(np.clip(q[r["stimulus"]] + bias[p], 0, 100)))


def test_full_model_sessions_outliers_and_determinism(manifest, tmp_path):
    opts = SimulationOptions(raters=6, outliers=2, outlier_kind="mixed", seed=5)
    truth = json.loads(simulate_panel(manifest, tmp_path / "a", opts, progress=False).read_text())
    again = json.loads(simulate_panel(manifest, tmp_path / "b", opts, progress=False).read_text())
    assert truth == again
    ratings = _ratings(tmp_path / "a", 6)
    assert ratings == _ratings(tmp_path / "b", 6)  # same seed: the same sessions
    for f in sorted((tmp_path / "a").glob("*.sqlite")):  # byte for byte: no real clock in them
        assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name
        record = read_session(f)
        last = max(r["presented_at"] for r in record.ratings)
        assert all(e["at"] <= last or e["kind"] == "finish" for e in record.events)
        finish = next(e["at"] for e in record.events if e["kind"] == "finish")
        assert last <= finish < last[:10] + "T23:59"  # finished right after, not months later
        assert all(p["logged_at"] <= finish for p in record.presentations)
    q = {s["id"]: s["true_quality"] for s in truth["stimuli"]}
    kinds = {r["participant"]: r["outlier"] for r in truth["raters"]}
    assert sorted(k for k in kinds.values() if k) == ["inverted", "random"]
    assert truth["outliers"] == [p for p, k in kinds.items() if k]
    items = [ScheduleItem(s["id"], s["reference"], s["is_hidden_reference"])
             for s in truth["stimuli"]]
    for p, rows in ratings.items():
        path = tmp_path / "a" / f"{p}.sqlite"
        assert verify_session(path).exit_code == 0  # intact, complete, finished
        info = read_info(path)
        # the app's own schedule for the stored seed
        plan = make_schedule(items, 3, info.seed)
        assert [r["stimulus"] for r in rows] == [t.stimulus for t in plan]
        values = np.array([r["rating"] for r in rows])
        assert values.min() >= 0 and values.max() <= 100
        r_q = np.corrcoef(values, [q[r["stimulus"]] for r in rows])[0, 1]
        if kinds[p] is None:
            assert r_q > 0.8
        elif kinds[p] == "inverted":
            assert r_q < -0.8
        else:
            assert abs(r_q) < 0.5
    other = json.loads(simulate_panel(manifest, tmp_path / "c",
                                      SimulationOptions(raters=6, outliers=2, seed=6),
                                      progress=False).read_text())
    assert other["raters"] != truth["raters"]


def test_existing_sessions_are_not_overwritten(manifest, tmp_path):
    opts = SimulationOptions(raters=1, seed=0)
    simulate_panel(manifest, tmp_path, opts, progress=False)
    with pytest.raises(StudyError, match="--overwrite"):
        simulate_panel(manifest, tmp_path, opts, progress=False)
    simulate_panel(manifest, tmp_path, opts, overwrite=True, progress=False)


def test_cli(manifest, tmp_path):
    run = [sys.executable, "-m", "cgvq_cli.study_cli", "simulate", "--manifest", str(manifest),
           "--out", str(tmp_path), "--no-progress"]
    res = subprocess.run([*run, "--raters", "2", "--outliers", "3"], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 2 and "--outliers 3" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    res = subprocess.run([*run, "--raters", "2", "--outliers", "1", "--seed", "4"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "ground_truth.json", "ground_truth_stimuli.csv", "sim01.sqlite", "sim02.sqlite"]


@pytest.mark.parametrize("args, says", [
    (["--raters", "100000000"], "from 1 to 10000 raters"),
    (["--raters", "2", "--pace", "-1"], "--pace"),
    (["--raters", "2", "--stagger", "nan"], "--stagger"),
    (["--raters", "2", "--upload-timeout", "-1"], "--upload-timeout"),
    (["--raters", "2", "--upload-timeout", "inf"], "--upload-timeout"),
    # options that would change nothing: uploads without a server, a kind without outliers
    (["--raters", "2", "--pace", "1"], "--pace applies to uploads to a study server"),
    (["--raters", "2", "--stagger", "1"], "--stagger applies to uploads"),
    (["--raters", "2", "--offline", "sim01:0:5"], "--offline applies to uploads"),
    (["--raters", "2", "--upload-timeout", "5"], "--upload-timeout applies to uploads"),
    (["--raters", "2", "--outlier-kind", "inverted"], "no outliers are simulated"),
])
def test_cli_refuses_out_of_range_options(manifest, tmp_path, capsys, args, says):
    out = tmp_path / "out"
    code = main(["simulate", "--manifest", str(manifest), "--out", str(out), "--no-progress",
                 *args])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not out.exists()


def test_cli_refuses_an_outage_of_a_rater_it_does_not_simulate(manifest, tmp_path, capsys):
    invites = tmp_path / "invites.csv"
    invites.write_text("participant,token,server,command\n"
                       "P01,tok_0123456789abcdef0123456789,http://127.0.0.1:9,x\n"
                       "P02,tok_abcdef0123456789abcdef012345,http://127.0.0.1:9,x\n")
    out = tmp_path / "out"
    code = main(["simulate", "--manifest", str(manifest), "--raters", "1", "--out", str(out),
                 "--no-progress", "--server", "http://127.0.0.1:9", "--invites", str(invites),
                 "--offline", "P02:1:5"])  # one rater: P01 only
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "--offline P02: not one of the 1 raters simulated here (P01" in err
    assert not out.exists()


def _variant(manifest, tmp_path, **changes):
    doc = json.loads(manifest.read_text())
    doc.update(changes)
    return save_manifest(parse_manifest(doc), tmp_path / "variant.json")


@pytest.mark.parametrize("changes, args, says", [
    ({}, ["--colour-failures", "1"], "does not screen colour vision"),
    ({"panel": "colour-off"}, ["--colour-failures", "1"], "does not screen colour vision"),
    ({"panel": "colour-on"}, ["--outliers", "2", "--colour-failures", "2"],
     "at most the raters who are not outliers (1)"),
    ({"conditions": []}, [], "lists no test videos"),
    ({"protocol": "adaptive"}, ["--repetitions", "7"], "allocates trials adaptively"),
])
def test_cli_refuses_what_it_would_silently_leave_out(manifest, tmp_path, capsys, changes,
                                                      args, says):
    """Colour-check failures the panel cannot produce, more failures than honest raters, or
    a manifest of references alone: refused rather than simulated as something else."""
    from stimuli_manifests.panel_templates import default_panel

    if "panel" in changes:
        changes["panel"] = default_panel(colour_check=changes["panel"] == "colour-on")
    if "protocol" in changes:  # its blocks set the trials, not --repetitions
        changes["protocol"] = {**json.loads(manifest.read_text())["protocol"],
                               "allocation": "adaptive", "adaptive": {"blocks": 3}}
    variant = _variant(manifest, tmp_path, **changes)
    out = tmp_path / "out"
    code = main(["simulate", "--manifest", str(variant), "--out", str(out), "--no-progress",
                 "--raters", "3", *args])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and says in err, err
    assert not out.exists()


def test_colour_failures_are_simulated_as_asked(manifest, tmp_path):
    from session_store import read_session
    from stimuli_manifests.panel_templates import default_panel

    variant = _variant(manifest, tmp_path, panel=default_panel())
    out = tmp_path / "out"
    assert main(["simulate", "--manifest", str(variant), "--out", str(out), "--no-progress",
                 "--raters", "3", "--outliers", "1", "--colour-failures", "2"]) == 0
    outcomes = [read_session(p).screenings for p in sorted(out.glob("*.sqlite"))]
    failed = sum(any(s["test"] == "colour" and s["outcome"] == "failed" for s in r)
                 for r in outcomes)
    assert failed == 2


def test_cli_refuses_an_unreachable_server_before_writing(manifest, tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    invites = tmp_path / "invites.csv"
    invites.write_text("participant,token,server,command\n"
                       f"P01,tok_0123456789abcdef0123456789,http://127.0.0.1:{port},x\n"
                       f"P02,tok_abcdef0123456789abcdef012345,http://127.0.0.1:{port},x\n")
    out = tmp_path / "out"
    code = main(["simulate", "--manifest", str(manifest), "--raters", "2", "--out", str(out),
                 "--no-progress", "--server", f"http://127.0.0.1:{port}", "--invites",
                 str(invites), "--upload-timeout", "1"])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.err.count("\n") == 1 and "cannot reach the study server" in captured.err
    assert not out.exists()
