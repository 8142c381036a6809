"""Panel audit fixes in the analysis: a withdrawal covers all of a participant's sessions, a
failed vision check is not undone by a later session, repeated Likert labels are counted
apart, a stored answer the question refuses is an input problem, participants a vision check
stopped or excluded are counted in the screening, and custom gender labels read as given."""

from __future__ import annotations

import copy
import hashlib
import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from analysis.data import PanelAnswers
from analysis.inputs import load_ratings
from analysis.panel import NOT_ANSWERED, PREFERRED_NOT, panel_sentence, summarise_panel
from analysis.panel_figure import likert_shares, survey_questions
from analysis.pipeline import AnalysisConfig, run_analysis
from session_store import SessionStore, read_session
from session_store.schedule import ScheduleItem, make_schedule
from stimuli_manifests import parse_manifest, save_manifest
from stimuli_manifests.panel import Panel
from stimuli_manifests.panel_templates import default_panel
from study_app.simulate import SimulationOptions, run_simulation

FAST = {"n_boot": 20, "n_splits": 20, "ci_draws": 5}


def _study(folder: Path, *, on_fail: str = "flag", raters: int = 5,
           colour_failures: int = 0) -> tuple[Path, Path]:
    """3 SRC x 2 levels plus hidden references, the default panel, simulated raters."""
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "scene": f"scene{i}"} for i in range(3)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(3) for lv in (1, 2)]
    panel = copy.deepcopy(default_panel())
    panel["vision_screening"]["on_fail"] = on_fail
    manifest = save_manifest(parse_manifest({"study_id": "fixes", "references": refs,
                                             "conditions": conds, "panel": panel,
                                             "protocol": {"repetitions": 1}}),
                             folder / "manifest.json")
    sessions = folder / "sessions"
    run_simulation(manifest, sessions, SimulationOptions(raters=raters, seed=11,
                                                         colour_failures=colour_failures),
                   progress=False)
    return manifest, sessions


@pytest.fixture(scope="module")
def flag_study(tmp_path_factory):
    return _study(tmp_path_factory.mktemp("flag"), colour_failures=1)


@pytest.fixture
def study(flag_study, tmp_path):
    """A private copy of the simulated study, free to change."""
    manifest, _ = flag_study
    shutil.copytree(manifest.parent, tmp_path / "s")
    return tmp_path / "s" / "manifest.json", tmp_path / "s" / "sessions"


def _extra_session(manifest: Path, sessions: Path, name: str, participant: str,
                   created_at: str) -> SessionStore:
    """A further session of the study (no rating yet), as the player creates it."""
    doc = json.loads(manifest.read_text())
    items = [ScheduleItem(c["id"], c["reference"], False) for c in doc["conditions"]]
    items += [ScheduleItem(r["id"], r["id"], True) for r in doc["references"]]
    return SessionStore.create(sessions / name, participant=participant, study_id="fixes",
                               manifest_sha256=hashlib.sha256(manifest.read_bytes()).hexdigest(),
                               seed=99, app_version="test", plan=make_schedule(items, 1, 99),
                               settings={}, created_at=created_at)


def _failed_participant(sessions: Path) -> str:
    """Who failed the colour check, read straight from the session files."""
    failed = [read_session(p).info.participant for p in sorted(sessions.glob("*.sqlite"))
              if any(s["outcome"] == "failed" for s in read_session(p).screenings)]
    assert len(failed) == 1
    return failed[0]


# -- 1. a withdrawal covers the participant -----------------------------------------------
def test_a_withdrawal_covers_every_session_of_the_participant(study):
    manifest, sessions = study
    with SessionStore.open(sessions / "sim03.sqlite") as s:
        s.record_answer("post_study", "comments", "P03: my colleague Bob sat next to me",
                        page=1)
    with _extra_session(manifest, sessions, "sim03_second.sqlite", "sim03",
                        "2031-01-01T00:00:00Z") as store:
        store.mark_started(display={})
        store.withdraw()
    rs = load_ratings(manifest, sessions=[sessions])
    assert "sim03" not in rs.raters and "sim03" not in rs.panel.answers
    refused = {Path(x.who).name for x in rs.exclusions if x.kind == "refused session"}
    assert refused == {"sim03.sqlite", "sim03_second.sqlite"}
    summary = summarise_panel(rs.panel.definition, rs.panel, list(rs.raters))
    assert summary.sentence.startswith("4 participants")
    assert not any("Bob" in t for t in summary.free_text["comments"])


# -- 3. a failed check is not undone by a later session -------------------------------------
def test_a_failed_check_is_not_undone_by_passing_it_later(study):
    manifest, sessions = study
    who = _failed_participant(sessions)
    with _extra_session(manifest, sessions, f"{who}_day2.sqlite", who,
                        "2031-01-01T00:00:00Z") as store:
        store.mark_started(display={})
        store.record_screening("colour", "passed", {"test": "colour"})
    rs = load_ratings(manifest, sessions=[sessions])
    assert rs.panel.screenings[who] == {"colour": "failed"}
    assert rs.panel.failed_vision() == [who]
    a = run_analysis(rs, AnalysisConfig(**FAST, exclude_failed_vision=True), progress=False)
    assert who not in a.screened.raters
    assert a.quality.loc[who, "vision"] == "colour failed"


# -- 5. repeated Likert point labels ----------------------------------------------------------
def test_repeated_likert_labels_are_counted_per_point():
    points = ["Strongly disagree", "-", "-", "Neutral", "-", "-", "Strongly agree"]
    panel = Panel.model_validate({"questionnaires": [{
        "id": "post", "when": "after", "title": "Survey", "pages": [{"questions": [
            {"id": "task_clear", "type": "likert", "text": "Task was clear",
             "points": points}]}]}]})
    given = {"p1": 1, "p2": 2, "p3": 3, "p4": 4, "p5": 7, "p6": 2}
    data = PanelAnswers(answers={p: {"task_clear": v} for p, v in given.items()})
    q = summarise_panel(panel, data, list(given)).likert()[0]
    per_point = [v for k, v in q.counts.items() if k not in (PREFERRED_NOT, NOT_ANSWERED)]
    assert per_point == [1, 2, 1, 1, 0, 0, 1]  # by hand from ``given``
    _, scale = survey_questions(panel)
    shares, n = likert_shares(q, scale)
    assert n == 6
    assert [round(x, 6) for x in shares] == [round(x / 6, 6) for x in (1, 2, 1, 1, 0, 0, 1)]


# -- 6. an answer the question refuses --------------------------------------------------------
def test_an_answer_the_question_refuses_is_an_input_problem(study):
    manifest, sessions = study
    path = sessions / "sim02.sqlite"
    before = [r["value"] for r in read_session(path).answers if r["question"] == "task_clear"]
    with SessionStore.open(path) as s:
        s.record_answer("post_study", "task_clear", "agree", page=1)
    rs = load_ratings(manifest, sessions=[sessions])
    a = run_analysis(rs, AnalysisConfig(**FAST), progress=False)
    mine = [p for p in a.problems if Path(p.source).name == "sim02.sqlite"]
    assert len(mine) == 1
    assert mine[0].message.startswith("answer task_clear: expected a point 1..5, got a text of ")
    # the refused answer is left out: sim02's earlier answer (if any) stands
    assert rs.panel.answers["sim02"].get("task_clear") == (before[-1] if before else None)
    answers = {p: read_session(f).answers for p, f in
               ((read_session(f).info.participant, f) for f in sessions.glob("*.sqlite"))}
    expected = sum(any(r["question"] == "task_clear" and isinstance(r["value"], int)
                       for r in rows) for rows in answers.values())
    q = next(q for q in a.panel.questions if q.id == "task_clear")
    assert q.n_answered == expected


# -- 7. screened out or excluded participants in the screening ------------------------------
def test_a_participant_the_check_ended_is_counted_in_the_screening(tmp_path):
    manifest, sessions = _study(tmp_path, on_fail="end", raters=5)
    with _extra_session(manifest, sessions, "screened_out.sqlite", "p_out",
                        "2030-06-01T00:00:00Z") as store:
        store.mark_started(display={})
        store.record_screening("colour", "failed", {"test": "colour"})
        store.log_event("ended_by_vision_check", test="colour")
        store.finish(allow_incomplete=True)
    rs = load_ratings(manifest, sessions=[sessions])
    a = run_analysis(rs, AnalysisConfig(**FAST), progress=False)
    assert a.panel.failed_vision == ["p_out"]
    row = next(r for r in a.panel.screening if r["participant"] == "p_out")
    assert row["colour"] == "failed" and row["ratings used"] == "no"
    assert a.panel.sentence.endswith(
        "a screening, not a diagnosis) and all passed it; 1 further participant failed it and "
        "was not admitted (the check ended their session).")
    assert "; 5 took the remote vision screening (" in a.panel.sentence
    ended = [x for x in a.exclusions if x.kind == "ended by vision check"]
    assert [x.who for x in ended] == ["p_out"]


def test_the_sentence_counts_raters_excluded_for_their_vision(study):
    manifest, sessions = study
    who = _failed_participant(sessions)
    with sqlite3.connect(sessions / f"{who}.sqlite") as con:
        assert con.execute("SELECT count(*) FROM ratings").fetchone()[0] > 0
    rs = load_ratings(manifest, sessions=[sessions])
    a = run_analysis(rs, AnalysisConfig(**FAST, exclude_failed_vision=True), progress=False)
    assert a.panel.sentence.endswith(
        "a screening, not a diagnosis) and all passed it; 1 further participant failed it and "
        "was left out of the analysis.")
    assert "; 4 took the remote vision screening (" in a.panel.sentence
    assert a.panel.failed_vision == [who]


# -- 10. gender labels that do not follow a number -------------------------------------------
def test_custom_gender_labels_are_listed_as_given():
    block = copy.deepcopy(default_panel())  # the template's dicts are shared
    gender = block["questionnaires"][0]["pages"][0]["questions"][1]
    assert gender["id"] == "gender"
    gender["options"] = [{"value": "man", "label": "Man"}, {"value": "woman", "label": "Woman"}]
    panel = Panel.model_validate(block)
    answers = {"p1": {"gender": "man"}, "p2": {"gender": "woman"}, "p3": {"gender": "man"},
               "p4": {"gender": "prefer-not-to-say"}}
    sentence = panel_sentence(panel, PanelAnswers(answers=answers), list(answers))
    assert sentence.startswith("4 participants (gender: Man 2, Woman 1; 1 did not say)")
    assert "man" not in sentence.replace("Man", "").replace("Woman", "")


def test_another_gender_reads_as_a_phrase():
    panel = Panel.model_validate(default_panel())
    answers = {"p1": {"gender": "male"}, "p2": {"gender": "other"}}
    sentence = panel_sentence(panel, PanelAnswers(answers=answers), list(answers))
    assert sentence.startswith("2 participants, 1 male and 1 of another gender")
