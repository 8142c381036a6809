"""Panel audit fixes on the player's side: an answer taken back is stored as no answer (and
Skip keeps nothing of its page), ``simulate`` ends a session as the app does with
``on_fail: end``, and optotype levels too tall for the window are listed."""

from __future__ import annotations

import copy
import itertools
import math
import sqlite3
from types import SimpleNamespace

import pygame
import pytest

from session_store import SessionStore, read_session
from session_store.schedule import ScheduleItem, make_schedule
from stimuli_manifests import parse_manifest, save_manifest
from stimuli_manifests.panel import Panel
from stimuli_manifests.panel_templates import default_panel
from study_app import form_screen
from study_app.acuity_check_screen import optotype_room
from study_app.fonts import Fonts
from study_app.screens.form_layout import form_layout
from study_app.screens.form_state import FormState
from study_app.simulate import SimulationOptions, run_simulation
from study_app.vision.acuity import card_calibration
from study_app.vision.acuity_plan import acuity_plan
from study_app.vision.acuity_scoring import OptotypeAnswer, score_acuity

PANEL = Panel.model_validate(default_panel())
SURVEY = next(q for q in PANEL.questionnaires if q.id == "post_study")
WINDOW = (1024, 768)
COMMENT = "My name is Jane Doe, I work at ACME"


# -- a FormScreen without a display: scripted input events, nothing drawn ------------------
class _Pg:
    """pygame's constants and event type, with a scripted event queue."""

    def __init__(self, batches: list[list[pygame.event.Event]]) -> None:
        self._batches = list(batches)
        self.event = SimpleNamespace(get=self._next)
        self.key = SimpleNamespace(start_text_input=lambda: None,
                                   stop_text_input=lambda: None)

    def _next(self) -> list[pygame.event.Event]:
        if not self._batches:
            raise AssertionError("the page asked for more input than the script has")
        return self._batches.pop(0)

    def __getattr__(self, name: str):
        return getattr(pygame, name)


def _display(batches: list[list[pygame.event.Event]]) -> SimpleNamespace:
    return SimpleNamespace(pg=_Pg(batches), size=WINDOW, fonts=Fonts(), pacer=None,
                           renderer=None, flip=lambda: None, to_pixels=lambda pos: pos)


def _key(key: int) -> pygame.event.Event:
    return pygame.event.Event(pygame.KEYDOWN, key=key, mod=0)


def _text(text: str) -> pygame.event.Event:
    return pygame.event.Event(pygame.TEXTINPUT, text=text)


def _click_button(page: int, action: str, answered: dict) -> pygame.event.Event:
    """A click on a page's button, where the layout puts it."""
    fs = FormState.for_page(list(SURVEY.pages[page].questions), answered)
    screen = form_screen.FormScreen(_display([]), lambda *a, **k: None, lambda n: False,
                                    lambda: None)
    lay = form_layout(WINDOW, Fonts(), title=f"{SURVEY.title} ({page + 1} of 2)",
                      intro=SURVEY.intro if page == 0 else None, state=fs,
                      buttons=screen._buttons(SURVEY, page))
    rect = next(b.rect for b in lay.buttons if b.action == action)
    return pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1,
                              pos=(rect.x + rect.w / 2, rect.y + rect.h / 2))


def _run_survey(monkeypatch, tmp_path, batches, *, start_page: int, answered: dict):
    """The survey on the scripted display; every answer stored in a real session file as
    the app does. Returns (outcome, the last stored value per question)."""
    monkeypatch.setattr(form_screen, "draw_form", lambda *a: None)
    items = [ScheduleItem("S1", "S1", True)]
    store = SessionStore.create(tmp_path / "s.sqlite", participant="p1", study_id="st",
                                manifest_sha256="0" * 64, seed=1, app_version="test",
                                plan=make_schedule(items, 1, 1), settings={})
    with store:
        for qid, value in answered.items():  # given earlier (before a Back, or a crash)
            store.record_answer(SURVEY.id, qid, value, page=start_page)

        def on_answer(page: int, question: str, value) -> None:
            store.record_answer(SURVEY.id, question, value, page=page)

        screen = form_screen.FormScreen(_display(batches), lambda *a, **k: None,
                                        lambda n: False, lambda: None)
        outcome = screen.run(SURVEY, answered=answered, start_page=start_page,
                             on_answer=on_answer)
    last = {row["question"]: row["value"] for row in read_session(tmp_path / "s.sqlite").answers}
    return outcome, last


def test_a_deleted_comment_is_stored_as_no_answer(monkeypatch, tmp_path):
    """The comment was stored when the participant moved on; they came back, deleted it and
    pressed Done: the session file must no longer hold it."""
    questions = [q.id for q in SURVEY.pages[1].questions]
    comment = questions.index("comments")
    batches = [[_key(pygame.K_TAB)] for _ in range(comment)]  # focus to the comment field
    batches += [[_key(pygame.K_BACKSPACE) for _ in COMMENT]]
    batches += [[_key(pygame.K_RETURN)]]
    outcome, last = _run_survey(monkeypatch, tmp_path, batches, start_page=1,
                                answered={"comments": COMMENT})
    assert outcome == "done"
    assert last["comments"] is None


def test_skip_keeps_no_answer_of_its_page(monkeypatch, tmp_path):
    """One Likert point clicked (stored at once), then "Skip these questions": the point
    is taken back, so the participant does not count as having answered the survey."""
    batches = [[_text("4")], [_click_button(0, "skip", {})]]
    outcome, last = _run_survey(monkeypatch, tmp_path, batches, start_page=0, answered={})
    assert outcome == "skipped"
    first = SURVEY.pages[0].questions[0].id
    assert last == {first: None}


def test_back_and_skip_have_keys_with_a_modifier(monkeypatch, tmp_path):
    """Alt+Left goes back a page (nothing on the first), Alt+S skips a voluntary
    questionnaire; without Alt the keys choose or type as before. The buttons name them."""
    def alt(key: int) -> pygame.event.Event:
        return pygame.event.Event(pygame.KEYDOWN, key=key, mod=pygame.KMOD_LALT)

    pages: list[int] = []
    real = form_screen.FormScreen._page

    def page(self, qn, number, *args, **kwargs):
        pages.append(number)
        return real(self, qn, number, *args, **kwargs)

    monkeypatch.setattr(form_screen.FormScreen, "_page", page)
    batches = [[alt(pygame.K_LEFT)], [alt(pygame.K_LEFT)], [_key(pygame.K_s)],
               [alt(pygame.K_s)]]
    outcome, _ = _run_survey(monkeypatch, tmp_path, batches, start_page=1, answered={})
    assert outcome == "skipped" and pages == [1, 0]
    screen = form_screen.FormScreen(_display([]), lambda *a, **k: None, lambda n: False,
                                    lambda: None)
    labels = dict(screen._buttons(SURVEY, 1))
    assert labels["back"] == "Back (Alt+\u2190)" and labels["skip"].endswith("(Alt+S)")


def test_a_resumed_page_shows_an_answer_taken_back_as_empty():
    questions = list(SURVEY.pages[1].questions)
    comment = [q.id for q in questions].index("comments")
    fs = FormState.for_page(questions, {"comments": None, "task_clear": None})
    assert fs.fields[comment].text == "" and fs.fields[0].choice is None


# -- simulate with on_fail: end ---------------------------------------------------------------
def test_simulate_ends_a_session_failed_with_on_fail_end(tmp_path):
    refs = [{"id": f"R{i}", "path": f"r{i}.mkv", "scene": f"scene{i}"} for i in range(2)]
    conds = [{"id": f"R{i}_blur_L{lv}", "reference": f"R{i}", "path": f"r{i}_{lv}.mkv",
              "method": "blur", "level": lv} for i in range(2) for lv in (1, 2)]
    panel = copy.deepcopy(default_panel())  # the template's dicts are shared
    panel["vision_screening"]["on_fail"] = "end"
    manifest = save_manifest(parse_manifest({"study_id": "end-study", "references": refs,
                                             "conditions": conds, "panel": panel,
                                             "protocol": {"repetitions": 1}}),
                             tmp_path / "manifest.json")
    out = tmp_path / "sessions"
    run_simulation(manifest, out, SimulationOptions(raters=3, seed=2, colour_failures=1),
                   progress=False)
    n_trials = len(refs) + len(conds)  # hidden references on, one repetition
    seen = {}
    for path in sorted(out.glob("*.sqlite")):
        rec = read_session(path)
        failed = [s["test"] for s in rec.screenings if s["outcome"] == "failed"]
        ended = [e for e in rec.events if e["kind"] == "ended_by_vision_check"]
        with sqlite3.connect(path) as con:
            finished = con.execute("SELECT finished_at FROM session").fetchone()[0]
        seen[rec.info.participant] = (failed, len(rec.ratings), len(ended), len(rec.answers))
        assert finished is not None
    failing = [p for p, v in seen.items() if v[0]]
    assert len(failing) == 1
    assert seen[failing[0]] == (["colour"], 0, 1, 0)  # no rating, no questionnaire
    for p, (failed, n, ended, _) in seen.items():
        if p not in failing:
            assert (failed, n, ended) == ([], n_trials, 0)


# -- acuity levels too tall for the window ---------------------------------------------------
def test_levels_too_tall_for_the_window_are_listed():
    """20 px/mm at 150 cm: one arcmin is 1500 mm * tan(1/60 deg) * 20 px/mm = 8.73 px, so
    logMAR 1.0 (50 arcmin) is 436 px tall and 0.8 (31.5 arcmin) 275 px; a 1280x720 window
    has room for 360 px."""
    px_per_arcmin = 1500 * math.tan(math.radians(1 / 60)) * 20
    assert 50 * px_per_arcmin > 360 > 31.5 * px_per_arcmin
    g = card_calibration(20 * 85.6, 150)
    room = optotype_room((1280, 720))
    assert room == 360
    plan = acuity_plan(g, 1, max_size_px=room)
    assert plan.too_large_logmar == [1.0]
    assert plan.undrawable_logmar == []
    assert max(t.logmar for t in plan.series("acuity")) == 0.8
    answers = [OptotypeAnswer(t, t.orientation, 500.0) for t in plan.trials]
    _, result = score_acuity(plan, answers, g)
    assert result["acuity"]["too_large_logmar"] == [1.0]


@pytest.mark.parametrize("window", [(800, 600), (1024, 600), (1280, 720), (1920, 1080)])
def test_the_optotype_count_sits_between_the_question_and_the_largest_optotype(window):
    """The progress line ("3 of at most 42") is drawn under the question's lines and above
    the tallest optotype the window has room for (centred), so it never touches one."""
    from study_app.acuity_check_screen import TRIAL_TEXT, count_text
    from study_app.layout import GAP, ui_px, wrap_words

    g = card_calibration(20 * 85.6, 150)
    plan = acuity_plan(g, 1, max_size_px=optotype_room(window))
    assert count_text(3, plan, []) == f"3 of at most {len(plan.trials)}"
    fonts, px = Fonts(), ui_px(window)
    lines = wrap_words(TRIAL_TEXT, window[0] - 4 * GAP, px, fonts)
    count_bottom = GAP + (len(lines) + 1) * fonts.line_height(px)
    optotype_top = (window[1] - optotype_room(window)) / 2
    assert count_bottom <= optotype_top
    assert fonts.size(count_text(42, plan, []), px)[0] < window[0] - 4 * GAP


@pytest.mark.parametrize("p_right", [1.0, 0.8, 0.5, 0.25])
def test_the_count_s_bound_shrinks_to_the_trials_the_check_took(p_right):
    """"k of at most N": N never grows, never falls below what the check will still show,
    and ends at the number shown (replayed through next_trial with seeded answers)."""
    import numpy as np

    from study_app.vision.acuity_scoring import most_trials, next_trial

    g = card_calibration(20 * 85.6, 150)
    plan = acuity_plan(g, 1, max_size_px=optotype_room((1920, 1080)))
    rng = np.random.default_rng(int(p_right * 100))
    answers: list[OptotypeAnswer] = []
    bounds = [most_trials(plan, answers)]
    assert bounds[0] == len(plan.trials)
    while (trial := next_trial(plan, answers)) is not None:
        right = rng.random() < p_right
        wrong = next(w for w in ("left", "up", "right", "down") if w != trial.orientation)
        answers.append(OptotypeAnswer(trial, trial.orientation if right else wrong, 500.0))
        bounds.append(most_trials(plan, answers))
    assert all(a >= b for a, b in itertools.pairwise(bounds))
    assert all(b >= len(answers) for b in bounds) and bounds[-1] == len(answers)
    if p_right == 1.0:  # every level passes on its first three: 3 of each level's 5
        assert len(answers) == 3 * len(plan.trials) // 5


def test_a_window_too_small_for_the_contrast_optotype_says_so():
    """At 8.73 px/arcmin the contrast series' optotype (logMAR 0.8) is 275 px tall: a room
    of 200 px cannot hold it; the reason is the window, not a too small display."""
    g = card_calibration(20 * 85.6, 150)
    with pytest.raises(ValueError, match="window is too small") as info:
        acuity_plan(g, 1, max_size_px=200)
    assert "275 px" in str(info.value) and "200 px" in str(info.value)


def test_skip_takes_back_a_required_answer_of_a_voluntary_questionnaire():
    """A required question of a voluntary questionnaire: answered, then the page skipped.
    The answer is taken back (it used to stay, as the answer rule refused "no answer"), and
    the rule the server and the analysis apply accepts that; in a questionnaire that cannot
    be skipped, a required question still needs an answer."""
    data = default_panel()
    survey = next(q for q in data["questionnaires"] if q["id"] == "post_study")
    first = survey["pages"][0]["questions"][0]
    first["required"] = True
    panel = Panel.model_validate(data)
    qn = next(q for q in panel.questionnaires if q.id == "post_study")
    assert qn.voluntary
    fs = FormState.for_page(list(qn.pages[0].questions), {first["id"]: 4})
    assert first["id"] in fs.take_back()
    assert panel.check("post_study", first["id"], None) is None
    strict = copy.deepcopy(data)
    next(q for q in strict["questionnaires"] if q["id"] == "post_study")["voluntary"] = False
    with pytest.raises(Exception, match="an answer is required"):
        Panel.model_validate(strict).check("post_study", first["id"], None)


# -- "Prefer not to say" from the keyboard ----------------------------------------------------
def test_arrows_reach_prefer_not_to_say_after_the_last_option_and_come_back():
    """Left/Right stopped at the last option, and a participant arrowing on stored it."""
    from stimuli_manifests.panel import PREFER_NOT_TO_SAY

    demographics = PANEL.questionnaires[0]
    questions = list(demographics.pages[0].questions)
    gender = next(i for i, q in enumerate(questions) if q.id == "gender")
    fs = FormState.for_page(questions, {})
    n = len(fs.fields[gender].options())
    for _ in range(n):
        fs.step(gender, 1)
    assert fs.fields[gender].choice == fs.fields[gender].options()[-1][0]
    fs.step(gender, 1)
    assert fs.confirmed(gender) == PREFER_NOT_TO_SAY
    fs.step(gender, 1)  # the last stop stays the last
    assert fs.fields[gender].prefer_not
    fs.step(gender, -1)
    assert not fs.fields[gender].prefer_not
    assert fs.confirmed(gender) == fs.fields[gender].options()[-1][0]


def test_zero_and_ctrl_p_choose_prefer_not_to_say_and_the_hint_says_so(monkeypatch, tmp_path):
    """A Likert point by '0'; the survey's first question is stored as Prefer not to say."""
    from stimuli_manifests.panel import PREFER_NOT_TO_SAY

    first = SURVEY.pages[0].questions[0]
    assert first.offers_prefer_not_to_say
    batches = [[_text("3")], [_text("0")], [_click_button(0, "skip", {})]]
    _run_survey(monkeypatch, tmp_path, batches, start_page=0, answered={})
    # stored as the keys were pressed (Skip then takes the page's answers back)
    rows = [r for r in read_session(tmp_path / "s.sqlite").answers if r["question"] == first.id]
    assert [r["value"] for r in rows] == [3, PREFER_NOT_TO_SAY, None]

    demographics = PANEL.questionnaires[0]
    fs = FormState.for_page(list(demographics.pages[0].questions), {})
    age = next(i for i, f in enumerate(fs.fields) if f.kind == "number")
    assert fs.fields[age].question.offers_prefer_not_to_say
    screen = form_screen.FormScreen(_display([]), lambda *a, **k: None, lambda n: False,
                                    lambda: None)
    fs.focus = age
    ctrl_p = pygame.event.Event(pygame.KEYDOWN, key=pygame.K_p, mod=pygame.KMOD_LCTRL)
    assert screen._event(ctrl_p, fs, None, 0) == f"commit:{age}"
    fs.type(age, "p")  # the letter a text input may also deliver: no digit, nothing undone
    assert fs.confirmed(age) == PREFER_NOT_TO_SAY
    assert "Ctrl+P: prefer not to say" in form_screen.key_hint(fs.fields[age])
    gender = next(i for i, q in enumerate(fs.fields) if q.question.id == "gender")
    assert "0: prefer not to say" in form_screen.key_hint(fs.fields[gender])
    assert form_screen.key_hint(fs.fields[gender]).endswith("Enter: next page   Esc: pause")
    assert "Enter: done" in form_screen.key_hint(fs.fields[gender], last_page=True)
    fonts = Fonts()
    for width in (800, 1024):  # the longest hint fits the smallest windows' width
        px = form_layout((width, 600), fonts, title="t", intro=None, state=fs,
                         buttons=screen._buttons(demographics, 0)).px - 4
        assert fonts.size(form_screen.key_hint(fs.fields[gender]), px)[0] < width - 20


# -- a pause outside the trials ----------------------------------------------------------------
def test_esc_in_a_questionnaire_opens_the_pause_menu_and_keeps_the_answer(monkeypatch,
                                                                        tmp_path):
    """Esc and P did nothing on questionnaire pages and vision checks, and full screen has
    no close button: a participant could neither stop nor withdraw there."""
    paused = []
    monkeypatch.setattr(form_screen, "draw_form", lambda *a: None)
    items = [ScheduleItem("S1", "S1", True)]
    store = SessionStore.create(tmp_path / "s.sqlite", participant="p1", study_id="st",
                                manifest_sha256="0" * 64, seed=1, app_version="test",
                                plan=make_schedule(items, 1, 1), settings={})
    batches = [[_text("4"), _key(pygame.K_ESCAPE)], [_click_button(0, "skip", {})]]
    with store:
        screen = form_screen.FormScreen(_display(batches), lambda *a, **k: None,
                                        lambda n: False, lambda: None,
                                        lambda: paused.append(True))
        outcome = screen.run(SURVEY, answered={}, start_page=0, on_answer=lambda page, q, v:
                             store.record_answer(SURVEY.id, q, v, page=page))
    assert paused == [True] and outcome == "skipped"  # the page went on after the pause
    first = SURVEY.pages[0].questions[0].id
    rows = [r["value"] for r in read_session(tmp_path / "s.sqlite").answers
            if r["question"] == first]
    assert rows == [4, None]  # stored before the pause (Skip took it back afterwards)


def test_esc_and_p_pause_the_vision_checks():
    from study_app.acuity_check_screen import AcuityCheckScreen
    from study_app.colour_check_screen import ColourCheckScreen

    colour = ColourCheckScreen(_display([]), lambda *a, **k: None, lambda n: False,
                               lambda: None)
    for key in (pygame.K_ESCAPE, pygame.K_p):
        assert colour._answer(_key(key), []) == "pause"
    assert colour._answer(_key(pygame.K_q), []) is None
    paused = []
    acuity = AcuityCheckScreen(_display([]), lambda *a, **k: None, lambda n: False,
                               lambda: None, lambda: paused.append(True))
    assert acuity._paused(_key(pygame.K_ESCAPE)) and acuity._paused(_key(pygame.K_p))
    assert not acuity._paused(_key(pygame.K_LEFT)) and paused == [True, True]


def test_the_pause_and_check_texts_say_what_happens():
    from study_app.screens import content

    keys = lambda keymap, action: action  # noqa: E731
    during = content.pause(3, 10, keys, during="questions").body
    assert "back on the same page of questions" in during and "starts again" not in during
    assert "starts again from its beginning" in content.pause(3, 10, keys).body
    ends = content.colour_check_intro(8, keys, ends_study=True).body
    assert "the study ends after it" in ends and "only tells the experimenter" not in ends
    assert "only tells the experimenter" in content.colour_check_intro(8, keys).body
    assert "Esc" in content.colour_check_intro(8, keys).body
    acuity = content.acuity_check_intro(60, keys, ends_study=True).body
    assert "the study ends after it" in acuity and "Esc" in acuity


def test_words_on_the_screen_background_reach_the_wcag_contrast_for_text():
    """Refusals were red (0.85, 0.10, 0.10) on the dark background: 3:1, below WCAG's 4.5:1
    for text, and darker still for the protan participants a colour check screens."""
    from study_app.screens import draw

    def luminance(c):
        lin = [x / 12.92 if x <= 0.04045 else ((x + 0.055) / 1.055) ** 2.4 for x in c[:3]]
        return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]

    bg = luminance(draw.SCREEN_BG)
    for name in ("BODY", "MUTED", "ACCENT", "ERROR_TEXT"):
        fg = luminance(getattr(draw, name))
        assert (fg + 0.05) / (bg + 0.05) >= 4.5, name
    assert (luminance(draw.MARKER) + 0.05) / (bg + 0.05) < 4.5  # why it is not used for words


def test_a_resumed_session_says_what_comes_next(tmp_path):
    """'You continue with trial 6' of 5 after a restart in the survey after the videos, and
    'trial 1' before the questions that came first."""
    from study_app.app import App
    from study_app.panel_progress import QUESTIONNAIRE_EVENT
    from study_app.screens import content

    panel = Panel.model_validate(default_panel(colour_check=True))
    demographics, survey = panel.questionnaires
    items = [ScheduleItem("S1", "S1", True)]
    store = SessionStore.create(tmp_path / "s.sqlite", participant="p1", study_id="st",
                                manifest_sha256="0" * 64, seed=1, app_version="test",
                                plan=make_schedule(items, 1, 1), settings={})
    with store:
        app = SimpleNamespace(m=SimpleNamespace(panel=panel), store=store)
        assert App._next_part(app, 0, 1) == "the colour vision check"
        store.record_screening("colour", "passed", {})
        assert App._next_part(app, 0, 1) == f"the questions \u201c{demographics.title}\u201d"
        store.log_event(QUESTIONNAIRE_EVENT, questionnaire=demographics.id, outcome="done")
        assert App._next_part(app, 0, 1) == ""  # a trial
        assert App._next_part(app, 1, 1) == f"the last questions \u201c{survey.title}\u201d"
    body = content.welcome_back(1, 1, lambda k, a: a, "the last questions").body
    assert body.endswith("You continue with the last questions.") and "trial 2" not in body
    assert content.welcome_back(2, 5, lambda k, a: a).body.endswith("with trial 3.")


def test_page_down_scrolls_past_the_focused_question_and_stays(monkeypatch, tmp_path):
    """At 800x600 the survey's first page is taller than its column: Page Down moved the view
    and the next frame pulled it back to the focused first question, so the page could not
    be scrolled and 'more below (Page Down)' never went away."""
    drawn = []
    monkeypatch.setattr(form_screen, "draw_form", lambda r, lay, fs, offset: drawn.append(
        (offset, lay.max_offset())))
    display = _display([[_key(pygame.K_PAGEDOWN)], [], [_key(pygame.K_PAGEUP)], [],
                        [_key(pygame.K_ESCAPE)]])
    display.size = (800, 600)

    class StopScriptError(Exception):
        pass

    def stop():
        raise StopScriptError

    screen = form_screen.FormScreen(display, lambda *a, **k: None, lambda n: False,
                                    lambda: None, stop)
    with pytest.raises(StopScriptError):  # Esc: the pause menu, here the end of the script
        screen.run(SURVEY, answered={}, start_page=0, on_answer=lambda *a: None)
    offsets = [o for o, _ in drawn]
    bottom = drawn[0][1]
    assert bottom > 0 and offsets[:4] == [bottom, bottom, 0, 0]


def test_a_page_that_fits_but_for_its_empty_error_line_does_not_scroll():
    """The free line under the last question (where a refusal is written) counted in the
    page's height: at 1280x720 the survey scrolled by those few pixels for nothing."""
    fonts = Fonts()
    fs = FormState.for_page(list(SURVEY.pages[0].questions), {})
    buttons = [("next", "Next"), ("skip", "Skip these questions")]
    lay = form_layout((1280, 720), fonts, title=SURVEY.title, intro=SURVEY.intro, state=fs,
                      buttons=buttons)
    assert lay.content_height == lay.questions[-1].error_y  # ends with the last answers
    fs.fields[-1].error = "Please answer this question"
    refused = form_layout((1280, 720), fonts, title=SURVEY.title, intro=SURVEY.intro,
                          state=fs, buttons=buttons)
    assert refused.content_height >= refused.questions[-1].error_y + fonts.line_height(
        refused.px)  # a refusal there is part of the page, scrolled to


@pytest.mark.parametrize("window", [(800, 600), (1366, 768), (1920, 1080)])
def test_a_likert_scale_reads_as_one_row_in_order(window):
    """The points flowed and wrapped: 'Strongly agree' sat under 'Strongly disagree'."""
    fs = FormState.for_page(list(SURVEY.pages[0].questions), {})
    lay = form_layout(window, Fonts(), title=SURVEY.title, intro=SURVEY.intro, state=fs,
                      buttons=[("next", "Next"), ("skip", "Skip these questions")])
    for q in lay.questions:
        points = [h for h in q.hits if h.kind == "option"]
        assert len(points) == 5 and len({h.rect.y for h in points}) == 1
        assert len({h.rect.w for h in points}) == 1  # equal cells: the scale's steps
        assert [h.value for h in sorted(points, key=lambda h: h.rect.x)] == [1, 2, 3, 4, 5]
        (prefer,) = [h for h in q.hits if h.kind == "prefer"]
        assert prefer.rect.y > points[0].rect.y or prefer.rect.x > points[-1].rect.x


def test_an_age_out_of_range_is_refused_when_the_participant_tabs_on(monkeypatch):
    """'12' then Tab showed nothing; the refusal came only at Enter, after other questions."""
    demographics = PANEL.questionnaires[0]
    questions = list(demographics.pages[0].questions)
    age = next(i for i, q in enumerate(questions) if q.type == "number")
    errors = []
    monkeypatch.setattr(form_screen, "draw_form", lambda r, lay, fs, offset: errors.append(
        fs.fields[age].error))

    class StopScriptError(Exception):
        pass

    def stop():
        raise StopScriptError

    tabs = [_key(pygame.K_TAB)] * age  # to the age field, wherever the template puts it
    screen = form_screen.FormScreen(
        _display([tabs, [_text("12")], [_key(pygame.K_TAB)], [_key(pygame.K_ESCAPE)]]),
        lambda *a, **k: None, lambda n: False, lambda: None, stop)
    with pytest.raises(StopScriptError):
        screen.run(demographics, answered={}, start_page=0, on_answer=lambda *a: None)
    assert errors[:3] == [None, None, "Enter a whole number between 18 and 99"]
    empty = FormState.for_page(questions, {})
    empty.left(age)  # nothing typed: no refusal until Enter
    assert empty.fields[age].error is None


def test_a_number_question_shows_its_unit_and_range_before_any_refusal():
    from study_app.screens.form_layout import number_range

    demographics = PANEL.questionnaires[0]
    fs = FormState.for_page(list(demographics.pages[0].questions), {})
    age = next(f.question for f in fs.fields if f.kind == "number")
    assert number_range(age) == f" ({age.unit}, {age.min:g}-{age.max:g})" == " (years, 18-99)"
    lay = form_layout((1024, 768), Fonts(), title="t", intro=None, state=fs,
                      buttons=[("next", "Next")])
    shown = " ".join(t for q in lay.questions for t, _ in q.text.lines)
    assert "(years, 18-99)" in shown


def test_the_announced_time_counts_the_checks_and_questions():
    """'about 1-2 minutes (5 trials)' announced a session whose plates, card, optotypes and
    12 questions took 5 minutes more."""
    from study_app.duration import describe_duration, estimate_minutes, panel_seconds

    panel = Panel.model_validate(default_panel())  # colour plates and both questionnaires
    n_questions = sum(len(p.questions) for qn in panel.questionnaires for p in qn.pages)
    low, high, parts = panel_seconds(panel)
    assert parts == ["a colour vision check", f"{n_questions} questions"]
    assert (low, high) == (8 * 3.0 + n_questions * 8.0, 8 * 8.0 + n_questions * 20.0)
    text = describe_duration(5, 3.0, 0.5, panel)
    assert f"(5 trials, a colour vision check and {n_questions} questions)" in text
    plain = estimate_minutes(5, 3.0, 0.5)
    assert describe_duration(5, 3.0, 0.5) == (
        f"about {plain[0]}-{plain[1]} minutes (5 trials), plus the breaks you take")
    span = text.split("about ")[1].split(" minutes")[0]
    assert int(span.split("-")[1]) > plain[1]


@pytest.mark.parametrize("window", [(1024, 600), (1280, 720), (1920, 1080)])
def test_the_card_stays_between_the_instructions_and_the_buttons(window):
    """Grown with Shift+Right, the card covered the title and text, the buttons were drawn
    over it, and a refusal under it fell off the screen."""
    from study_app.acuity_check_screen import card_page
    from study_app.layout import ui_px

    fonts = Fonts()
    lh = fonts.line_height(ui_px(window))
    lay, lines, card = card_page(window, fonts)
    card.set_width(10_000)  # as wide as it goes
    rect = card.rect()
    assert rect.y > lay.column.y + len(lines) * lh  # below the instructions
    assert rect.bottom + lh < min(b.rect.y for b in lay.buttons)  # a refusal line, then buttons
    assert rect.x >= 0 and rect.x + rect.w <= window[0]


def test_a_comment_wraps_between_words():
    measure = len  # one unit per character: a line holds 12
    lines = form_screen.wrap_typed("this comment has some more words", 12, measure)
    assert lines == ["this comment ", "has some ", "more words"]
    assert "".join(lines) == "this comment has some more words"  # nothing lost or added
    long = form_screen.wrap_typed("a " + "x" * 30, 12, measure)
    assert all(measure(line.rstrip()) <= 12 for line in long)
    assert "".join(long) == "a " + "x" * 30


def test_the_practice_intro_fits_a_1280x720_screen_unscrolled():
    """At 1280x720 its last lines (P or Esc: pause, withdraw) were below the fold, and Space
    started the practice without them having been shown."""
    from study_app.keys import keymap
    from study_app.layout import text_screen_layout
    from study_app.screens import content
    from study_app.screens.markdown import parse_markdown
    from study_app.screens.textflow import flow_blocks

    spec = content.practice_intro(2, keymap(switch=["space"], rate=["enter"]),
                                  keymap(submit=["enter"]), 3.0, lambda k, a: a)
    fonts = Fonts()
    for window in ((1280, 720), (1366, 768)):
        lay = text_screen_layout(window, fonts, title=spec.title, buttons=spec.buttons)
        flow = flow_blocks(parse_markdown(spec.body), lay.column.w, fonts, px=lay.px)
        assert flow.at_end(0, lay.column.h), window
