"""Ready-made questionnaires for the manifest's panel block: the demographics a paper reports
and a post-study survey on experience with graphics content and artefacts (the topics of the
CGVQM+D paper's voluntary survey, in this toolkit's own words). Copy them into a manifest
with ``cgvq-study panel-template`` and edit them there."""

from __future__ import annotations

from typing import Any

from .panel import PANEL_FORMAT, Panel

AGREEMENT = ["Strongly disagree", "Disagree", "Neither agree nor disagree", "Agree",
             "Strongly agree"]
FREQUENCY = ["Never", "Rarely", "Sometimes", "Often", "Very often"]

DEMOGRAPHICS: dict[str, Any] = {
    "id": "demographics",
    "when": "before",
    "title": "About you",
    "intro": "These answers describe the panel in publications, as counts and ranges only.",
    "pages": [
        {"title": "About you", "questions": [
            {"id": "age", "type": "number", "text": "Your age", "min": 18, "max": 99,
             "unit": "years", "prefer_not_to_say": True},
            {"id": "gender", "type": "single", "text": "Your gender",
             "prefer_not_to_say": True, "options": [
                 {"value": "female", "label": "Female"},
                 {"value": "male", "label": "Male"},
                 {"value": "non_binary", "label": "Non-binary"},
                 {"value": "other", "label": "Another gender"}]},
        ]},
        {"title": "Your vision", "questions": [
            {"id": "vision", "type": "single",
             "text": "Is your vision normal, or corrected to normal (glasses, contact lenses) "
                     "as you sit now?",
             "options": [
                 {"value": "normal", "label": "Normal"},
                 {"value": "corrected", "label": "Corrected to normal, and I wear the "
                                                "correction now"},
                 {"value": "not_corrected", "label": "No: I need glasses or lenses I am not "
                                                    "wearing now, or my vision is not normal"}]},
            {"id": "colour_vision", "type": "single",
             "text": "Have you ever been told that your colour vision is not normal?",
             "prefer_not_to_say": True, "options": [
                 {"value": "no", "label": "No"},
                 {"value": "yes", "label": "Yes"},
                 {"value": "unsure", "label": "I am not sure"}]},
        ]},
        {"title": "Your experience", "questions": [
            {"id": "games_experience", "type": "likert",
             "text": "How often do you play video games or watch computer-animated films "
                     "or videos?",
             "points": FREQUENCY},
            {"id": "graphics_background", "type": "single",
             "text": "Do you work or study in computer graphics, vision or video?",
             "options": [
                 {"value": "yes", "label": "Yes"},
                 {"value": "no", "label": "No"}]},
        ]},
    ],
}

POST_STUDY_SURVEY: dict[str, Any] = {
    "id": "post_study",
    "when": "after",
    "title": "A few questions about the study",
    "intro": "Voluntary: skip it if you prefer. Your ratings are already saved.",
    "voluntary": True,
    "pages": [
        {"title": "Your experience", "questions": [
            {"id": "notice_artifacts", "type": "likert", "required": False,
             "text": "I notice rendering artefacts (noise, flicker, blur) in games and films.",
             "points": AGREEMENT},
            {"id": "artifacts_annoying", "type": "likert", "required": False,
             "text": "Rendering artefacts spoil my enjoyment of games and films.",
             "points": AGREEMENT},
            {"id": "familiar_methods", "type": "likert", "required": False,
             "text": "I know how rendering methods such as upscaling or denoising work.",
             "points": AGREEMENT},
        ]},
        {"title": "This study", "questions": [
            {"id": "task_clear", "type": "likert", "required": False,
             "text": "It was clear what I was asked to rate.", "points": AGREEMENT},
            {"id": "confident_ratings", "type": "likert", "required": False,
             "text": "I am confident in my ratings.", "points": AGREEMENT},
            {"id": "comments", "type": "text", "required": False, "max_length": 500,
             "text": "Anything else you would like to tell us? (optional)"},
        ]},
    ],
}


def default_panel(*, colour_check: bool = True) -> dict[str, Any]:
    """The panel block with both templates and, by default, the colour-vision check."""
    block: dict[str, Any] = {"format": PANEL_FORMAT.version,
                             "questionnaires": [DEMOGRAPHICS, POST_STUDY_SURVEY]}
    if colour_check:
        block["vision_screening"] = {"colour": True, "acuity": False, "on_fail": "flag"}
    Panel.model_validate(block)  # the templates are always valid
    return block
