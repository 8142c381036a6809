"""Where a session stands in its panel, read back from the file: what a resumed run shows."""

from __future__ import annotations

from support.sessions import bare_session

from session_store import read_session
from stimuli_manifests.panel import Panel
from stimuli_manifests.panel_templates import default_panel
from study_app.panel_progress import QUESTIONNAIRE_EVENT, panel_progress, vision_tests


def _progress(path, panel):
    r = read_session(path)
    return panel_progress(panel, r.answers, r.screenings, r.events)


def test_a_resumed_session_continues_on_the_page_it_was_on(tmp_path):
    panel = Panel.model_validate(default_panel())
    path = tmp_path / "P01.sqlite"
    store = bare_session(path)
    p = _progress(path, panel)
    assert p.vision_todo == ["colour"] and [q.questionnaire.id for q in p.before] == [
        "demographics"] and p.before[0].start_page == 0
    store.record_screening("colour", "failed", {})
    store.record_answer("demographics", "age", 30, page=0)
    store.record_answer("demographics", "gender", "male", page=0)
    store.record_answer("demographics", "vision", "normal", page=1)
    store.close()  # the run is killed here
    p = _progress(path, panel)
    assert p.vision_todo == [] and p.failed_vision == ["colour"]
    before = p.before[0]
    assert before.start_page == 1
    assert before.answered == {"age": 30, "gender": "male", "vision": "normal"}
    assert [q.questionnaire.id for q in p.after] == ["post_study"]

    from session_store import SessionStore

    with SessionStore.open(path) as store:
        store.log_event(QUESTIONNAIRE_EVENT, questionnaire="demographics", outcome="done")
        store.log_event(QUESTIONNAIRE_EVENT, questionnaire="post_study", outcome="skipped")
    p = _progress(path, panel)
    assert p.before == [] and p.after == []


def test_no_panel_no_work(tmp_path):
    path = tmp_path / "P01.sqlite"
    bare_session(path).close()
    p = _progress(path, None)
    assert (p.vision_todo, p.before, p.after) == ([], [], [])
    assert vision_tests(Panel.model_validate(default_panel(colour_check=False))) == []
