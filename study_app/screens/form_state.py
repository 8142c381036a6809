"""One questionnaire page as a participant fills it in: what is chosen or typed, which question
has the focus, and why an answer is refused. Pure (no display), so every rule is testable.

Answers are checked by the one answer rule (``stimuli_manifests.panel.check_answer``); a
question that holds a valid answer reports it through :meth:`FormState.confirmed`, which the
screen stores at once in the session file, so a crash loses at most what is being typed.
"""

from __future__ import annotations

import unicodedata
from dataclasses import dataclass, field
from typing import Any

from stimuli_manifests.panel import (
    PREFER_NOT_TO_SAY,
    Likert,
    MultipleChoice,
    Number,
    PanelError,
    Text,
    check_answer,
)

MAX_NUMBER_CHARS = 12


@dataclass
class Field:
    """The editable state of one question."""

    question: Any
    choice: Any = None  # single: option value; likert: point 1..n; multiple: list of values
    text: str = ""  # number and text questions: what was typed
    prefer_not: bool = False
    error: str | None = None

    @property
    def kind(self) -> str:
        return self.question.type

    def options(self) -> list[tuple[Any, str]]:
        """(stored value, label) of each choice, "Prefer not to say" excluded."""
        q = self.question
        if isinstance(q, Likert):
            return [(k + 1, label) for k, label in enumerate(q.points)]
        return [(o.value, o.label) for o in getattr(q, "options", [])]

    def raw(self) -> Any:
        """The answer as given so far, before the answer rule normalises it."""
        if self.prefer_not:
            return PREFER_NOT_TO_SAY
        if isinstance(self.question, Number):
            text = self.text.strip()
            if not text:
                return None
            try:
                return float(text)
            except ValueError:
                return text  # refused by the rule, with a reason
        if isinstance(self.question, Text):
            return self.text if self.text.strip() else None
        if isinstance(self.question, MultipleChoice):
            return list(self.choice or []) or None
        return self.choice

    def load(self, value: Any) -> None:
        """Prefill from a stored answer (a resumed session); None is an answer taken back."""
        if value is None:
            return
        if value == PREFER_NOT_TO_SAY:
            self.prefer_not = True
        elif isinstance(self.question, Number):
            self.text = f"{value:g}" if isinstance(value, int | float) else ""
        elif isinstance(self.question, Text):
            self.text = str(value)
        elif isinstance(self.question, MultipleChoice):
            self.choice = list(value or [])
        else:
            self.choice = value


@dataclass
class FormState:
    """A page of questions: focus, edits, refusals."""

    fields: list[Field]
    focus: int = 0
    stored: dict[str, Any] = field(default_factory=dict)  # question id -> last value stored

    @classmethod
    def for_page(cls, questions: list[Any], answered: dict[str, Any]) -> FormState:
        fields = [Field(q) for q in questions]
        for f in fields:
            if f.question.id in answered:
                f.load(answered[f.question.id])
        return cls(fields, stored={f.question.id: answered[f.question.id]
                                   for f in fields if f.question.id in answered})

    # -- editing ----------------------------------------------------------------------
    def choose(self, qi: int, value: Any) -> None:
        """Pick (or for multiple choice toggle) an option of question ``qi``."""
        f = self.fields[qi]
        self.focus = qi
        f.prefer_not = False
        if isinstance(f.question, MultipleChoice):
            chosen = list(f.choice or [])
            chosen.remove(value) if value in chosen else chosen.append(value)
            f.choice = chosen
        else:
            f.choice = value
        f.error = None

    def step(self, qi: int, delta: int) -> None:
        """Left/Right: move a single choice or Likert point by ``delta``; "Prefer not to say",
        where offered, is the last stop (drawn after the options), so the keyboard reaches
        every choice the mouse does."""
        f = self.fields[qi]
        if f.kind not in ("single", "likert"):
            return
        values = [v for v, _ in f.options()]
        last = len(values) if f.question.offers_prefer_not_to_say else len(values) - 1
        if f.prefer_not:
            k = min(max(len(values) + delta, 0), last)
        elif f.choice in values:
            k = min(max(values.index(f.choice) + delta, 0), last)
        else:
            k = 0 if delta > 0 else last
        if k == len(values):
            self.prefer_not_to_say(qi)
        else:
            self.choose(qi, values[k])

    def prefer_not_to_say(self, qi: int) -> None:
        """Choose "Prefer not to say" (where the question offers it)."""
        f = self.fields[qi]
        if f.question.offers_prefer_not_to_say:
            self.focus = qi
            f.prefer_not, f.error = True, None

    def toggle_prefer_not(self, qi: int) -> None:
        f = self.fields[qi]
        if not f.question.offers_prefer_not_to_say:
            return
        self.focus = qi
        f.prefer_not = not f.prefer_not
        f.error = None

    def type(self, qi: int, text: str) -> None:
        """Typed characters into a number or text question (control characters dropped;
        a text never grows past its limit, a number past a few characters)."""
        f = self.fields[qi]
        if f.kind not in ("number", "text"):
            return
        clean = "".join(c for c in text if unicodedata.category(c)[0] != "C")
        if f.kind == "number":
            clean = "".join(c for c in clean if c in "0123456789.-")
            limit = MAX_NUMBER_CHARS
        else:
            limit = f.question.max_length
        if not clean:  # a letter in a number field: nothing typed, no choice undone
            return
        f.text = (f.text + clean)[:limit]
        f.prefer_not = False
        f.error = None

    def backspace(self, qi: int) -> None:
        f = self.fields[qi]
        if f.kind in ("number", "text"):
            f.text = f.text[:-1]
            f.error = None

    def move_focus(self, delta: int) -> None:
        self.focus = min(max(self.focus + delta, 0), len(self.fields) - 1)

    def left(self, qi: int) -> None:
        """The participant moved on from ``qi``: a typed answer the rule refuses ("12" for
        an age of 18-99) shows its reason now, not only at Enter; an empty one waits."""
        f = self.fields[qi]
        if f.kind in ("number", "text") and f.text.strip() and not f.prefer_not:
            self.check(qi)

    # -- checking ---------------------------------------------------------------------
    def check(self, qi: int) -> tuple[bool, Any]:
        """(valid, stored value) of question ``qi``; an invalid one gets its reason."""
        f = self.fields[qi]
        try:
            value = check_answer(f.question, f.raw())
        except PanelError as exc:
            f.error = _plain(str(exc), f.question)
            return False, None
        f.error = None
        return True, value

    def confirmed(self, qi: int) -> Any | None:
        """The value to store for ``qi`` now: valid, answered and not stored yet (else None)."""
        changed, value = self.to_store(qi)
        return value if changed else None

    def to_store(self, qi: int) -> tuple[bool, Any]:
        """(whether to store, value) for ``qi`` now: a valid answer not stored yet, or None
        when an optional question that holds a stored answer was emptied again (a deleted
        comment, every option unchosen, "Prefer not to say" switched off): the participant
        took the answer back, so the session file must not keep it."""
        f = self.fields[qi]
        try:
            value = check_answer(f.question, f.raw())
        except PanelError:
            return False, None
        before = self.stored.get(f.question.id, _UNSET)
        if (value is None and before in (_UNSET, None)) or before == value:
            return False, None
        self.stored[f.question.id] = value
        return True, value

    def take_back(self) -> list[str]:
        """Skip (offered on voluntary questionnaires only): the page's questions are emptied
        and those with a stored answer are returned (to be stored as None), so that a skipped
        questionnaire keeps no answer of its page, required ones included (the answer rule,
        which the server applies too, takes "no answer" back in a voluntary questionnaire)."""
        ids = []
        for f in self.fields:
            f.choice, f.text, f.prefer_not, f.error = None, "", False, None
            if self.stored.get(f.question.id) is not None:
                self.stored[f.question.id] = None
                ids.append(f.question.id)
        return ids

    def validate_page(self) -> bool:
        """Check every question (refusals shown); True when the page can be left forward."""
        ok = True
        for qi in range(len(self.fields)):
            valid, _ = self.check(qi)
            if not valid and ok:
                self.focus = qi
            ok &= valid
        return ok


_UNSET = object()


def _plain(message: str, question: Any) -> str:
    """The answer rule's reason in the participant's words (without the question id)."""
    text = message.split(": ", 1)[-1]
    if isinstance(question, Number) and ("outside" in text or "number" in text):
        whole = "a whole number" if question.integer else "a number"
        return f"Enter {whole} between {question.min:g} and {question.max:g}"
    if text == "an answer is required":
        return "Please answer this question" + (
            " (or choose Prefer not to say)" if question.offers_prefer_not_to_say else "")
    return text[:1].upper() + text[1:]
