"""Synthetic computer-graphics stimuli: GLSL scenes rendered off-screen, six distortion
families at four levels each, written as a lossless study folder with its manifest."""

from .build import DEFAULT_SCENES, MANIFEST_NAME, VIDEO_DIR, SynthOptions, synthesize
from .methods import METHODS, Level, Method, parse_methods
from .renderer import available_scenes

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
