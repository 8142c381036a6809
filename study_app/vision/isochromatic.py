"""Pseudo-isochromatic plates, generated: a disc of dots of random size, those inside a digit
in one colour and the rest in another.

On a deficiency plate the two colours lie on a confusion line of that dichromat (they differ
along the null direction of its simulation matrix, :mod:`.dichromacy`), so a normal observer
reads the digit and the dichromat does not. Every dot's brightness is scaled at random
(0.75..1.15, the same law for figure and background), so the digit cannot be read from
brightness alone. Control plates draw the digit much darker than the background: any observer
reads them, under every simulation. Nothing here copies a published plate; everything is
drawn from the seed. This is a screening on an uncalibrated display, never a diagnosis.

The tritan plates are weak: Machado's tritan matrix is not singular, so their colours differ
along its weakest direction and a hue difference of about 4 Delta E 2000 remains under the
tritan simulation (docs/panel.md gives the numbers). Chromatic jitter cannot hide it from the
tritan simulation without hiding the digit as much from everyone: the matrix is invertible.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .dichromacy import DEFICIENCIES, confusion_direction, linear_to_srgb

PlateKind = Literal["protan", "deutan", "tritan", "control"]
FONT = Path(__file__).resolve().parents[1] / "assets" / "fonts" / "DejaVuSans-Bold.ttf"
MID = np.array([0.22, 0.22, 0.22])  # linear RGB the two colours are centred on
# How far apart the two colours are along the confusion direction: far enough for a normal
# observer (Delta E > 15), small enough that the tritan matrix, which is not singular, keeps
# the difference it sees near a quarter of what a normal observer sees (below 4).
STEP = {"protan": 0.30, "deutan": 0.30, "tritan": 0.095}
BRIGHTNESS = (0.75, 1.15)
CONTROL_DIGIT, CONTROL_BACKGROUND = 2.0, 0.4
"""A control plate's digit and background dots, in units of ``MID``: a light digit on dim
dots (a dark digit read as a hole in the plate on the dark screen, and at 288-360 px it was
misread, making the check inconclusive)."""
BACKDROP = (36, 38, 43)  # the screens' background (study_app.screens.draw.SCREEN_BG)


@dataclass(frozen=True)
class Plate:
    """A plate: its picture and everything needed to check it from the pixels."""

    kind: PlateKind
    answer: str
    image: np.ndarray  # (H, W, 3) uint8 sRGB
    centres: np.ndarray  # (n, 2) dot centres (x, y) in pixels
    radii: np.ndarray  # (n,)
    figure: np.ndarray  # (n,) bool: the dot belongs to the digit
    colours: np.ndarray  # (n, 3) uint8 sRGB of each dot


def plate_colours(kind: PlateKind) -> tuple[np.ndarray, np.ndarray]:
    """(figure, background) base colours in linear RGB."""
    if kind == "control":
        return MID * CONTROL_DIGIT, MID * CONTROL_BACKGROUND
    half = STEP[kind] / 2 * confusion_direction(kind)
    return MID + half, MID - half


def _digit_mask(digit: str, size: int) -> np.ndarray:
    # Pillow's font module is imported only when plates are drawn: imported with the app at
    # start-up, it made the preview with its timing overlay stop taking keys under Xvfb
    # (seen in the tests; the cause, two FreeType copies in one process, is a guess).
    from PIL import Image, ImageDraw, ImageFont

    img = Image.new("L", (size, size), 0)
    font = ImageFont.truetype(str(FONT), round(size * 0.72))
    draw = ImageDraw.Draw(img)
    box = draw.textbbox((0, 0), digit, font=font)
    x = (size - (box[2] - box[0])) / 2 - box[0]
    y = (size - (box[3] - box[1])) / 2 - box[1]
    draw.text((x, y), digit, fill=255, font=font)
    return np.asarray(img) > 127


def _dots(size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Non-overlapping dots of random radius filling a disc: candidates are tested against
    a raster of the dots placed so far (a dot's disc plus a one-pixel gap)."""
    r_min, r_max = size / 130, size / 55
    c, radius = size / 2, size / 2 - 2
    taken = np.zeros((size + 2, size + 2), dtype=bool)
    yy, xx = np.mgrid[0:size + 2, 0:size + 2]
    centres: list[tuple[float, float]] = []
    radii: list[float] = []
    fails = 0
    while fails < 1500:
        r = float(rng.uniform(r_min, r_max))
        x, y = rng.uniform(c - radius, c + radius, size=2)
        if (x - c) ** 2 + (y - c) ** 2 > (radius - r) ** 2:
            fails += 1
            continue
        x0, x1 = int(x - r - 1), int(x + r + 2)
        y0, y1 = int(y - r - 1), int(y + r + 2)
        disc = (xx[y0:y1, x0:x1] - x) ** 2 + (yy[y0:y1, x0:x1] - y) ** 2 <= (r + 1) ** 2
        if (taken[y0:y1, x0:x1] & disc).any():
            fails += 1
            continue
        taken[y0:y1, x0:x1] |= disc
        centres.append((x, y))
        radii.append(r)
        fails = 0
    return np.array(centres), np.array(radii)


def make_plate(kind: PlateKind, digit: str, *, size: int = 360, seed: int = 0) -> Plate:
    """A plate of ``kind`` showing ``digit`` (one character), ``size`` pixels square."""
    if kind not in (*DEFICIENCIES, "control"):
        raise ValueError(f"plate kind {kind!r} is not protan, deutan, tritan or control")
    if len(digit) != 1 or not digit.isdigit():
        raise ValueError(f"a plate shows one digit, got {digit!r}")
    rng = np.random.default_rng(seed)
    centres, radii = _dots(size, rng)
    mask = _digit_mask(digit, size)
    ix = np.clip(centres.round().astype(int), 0, size - 1)
    figure = mask[ix[:, 1], ix[:, 0]]
    fg, bg = plate_colours(kind)
    bright = rng.uniform(*BRIGHTNESS, size=len(centres))
    linear = np.where(figure[:, None], fg, bg) * bright[:, None]
    colours = np.round(linear_to_srgb(linear) * 255).astype(np.uint8)
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (size, size), BACKDROP)
    draw = ImageDraw.Draw(img)
    for (x, y), r, col in zip(centres, radii, colours, strict=True):
        draw.ellipse((x - r, y - r, x + r, y + r), fill=tuple(int(v) for v in col))
    return Plate(kind, digit, np.asarray(img), centres, radii, figure, colours)


def plate_series(seed: int = 0, *, size: int = 360) -> list[Plate]:
    """The default check: two controls, then two plates per deficiency, in a seeded order,
    digits drawn so that no digit follows itself."""
    rng = np.random.default_rng(seed)
    kinds: list[PlateKind] = ["control", "control", *[k for k in DEFICIENCIES for _ in (0, 1)]]
    order = ["control", "control", *(str(k) for k in rng.permutation(kinds[2:]))]
    plates, last = [], ""
    for k, kind in enumerate(order):
        digit = str(rng.choice([d for d in "2345679" if d != last]))
        plates.append(make_plate(kind, digit, size=size, seed=seed * 1000 + k))
        last = digit
    return plates
