"""Questionnaire pages in the player: the answer state (pure), the page geometry at several
window sizes (nothing overlaps, everything inside), and the real app at 800x600 and
1920x1080 under Xvfb with screenshots kept as artifacts."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from support.studies import make_study

from stimuli_manifests import fill_checksums, load_manifest, parse_manifest, save_manifest
from stimuli_manifests.panel import PREFER_NOT_TO_SAY, Panel
from stimuli_manifests.panel_templates import default_panel
from study_app.fonts import Fonts
from study_app.screens.form_layout import form_layout
from study_app.screens.form_state import FormState

REPO = Path(__file__).resolve().parents[2]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "questionnaire"
PANEL = Panel.model_validate(default_panel())
DEMOGRAPHICS, SURVEY = PANEL.questionnaires


def test_answers_are_checked_typed_and_confirmed_once():
    fs = FormState.for_page(list(DEMOGRAPHICS.pages[0].questions), {})
    age, gender = 0, 1
    fs.type(age, "1\x07x7")  # control characters and letters never reach a number field
    assert fs.fields[age].text == "17"
    assert fs.check(age) == (False, None)
    assert fs.fields[age].error == "Enter a whole number between 18 and 99"
    fs.backspace(age)
    fs.type(age, "9")
    assert fs.confirmed(age) == 19 and fs.confirmed(age) is None  # stored once
    assert not fs.validate_page() and fs.focus == gender
    assert fs.fields[gender].error.startswith("Please answer this question")
    fs.step(gender, 1)
    assert fs.fields[gender].choice == "female" and fs.confirmed(gender) == "female"
    fs.toggle_prefer_not(gender)
    assert fs.confirmed(gender) == PREFER_NOT_TO_SAY and fs.validate_page()


def test_free_text_keeps_its_limit_and_a_resumed_page_is_prefilled():
    questions = list(SURVEY.pages[1].questions)
    comment = next(i for i, q in enumerate(questions) if q.type == "text")
    fs = FormState.for_page(questions, {"task_clear": 5, "comments": "kept"})
    assert fs.fields[0].choice == 5 and fs.fields[comment].text == "kept"
    fs.type(comment, "x" * 10_000)
    assert len(fs.fields[comment].text) == questions[comment].max_length
    assert fs.validate_page()  # every question of the survey is optional


@pytest.mark.parametrize("window", [(800, 600), (1024, 768), (1920, 1080)])
def test_every_template_page_fits_without_overlap(window):
    m = Fonts()
    for qn in PANEL.questionnaires:
        for k, page in enumerate(qn.pages):
            fs = FormState.for_page(list(page.questions), {})
            for f in fs.fields:
                f.error = "Please answer this question (or choose Prefer not to say)"
            lay = form_layout(window, m, title=f"{qn.title} ({k + 1} of {len(qn.pages)})",
                              intro=qn.intro if k == 0 else None, state=fs,
                              buttons=[("back", "Back"), ("skip", "Skip these questions"),
                                       ("next", "Next")])
            rects = []
            if lay.intro is not None:
                rects += lay.intro.rects
            for q in lay.questions:
                rects += q.text.rects + [h.rect for h in q.hits]
                err_w = m.size(fs.fields[q.qi].error, lay.px - 2, "bold")[0]
                rects.append(type(q.text.rects[0])(0, q.error_y, err_w, m.line_height(
                    lay.px - 2)))
            for i, a in enumerate(rects):
                assert a.x >= 0 and a.right <= lay.column.w, (qn.id, k, a)
                for b in rects[i + 1:]:
                    assert not a.intersects(b), (window, qn.id, k, a, b)
            for b in lay.buttons:
                assert b.rect.inside(*window) and b.rect.y >= lay.column.bottom
                assert not b.rect.intersects(lay.title.rects[-1])
            assert lay.column.y >= lay.title.rects[-1].bottom


@pytest.mark.gui
@pytest.mark.parametrize("size", [(800, 600),  # about 8 s each: the large one in CI's slow step
                                  pytest.param((1920, 1080), marks=pytest.mark.slow)])
def test_questionnaire_pages_in_the_app(tmp_path, xvfb_factory, app_driver, size):
    env = xvfb_factory(size)
    study = make_study(tmp_path / "study", min_display=(640, 480))
    path = study / "manifest.json"
    data = json.loads(path.read_text())
    data["panel"] = default_panel(colour_check=False)
    save_manifest(parse_manifest(data), path)
    save_manifest(fill_checksums(load_manifest(path)), path)
    shots = ARTIFACTS / f"{size[0]}x{size[1]}"
    shutil.rmtree(shots, ignore_errors=True)
    app = app_driver(env, [str(study), "--participant", "P01", "--practice", "0",
                           "--pilot-no-vsync", "--screenshots", str(shots)])
    app.wait("preflight-passed")
    app.key("space")
    app.wait("welcome")
    app.key("space")
    app.wait("consent")
    app.key("a")
    app.wait("questionnaire id=demographics page=1")
    app.key("Return")  # nothing answered: refused, the page stays
    app.wait("questionnaire-refused id=demographics page=1 question=age")
    subprocess.run(["xdotool", "type", "--delay", "50", "41"], env=env, check=True)
    time.sleep(0.2)
    app.key("Tab", "1", "Return")
    app.wait("questionnaire id=demographics page=2")
    app.key("2", "Escape")  # full screen has no close button: Esc pauses here too
    app.wait("pause")
    app.key("Return")  # continue: back on the same page, the answer kept
    app.wait("questionnaire id=demographics page=2")
    app.key("Tab", "3", "Return")
    app.wait("questionnaire id=demographics page=3")
    app.key("5", "Tab", "1", "Return")
    app.wait("questionnaire-done id=demographics")
    app.wait("viewing")
    app.key("p")
    app.wait("pause")
    code, _ = app.quit_confirmed()
    assert code == 0
    for page in (1, 2, 3):
        assert (shots / f"questionnaire-demographics-{page}.png").is_file()
