"""The panel end to end: the real app under Xvfb, driven by X input, answers the
demographics questionnaire (killed with SIGKILL on its second page and resumed there with
nothing lost), rates, answers the post-study survey and uploads to a real server; simulated
raters fill the panel; ``pull`` and ``cgvq-analyze report`` show the panel sentence and the
survey counts with the answers given."""

from __future__ import annotations

import json
import os
import shutil
import signal
from collections import Counter

import pytest
from support.gui import AppDriver
from support.studies import make_study

from session_store import read_session
from session_store.answers import latest_answers
from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from stimuli_manifests.panel_templates import default_panel
from study_app.remote.admin import pull
from study_app.simulate import SimulationOptions, UploadOptions, run_simulation
from study_app.vision.isochromatic import plate_series

from .conftest import ADMIN, REPO, cli_env

# about 35 s: CI runs it after `make test` (.ci/run), as does `make test-slow`
pytestmark = [pytest.mark.gui, pytest.mark.slow]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "questionnaire"
COMMENT = "<b>Nice</b> & clear"


def _panel_study(folder):
    study = make_study(folder, min_display=(640, 480))  # 3 stimuli, 64x64, 1 s
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["panel"] = default_panel()  # with the colour-vision check
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    return study


def test_questionnaires_in_the_real_app_through_the_server(tmp_path, xdisplay, invites,
                                                           server_factory):
    study = _panel_study(tmp_path / "served")
    inv = invites(5, study=study)
    srv = server_factory(study, "--stats-every", "1")
    data = tmp_path / "participant-home"
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    me = inv[0]
    args = ["--server", srv.url, "--participant", me.participant, "--token", me.token,
            "--data-dir", str(data), "--seed", "5", "--practice", "0",
            "--max-dropped-frames", "-1", "--screenshots", str(ARTIFACTS), "--pilot-no-vsync"]
    env = {**xdisplay, **{k: v for k, v in cli_env().items() if k == "CGVQ_ADMIN_TOKEN"}}

    app = AppDriver(env, args)
    app.wait("preflight-passed", timeout=90)
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    app.key("a")
    app.wait("colour-check")
    app.key("space")
    plates = plate_series(5)  # the session's seed (--seed 5) draws the plates
    for k, plate in enumerate(plates, start=1):
        app.wait(f"colour-plate index={k} of={len(plates)} kind={plate.kind}")
        # every plate read right but one deuteranopia plate: one slip is no failure
        slip = plate.kind == "deutan" and k == next(
            i for i, p in enumerate(plates, start=1) if p.kind == "deutan")
        app.key("n" if slip else plate.answer, "Return")
        app.wait(f"colour-plate-answered index={k}")
    app.wait("colour-check-done")
    app.wait("questionnaire id=demographics page=1")
    subprocess_type(env, "34")  # the age field has the focus
    app.key("Tab", "2")  # leaving the age field stores it; gender: the second option (Male)
    app.wait("answered id=demographics question=age")
    app.wait("answered id=demographics question=gender")
    app.key("Return")
    app.wait("questionnaire id=demographics page=2")
    app.key("1")  # vision: Normal
    app.wait("answered id=demographics question=vision")
    os.kill(app.proc.pid, signal.SIGKILL)  # killed mid-page
    app.proc.wait(timeout=10)

    app = AppDriver(env, args)
    if app.wait("preflight-passed", timeout=90, required=False) is None:
        pytest.fail(f"resume failed: {app.finish()} {app.lines}")
    app.key("space")
    app.wait("welcome-back")
    app.key("space")
    app.wait("questionnaire id=demographics page=2")  # the same page, answers kept
    app.key("Tab", "1")  # colour vision: No
    app.wait("answered id=demographics question=colour_vision")
    app.key("Return")
    app.wait("questionnaire id=demographics page=3")
    app.key("4", "Tab", "2")  # games: Often; graphics background: No
    app.wait("answered id=demographics question=graphics_background")
    app.key("Return")
    app.wait("questionnaire-done id=demographics")
    for _ in range(3):
        app.wait("viewing")
        app.open_rating()
        app.key("Right", "Right", "Return")
        app.wait("recorded")
    app.wait("questionnaire id=post_study page=1")
    app.key("4", "Tab", "5", "Tab", "3", "Return")
    app.wait("questionnaire id=post_study page=2")
    app.key("5", "Tab", "4", "Tab")
    subprocess_type(env, COMMENT)
    app.key("Return")
    app.wait("questionnaire-done id=post_study")
    app.wait("uploaded arrived=1", timeout=60)
    app.wait("end")
    app.key("Return")
    code, out = app.finish(timeout=60)
    assert code == 0, (out, app.lines[-10:])
    assert not any(COMMENT in line or "34" in line.split("state:")[-1] for line in app.lines
                   if "answered" in line)  # answers are never logged

    local = next(data.rglob("sessions/*.sqlite"))
    mine = {q: row["value"] for (_, q), row in
            latest_answers(read_session(local).answers).items()}
    assert mine == {"age": 34, "gender": "male", "vision": "normal", "colour_vision": "no",
                    "games_experience": 4, "graphics_background": "no",
                    "notice_artifacts": 4, "artifacts_annoying": 5, "familiar_methods": 3,
                    "task_clear": 5, "confident_ratings": 4, "comments": COMMENT}

    record = read_session(local)
    [check] = record.screenings
    assert check["outcome"] == "passed" and check["result"]["errors"]["deutan"] == 1
    assert [p["given"] == p["answer"] for p in check["result"]["plates"]].count(False) == 1

    run_simulation(study / "manifest.json", tmp_path / "sim", SimulationOptions(
                       raters=4, seed=9, colour_failures=1),
                   progress=False, upload=UploadOptions(
                       srv.url, {i.participant: i.token for i in inv[1:]}, timeout_s=120))
    pulled = tmp_path / "pulled"
    pull(srv.url, ADMIN, pulled, answers=tmp_path / "answers.csv")
    report = tmp_path / "report"
    res = __import__("subprocess").run(
        [__import__("sys").executable, "-m", "analysis.cli", "report", "--sessions",
         str(pulled), "--manifest", str(study / "manifest.json"), "--out", str(report),
         "--bootstrap", "20", "--splits", "20", "--min-completeness", "0"],
        capture_output=True, text=True, timeout=300, cwd=REPO)
    assert res.returncode == 0, res.stderr[-2000:]
    panel = json.loads((report / "summary.json").read_text())["panel"]
    # the expected counts, straight from the pulled session files
    records = [read_session(p) for p in sorted(pulled.glob("*.sqlite"))]
    answers = [{q: row["value"] for (_, q), row in latest_answers(r.answers).items()}
               for r in records]
    used = panel["n_participants"]
    assert used == 5
    gender = next(q for q in panel["questions"] if q["id"] == "gender")["counts"]
    assert gender["Male"] == sum(a.get("gender") == "male" for a in answers) >= 1
    task = next(q for q in panel["questions"] if q["id"] == "task_clear")["counts"]
    assert task["Strongly agree"] == Counter(a.get("task_clear") for a in answers)[5] >= 1
    ages = [a["age"] for a in answers if isinstance(a.get("age"), int)]
    assert panel["sentence"].startswith(f"5 participants aged {min(ages)}-{max(ages)}")
    survey = sum(any(k in a for k in ("notice_artifacts", "task_clear", "comments"))
                 for a in answers)
    assert f"{survey} of 5 answered the post-study survey" in panel["sentence"]
    assert "5 took the remote vision screening (" in panel["sentence"]
    assert "): 4 passed and 1 failed it (colour 1)" in panel["sentence"]
    assert me.participant not in panel["failed_vision"] and len(panel["failed_vision"]) == 1
    html = (report / "report.html").read_text()
    assert "&lt;b&gt;Nice&lt;/b&gt; &amp; clear" in html and COMMENT not in html
    assert (report / "figures" / "panel_survey.png").is_file()
    for page in ("questionnaire-demographics-1", "questionnaire-demographics-3",
                 "questionnaire-post_study-2", "colour-check", "colour-plate-protan",
                 "colour-plate-control"):
        assert (ARTIFACTS / f"{page}.png").is_file(), sorted(p.name for p in
                                                            ARTIFACTS.iterdir())


def subprocess_type(env: dict[str, str], text: str) -> None:
    """Type ``text`` with xdotool (characters arrive as text input)."""
    import subprocess
    import time

    subprocess.run(["xdotool", "type", "--delay", "60", text], env=env, check=True)
    time.sleep(0.2)
