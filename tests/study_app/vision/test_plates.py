"""The colour-vision plates, checked from their pixels: on a deficiency plate the digit and
its background differ (almost) only along that dichromat's confusion line, and a control
plate stays readable under every simulation. Contact sheets are saved as artifacts."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from study_app.vision.dichromacy import (
    DEFICIENCIES,
    delta_e,
    lab,
    linear_to_srgb,
    simulate,
    srgb_to_linear,
)
from study_app.vision.isochromatic import make_plate, plate_series

REPO = Path(__file__).resolve().parents[3]
ARTIFACTS = REPO / "test-artifacts" / "study_app" / "vision"
SAME = 1.0  # Delta E: the dichromat sees no difference (protan, deutan: singular matrices)
TRITAN_SAME = 4.0  # Machado's tritan matrix is not singular: a small difference remains
CLEAR = 12.0  # Delta E: clearly different


def dot_colours(plate):
    """Each dot's colour read back from the image at its centre (linear RGB)."""
    ix = plate.centres.round().astype(int)
    return srgb_to_linear(plate.image[ix[:, 1], ix[:, 0]] / 255.0)


def test_colour_arithmetic_against_known_values():
    assert np.allclose(lab(np.ones(3)), [100.0, 0.0, 0.0], atol=1e-3)
    # sRGB red in CIELAB (D65), the textbook value
    assert np.allclose(lab(srgb_to_linear(np.array([1.0, 0, 0]))), [53.24, 80.09, 67.20],
                       atol=0.05)
    grey = np.array([0.3, 0.3, 0.3])
    for d in DEFICIENCIES:  # every simulation keeps greys (white balance)
        assert np.allclose(simulate(grey, d), grey, atol=1e-5)
    c = np.linspace(0, 1, 11)
    assert np.allclose(linear_to_srgb(srgb_to_linear(c)), c, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("kind", DEFICIENCIES)
def test_deficiency_plates_hide_the_digit_only_from_their_dichromat(kind, seed):
    plate = make_plate(kind, "5", seed=seed)
    px = dot_colours(plate)
    fig, bg = px[plate.figure].mean(axis=0), px[~plate.figure].mean(axis=0)
    assert plate.figure.sum() > 60 and (~plate.figure).sum() > 300
    normal = float(delta_e(fig, bg))
    seen = float(delta_e(simulate(fig, kind), simulate(bg, kind)))
    assert normal > CLEAR, normal
    if kind == "tritan":
        assert seen < TRITAN_SAME and seen < 0.3 * normal, (seen, normal)
    else:
        assert seen < SAME, seen
        other = "deutan" if kind == "protan" else "protan"
        assert float(delta_e(simulate(fig, other), simulate(bg, other))) > 8.0


@pytest.mark.parametrize("seed", [0, 1])
def test_control_plates_stay_readable_under_every_simulation(seed):
    plate = make_plate("control", "7", seed=seed)
    px = dot_colours(plate)
    fig, bg = px[plate.figure].mean(axis=0), px[~plate.figure].mean(axis=0)
    assert float(delta_e(fig, bg)) > CLEAR
    for d in DEFICIENCIES:
        assert float(delta_e(simulate(fig, d), simulate(bg, d))) > CLEAR, d


@pytest.mark.parametrize("size", [288, 360])  # the plate at 1024x600 and at 1366x768
def test_a_control_digit_is_a_light_figure_not_a_hole_in_the_plate(size):
    """A dark digit on the dark screen read as a gap between the dots (a "2" taken for an
    "8"): the digit's dots are now lighter than the others, which are lighter than the
    screen, in the pixels as drawn."""
    from study_app.vision.isochromatic import BACKDROP

    plate = make_plate("control", "2", seed=7, size=size)
    luminance = srgb_to_linear(plate.colours / 255.0) @ np.array([0.2126, 0.7152, 0.0722])
    digit, others = luminance[plate.figure].mean(), luminance[~plate.figure].mean()
    screen = srgb_to_linear(np.array(BACKDROP) / 255.0) @ np.array([0.2126, 0.7152, 0.0722])
    assert digit > 4 * others and others > 3 * screen


def test_plates_follow_the_seed_and_the_series_is_balanced():
    a = make_plate("protan", "3", seed=4, size=120)
    b = make_plate("protan", "3", seed=4, size=120)
    assert np.array_equal(a.image, b.image) and a.answer == "3"
    assert not np.array_equal(a.image, make_plate("protan", "3", seed=5, size=120).image)
    series = plate_series(2, size=120)
    kinds = [p.kind for p in series]
    assert kinds[:2] == ["control", "control"]
    assert sorted(kinds[2:]) == sorted(k for k in DEFICIENCIES for _ in (0, 1))
    assert all(p.answer != q.answer for p, q in itertools.pairwise(series))
    with pytest.raises(ValueError, match="one digit"):
        make_plate("protan", "12")
    with pytest.raises(ValueError, match="plate kind"):
        make_plate("monochromat", "1")  # type: ignore[arg-type]


@pytest.mark.slow  # about 7 s here: CI runs it after `make test` (.ci/run)
def test_contact_sheets_for_the_eye():
    """Saved for a person to look at: the plates as drawn, and as each dichromat sees them."""
    plates = [make_plate(k, d, seed=7) for k, d in
              (("control", "2"), ("protan", "6"), ("deutan", "9"), ("tritan", "4"))]
    sheet = np.concatenate([p.image for p in plates], axis=1)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(ARTIFACTS / "plates.png")
    linear = srgb_to_linear(sheet / 255.0)
    for d in DEFICIENCIES:
        seen = np.round(linear_to_srgb(simulate(linear, d)) * 255).astype(np.uint8)
        Image.fromarray(seen).save(ARTIFACTS / f"plates_as_{d}.png")
    assert (ARTIFACTS / "plates_as_tritan.png").is_file()


def test_scoring_rule():
    from study_app.vision.scoring import PlateAnswer, score_colour

    def answers(wrong: set[int]):
        kinds = ["control", "control", "protan", "protan", "deutan", "deutan", "tritan",
                 "tritan"]
        return [PlateAnswer(k, "5", "3" if i in wrong else "5", 900.0)
                for i, k in enumerate(kinds)]

    assert score_colour(answers(set()))[0] == "passed"
    assert score_colour(answers({2}))[0] == "passed"  # one slip
    outcome, result = score_colour(answers({2, 3}))
    assert outcome == "failed" and result["failed_types"] == ["protan"]
    assert result["errors"] == {"deutan": 0, "protan": 2, "tritan": 0}
    assert score_colour(answers({0, 2, 3}))[0] == "inconclusive"  # a control misread
