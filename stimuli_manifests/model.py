"""The ``cgvq-manifest/1`` data model: what a stimulus set is.

A manifest names a study, the rating scale, the presentation protocol, the reference videos
(SRC) and the processed videos (PVS, "conditions") made from them by a distortion method
(HRC family) at a level. Paths are relative to ``root``, which is relative to the manifest
file. Every other package reads stimuli through this model.
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .allocation import AdaptiveAllocation, AllocationPolicy
from .formats import VersionedFormat
from .ids import assign_missing_ids
from .panel import Panel

MANIFEST_FORMAT = VersionedFormat(
    "cgvq-manifest", 1, field="manifest format", document="document",
    advice="upgrade the toolkit or convert the manifest")
FORMAT = MANIFEST_FORMAT.version

_ID_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]*")  # used with fullmatch: "$" takes "\n"
# Participant-facing texts a study folder may hold beside its manifest; their sha256 go into
# ``Manifest.texts`` like the videos' (the participant consents to exactly this text).
STUDY_TEXT_FILES = ("briefing.md", "consent.md")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ScaleLabel(_Strict):
    """One anchor label on the rating scale."""

    position: float = Field(allow_inf_nan=False)
    text: str = Field(min_length=1)


DEFAULT_LABELS: tuple[tuple[float, str], ...] = (
    (0.0, "Very annoying"),
    (25.0, "Annoying"),
    (50.0, "Slightly annoying"),
    (75.0, "Perceptible but not annoying"),
    (100.0, "Imperceptible"),
)


DEFAULT_QUESTION = ("Rate the quality of distortions in the shown video with respect to its "
                    "reference")
"""The question above the slider when a manifest gives none (the CGVQM study's wording)."""
MAX_QUESTION_CHARS = 160
"""A question, not instructions (those belong on the intro screens): the rating screen's
layout test shows one this long at every window size the pre-flight accepts."""


def _default_labels() -> list[ScaleLabel]:
    return [ScaleLabel(position=p, text=t) for p, t in DEFAULT_LABELS]


class RatingScale(_Strict):
    """A continuous rating scale; by default 0..100 with the five impairment labels."""

    # Finite only: an infinite bound (JSON 1e400 reads as inf) would turn every DMOS into inf.
    min: float = Field(default=0.0, allow_inf_nan=False)
    max: float = Field(default=100.0, allow_inf_nan=False)
    direction: Literal["higher_is_better", "lower_is_better"] = "higher_is_better"
    labels: list[ScaleLabel] = Field(default_factory=_default_labels)
    question: str | None = Field(
        default=None, min_length=1, max_length=MAX_QUESTION_CHARS,
        description="the question above the slider, in the participants' words (e.g. \"How "
        "annoying are the differences from the reference?\"); None = the CGVQM study's "
        "wording, DEFAULT_QUESTION")

    @property
    def shown_question(self) -> str:
        """The question the player shows above the slider."""
        return self.question if self.question is not None else DEFAULT_QUESTION

    @model_validator(mode="after")
    def _check(self) -> RatingScale:
        if not self.max > self.min:
            raise ValueError(f"scale.max ({self.max}) must be greater than scale.min ({self.min})")
        positions = [label.position for label in self.labels]
        if "labels" not in self.model_fields_set and (self.min, self.max) != (0.0, 100.0):
            raise ValueError(
                f"scale.labels must be given for a range other than 0..100 (the default "
                f"labels sit at 0, 25, 50, 75 and 100; this scale is {self.min:g}..{self.max:g}); "
                "[] will do for a manifest that is only analysed")
        for label in self.labels:
            if not self.min <= label.position <= self.max:
                raise ValueError(
                    f"scale label {label.text!r} at {label.position} lies outside "
                    f"[{self.min}, {self.max}]"
                )
        if positions != sorted(positions) or len(set(positions)) != len(positions):
            raise ValueError("scale.labels must have strictly increasing positions")
        if self.question is not None and not self.question.strip():
            raise ValueError("scale.question is blank; give the question or leave it out")
        return self


class Protocol(_Strict):
    """How trials are presented."""

    repetitions: int = Field(default=3, ge=1, le=100)
    blank_seconds: float = Field(default=0.5, ge=0.0, le=10.0)
    hidden_reference: bool = True
    loop: bool = True
    min_view_seconds: float | None = Field(
        default=None, ge=0.0, description="minimum viewing time before submit; None = one loop"
    )
    viewing_distance_cm: float | None = Field(
        default=None, ge=30.0, le=200.0,
        description="how far from the screen participants are asked to sit while they rate "
        "(told before the trials and after each break); None = no instruction")
    allocation: AllocationPolicy = Field(
        default="full", description="full: every stimulus `repetitions` times; adaptive: "
        "blocks planned by the study server")
    adaptive: AdaptiveAllocation | None = Field(
        default=None, description="settings of adaptive allocation (defaults when omitted)")

    @model_validator(mode="after")
    def _adaptive_settings(self) -> Protocol:
        if self.adaptive is not None and self.allocation != "adaptive":
            raise ValueError("protocol.adaptive is set but protocol.allocation is "
                             f"{self.allocation!r}: set allocation to 'adaptive' or remove it")
        return self

    def adaptive_settings(self) -> AdaptiveAllocation | None:
        """The adaptive settings (defaults filled in), None for the full design."""
        if self.allocation != "adaptive":
            return None
        return self.adaptive or AdaptiveAllocation()


class DisplayRequirements(_Strict):
    """What the participant's display must offer (checked by the study app's pre-flight)."""

    min_width: int = Field(default=1920, ge=1)
    min_height: int = Field(default=1080, ge=1)
    min_refresh_hz: float = Field(default=59.0, gt=0)


class _IdAndChecksum(_Strict):
    @field_validator("id", check_fields=False)
    @classmethod
    def check_id(cls, value: str | None) -> str | None:
        return _valid_id(value)

    @field_validator("sha256", check_fields=False)
    @classmethod
    def check_sha256(cls, value: str | None) -> str | None:
        return _valid_sha(value)


class Reference(_IdAndChecksum):
    """A source video (SRC)."""

    id: str | None = None
    path: str
    sha256: str | None = None
    scene: str | None = Field(default=None, description="scene name; defaults to the id")
    fps: float | None = Field(default=None, gt=0)
    width: int | None = Field(default=None, ge=1)
    height: int | None = Field(default=None, ge=1)
    frames: int | None = Field(default=None, ge=1)
    metadata: dict[str, Any] = Field(default_factory=dict)


class Condition(_IdAndChecksum):
    """A processed video sequence (PVS): a reference through a distortion method at a level.

    ``level`` is an ordinal severity rank within the method: 1 is the strongest distortion,
    higher levels are milder. ``setting`` is the human-readable parameter ("4 spp", "1/2").
    """

    id: str | None = None
    reference: str
    path: str
    method: str = Field(min_length=1)
    level: int = Field(ge=0)
    setting: str | None = None
    sha256: str | None = None
    metadata: dict[str, Any] = Field(default_factory=dict)


class Stimulus(BaseModel):
    """One thing a participant rates: a condition, or a reference shown as hidden reference."""

    model_config = ConfigDict(frozen=True)

    id: str
    reference: str
    path: str
    scene: str
    method: str
    level: int | None
    is_hidden_reference: bool
    sha256: str | None = None


HIDDEN_REFERENCE_METHOD = "reference"


class Manifest(_Strict):
    """A stimulus set: the ``cgvq-manifest/1`` document."""

    format: str = FORMAT
    study_id: str = Field(min_length=1)
    title: str | None = None
    description: str | None = None
    root: str = "."
    scale: RatingScale = Field(default_factory=RatingScale)
    protocol: Protocol = Field(default_factory=Protocol)
    display: DisplayRequirements = Field(default_factory=DisplayRequirements)
    references: list[Reference] = Field(min_length=1)
    conditions: list[Condition] = Field(default_factory=list)
    texts: dict[str, str] = Field(
        default_factory=dict,
        description="sha256 of the texts beside the manifest (briefing.md, consent.md)")
    panel: Panel | None = Field(
        default=None, description="questionnaires and vision screening (cgvq-panel/1)")
    metadata: dict[str, Any] = Field(default_factory=dict)

    @field_validator("texts")
    @classmethod
    def _check_texts(cls, value: dict[str, str]) -> dict[str, str]:
        for name in value:
            if name not in STUDY_TEXT_FILES:
                raise ValueError(f"texts: {name!r} is not one of {', '.join(STUDY_TEXT_FILES)}")
        return {name: _valid_sha(sha) for name, sha in value.items()}

    @field_validator("format")
    @classmethod
    def _check_format(cls, value: str) -> str:
        MANIFEST_FORMAT.check(value)  # a FormatVersionError is a ValueError: a field error
        return value

    @model_validator(mode="after")
    def _check_ids(self) -> Manifest:
        assign_missing_ids(self.references, self.conditions)
        ref_ids = [r.id for r in self.references]
        dup = _duplicates(ref_ids)
        if dup:
            raise ValueError(f"duplicate reference id(s): {', '.join(dup)}")
        cond_ids = [c.id for c in self.conditions]
        dup = _duplicates(cond_ids + ref_ids)
        if dup:
            raise ValueError(f"duplicate stimulus id(s): {', '.join(dup)}")
        known = set(ref_ids)
        for i, cond in enumerate(self.conditions):
            if cond.reference not in known:
                raise ValueError(
                    f"conditions[{i}] ({cond.id}): reference {cond.reference!r} is not one of "
                    f"the manifest's references"
                )
        return self

    @model_validator(mode="after")
    def _check_blocks(self) -> Manifest:
        adaptive = self.protocol.adaptive_settings()
        if adaptive is not None and not self.protocol.hidden_reference:
            # The planner sizes each condition's DMOS interval from its reference's ratings;
            # without hidden references every interval reads as zero and all adapted trials
            # would go to the first stimuli in manifest order.
            raise ValueError(
                "protocol.allocation 'adaptive' needs protocol.hidden_reference: true (its "
                "DMOS intervals need each scene's hidden reference); turn hidden references "
                "on or use allocation 'full'")
        if adaptive is not None and adaptive.block_trials is not None:
            n = len(self.stimuli())
            if adaptive.block_trials > n * adaptive.max_per_block:
                raise ValueError(
                    f"protocol.adaptive.block_trials {adaptive.block_trials} cannot be filled: "
                    f"{n} stimuli at most {adaptive.max_per_block} times each hold "
                    f"{n * adaptive.max_per_block}")
        return self

    # -- convenient views -------------------------------------------------------------
    def reference_by_id(self, ref_id: str) -> Reference:
        for ref in self.references:
            if ref.id == ref_id:
                return ref
        raise KeyError(ref_id)

    def scene_of(self, ref_id: str) -> str:
        ref = self.reference_by_id(ref_id)
        return ref.scene or str(ref.id)

    def stimuli(self, *, include_hidden_references: bool | None = None) -> list[Stimulus]:
        """Everything that is rated: conditions, plus references when hidden references are on."""
        if include_hidden_references is None:
            include_hidden_references = self.protocol.hidden_reference
        out = [
            Stimulus(
                id=str(c.id),
                reference=c.reference,
                path=c.path,
                scene=self.scene_of(c.reference),
                method=c.method,
                level=c.level,
                is_hidden_reference=False,
                sha256=c.sha256,
            )
            for c in self.conditions
        ]
        if include_hidden_references:
            out += [
                Stimulus(
                    id=str(r.id),
                    reference=str(r.id),
                    path=r.path,
                    scene=r.scene or str(r.id),
                    method=HIDDEN_REFERENCE_METHOD,
                    level=None,
                    is_hidden_reference=True,
                    sha256=r.sha256,
                )
                for r in self.references
            ]
        return out

    def stimulus_by_id(self, stimulus_id: str) -> Stimulus:
        for stim in self.stimuli(include_hidden_references=True):
            if stim.id == stimulus_id:
                return stim
        raise KeyError(stimulus_id)

    def methods(self) -> list[str]:
        """Distortion methods in order of first appearance."""
        return list(dict.fromkeys(c.method for c in self.conditions))


def is_valid_id(text: str) -> bool:
    """Whether ``text`` can be a reference or stimulus id (ASCII letters, digits, ``_-.``)."""
    return bool(_ID_RE.fullmatch(text))


def _valid_id(value: str | None) -> str | None:
    if value is not None and not _ID_RE.fullmatch(value):
        raise ValueError(
            f"id {value!r} may contain only ASCII letters, digits, '_', '-' and '.', "
            "and must start with a letter or digit"
        )
    return value


def _valid_sha(value: str | None) -> str | None:
    if value is None:
        return None
    value = value.lower()
    if not re.fullmatch(r"[0-9a-f]{64}", value):
        raise ValueError(f"sha256 must be 64 hexadecimal digits, got {value!r}")
    return value


def _duplicates(values: list[Any]) -> list[str]:
    seen: set[Any] = set()
    dup: list[str] = []
    for v in values:
        if v in seen and str(v) not in dup:
            dup.append(str(v))
        seen.add(v)
    return dup
