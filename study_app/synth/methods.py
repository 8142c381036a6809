"""The six distortion families and their four levels each.

``level`` is a severity rank: 1 is the strongest distortion, 4 the mildest (the manifest's
convention). ``value`` is the family's own parameter at that level and ``setting`` says it in
words for people reading the manifest.
"""

from __future__ import annotations

from dataclasses import dataclass

from session_store.errors import StudyError

# Scenes rendered when the user names none (the GLSL programs in shaders/).
DEFAULT_SCENES = ("colonnade", "lattice")


@dataclass(frozen=True)
class Level:
    level: int
    value: float
    setting: str


@dataclass(frozen=True)
class Method:
    name: str
    description: str
    levels: tuple[Level, ...]


def _levels(values: tuple[float, ...], fmt: str) -> tuple[Level, ...]:
    return tuple(Level(i + 1, v, fmt.format(v=v)) for i, v in enumerate(values))


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method(
            "path_tracing",
            "Monte Carlo lighting noise and fireflies (samples per pixel)",
            _levels((4, 16, 64, 256), "{v:g} spp"),
        ),
        Method(
            "denoising",
            "low-sample renders through an edge-aware a-trous filter (samples per pixel)",
            _levels((2, 4, 8, 16), "{v:g} spp + denoiser"),
        ),
        Method(
            "upscaling",
            "jittered low-resolution render, temporal accumulation, upscaled (scale divisor)",
            _levels((3.0, 2.3, 2.0, 1.5), "1/{v:g} resolution"),
        ),
        Method(
            "splatting",
            "scene approximated by Gaussian splats refitted at keyframes (pixels per splat)",
            _levels((16, 8, 4, 2), "1 splat per {v:g} pixels"),
        ),
        Method(
            "frame_interpolation",
            "rendered at a low frame rate, blended up to 60 fps (rendered fps)",
            _levels((12, 15, 20, 30), "{v:g} fps -> 60 fps"),
        ),
        Method(
            "vrs",
            "coarse 2x2 / 4x4 shading in low-contrast tiles (shading budget, percent)",
            _levels((6.25, 12.5, 25.0, 50.0), "{v:g} % shading budget"),
        ),
    )
}

INTERPOLATED_FPS = 60
"""Frame rate of the frame-interpolation family's output (and its reference)."""


def parse_methods(text: str | None) -> list[str]:
    """Comma-separated family names (or ``all``) -> list in the canonical order."""
    if text is None or text.strip().lower() == "all":
        return list(METHODS)
    wanted = [t.strip() for t in text.split(",") if t.strip()]
    if not wanted:
        raise StudyError(f"--methods is empty; give 'all' or some of {', '.join(METHODS)}")
    unknown = [w for w in wanted if w not in METHODS]
    if unknown:
        raise StudyError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)}"
        )
    return [m for m in METHODS if m in wanted]
