"""The panel section: the paper's sentence, answer counts, the survey figure's data, vision
screening and its exclusion, and free text kept escaped and out of summary.json."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from analysis.data import PanelAnswers
from analysis.inputs import load_ratings
from analysis.panel import NOT_ANSWERED, PREFERRED_NOT, panel_sentence, summarise_panel
from analysis.panel_figure import likert_shares, survey_questions
from analysis.pipeline import AnalysisConfig, run_analysis
from analysis.report import write_report
from session_store import SessionStore, read_session
from stimuli_manifests import parse_manifest, save_manifest
from stimuli_manifests.panel import Panel
from stimuli_manifests.panel_templates import default_panel
from study_app.simulate import SimulationOptions, run_simulation

PAYLOAD = "<script>alert('x')</script><img src=x onerror=alert(1)>"


def _panel() -> Panel:
    return Panel.model_validate(default_panel())


def test_the_papers_sentence_from_known_answers():
    answers = {
        "p1": {"age": 25, "gender": "male", "vision": "normal", "notice_artifacts": 4},
        "p2": {"age": 57, "gender": "female", "vision": "corrected"},
        "p3": {"age": 31, "gender": "male", "vision": "corrected", "task_clear": 5},
        "p4": {"age": "prefer-not-to-say", "gender": "prefer-not-to-say", "vision": "normal"},
    }
    data = PanelAnswers(answers=answers, screenings={"p1": {"colour": "passed"},
                                                     "p2": {"colour": "failed"}})
    panel = _panel()
    ages = np.array([25, 57, 31])
    assert panel_sentence(panel, data, ["p1", "p2", "p3", "p4"]) == (
        f"4 participants aged 25-57 (mean {ages.mean():.1f}, SD {ages.std(ddof=1):.1f}; 1 did "
        "not give their age), 2 male, 1 female and 1 did not say, with normal or "
        "corrected-to-normal vision (self-reported); 2 of 4 answered the post-study survey; "
        "2 took the remote vision screening (colour: generated pseudo-isochromatic plates; "
        "at 60 cm on the participants' own uncalibrated screens, a screening, not a "
        "diagnosis): 1 passed and 1 failed it (colour 1); the ratings of the one who failed "
        "were kept (flagged, not excluded).")
    data.screenings["p3"] = {"colour": "inconclusive"}
    assert "3 took the remote vision screening (" in panel_sentence(
        panel, data, ["p1", "p2", "p3", "p4"])
    assert "): 1 passed, 1 failed it (colour 1) and 1 was inconclusive; the ratings" in \
        panel_sentence(panel, data, ["p1", "p2", "p3", "p4"])
    del data.screenings["p3"]
    answers["p3"]["graphics_background"] = "yes"
    answers["p1"]["graphics_background"] = "no"
    assert ", 1 of 2 working or studying in computer graphics, vision or video;" in \
        panel_sentence(panel, data, ["p1", "p2", "p3", "p4"])
    answers["p4"]["vision"] = "not_corrected"
    assert "3 of 4 with normal or corrected-to-normal vision" in panel_sentence(
        panel, data, ["p1", "p2", "p3", "p4"])
    summary = summarise_panel(panel, data, ["p1", "p2", "p3"], ["p1", "p2", "p3", "p4"])
    gender = next(q for q in summary.questions if q.id == "gender")
    assert gender.counts == {"Female": 1, "Male": 2, "Non-binary": 0, "Another gender": 0}
    notice = next(q for q in summary.questions if q.id == "notice_artifacts")
    assert notice.counts["Agree"] == 1 and notice.counts[NOT_ANSWERED] == 2
    age = next(q for q in summary.questions if q.id == "age")
    assert age.values == [25, 57, 31]
    assert summary.failed_vision == ["p2"]
    assert summary.answered == {"demographics": 3, "post_study": 2}


def test_one_age_and_a_vision_question_left_unanswered():
    """"aged 30-30" for one shared age; a rater who did not answer the vision question was
    counted as one without normal vision ("1 of 2"), unlike a missing age."""
    data = PanelAnswers(answers={"p1": {"age": 30, "gender": "male", "vision": "normal"},
                                 "p2": {"age": 30, "gender": "female"}})
    sentence = panel_sentence(_panel(), data, ["p1", "p2"])
    assert sentence.startswith("2 participants aged 30, 1 male and 1 female, with normal or "
                               "corrected-to-normal vision (self-reported; 1 did not say how "
                               "they see)")
    data.answers["p2"]["vision"] = "not_corrected"
    assert "1 of 2 with normal or corrected-to-normal vision" in panel_sentence(
        _panel(), data, ["p1", "p2"])


def test_likert_shares_leave_out_prefer_not_to_say():
    panel = _panel()
    data = PanelAnswers(answers={f"p{i}": {"task_clear": v} for i, v in
                                 enumerate([5, 5, 4, 2, "prefer-not-to-say", None])})
    summary = summarise_panel(panel, data, [f"p{i}" for i in range(6)])
    ids, points = survey_questions(panel)
    assert "task_clear" in ids and "games_experience" not in ids  # after the trials only
    q = next(q for q in summary.likert() if q.id == "task_clear")
    shares, n = likert_shares(q, points)
    assert n == 4 and list(shares) == [0, 0.25, 0, 0.25, 0.5]
    assert q.counts[PREFERRED_NOT] == 1


@pytest.fixture(scope="module")
def panel_study(tmp_path_factory):
    """A small study whose manifest has the default panel, simulated with one colour-check
    failure, plus one session with a hostile comment."""
    folder = tmp_path_factory.mktemp("panel")
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "scene": f"scene{i}"} for i in range(3)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(3) for lv in (1, 2)]
    manifest = parse_manifest({"study_id": "panel-study", "references": refs,
                               "conditions": conds, "panel": default_panel()})
    path = save_manifest(manifest, folder / "manifest.json")
    sessions = folder / "sessions"
    run_simulation(path, sessions, SimulationOptions(raters=8, seed=3, colour_failures=1),
                   progress=False)
    hostile = sessions / "sim01.sqlite"
    with SessionStore.open(hostile) as store:
        store.record_answer("post_study", "comments", PAYLOAD, page=1)
    return path, sessions


@pytest.mark.slow  # about 10 s here: CI runs it after `make test` (.ci/run)
def test_report_panel_from_simulated_sessions(panel_study, tmp_path):
    manifest, sessions = panel_study
    # an independent count straight from the session files
    records = [read_session(p) for p in sorted(sessions.glob("*.sqlite"))]
    last = [{a["question"]: a["value"] for a in r.answers} for r in records]
    genders = Counter(a.get("gender") for a in last)
    ages = [a["age"] for a in last if isinstance(a.get("age"), int)]
    failed = [r.info.participant for r in records
              if any(s["outcome"] == "failed" for s in r.screenings)]
    survey = sum(any(q in a for q in ("notice_artifacts", "artifacts_annoying",
                                      "familiar_methods", "task_clear", "confident_ratings",
                                      "comments")) for a in last)
    assert len(failed) == 1

    rs = load_ratings(manifest, sessions=[sessions])
    a = run_analysis(rs, AnalysisConfig(n_boot=20, n_splits=20, ci_draws=5), progress=False)
    s = a.panel.sentence
    assert s.startswith(f"8 participants aged {min(ages)}-{max(ages)}")
    assert f"{genders['male']} male" in s
    assert f"{survey} of 8 answered the post-study survey" in s
    assert "7 passed and 1 failed it (colour 1); the ratings of the one who failed were " \
        "kept" in s and "8 took the remote vision screening (" in s
    assert a.quality.loc[failed[0], "vision"] == "colour failed"
    assert "colour check failed (vision screening)" in a.quality.loc[failed[0], "flags"]
    assert not any("vision screening" in str(f) for r, f in a.quality["flags"].items()
                   if r != failed[0])

    report = write_report(a, tmp_path / "report")
    summary = json.loads((report.parent / "summary.json").read_text())
    assert summary["panel"]["sentence"] == s
    # and the paper's text describes the panel with the same sentence
    assert f"The raters analysed were {s}" in (report.parent / "methods.txt").read_text()
    assert summary["panel"]["failed_vision"] == failed
    assert PAYLOAD not in json.dumps(summary) and summary["panel"]["n_free_text"]["comments"] >= 1
    html = report.read_text()
    assert "&lt;script&gt;alert(" in html and "<script>alert(" not in html
    assert "<img src=x" not in html
    assert (report.parent / "figures" / "panel_survey.png").is_file()
    assert (report.parent / "figures" / "panel_survey.pdf").read_bytes().startswith(b"%PDF")

    excluded = run_analysis(rs, AnalysisConfig(n_boot=20, n_splits=20, ci_draws=5,
                                               exclude_failed_vision=True), progress=False)
    assert failed[0] not in excluded.screened.raters
    assert any(x.kind == "failed vision check" and x.who == failed[0]
               for x in excluded.exclusions)
    assert excluded.panel.sentence.startswith("7 participants")
    assert excluded.quality.loc[failed[0], "status"] == "excluded (vision check)"


def test_split_half_histogram_of_a_tiny_panel(tmp_path):
    """Nearly constant split-half values (a tiny panel) used to crash the report."""
    from types import SimpleNamespace

    from analysis.figures import split_half_hist

    values = {k: [1.0, 1.0 - 1e-16, 1.0] for k in ("plcc", "srcc", "krcc")}
    values["rmse"] = [float("nan"), 0.5, 0.5 + 1e-17]
    a = SimpleNamespace(ceiling=SimpleNamespace(values=values))
    assert split_half_hist(a, tmp_path / "s.png").is_file()


def test_excluding_failed_vision_needs_sessions_that_took_a_check(tmp_path, capsys):
    """Sessions of a study whose panel screens no vision: --exclude-failed-vision would
    exclude nobody, silently; it is refused."""
    from analysis.cli import main

    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "scene": f"scene{i}"} for i in range(3)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(3) for lv in (1, 2)]
    path = save_manifest(parse_manifest({"study_id": "no-panel", "references": refs,
                                         "conditions": conds}), tmp_path / "manifest.json")
    sessions = tmp_path / "sessions"
    run_simulation(path, sessions, SimulationOptions(raters=4, seed=1), progress=False)
    out = tmp_path / "d.csv"
    assert main(["dmos", "--sessions", str(sessions), "--manifest", str(path),
                 "--exclude-failed-vision", "--bootstrap", "20", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no participant took a vision check" in err, err
    assert not out.exists()


def test_a_take_back_concerns_its_own_session_only():
    """A survey answered in session 1 and answered-then-taken-back in session 2 was counted
    as never answered; within one session a take-back erases, and a later valid answer
    replaces an earlier one."""
    from types import SimpleNamespace

    from analysis.panel import panel_from_sessions

    definition = Panel.model_validate(default_panel())

    def session(key, rows):
        return SimpleNamespace(
            path=f"s{key}.sqlite", order_key=key, info=SimpleNamespace(participant="P1"),
            answers=[{"questionnaire": q, "question": k, "value": v} for q, k, v in rows],
            screenings=[])

    first = session(1, [("demographics", "age", 30), ("post_study", "task_clear", 4),
                        ("post_study", "comments", "fine"), ("post_study", "comments", None)])
    second = session(2, [("demographics", "age", 31), ("post_study", "task_clear", 2),
                         ("post_study", "task_clear", None), ("post_study", "comments", None)])
    merged = panel_from_sessions([second, first], definition)
    assert merged.problems == []  # every stored answer is one the rule accepts
    answers = merged.answers["P1"]
    assert answers["age"] == 31  # the later valid answer
    assert answers["task_clear"] == 4  # session 2 took back only its own answer
    assert answers["comments"] is None  # taken back in the session that held it
    alone = panel_from_sessions([first], definition).answers["P1"]
    assert alone["comments"] is None and alone["task_clear"] == 4
