"""Patterns that would map a renders folder the default patterns do not: read off the file
names (a reference word such as ``ref`` or ``GT`` in the name or as a folder of per-method
layouts, a trailing level number), then checked by
mapping the folder with them. Only a pair that maps every video (but for a stray file or
three, which the suggestion names) with no problem and no doubt is suggested, so a guess
never reaches the researcher as advice."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from .mapping import REFERENCE_WORDS, map_by_pattern

_SEPARATORS = "_-. "
# a level may carry a short word before it (``_q1``, ``_L2``) or a unit after it (``_64spp``,
# ``_1080p``, ``_2x``): renderers name outputs by the sample count
_LEVEL_AFTER_SEPARATOR = re.compile(r"^(?P<method>.+?)(?P<sep>[_\-. ])(?P<prefix>[A-Za-z]{0,5})"
                                    r"(?P<level>\d+)(?P<unit>[A-Za-z]{0,5})$")
_LEVEL_AT_END = re.compile(r"^(?P<method>.*?[^\d])(?P<level>\d+)(?P<unit>[A-Za-z]{0,5})$")


@dataclass(frozen=True)
class PatternSuggestion:
    """A ``--reference-pattern``/``--pattern`` pair and what it maps."""

    reference_pattern: str
    test_pattern: str
    scenes: int
    videos: int
    left_out: tuple[str, ...] = ()
    """Files the pair does not match (a stray copy such as ``x (1).mp4``), at most
    :data:`MAX_LEFT_OUT`; they are named with the suggestion."""
    doubts: tuple[str, ...] = ()
    """What the mapping warns of (a scene that seems to have lost its reference): a pair with
    doubts is offered only with them, never as plain advice."""

    def flags(self) -> str:
        return (f"--reference-pattern '{self.reference_pattern}' "
                f"--pattern '{self.test_pattern}'")


def _is_reference_word(word: str) -> bool:
    return word.lower() in REFERENCE_WORDS


def _reference_ending(stem: str) -> str | None:
    """``Sponza-GT`` -> ``-GT`` (the separator and the reference word as spelled)."""
    for word in sorted(REFERENCE_WORDS, key=len, reverse=True):
        n = len(word) + 1
        if len(stem) > n and stem.lower().endswith(word) and stem[-n] in _SEPARATORS:
            return stem[-n:]
    return None


def _level_template(name: str) -> str | None:
    """``TAA_q1`` -> ``{method}_q{level}``; ``ours_64spp`` -> ``{method}_{level}spp``;
    ``crf23`` -> ``{method}{level}``; None: no number at the end (or before a short unit),
    so no level to read."""
    if m := _LEVEL_AFTER_SEPARATOR.fullmatch(name):
        return "{method}" + m["sep"] + m["prefix"] + "{level}" + m["unit"]
    if m := _LEVEL_AT_END.fullmatch(name):
        return "{method}{level}" + m["unit"]
    return None


def _split_scene(stem: str, scenes: list[str]) -> tuple[str, str] | None:
    """(separator, rest) of a flat test name: after the longest scene a reference named, or
    else at the first separator."""
    for scene in sorted(scenes, key=len, reverse=True):
        if stem.startswith(scene) and len(stem) > len(scene) + 1 \
                and stem[len(scene)] in _SEPARATORS:
            return stem[len(scene)], stem[len(scene) + 1:]
    cut = min((stem.find(c) for c in _SEPARATORS if c in stem), default=-1)
    return (stem[cut], stem[cut + 1:]) if cut > 0 else None


def _candidates(videos: list[PurePosixPath]) -> list[tuple[str, str]]:
    """(reference pattern, test pattern) pairs, the most common spellings first."""
    refs: Counter[str] = Counter()
    tests: Counter[str] = Counter()
    scenes: list[str] = []
    rest: list[tuple[PurePosixPath, str]] = []
    for rel in videos:
        stem = rel.name[: -len(rel.suffix)] if rel.suffix else rel.name
        if len(rel.parts) == 2 and _is_reference_word(stem):  # scene/ref.ext
            refs["{scene}/" + stem + ".{ext}"] += 1
        elif len(rel.parts) == 2 and _is_reference_word(rel.parts[0]):  # ref/scene.ext
            refs[rel.parts[0] + "/{scene}.{ext}"] += 1
        elif len(rel.parts) == 2 and (ending := _reference_ending(stem)) is not None \
                and stem[: -len(ending)] == rel.parts[0]:  # scene/scene_ref.ext
            refs["{scene}/{scene}" + ending + ".{ext}"] += 1
        elif len(rel.parts) == 1 and (ending := _reference_ending(stem)) is not None:
            refs["{scene}" + ending + ".{ext}"] += 1  # scene<sep>ref.ext
            scenes.append(stem[: -len(ending)])
        else:
            rest.append((rel, stem))
    for rel, stem in rest:
        if len(rel.parts) == 2 and (template := _level_template(stem)) is not None:
            scene = rel.parts[0]  # scene/scene_dlss_L1.ext first: else methods 'scene_dlss'
            if stem.startswith(scene) and len(stem) > len(scene) + 1 and \
                    stem[len(scene)] in _SEPARATORS and \
                    (inner := _level_template(stem[len(scene) + 1:])) is not None:
                tests["{scene}/{scene}" + stem[len(scene)] + inner + ".{ext}"] += 1
            tests["{scene}/" + template + ".{ext}"] += 1
            if m := _LEVEL_AFTER_SEPARATOR.fullmatch(stem):  # method/scene_L1.ext
                tests["{method}/{scene}" + m["sep"] + m["prefix"] + "{level}" + m["unit"]
                      + ".{ext}"] += 1
        elif len(rel.parts) == 1 and (split := _split_scene(stem, scenes)) is not None \
                and (template := _level_template(split[1])) is not None:
            tests["{scene}" + split[0] + template + ".{ext}"] += 1
    return [(r, t) for r, _ in refs.most_common(3) for t, _ in tests.most_common(3)]


def suggest_patterns(folder: Path, videos: list[PurePosixPath],
                     exclude: Path | None = None) -> PatternSuggestion | None:
    """The first pattern pair read off ``videos`` (the folder's video files) that maps every
    one of them with no problem and no doubt, or all but a few strays it leaves out (named);
    else the first that maps them with doubts (:attr:`PatternSuggestion.doubts`); None when
    there is none."""
    doubtful = None
    for reference_pattern, test_pattern in _candidates(videos):
        try:
            mapped = map_by_pattern(folder, test_pattern=test_pattern,
                                    reference_pattern=reference_pattern, exclude=exclude)
        except ValueError:
            continue
        strays = len(mapped.unmatched)
        if mapped.problems or strays > _max_left_out(len(videos)) \
                or len(mapped.videos) + strays != len(videos):
            continue
        found = PatternSuggestion(reference_pattern, test_pattern, len(mapped.references()),
                                  len(mapped.videos),
                                  tuple(p.as_posix() for p in mapped.unmatched),
                                  tuple(mapped.warnings))
        if not found.doubts:
            return found
        doubtful = doubtful or found  # a split in doubt: said with its doubts, if nothing else
    return doubtful


MAX_LEFT_OUT = 3


def _max_left_out(n_videos: int) -> int:
    """Strays a suggestion may leave out: one, or a tenth of the files up to three."""
    return min(MAX_LEFT_OUT, max(1, n_videos // 10))
