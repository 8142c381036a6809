"""The panel block of a manifest (``cgvq-panel/1``): what participants are asked besides the
ratings, and whether their vision is screened.

A paper describes its panel ("20 participants aged 25-57 ... normal or corrected-to-normal
vision; 13 of 20 answered the post-study survey"), so the questions live in the manifest, are
answered in the player, stored in the session's hash chain and summarised by the analysis.
Each question is one of five kinds (single choice, multiple choice, Likert, number, short
text); :func:`check_answer` is the one rule for what a valid answer is, used by the player
(refusing an answer), the server (refusing an upload) and the analysis (reading).
"""

from __future__ import annotations

import math
import unicodedata
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .formats import VersionedFormat

PANEL_FORMAT = VersionedFormat("cgvq-panel", 1, field="panel format", document="panel block",
                               advice="upgrade the toolkit or rewrite the panel block")
# The answer a participant gives by choosing "Prefer not to say" (any optional question and
# any question with ``prefer_not_to_say``); stored as such, counted separately in the report.
PREFER_NOT_TO_SAY = "prefer-not-to-say"
MAX_TEXT_LENGTH = 2000
_ID = r"^[a-z][a-z0-9_]{0,39}$"


class PanelError(ValueError):
    """An answer that the question does not accept (its message says why, in one line)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Option(_Strict):
    """One answer of a choice question: a stable value (stored) and the label shown."""

    value: str = Field(pattern=_ID)
    label: str = Field(min_length=1, max_length=120)


class _Question(_Strict):
    id: str = Field(pattern=_ID, description="stable id, unique in the manifest")
    text: str = Field(min_length=1, max_length=300)
    required: bool = True
    prefer_not_to_say: bool = Field(
        default=False, description="offer 'Prefer not to say' (always offered when optional)")

    @field_validator("text")
    @classmethod
    def _printable(cls, value: str) -> str:
        return _printable_text(value)

    @property
    def offers_prefer_not_to_say(self) -> bool:
        return self.prefer_not_to_say or not self.required


class _Choices(_Question):
    options: list[Option] = Field(min_length=2, max_length=12)

    @model_validator(mode="after")
    def _unique(self) -> _Choices:
        values = [o.value for o in self.options]
        if len(set(values)) != len(values):
            raise ValueError(f"question {self.id}: option values must be unique")
        if PREFER_NOT_TO_SAY in values:
            raise ValueError(f"question {self.id}: use prefer_not_to_say instead of an option "
                             f"{PREFER_NOT_TO_SAY!r}")
        return self


class SingleChoice(_Choices):
    """Exactly one of the options (gender, vision status)."""

    type: Literal["single"]


class MultipleChoice(_Choices):
    """Any number of the options between ``min_selected`` and ``max_selected``."""

    type: Literal["multiple"]
    min_selected: int = Field(default=1, ge=0)
    max_selected: int | None = Field(default=None, ge=1)

    @model_validator(mode="after")
    def _bounds(self) -> MultipleChoice:
        top = len(self.options) if self.max_selected is None else self.max_selected
        if not self.min_selected <= top <= len(self.options):
            raise ValueError(f"question {self.id}: need min_selected <= max_selected <= "
                             f"{len(self.options)} options")
        return self


class Likert(_Question):
    """One of ``len(points)`` labelled points (5 or 7 usually); stored as 1..len(points)."""

    type: Literal["likert"]
    points: list[Annotated[str, Field(min_length=1, max_length=40)]] = Field(
        min_length=3, max_length=11)


class Number(_Question):
    """A number in [min, max] (age in years), whole unless ``integer`` is false."""

    type: Literal["number"]
    min: float = Field(allow_inf_nan=False)
    max: float = Field(allow_inf_nan=False)
    integer: bool = True
    unit: str | None = Field(default=None, max_length=20)

    @model_validator(mode="after")
    def _range(self) -> Number:
        if not self.max > self.min:
            raise ValueError(f"question {self.id}: max ({self.max:g}) must be greater than "
                             f"min ({self.min:g})")
        return self


class Text(_Question):
    """Short free text up to ``max_length`` characters (never used in file names or logs)."""

    type: Literal["text"]
    max_length: int = Field(default=500, ge=1, le=MAX_TEXT_LENGTH)
    required: bool = False


Question = Annotated[SingleChoice | MultipleChoice | Likert | Number | Text,
                     Field(discriminator="type")]


class Page(_Strict):
    """Questions shown together on one screen."""

    title: str | None = Field(default=None, max_length=120)
    questions: list[Question] = Field(min_length=1, max_length=6)


class Questionnaire(_Strict):
    """Pages shown before the first trial (after consent) or after the last one."""

    id: str = Field(pattern=_ID)
    when: Literal["before", "after"]
    title: str = Field(min_length=1, max_length=120)
    intro: str | None = Field(default=None, max_length=1000)
    voluntary: bool = Field(default=False, description="the participant may skip it whole")
    pages: list[Page] = Field(min_length=1, max_length=20)

    def questions(self) -> list[Any]:
        return [q for page in self.pages for q in page.questions]


ACUITY_CRITERION_LOGMAR = 0.3  # 20/40 (6/12), a common screening cut-off
CONTRAST_CRITERION_WEBER = 0.063  # log contrast sensitivity 1.2


class VisionScreening(_Strict):
    """Optional remote vision checks and what a failed check does."""

    colour: bool = True
    acuity: bool = Field(default=False, description="the contrast/acuity check")
    viewing_distance_cm: float = Field(default=60.0, ge=30.0, le=200.0)
    optotype: Literal["landolt_c", "tumbling_e"] = "landolt_c"
    acuity_logmar: float = Field(
        default=ACUITY_CRITERION_LOGMAR, ge=0.0, le=0.8,
        description="pass when optotypes this small (logMAR) are read")
    contrast_weber: float = Field(
        default=CONTRAST_CRITERION_WEBER, ge=0.03, le=0.5,
        description="pass when optotypes this faint (Weber contrast) are read")
    on_fail: Literal["end", "flag", "record"] = Field(
        default="flag", description="end the session politely, flag the rater, or only record")


class Panel(_Strict):
    """The ``panel`` block of a manifest."""

    format: str = PANEL_FORMAT.version
    questionnaires: list[Questionnaire] = Field(default_factory=list)
    vision_screening: VisionScreening | None = None

    @field_validator("format")
    @classmethod
    def _check_format(cls, value: str) -> str:
        PANEL_FORMAT.check(value)
        return value

    @model_validator(mode="after")
    def _unique_ids(self) -> Panel:
        seen: set[str] = set()
        for q in self.questionnaires:
            if q.id in seen:
                raise ValueError(f"panel: questionnaire id {q.id!r} is used twice")
            seen.add(q.id)
        seen = set()
        for question in (q for qn in self.questionnaires for q in qn.questions()):
            if question.id in seen:
                raise ValueError(f"panel: question id {question.id!r} is used twice")
            seen.add(question.id)
        return self

    def questionnaires_at(self, when: str) -> list[Questionnaire]:
        return [q for q in self.questionnaires if q.when == when]

    def check(self, questionnaire_id: str, question_id: str, value: Any) -> Any:
        """:func:`check_answer` for a question named by its questionnaire and id;
        :class:`PanelError` also for a questionnaire or question the panel does not ask."""
        for qn in self.questionnaires:
            if qn.id == questionnaire_id:
                for q in qn.questions():
                    if q.id == question_id:
                        return check_answer(q, value, taken_back=qn.voluntary)
                raise PanelError(f"questionnaire {questionnaire_id} has no question "
                                 f"{_short(question_id)}")
        raise PanelError(f"the study asks no questionnaire {_short(questionnaire_id)}")

    def question(self, question_id: str) -> Any:
        for qn in self.questionnaires:
            for q in qn.questions():
                if q.id == question_id:
                    return q
        raise KeyError(question_id)


def _printable_text(value: str) -> str:
    """Refuse control characters (other than none at all) in texts shown to participants."""
    bad = [c for c in value if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co")]
    if bad:
        raise ValueError(f"contains a control character (U+{ord(bad[0]):04X})")
    return value


def check_answer(question: Any, value: Any, *, taken_back: bool = False) -> Any:
    """The answer as stored (normalised), or :class:`PanelError` saying why it is refused.

    ``None`` is "not answered" (allowed for optional questions, and for any question of a
    voluntary questionnaire when ``taken_back``: Skip takes back what its page held, and a
    questionnaire may be skipped whole); ``PREFER_NOT_TO_SAY`` where
    the question offers it. Choices store option values (a list for multiple choice),
    Likert the point 1..n, numbers a float (an int when ``integer``), text the stripped string.
    """
    qid = question.id
    if value is None:
        if question.required and not taken_back:
            raise PanelError(f"{qid}: an answer is required")
        return None
    if value == PREFER_NOT_TO_SAY:
        if not question.offers_prefer_not_to_say:
            raise PanelError(f"{qid}: 'prefer not to say' is not offered for this question")
        return value
    if isinstance(question, SingleChoice):
        values = [o.value for o in question.options]
        if not isinstance(value, str) or value not in values:
            raise PanelError(f"{qid}: {_answer_value(value)} is not one of {', '.join(values)}")
        return value
    if isinstance(question, MultipleChoice):
        values = [o.value for o in question.options]
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise PanelError(f"{qid}: expected a list of options")
        unknown = [v for v in value if v not in values]
        if unknown:
            raise PanelError(f"{qid}: {_answer_value(unknown[0])} is not one of "
                             f"{', '.join(values)}")
        if len(set(value)) != len(value):
            raise PanelError(f"{qid}: an option is chosen twice")
        top = len(values) if question.max_selected is None else question.max_selected
        if not question.min_selected <= len(value) <= top:
            raise PanelError(f"{qid}: choose between {question.min_selected} and {top} options")
        return [v for v in values if v in value]  # in the options' order
    if isinstance(question, Likert):
        if isinstance(value, bool) or not isinstance(value, int) or \
                not 1 <= value <= len(question.points):
            raise PanelError(f"{qid}: expected a point 1..{len(question.points)}, got "
                             f"{_answer_value(value)}")
        return value
    if isinstance(question, Number):
        return _number(question, value)
    if isinstance(question, Text):
        if not isinstance(value, str):
            raise PanelError(f"{qid}: expected text")
        text = value.strip()
        if len(text) > question.max_length:
            raise PanelError(f"{qid}: {len(text)} characters; at most {question.max_length}")
        try:
            _printable_text(text.replace("\n", " "))
        except ValueError as exc:
            raise PanelError(f"{qid}: {exc}") from None
        if not text:
            if question.required:
                raise PanelError(f"{qid}: an answer is required")
            return None
        return text
    raise PanelError(f"{qid}: unknown question type")


def _number(question: Number, value: Any) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PanelError(f"{question.id}: expected a number, got {_answer_value(value)}")
    if not math.isfinite(value):
        raise PanelError(f"{question.id}: expected a finite number")
    if question.integer and value != int(value):
        raise PanelError(f"{question.id}: expected a whole number, got {value:g}")
    if not question.min <= value <= question.max:
        raise PanelError(f"{question.id}: {value:g} is outside {question.min:g}.."
                         f"{question.max:g}")
    return int(value) if question.integer else float(value)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _answer_value(value: Any) -> str:
    """A refused answer, described without its words: refusals go into the server's flags
    and log and the report's problems table, where free text must never appear."""
    if isinstance(value, str):
        return f"a text of {len(value)} character{'' if len(value) == 1 else 's'}"
    if isinstance(value, bool) or value is None:
        return repr(value)
    if isinstance(value, int | float):
        return f"{value:g}"
    if isinstance(value, list | tuple | dict):
        return f"a {type(value).__name__} of {len(value)}"
    return f"a {type(value).__name__}"


def screening_distance_problem(manifest: Any) -> str | None:
    """The acuity check measured at another distance than the one participants are told to
    sit at while rating: it then screens the acuity of another viewing condition."""
    vs = manifest.panel.vision_screening if manifest.panel is not None else None
    seat = manifest.protocol.viewing_distance_cm
    if vs is None or not vs.acuity or seat is None or abs(vs.viewing_distance_cm - seat) < 1:
        return None
    return (f"the acuity check runs at {vs.viewing_distance_cm:g} cm, but participants are "
            f"told to sit {seat:g} cm from the screen while they rate: set "
            f"panel.vision_screening.viewing_distance_cm to {seat:g} in manifest.json to "
            "screen the viewing condition they rate in")
