"""What each text screen says and which actions it offers (pure; no drawing).

Participant-facing text only: it says what to do or change on the computer, never a
command-line option. Each screen's actions have keys (``keys``) and buttons; a button's text
names its keys as the participant's keyboard layout labels them (``name_keys``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..keys import Keymap, keymap
from ..preflight import Check

NameKeys = Callable[[Keymap, str], str]


@dataclass(frozen=True)
class ScreenSpec:
    """A text screen: ``name`` (logged and used for screenshots), title, Markdown body,
    buttons as (action, text) and the key bindings of those actions.

    ``needs_end``: actions offered only once the text was scrolled to its end (consent).
    ``close_action``: what closing the window means on this screen.
    """

    name: str
    title: str
    body: str
    buttons: tuple[tuple[str, str], ...]
    keys: Keymap
    needs_end: frozenset[str] = field(default_factory=frozenset)
    close_action: str = "quit"
    primary: str | None = None


def _button(keys: Keymap, action: str, text: str, name_keys: NameKeys) -> tuple[str, str]:
    return action, f"{text}  ({name_keys(keys, action)})"


def _spec(name: str, title: str, body: str, keys: Keymap,
          buttons: Sequence[tuple[str, str]], name_keys: NameKeys, **kw) -> ScreenSpec:
    return ScreenSpec(name, title, body,
                      tuple(_button(keys, a, t, name_keys) for a, t in buttons), keys, **kw)


CONTINUE = keymap(go=["space", "enter"])


def without_title(text: str, title: str) -> str:
    """``text`` without a first heading that only repeats the screen's ``title`` (a
    briefing.md opening with "# Welcome" showed "Welcome" twice)."""
    lines = text.lstrip("\n").split("\n")
    head = lines[0].strip()
    if head.startswith("#") and head.lstrip("#").strip().lower() == title.lower():
        return "\n".join(lines[1:]).lstrip("\n")
    return text


def welcome(briefing: str | None, duration: str, name_keys: NameKeys) -> ScreenSpec:
    body = without_title(briefing, "Welcome") if briefing else \
        "You will watch short videos and rate their quality."
    body += f"\n\n---\n\n**How long:** {duration}. You can take a break whenever you like."
    return _spec("welcome", "Welcome", body, CONTINUE, [("go", "Continue")], name_keys,
                 primary="go")


def consent(text: str, name_keys: NameKeys) -> ScreenSpec:
    keys = keymap(accept=["a"], decline=["esc"])
    body = without_title(text, "Consent") + (
        "\n\n---\n\nIf you agree, choose **I agree**. If you do not, choose **I do not "
        "agree**: nothing is recorded and the program closes.")
    return _spec("consent", "Consent", body, keys,
                 [("decline", "I do not agree"), ("accept", "I agree")], name_keys,
                 needs_end=frozenset({"accept"}), close_action="decline", primary="accept")


def preflight_passed(checks: Sequence[Check], duration: str, resumed: bool,
                     name_keys: NameKeys) -> ScreenSpec:
    lines = []
    for c in checks:
        label = {"screen_size": "Screen", "refresh_rate": "Refresh",
                 "pixel_mapping": "Pixels", "memory": "Memory",
                 "decode_speed": "Video loading", "checksums": "Study files"}.get(c.name, c.name)
        lines.append(f"- **{label}:** {c.message}")
    what = "continue the study" if resumed else "take part"
    takes = "The rest of the study takes" if resumed else "The study takes"
    body = (f"Your computer and screen can show the videos exactly as needed, so you can "
            f"{what}.\n\n" + "\n".join(lines) + f"\n\n**{takes} {duration}.**")
    return _spec("preflight-passed", "Your display passed the check", body, CONTINUE,
                 [("go", "Continue")], name_keys, primary="go")


def preflight_failed(failed: Sequence[Check], name_keys: NameKeys,
                     saved: tuple[int, int] | None = None) -> ScreenSpec:
    """``saved``: (answered, total) of a session being resumed, whose answers are kept."""
    keys = keymap(close=["esc", "enter"])
    items = "\n".join(f"- {c.message[0].upper()}{c.message[1:]}." for c in failed)
    if saved is None:
        status = "Nothing was recorded."
        again = "start the study again"
    else:
        status = (f"Your {saved[0]} of {saved[1]} answers so far are saved, and nothing was "
                  "changed.")
        again = "start the study again the same way to continue where you left off"
    files_only = all(c.name == "checksums" for c in failed)
    lead = ("Some of the study's video files on this computer are missing or not as the "
            "experimenter prepared them. " if files_only else
            "This computer cannot show the study's videos exactly as needed yet. ")
    title = ("Some study files are missing or damaged" if files_only else
             "Your display needs a change" if not any(c.name == "checksums" for c in failed)
             else "This computer needs a change")
    body = (lead + status + "\n\n" + items + f"\n\nPlease do what the list above says and "
            f"{again}. If it still does not work, tell the experimenter what this screen says.")
    return _spec("preflight-failed", title, body, keys,
                 [("close", "Close")], name_keys, close_action="close", primary="close")


def practice_intro(n: int, viewing: Keymap, rating: Keymap, min_view_s: float,
                   name_keys: NameKeys) -> ScreenSpec:
    k = name_keys
    trials = "trial" if n == 1 else "trials"
    body = (f"First, {n} practice {trials} to get to know the controls. They are not "
            "recorded.\n\n"
            "## Watching\n\n"
            f"- **{k(viewing, 'switch')}**: switch between the *test video* and its "
            "*reference* (a grey screen shows briefly in between).\n"
            "- The label beside the video says which one is showing: the **Test video** "
            "label is a filled yellow box, the **Reference** label a blue frame.\n"
            f"- **{k(viewing, 'rate')}**: go to the rating, after watching at least "
            f"{min_view_s:.1f} s.\n\n"
            "## Rating\n\n"
            "- Click on the scale, drag the marker, or use the **←** and **→** keys "
            "(with **Shift**: bigger steps).\n"
            f"- **{k(rating, 'submit')}** or the **Submit** button: record your rating.\n"
            f"- **{k(rating, 'back')}** or **Back to the videos**: watch again.\n\n"
            "## Breaks\n\n"
            f"- **{k(viewing, 'pause')}**: pause at any time. From the pause screen you can "
            "continue, stop and continue later, or withdraw from the study.")
    return _spec("practice", "Practice", body, CONTINUE, [("go", "Start the practice")],
                 name_keys, primary="go")


def practice_done(name_keys: NameKeys) -> ScreenSpec:
    body = ("That was the practice. The real trials start now; your ratings are recorded "
            "from here on.")
    return _spec("practice-end", "Practice done", body, CONTINUE,
                 [("go", "Start the study")], name_keys, primary="go")


def _card_widths(distance_cm: float) -> str:
    """The distance in bank-card widths (8.56 cm), which everyone has at hand to measure."""
    arm = "; roughly an arm's length" if 50 <= distance_cm <= 80 else ""
    return f"about {distance_cm / 8.56:.0f} bank-card widths{arm}"


def seating(distance_cm: float, name_keys: NameKeys, *, again: bool = False) -> ScreenSpec:
    """Before the trials (and on a return): where to sit while rating."""
    lead = "Before you go on: **sit" if again else "**Sit"
    body = (f"{lead} with your eyes about {distance_cm:g} cm from the screen** "
            f"({_card_widths(distance_cm)}), facing its centre, "
            "and keep that distance while you rate the videos.\n\n"
            "The experimenter chose this distance so that everyone sees the videos at the "
            "same size. Wear your glasses or contact lenses if you wear them to watch "
            "videos.")
    return _spec("seating", "Where to sit", body, CONTINUE, [("go", "Continue")],
                 name_keys, primary="go")


def welcome_back(answered: int, total: int, name_keys: NameKeys,
                 next_part: str = "") -> ScreenSpec:
    """``next_part`` names what comes next where it is not a trial (a vision check, the
    questions before or after the videos)."""
    body = (f"Your answers so far are saved ({answered} of {total} trials done). You "
            f"continue with {next_part or f'trial {answered + 1}'}.")
    return _spec("welcome-back", "Welcome back", body, CONTINUE, [("go", "Continue")],
                 name_keys, primary="go")


PAUSE_KEYS = keymap(resume=["space", "enter"], quit=["q"], withdraw=["w"])


PAUSED_DURING = {
    "questions": "When you continue, you are back on the same page of questions.",
    "check": "When you continue, the check goes on where you paused it.",
}
"""What continuing does, where a pause was asked outside a trial (``pause(during=...)``)."""


def pause(answered: int, total: int, name_keys: NameKeys, during: str = "") -> ScreenSpec:
    """The pause menu; ``during`` is ``questions`` or ``check`` when it was asked in a
    questionnaire or a vision check rather than in a trial."""
    then = PAUSED_DURING.get(during, "When you continue, the trial you were watching starts "
                             "again from its beginning.")
    body = (f"Your answers so far are saved ({answered} of {total} trials done). {then}\n\n"
            "- **Continue**: back to the study.\n"
            "- **Stop and continue later**: close the program now; start it again the same "
            "way to continue where you stopped.\n"
            "- **Withdraw from the study**: stop taking part.")
    return _spec("pause", "Paused", body, PAUSE_KEYS,
                 [("withdraw", "Withdraw from the study"), ("quit", "Stop and continue later"),
                  ("resume", "Continue")], name_keys, primary="resume")


def break_screen(answered: int, total: int, name_keys: NameKeys,
                 distance_cm: float | None = None) -> ScreenSpec:
    body = (f"{answered} of {total} trials done, and your answers are saved. Rest your eyes "
            "for a moment: look away from the screen, into the distance.\n\n"
            "The next trial starts when you continue."
            + (f" Sit about {distance_cm:g} cm from the screen again before you do."
               if distance_cm else ""))
    return _spec("break", "Time for a break", body, PAUSE_KEYS,
                 [("withdraw", "Withdraw from the study"), ("quit", "Stop and continue later"),
                  ("resume", "Continue")], name_keys, primary="resume")


# Enter keeps going (the highlighted "No"); stopping or withdrawing needs its own key.
CONFIRM_KEYS = keymap(yes=["y"], no=["enter", "esc", "n"])


def confirm_quit(answered: int, total: int, name_keys: NameKeys) -> ScreenSpec:
    body = (f"Your answers so far are saved ({answered} of {total} trials done). To continue "
            "later, start the study again the same way: it continues where you stopped.")
    return _spec("confirm-quit", "Stop now and continue later?", body, CONFIRM_KEYS,
                 [("no", "No, go back"), ("yes", "Yes, stop now")], name_keys,
                 close_action="yes", primary="no")


def confirm_withdraw(name_keys: NameKeys, *, served: bool = False) -> ScreenSpec:
    """``served``: the study came from a study server, which is told of the withdrawal."""
    body = ("You can stop taking part at any time, without giving a reason.\n\n" + (
        "If you withdraw, the study ends now and the study server is told: none of your "
        "answers will be used. (If this computer is offline, the next screen says how the "
        "withdrawal still reaches the experimenter.)" if served else
        "If you withdraw, the study ends now and your result file is marked as "
        "withdrawn. Please still send it to the experimenter, and tell them whether "
        "your answers so far may be used or should be deleted."))
    return _spec("confirm-withdraw", "Withdraw from the study?", body, CONFIRM_KEYS,
                 [("no", "No, go back"), ("yes", "Yes, withdraw")], name_keys,
                 close_action="no", primary="no")


ENDS_STUDY = ("If the check shows that this screen or your eyes do not show these "
              "differences, the study ends after it: you will not be asked anything more. ")
"""Said before a vision check that ends the session on a fail (``on_fail: end``)."""


def colour_check_intro(n: int, name_keys: NameKeys, ends_study: bool = False) -> ScreenSpec:
    """``ends_study``: a fail ends the session (``on_fail: end``), said beforehand."""
    result = (ENDS_STUDY + "It is not a medical test." if ends_study else
              "There are no trick questions, and a result only tells the experimenter how "
              "well this screen and your eyes show these colours. It is not a medical test.")
    body = (f"Before the videos, a short check of colour vision: {n} circles of coloured dots, "
            "one after the other. In most of them there is a number made of dots of another "
            "colour.\n\n"
            "- Type the number you see (or click its button under the circle), as soon as you "
            "see it.\n"
            "- If you see no number, press **N** (or click *No number*).\n"
            "- Your answer shows under the question: **Enter** (or *Next*) goes on, "
            "**Backspace** changes it.\n"
            "- **Esc** pauses the check (to continue, stop or withdraw).\n\n" + result)
    return _spec("colour-check", "Colour vision check", body, CONTINUE, [("go", "Start")],
                 name_keys, primary="go")


def block_unavailable(answered: int, name_keys: NameKeys) -> ScreenSpec:
    body = (f"Your {answered} answers so far are saved. The next part of the study comes from "
            "the study server, which cannot be reached just now (is the computer online?).\n\n"
            "- **Try again** once the connection is back;\n"
            "- or **finish here**: your answers count, and they are sent when the server can "
            "be reached again.")
    return _spec("block-unavailable", "The next part could not be fetched", body,
                 keymap(retry=["enter", "space"], finish=["f"]),
                 [("retry", "Try again"), ("finish", "Finish here")], name_keys,
                 close_action="finish", primary="retry")


def ended_by_server(answered: int, why: str, name_keys: NameKeys) -> ScreenSpec:
    """The study server no longer accepts this participant (withdrawn by the experimenter)."""
    body = (f"The study server no longer accepts answers from you ({_md_escape(why)}), so the "
            f"study ends here, after {answered} answers. There is nothing more to do or to "
            "send.\n\nThank you for your time. If this is a mistake, contact the experimenter.")
    return _spec("ended-by-server", "The study has ended for you", body,
                 keymap(close=["enter", "esc"]), [("close", "Close")], name_keys,
                 close_action="close", primary="close")


def acuity_check_intro(distance_cm: float, name_keys: NameKeys,
                       ends_study: bool = False) -> ScreenSpec:
    """``ends_study``: a fail ends the session (``on_fail: end``), said beforehand."""
    result = (ENDS_STUDY + "It is not a medical test." if ends_study else
              "A result only tells the experimenter what you could see on this screen. It is "
              "not a medical test.")
    body = ("Next, a short check of how sharp and how faint a shape you can see on this screen."
            "\n\n"
            "**First, the size of your screen.** Have a bank card at hand (or any card of that "
            "size: an ID card, a driving licence). Hold it against the screen and make the "
            "rectangle on the next screen exactly as wide as the card.\n\n"
            f"**Then sit with your eyes about {distance_cm:g} cm from the screen** "
            f"({_card_widths(distance_cm)}) and stay there during the check. "
            "Wear your glasses or contact lenses if you wear them to watch videos. **Esc** "
            "pauses the check (to continue, stop or withdraw).\n\n" + result)
    return _spec("acuity-check", "Sharpness and contrast check", body, CONTINUE,
                 [("go", "Start")], name_keys, primary="go")


def acuity_trials_intro(distance_cm: float, name_keys: NameKeys) -> ScreenSpec:
    body = (f"Sit about {distance_cm:g} cm from the screen now.\n\n"
            "You will see rings with a gap, one after another, getting smaller and then "
            "fainter. For each one, say where the gap is:\n\n"
            "- press the **arrow key** pointing to the gap (left, up, right or down), or click "
            "the button;\n"
            "- if you are not sure, guess: that is expected for the smallest and faintest "
            "ones.\n\n"
            "It takes about a minute.")
    return _spec("acuity-trials", "Where is the gap?", body, CONTINUE, [("go", "Start")],
                 name_keys, primary="go")


def end(session_path: Path, total: int, withdrawn: bool, name_keys: NameKeys,
        upload: tuple[bool, str] | None = None, *, screened_out: str = "",
        in_two_files: bool = False) -> ScreenSpec:
    """The last screen. ``upload`` (with a study server): whether everything arrived and the
    sentence saying so; when it all arrived there is nothing to send. ``screened_out``: the
    vision check (colour or acuity) that ended the study (the manifest's ``on_fail: end``).
    ``in_two_files``: the answers could not be written into the session file alone (a full
    disk), so they are in it and its ``-wal`` together, and both must reach the experimenter."""
    keys = keymap(close=["enter", "esc"], show=["o"])
    path = session_path.resolve()
    title = "You have withdrawn" if withdrawn else "Thank you!"
    first = ("You withdrew from the study. Thank you for your time." if withdrawn else
             f"All {total} trials are done.")
    if screened_out:
        what = {"colour": "colour differences",
                "acuity": "fine details and faint contrasts"}.get(screened_out, "details")
        first = (f"Thank you for your time. This study needs {what} that your screen and "
                 "eyes did not show clearly in the check, so it ends here. This is not a "
                 "medical result: screens differ a lot.")
    wal = path.with_name(path.name + "-wal")
    split = ""
    if in_two_files:
        where = (f"**{_md_escape(str(path))}**\n\n**{_md_escape(str(wal))}**\n\n"
                 f"(the files *{_md_escape(path.name)}* and *{_md_escape(wal.name)}* in the "
                 f"folder *{_md_escape(str(path.parent))}*)")
        split = ("Your computer could not finish writing your answers into one file (is its "
                 "disk full?). They are all saved, in two files that belong together:")
    else:
        where = (f"**{_md_escape(str(path))}**\n\n"
                 f"(the file *{_md_escape(path.name)}* in the folder "
                 f"*{_md_escape(str(path.parent))}*)")
    sent = f"{_md_escape(upload[1])}\n\n" if upload is not None else ""
    if upload is not None and upload[0]:
        kept = (f"{split}\n\n{where}\n\nKeep both files together." if in_two_files else
                f"A copy of your answers stays on this computer:\n\n{where}")
        body = f"{first}\n\n## {_md_escape(upload[1])}\n\nThere is nothing to send. {kept}"
    elif in_two_files:
        body = (f"{first}\n\n{sent}"
                "## Send these two files to the experimenter\n\n"
                f"{split}\n\n{where}\n\n"
                "Attach both to an e-mail to the experimenter, or upload both where the "
                "experimenter told you. Do not delete or rename either of them: one without "
                "the other is missing answers.")
    elif upload is not None:  # a study server: starting again sends the rest; e-mail if not
        body = (f"{first}\n\n{sent}"
                "## If you cannot start the study again\n\n"
                "Then send this one file to the experimenter instead:\n\n"
                f"{where}\n\n"
                "Attach it to an e-mail to the experimenter, or upload it where the "
                "experimenter told you. Send only this file: it holds all your answers.")
    else:
        body = (f"{first}\n\n{sent}"
                "## Send this one file to the experimenter\n\n"
                f"{where}\n\n"
                "Attach it to an e-mail to the experimenter, or upload it where the "
                "experimenter told you. Send only this file: it holds all your answers.")
    return _spec("end", title, body, keys,
                 [("show", "Show the files in their folder" if in_two_files else
                   "Show the file in its folder"), ("close", "Close")], name_keys,
                 close_action="close", primary="close")


def _md_escape(text: str) -> str:
    """Text shown literally in Markdown (file names with '_' or '*')."""
    return "".join("\\" + c if c in "\\*_`#[]" else c for c in text)
