"""What the answers to the colour-vision plates mean, as the session records it.

The rule: a participant who misreads a control plate (which any observer reads) has not
taken the check properly, so the outcome is ``inconclusive``, not a failure. Otherwise a
deficiency type counts as failed when both of its plates were misread (one slip is not
enough); any failed type makes the outcome ``failed``. It is a screening on an uncalibrated
display, never a diagnosis: a failure says "this participant may not see these colour
differences on this screen".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

RULE = ("controls all read correctly, else inconclusive; a deficiency type fails when both of "
        "its plates are misread")
NO_NUMBER = "none"


@dataclass(frozen=True)
class PlateAnswer:
    """One plate as shown and answered (``given``: a digit, or ``none``)."""

    kind: str
    answer: str
    given: str
    ms: float

    @property
    def correct(self) -> bool:
        return self.given == self.answer


def score_colour(answers: list[PlateAnswer]) -> tuple[str, dict[str, Any]]:
    """(outcome, result) of a colour check: passed, failed or inconclusive."""
    controls = [a for a in answers if a.kind == "control"]
    kinds = sorted({a.kind for a in answers} - {"control"})
    wrong = {k: sum(not a.correct for a in answers if a.kind == k) for k in kinds}
    shown = {k: sum(a.kind == k for a in answers) for k in kinds}
    failed = [k for k in kinds if shown[k] and wrong[k] == shown[k]]
    if not controls or not all(a.correct for a in controls):
        outcome = "inconclusive"
    else:
        outcome = "failed" if failed else "passed"
    return outcome, {"test": "colour", "rule": RULE, "passed": outcome == "passed",
                     "failed_types": failed if outcome != "inconclusive" else [],
                     "errors": wrong, "plates": [asdict(a) for a in answers]}
