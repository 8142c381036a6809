"""Screen layout rectangles with the shipped font's real metrics (no display needed).

The viewing screen never puts text on the video at any window size the pre-flight accepts;
the rating screen's parts never overlap; text screens keep everything inside the window.
"""

from __future__ import annotations

import itertools

import pytest

from session_store.study_folder import load_study
from stimuli_manifests.model import DEFAULT_QUESTION, MAX_QUESTION_CHARS
from study_app.fonts import Fonts
from study_app.layout import (
    GAP,
    rating_layout,
    text_screen_layout,
    viewing_layout,
    wrap_items,
)
from study_app.preflight import Monitor, PixelGeometry, check_pixel_mapping
from study_app.screens.draw import LABEL_REFERENCE, LABEL_TEST
from study_app.screens.markdown import parse_markdown
from study_app.screens.textflow import flow_blocks
from study_app.study_check import check_study

WINDOWS = [(800, 600), (1024, 768), (1280, 720), (1280, 1024), (1366, 768), (1440, 900),
           (1920, 1080), (1920, 1200), (2560, 1440), (3840, 2160), (1080, 1920)]
VIDEOS = [(64, 64), (320, 240), (640, 480), (720, 576), (1024, 1024), (1280, 720),
          (1600, 900), (1920, 1080)]
HINTS = ["Space: switch test / reference", "Enter: rate", "P or Esc: pause"]
NOTICE = ["Please watch for at least", "3.0 s before rating"]
LABELS = [(0.0, "Very annoying"), (0.25, "Annoying"), (0.5, "Slightly annoying"),
          (0.75, "Perceptible but not annoying"), (1.0, "Imperceptible")]
QUESTION = DEFAULT_QUESTION
_WORDS = ("How annoying are the differences between this video and its reference, for "
          "example flicker, blur, noise, aliasing or missing detail, when you compare them")
LONGEST_QUESTION = _WORDS + "?"


@pytest.fixture(scope="module")
def fonts() -> Fonts:
    return Fonts()


def _viewing(fonts, window, video, progress="Practice: Trial 240 of 240"):
    return viewing_layout(window, video, fonts, labels=[LABEL_TEST, LABEL_REFERENCE],
                          progress=progress, hints=HINTS, notice=NOTICE)


@pytest.mark.parametrize("window", WINDOWS)
def test_no_text_on_the_video_at_any_accepted_window(fonts, window):
    accepted = 0
    for video in VIDEOS:
        lay = _viewing(fonts, window, video)
        geom = PixelGeometry(window, window, (Monitor(0, "m", (0, 0, *window)),), (0, 0), 0)
        check = check_pixel_mapping(geom, video, fits_with_label=lay.label is not None)
        if not check.ok:
            continue  # the pre-flight refuses this window for this video
        accepted += 1
        assert lay.label is not None
        for rect in lay.text_rects():
            assert not rect.intersects(lay.video), (window, video, rect)
            assert rect.inside(*window), (window, video, rect)
        # Text never touches the video: at least the gap between them.
        for rect in lay.text_rects():
            grown = type(rect)(rect.x - GAP + 1, rect.y - GAP + 1, rect.w + 2 * GAP - 2,
                               rect.h + 2 * GAP - 2)
            assert not grown.intersects(lay.video), (window, video, rect)
    assert accepted >= 1


def test_paper_configuration_puts_hints_beside_the_video(fonts):
    """1024x1024 stimuli on a Full-HD screen: label, hints and progress in the side margins."""
    lay = _viewing(fonts, (1920, 1080), (1024, 1024))
    assert lay.video.as_tuple() == (448, 28, 1024, 1024)
    assert lay.label.right <= lay.video.x - GAP
    assert lay.hints is not None and all(r.x >= lay.video.right + GAP for r in lay.hints.rects)
    assert lay.notice is not None and all(r.x >= lay.video.right + GAP
                                          for r in lay.notice.rects)
    assert lay.progress is not None


def test_a_window_with_no_room_for_the_label_is_refused(fonts):
    lay = _viewing(fonts, (1024, 1024), (1024, 1024))
    assert lay.label is None and lay.hints is None and lay.progress is None


def _no_overlaps(parts: dict) -> None:
    for (a, ra), (b, rb) in itertools.combinations(parts.items(), 2):
        for x in ra:
            for y in rb:
                assert not x.intersects(y), (a, x, b, y)


@pytest.mark.parametrize("question", [QUESTION, LONGEST_QUESTION], ids=["default", "longest"])
@pytest.mark.parametrize("window", WINDOWS)
def test_rating_screen_parts_do_not_overlap(fonts, window, question):
    """The default question, and the longest a manifest's ``scale.question`` may be."""
    assert len(LONGEST_QUESTION) <= MAX_QUESTION_CHARS
    lay = rating_layout(window, fonts, question=question, labels=LABELS,
                        progress="Practice: Trial 240 of 240",
                        hints=["Click the scale or use ← → (with Shift: bigger steps)",
                               "Enter: submit", "Space: back to the videos", "P or Esc: pause"],
                        notice="Please watch for at least 3.0 s",
                        buttons=[("back", "Back to the videos"), ("submit", "Submit")])
    parts = lay.parts()
    _no_overlaps(parts)
    for rects in parts.values():
        for r in rects:
            assert r.inside(*window), (window, r)
    # The five labels share one row (the same top), left to right.
    tops = {lab.lines[0][1].y for lab in lay.labels}
    assert len(tops) == 1
    xs = [lab.x for lab in lay.labels]
    assert xs == sorted(xs)


def test_five_labels_on_one_line_each_at_full_hd(fonts):
    lay = rating_layout((1920, 1080), fonts, question=QUESTION, labels=LABELS,
                        progress="Trial 1 of 240", hints=[], notice="x",
                        buttons=[("submit", "Submit")])
    assert lay.one_row and all(len(lab.lines) == 1 for lab in lay.labels)
    assert lay.label_px >= 20


@pytest.mark.parametrize("window", WINDOWS)
def test_an_unlabelled_scale_lays_out(fonts, window):
    """A manifest may give ``"labels": []`` (an unlabelled slider); the rating screen used to
    crash on it at the first trial, after the session file was made."""
    lay = rating_layout(window, fonts, question=QUESTION, labels=[],
                        progress="Trial 1 of 240", hints=["Enter: submit"], notice="x",
                        buttons=[("back", "Back to the videos"), ("submit", "Submit")])
    assert lay.labels == ()
    _no_overlaps(lay.parts())
    assert lay.notice.rects[0].y > lay.track_y


@pytest.mark.parametrize("window", [(800, 600), (1280, 1024), (1920, 1080)])
def test_text_screen_flows_and_scrolls_everything_into_view(fonts, window):
    long_text = "\n\n".join(
        f"## Section {i}\n\nThis paragraph explains **part {i}** of the study in some *detail*, "
        "long enough to wrap over several lines at every window size.\n\n- one item\n"
        "- another item with a file name like /home/participant/Downloads/study/sessions/"
        "P01_with_a_rather_long_name.sqlite" for i in range(12))
    buttons = [("decline", "I do not agree  (Esc)"), ("accept", "I agree  (A)")]
    lay = text_screen_layout(window, fonts, title="Consent", buttons=buttons)
    flow = flow_blocks(parse_markdown(long_text), lay.column.w, fonts, px=lay.px)
    assert lay.column.inside(*window) and lay.column.h > 100
    for b in lay.buttons:
        assert b.rect.inside(*window) and not b.rect.intersects(lay.column)
    for _, r in lay.title.lines:
        assert not r.intersects(lay.column)
    for line in flow.lines:
        for p in line.pieces:
            assert p.x >= 0 and p.x + fonts.size(p.text, p.px, p.style)[0] <= lay.column.w
    # Scrolling by pages from the top shows every line at some point, and ends at the end.
    seen, offset = set(), 0
    for _ in range(200):
        seen |= {id(ln) for ln in flow.visible(offset, lay.column.h)}
        if flow.at_end(offset, lay.column.h):
            break
        offset = flow.page(offset, lay.column.h, 1)
    assert flow.at_end(offset, lay.column.h)
    assert seen == {id(ln) for ln in flow.lines}
    assert flow.page(offset, lay.column.h, -1) < offset


def test_hint_items_break_only_between_items(fonts):
    items = ["Enter: submit", "Space: back to the videos", "P or Esc: pause"]
    lines = wrap_items(items, 420, 20, fonts)
    assert len(lines) >= 2
    assert " ".join(" ".join(lines).split()) == " ".join(" ".join(items).split())
    for line in lines:
        assert fonts.size(line, 20)[0] <= 420


def test_even_letter_spacing_with_the_shipped_font(fonts):
    """The old default font set words wider than their letters ("study" 48 px against 45 px
    of letter advances at 26 px, seen as "stu dy", "expec ts"): with the shipped DejaVu Sans a
    word's width is the sum of its letters' advances (no stray gaps)."""
    for px in (18, 20, 24, 28):
        for word in ("least", "study", "expects", "display"):
            assert fonts.size(word, px)[0] <= sum(fonts.size(c, px)[0] for c in word) + 1
        space = fonts.size(" ", px)[0]
        assert fonts.size("at least", px)[0] == pytest.approx(
            fonts.size("at", px)[0] + space + fonts.size("least", px)[0], abs=1)


def test_check_refuses_a_minimum_display_with_no_room_for_the_label(tmp_path, study_factory):
    study = load_study(study_factory(tmp_path / "s", min_display=(64, 64)))
    result = check_study(study)
    assert any("no room for the test/reference label" in e for e in result.errors)
    ok = load_study(study_factory(tmp_path / "t", min_display=(800, 600)))
    assert not any("label" in e for e in check_study(ok).errors)
