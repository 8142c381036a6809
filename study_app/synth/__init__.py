"""Synthetic computer-graphics stimuli: GLSL scenes rendered off-screen, six distortion
families at four levels each, written as a lossless study folder with its manifest.

The family table (:mod:`.methods`) is light; the renderer and the post-processing need
ModernGL and scipy (the ``[synth]`` extra) and load only when first used, so listing the
subcommand in ``cgvq-study --help`` works in the participant's base install.
"""

from __future__ import annotations

from typing import Any

from .methods import DEFAULT_SCENES, METHODS, Level, Method, parse_methods

_LAZY = {
    "MANIFEST_NAME": ".build",
    "VIDEO_DIR": ".build",
    "SynthOptions": ".build",
    "synthesize": ".build",
    "available_scenes": ".renderer",
}

__all__ = [
    "DEFAULT_SCENES",
    "MANIFEST_NAME",
    "METHODS",
    "VIDEO_DIR",
    "Level",
    "Method",
    "SynthOptions",
    "available_scenes",
    "parse_methods",
    "synthesize",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
