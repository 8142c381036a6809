"""``scale.question``: the question above the slider in the experimenter's words (the
default is the CGVQM study's), shown by the player and quoted by the text for the paper
(tests/analysis/test_methods_text.py)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from stimuli_manifests import ManifestError, parse_manifest, save_manifest
from stimuli_manifests.model import DEFAULT_QUESTION, MAX_QUESTION_CHARS

ASKED = "How annoying are the differences from the reference?"


def _doc(**scale) -> dict:
    return {"format": "cgvq-manifest/1", "study_id": "s1", "scale": scale,
            "references": [{"path": "a.mkv"}],
            "conditions": [{"reference": "SRC01", "path": "b.mkv", "method": "blur",
                            "level": 1}]}


def test_without_a_question_the_study_s_wording_and_no_new_key(tmp_path):
    m = parse_manifest(_doc())
    assert m.scale.question is None and m.scale.shown_question == DEFAULT_QUESTION
    saved = save_manifest(m, tmp_path / "manifest.json").read_text()
    assert "question" not in saved  # manifests written before keep their bytes


def test_a_question_is_kept_and_shown_above_the_slider(tmp_path):
    from study_app.fonts import Fonts
    from study_app.trial_screen import rating_layout_for

    m = parse_manifest(_doc(question=ASKED))
    assert m.scale.shown_question == ASKED
    again = parse_manifest(json.loads(
        save_manifest(m, tmp_path / "manifest.json").read_text()))
    assert again.scale.question == ASKED
    lay = rating_layout_for(SimpleNamespace(size=(1280, 720), fonts=Fonts()),
                            lambda keymap, action: "Enter", m, "Trial 1 of 5", 3.0)
    assert " ".join(text for text, _ in lay.question.lines) == ASKED


@pytest.mark.parametrize(("question", "why"), [
    ("   ", "blank"), ("", "at least 1"), ("x" * (MAX_QUESTION_CHARS + 1), "at most")])
def test_a_blank_or_overlong_question_is_refused(question, why):
    with pytest.raises(ManifestError, match=why):
        parse_manifest(_doc(question=question))
