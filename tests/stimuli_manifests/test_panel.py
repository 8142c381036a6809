"""The manifest's panel block (cgvq-panel/1): templates, malformed definitions refused in
one line, and the one rule for what a valid answer is."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import pytest

from stimuli_manifests import ManifestError, parse_manifest
from stimuli_manifests.panel import (
    PREFER_NOT_TO_SAY,
    Likert,
    MultipleChoice,
    Number,
    Panel,
    PanelError,
    SingleChoice,
    Text,
    check_answer,
)
from stimuli_manifests.panel_templates import DEMOGRAPHICS, POST_STUDY_SURVEY, default_panel

BASE = {"study_id": "s", "references": [{"id": "r", "path": "r.mkv"}]}


def manifest_with(panel: dict):
    return parse_manifest({**BASE, "panel": panel})


def test_templates_are_valid_and_cover_what_a_paper_reports():
    panel = manifest_with(default_panel()).panel
    assert [q.when for q in panel.questionnaires] == ["before", "after"]
    ids = {q.id for qn in panel.questionnaires for q in qn.questions()}
    assert {"age", "gender", "vision", "colour_vision"} <= ids
    survey = panel.questionnaires_at("after")[0]
    assert survey.voluntary
    assert sum(isinstance(q, Likert) for q in survey.questions()) == 5
    assert panel.vision_screening is not None and panel.vision_screening.on_fail == "flag"
    assert manifest_with(default_panel(colour_check=False)).panel.vision_screening is None


def _broken(path: list, value) -> dict:
    panel = copy.deepcopy(default_panel())
    node = panel
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return panel


@pytest.mark.parametrize(("panel", "says"), [
    ({"format": "cgvq-panel/2"}, "not supported by this toolkit"),
    (_broken(["questionnaires", 0, "pages", 0, "questions", 0, "type"], "slider"),
     "does not match any of the expected tags"),
    (_broken(["questionnaires", 0, "pages", 0, "questions", 0, "max"], 10),
     "max (10) must be greater than min (18)"),
    (_broken(["questionnaires", 0, "pages", 0, "questions", 1, "options"],
              [{"value": "a", "label": "A"}, {"value": "a", "label": "B"}]),
     "option values must be unique"),
    (_broken(["questionnaires", 1, "pages", 0, "questions", 0, "id"], "age"),
     "question id 'age' is used twice"),
    (_broken(["questionnaires", 0, "pages", 0, "questions", 0, "text"], "Age\x07"),
     "control character (U+0007)"),
    (_broken(["questionnaires", 0, "pages", 0, "questions", 0, "id"], "Age!"),
     "should match pattern"),
    (_broken(["vision_screening", "on_fail"], "explode"), "'end', 'flag' or 'record'"),
    (_broken(["vision_screening", "viewing_distance_cm"], 5), "greater than or equal to 30"),
    (_broken(["vision_screening", "optotype"], "snellen_letters"), "'landolt_c' or 'tumbling_e'"),
    (_broken(["vision_screening", "acuity_logmar"], 1.2), "less than or equal to 0.8"),
    (_broken(["vision_screening", "contrast_weber"], 0.001), "greater than or equal to 0.03"),
    (_broken(["questionnaires", 1, "pages", 0, "questions", 0, "points"], ["a", "b"]),
     "at least 3 items"),
])
def test_malformed_panels_are_refused_with_one_line(panel, says):
    with pytest.raises(ManifestError) as info:
        manifest_with(panel)
    message = str(info.value)
    assert says in message and "\n" not in message and message.startswith("invalid manifest")


def test_check_refuses_a_malformed_panel_in_one_line(tmp_path):
    folder = tmp_path / "study"
    folder.mkdir()
    data = {**BASE, "panel": _broken(["questionnaires", 0, "when"], "during")}
    (folder / "manifest.json").write_text(json.dumps(data))
    res = subprocess.run([sys.executable, "-m", "cgvq_cli.study_cli", "check", str(folder)],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "'before' or 'after'" in res.stderr
    assert "Traceback" not in res.stderr


def question(kind, **kw):
    return {"single": SingleChoice, "multiple": MultipleChoice, "likert": Likert,
            "number": Number, "text": Text}[kind](type=kind, id="q", text="Q?", **kw)


OPTIONS = [{"value": "a", "label": "A"}, {"value": "b", "label": "B"},
           {"value": "c", "label": "C"}]


@pytest.mark.parametrize(("q", "value", "stored"), [
    (question("single", options=OPTIONS), "b", "b"),
    (question("multiple", options=OPTIONS, max_selected=2), ["c", "a"], ["a", "c"]),
    (question("likert", points=["1", "2", "3", "4", "5"]), 5, 5),
    (question("number", min=18, max=99), 34.0, 34),
    (question("number", min=0, max=10, integer=False), 2.5, 2.5),
    (question("text", max_length=20), "  <b>fine</b>  ", "<b>fine</b>"),
    (question("text", max_length=20), "   ", None),
    (question("single", options=OPTIONS, prefer_not_to_say=True), PREFER_NOT_TO_SAY,
     PREFER_NOT_TO_SAY),
    (question("single", options=OPTIONS, required=False), None, None),
])
def test_valid_answers_are_stored_normalised(q, value, stored):
    assert check_answer(q, value) == stored


@pytest.mark.parametrize(("q", "value", "says"), [
    (question("single", options=OPTIONS), "d", "a text of 1 character is not one of a, b, c"),
    (question("single", options=OPTIONS), None, "an answer is required"),
    (question("single", options=OPTIONS), PREFER_NOT_TO_SAY, "not offered"),
    (question("multiple", options=OPTIONS, max_selected=2), ["a", "b", "c"],
     "choose between 1 and 2"),
    (question("multiple", options=OPTIONS), ["a", "a"], "chosen twice"),
    (question("likert", points=["1", "2", "3"]), 4, "expected a point 1..3"),
    (question("likert", points=["1", "2", "3"]), True, "expected a point 1..3"),
    (question("number", min=18, max=99), 17, "17 is outside 18..99"),
    (question("number", min=18, max=99), 30.5, "expected a whole number"),
    (question("number", min=18, max=99), float("nan"), "finite"),
    (question("number", min=18, max=99), "34", "expected a number"),
    (question("text", max_length=500), "x" * 1_000_000, "1000000 characters; at most 500"),
    (question("text", max_length=500), "hi\x00there", "control character (U+0000)"),
    (question("text", max_length=500), "rtl\u202eoverride", "control character (U+202E)"),
])
def test_invalid_answers_are_refused_with_a_reason(q, value, says):
    with pytest.raises(PanelError, match=None) as info:
        check_answer(q, value)
    assert says in str(info.value) and str(info.value).startswith("q: ")


def test_panel_lookups():
    panel = Panel.model_validate({"questionnaires": [DEMOGRAPHICS, POST_STUDY_SURVEY]})
    assert panel.question("age").max == 99
    assert [q.id for q in panel.questionnaires_at("after")] == ["post_study"]
    with pytest.raises(KeyError):
        panel.question("shoe_size")


def test_a_refused_answer_never_repeats_its_words():
    """Refusals go into the server's flags and log and the report's problems table; free text
    sent as a choice or a number used to appear there (up to 37 characters of it)."""
    secret = "I am 34 and live at 5 Elm Street"
    for q in (question("single", options=OPTIONS), question("number", min=0, max=120),
              question("likert", points=["1", "2", "3"])):
        with pytest.raises(PanelError) as caught:
            check_answer(q, secret)
        assert "Elm" not in str(caught.value) and "34" not in str(caught.value)
        assert f"a text of {len(secret)} characters" in str(caught.value)
