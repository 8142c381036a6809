"""What the text screens say and how they end (pure: no display)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from study_app.fonts import Fonts
from study_app.keys import RATING, VIEWING
from study_app.layout import text_screen_layout
from study_app.preflight import Check
from study_app.screens import content
from study_app.screens.markdown import parse_markdown
from study_app.screens.text_state import TextScreenState
from study_app.screens.textflow import flow_blocks


def names(keys, action):
    return keys.label(action)


def _state(spec, window=(800, 600)) -> TextScreenState:
    fonts = Fonts()
    lay = text_screen_layout(window, fonts, title=spec.title, buttons=spec.buttons)
    flow = flow_blocks(parse_markdown(spec.body), lay.column.w, fonts, px=lay.px)
    return TextScreenState(spec, flow, lay.column.h)


def _all_specs(tmp_path: Path):
    fail = Check("refresh_rate", False, "turn on vertical sync in the driver settings")
    ok = Check("screen_size", True, "1920x1080 pixels")
    return [
        content.welcome("# Hi\n\nText.", "about 1 minute (3 trials)", names),
        content.consent("I agree.", names),
        content.preflight_passed([ok], "about 1 minute (3 trials)", False, names),
        content.preflight_failed([fail], names),
        content.preflight_failed([Check("checksums", False, "stimulus files are missing or "
                                        "modified (x.mkv does not exist)")], names),
        content.ended_by_server(3, "you were withdrawn from the study", names),
        content.practice_intro(2, VIEWING, RATING, 3.0, names),
        content.practice_done(names),
        content.welcome_back(3, 10, names),
        content.pause(3, 10, names),
        content.break_screen(40, 240, names),
        content.break_screen(40, 240, names, 70.0),
        content.seating(70.0, names),
        content.seating(120.0, names, again=True),
        content.confirm_quit(3, 10, names),
        content.confirm_withdraw(names),
        content.end(tmp_path / "sessions" / "P01.sqlite", 240, False, names),
    ]


def test_participant_texts_never_name_command_line_options(tmp_path):
    flag = re.compile(r"--[a-z]")
    for spec in _all_specs(tmp_path):
        shown = " ".join(b.text for b in parse_markdown(spec.body))
        assert not flag.search(shown) and not flag.search(spec.title), spec.name
        for _, text in spec.buttons:
            assert not flag.search(text)


def test_break_and_pause_are_different_screens(tmp_path):
    pause = content.pause(3, 10, names)
    brk = content.break_screen(40, 240, names)
    assert (pause.name, brk.name) == ("pause", "break")
    assert "starts again" in pause.body and "starts again" not in brk.body
    assert "40 of 240 trials done" in brk.body and "next trial" in brk.body


def test_practice_intro_shows_the_controls():
    spec = content.practice_intro(2, VIEWING, RATING, 3.0, names)
    for key in ("Space", "Enter", "P or Esc", "←", "→", "Shift"):
        assert key in spec.body, key
    assert "3.0 s" in spec.body and "not recorded" in spec.body


def test_end_screen_names_the_one_file_to_send(tmp_path):
    path = tmp_path / "my_study" / "sessions" / "P_01.sqlite"
    spec = content.end(path, 240, False, names)
    flat = "".join(b.text for b in parse_markdown(spec.body))
    assert str(path.resolve()) in flat  # underscores survive the Markdown
    assert "one file" in spec.body
    assert {a for a, _ in spec.buttons} == {"show", "close"}
    assert content.end(path, 240, True, names).title == "You have withdrawn"


def test_consent_is_given_only_after_reading_to_the_end():
    long = "\n\n".join(f"{i}. I understand point {i} of this long consent form, which goes on "
                       "for a while so that it cannot fit one screen." for i in range(30))
    st = _state(content.consent(long, names))
    assert not st.seen_end and st.disabled == ["accept"]
    assert "read to the end" in st.hint()
    assert st.handle("accept") is None and st.refusals == ["accept"]  # shows the next page
    assert st.offset > 0
    assert st.handle("end") is None and st.seen_end
    assert st.handle("accept") == "accept"
    # Declining needs no reading; closing the window declines.
    st = _state(content.consent(long, names))
    assert st.handle("decline") == "decline"
    assert _state(content.consent(long, names)).handle(
        content.consent(long, names).close_action) == "decline"


@pytest.mark.parametrize("window", [(800, 600), (1920, 1080)])
def test_short_screens_need_no_scrolling(window, tmp_path):
    for spec in _all_specs(tmp_path):
        if spec.name in ("practice",):
            continue  # the controls are a longer text at 800x600
        st = _state(spec, window)
        assert st.at_end and st.hint() == "", (spec.name, window)


def test_wheel_scrolls_both_ways():
    st = _state(content.welcome("\n\n".join(f"Paragraph {i} " * 20 for i in range(20)),
                                "about 1 minute (3 trials)", names))
    st.wheel(-1)
    down = st.offset
    assert down > 0
    st.wheel(+1)
    assert st.offset < down


def test_enter_never_stops_or_withdraws():
    for spec in (content.confirm_quit(3, 10, names), content.confirm_withdraw(names)):
        assert spec.keys.action(13, 40) == "no"  # Enter
        assert spec.keys.action(ord("y"), 28) == "yes"
        assert spec.primary == "no"


def test_the_failed_check_is_titled_by_what_failed():
    """A missing file was announced as "Your display needs a change"."""
    files = Check("checksums", False, "stimulus files are missing or modified (...)")
    display = Check("refresh_rate", False, "turn on vertical sync in the driver settings")
    assert content.preflight_failed([files], names).title == \
        "Some study files are missing or damaged"
    assert content.preflight_failed([display], names).title == "Your display needs a change"
    assert content.preflight_failed([display, files], names).title == \
        "This computer needs a change"
    assert "display" not in content.preflight_failed([files], names).body.split("\n")[0]


def test_the_seating_screen_gives_the_distance_in_centimetres_and_card_widths():
    first = content.seating(70.0, names).body
    assert "about 70 cm from the screen" in first and "about 8 bank-card widths" in first
    assert "arm's length" in first  # 70 cm is about an arm's length; 120 cm is not
    assert first.startswith("**Sit with your eyes")  # a sentence starts with a capital
    again = content.seating(120.0, names, again=True).body
    assert again.startswith("Before you go on: **sit with your eyes")
    assert "about 14 bank-card widths" in again
    assert "arm's length" not in again
    assert "Sit about 70 cm" in content.break_screen(1, 2, names, 70.0).body
    assert "Sit about" not in content.break_screen(1, 2, names).body


def test_a_served_withdrawal_says_the_server_is_told():
    """From a study server the file need not be sent by hand: the server is told (a local
    study's participant is asked to send the file and say what may be used)."""
    served = content.confirm_withdraw(names, served=True).body
    assert "the study server is told: none of your answers will be used" in served
    assert "send it to the experimenter" not in served
    local = content.confirm_withdraw(names).body
    assert "send it to the experimenter" in local and "server" not in local
