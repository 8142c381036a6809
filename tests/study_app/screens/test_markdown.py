"""Briefing/consent Markdown: parsed into styled blocks, never shown with its markup."""

from __future__ import annotations

from study_app.fonts import Fonts
from study_app.screens.markdown import Run, parse_inline, parse_markdown
from study_app.screens.textflow import flow_blocks


def test_inline_bold_italic_and_literal_underscores():
    assert parse_inline("Press **Space** to *switch*.") == [
        Run("Press "), Run("Space", "bold"), Run(" to "), Run("switch", "italic"), Run(".")]
    assert parse_inline("__bold__ and _it_") == [Run("bold", "bold"), Run(" and "),
                                                   Run("it", "italic")]
    # Underscores inside words and lone stars stay text.
    assert parse_inline("file_name_here.md costs 2 * 3") == [
        Run("file_name_here.md costs 2 * 3")]
    assert parse_inline(r"a \*literal\* star") == [Run("a *literal* star")]
    assert parse_inline("see [the form](https://example.org/f)") == [
        Run("see the form (https://example.org/f)")]


def test_blocks_headings_paragraphs_lists():
    text = ("# Welcome\n\nYou will see **short** videos\nand rate them.\n\n"
            "## What to do\n\n- watch\n- rate with the\n  slider\n\n1. first\n2. second\n\n---\n")
    blocks = parse_markdown(text)
    kinds = [(b.kind, b.level, b.marker) for b in blocks]
    assert kinds == [("heading", 1, ""), ("paragraph", 0, ""), ("heading", 2, ""),
                     ("item", 0, "•"), ("item", 0, "•"), ("item", 0, "1."), ("item", 0, "2."),
                     ("rule", 0, "")]
    assert blocks[1].text == "You will see short videos and rate them."
    assert blocks[1].runs[1] == Run("short", "bold")
    assert blocks[4].text == "rate with the slider"
    assert "**" not in "".join(b.text for b in blocks)


def test_flowed_text_has_no_markup_and_keeps_styles():
    fonts = Fonts()
    flow = flow_blocks(parse_markdown("# Title\n\nPress **Space** to continue."), 600, fonts,
                       px=20)
    pieces = [p for ln in flow.lines for p in ln.pieces]
    assert [p.text for p in pieces] == ["Title", "Press", "Space", "to continue."]
    assert [p.style for p in pieces] == ["bold", "regular", "bold", "regular"]
    assert pieces[0].px > 20 and pieces[0].role == "heading"
    # Words on a line are spaced by one space's advance of their font.
    press, space = pieces[1], pieces[2]
    assert space.x == press.x + fonts.size("Press", 20)[0] + fonts.size(" ", 20, "bold")[0]


def test_long_paths_break_at_separators_and_never_overflow():
    fonts = Fonts()
    path = "/home/participant/Downloads/cg-study/sessions/P01.sqlite"
    flow = flow_blocks(parse_markdown(f"Your file: {path}"), 200, fonts, px=20)
    texts = [p.text for ln in flow.lines for p in ln.pieces]
    assert "".join(t.replace("Your file: ", "").replace("Your file:", "") for t in texts
                   ).replace(" ", "") == path
    for ln in flow.lines:
        for p in ln.pieces:
            assert p.x + fonts.size(p.text, 20)[0] <= 200
    assert any(t.endswith("/") for t in texts)
