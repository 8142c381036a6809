"""Are a method's levels numbered the way the toolkit reads them (level 1 the strongest)?

Before anyone rates, the pixels give a first answer: a distortion's level 1 should differ
most from its reference. A method whose level 1 is the closest to its reference in most
scenes reads as numbered the wrong way round (``4 spp`` as level 1 of a sample count that
rises with the level, say). Pixel differences are not what people see, so this is a
warning that points to a pilot, never a refusal."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

from .pixel_sample import PixelSample, mean_squared_difference

CLEARLY_CLOSER = 0.8
"""Level 1 counts as closer to its reference when its mean squared difference is below this
share of the mildest level's (a margin for levels that differ in pixels by little)."""


@dataclass(frozen=True)
class LevelSample:
    """One test video: its method, scene and level, and its pixels."""

    method: str
    scene: str
    level: int
    sample: PixelSample | None


def level_order_warnings(tests: list[LevelSample],
                         references: dict[str, PixelSample | None]) -> list[str]:
    """One warning per method whose strongest level is closer to its reference than its
    mildest level in more than half of the scenes where both can be compared."""
    by_method: dict[str, dict[str, dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for t in tests:
        ref = references.get(t.scene)
        if t.sample is None or ref is None:
            continue
        msd = mean_squared_difference(t.sample, ref)
        if msd is not None:
            by_method[t.method][t.scene][t.level] = msd
    out = []
    for method in sorted(by_method):
        compared, reversed_in = 0, []
        for scene, levels in sorted(by_method[method].items()):
            if len(levels) < 2:
                continue
            strong, mild = levels[min(levels)], levels[max(levels)]
            compared += 1
            if strong < CLEARLY_CLOSER * mild:
                reversed_in.append((scene, min(levels), strong, max(levels), mild))
        if compared and len(reversed_in) * 2 > compared:
            scene, lo, strong, hi, mild = reversed_in[0]
            out.append(
                f"method {method!r}: the levels look numbered the wrong way round: level {lo} "
                f"is closer to its reference in pixels than level {hi} in {len(reversed_in)} "
                f"of {compared} scene(s) (mean squared difference {_msd(strong)} against "
                f"{_msd(mild)} in scene {scene!r}), and level 1 must be the strongest "
                f"distortion; if so, renumber its files (level {lo} becomes level {hi}, "
                f"level {hi} level {lo}, and so on) or map them in a CSV (pixels are not "
                "what people see: a pilot shows what they see, 'cgvq-analyze pilot')")
    return out


def _msd(x: float) -> str:
    """A mean squared difference as people read it: 1396, not 1.4e+03; 0.0123 stays."""
    return f"{x:.0f}" if x >= 100 else f"{x:.3g}"
