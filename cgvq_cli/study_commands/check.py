"""``cgvq-study check STUDY``: is a study folder ready to send to participants?"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "check"
HELP = "validate a study folder (manifest, files, checksums, durations, fps, sizes)"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")


def grouped_warnings(warnings: list[str], ids: set[str]) -> list[str]:
    """One line for a warning that three or more videos share ("15 videos (a, b, c and 12
    more): H.264 ... is lossy"), the others as they are, in their first order."""
    groups: dict[str, list[str]] = {}
    for w in warnings:
        sid, sep, rest = w.partition(": ")
        groups.setdefault(rest if sep and sid in ids else w, []).append(
            sid if sep and sid in ids else "")
    out = []
    for text, who in groups.items():
        if len(who) >= 3 and all(who):
            names = ", ".join(who[:3]) + (f" and {len(who) - 3} more" if len(who) > 3 else "")
            out.append(f"{len(who)} videos ({names}): {text}")
        else:
            out += [f"{sid}: {text}" if sid else text for sid in who]
    return out


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.study_folder import load_study
    from study_app.study_check import check_study

    study = load_study(args.study)
    result = check_study(study, progress=sys.stderr.isatty())
    m = study.manifest
    design = (f"{result.n_stimuli} stimuli x {m.protocol.repetitions} repetitions = "
              f"{result.n_trials} trials" if m.protocol.allocation == "full" else
              f"{result.n_stimuli} stimuli, adaptive allocation")
    print(f"study {m.study_id}: {design}; briefing "
          f"{'yes' if study.briefing else 'no'}, consent {'yes' if study.consent else 'no'}")
    adaptive = m.protocol.adaptive_settings()
    if adaptive is not None:
        per_block = adaptive.trials_per_block(result.n_stimuli)
        print(f"allocation: adaptive, {adaptive.blocks} blocks per session (block 1: every "
              f"stimulus once; then {adaptive.blocks - 1} x {per_block} trials planned by the "
              f"study server) = {result.n_stimuli + (adaptive.blocks - 1) * per_block} trials; "
              "without a server the blocks are uniform (see: docs, Adaptive allocation)")
    if m.panel is not None:
        questions = [q for qn in m.panel.questionnaires for q in qn.questions()]
        vs = m.panel.vision_screening
        checks = [n for n, on in (("colour", vs.colour), ("acuity", vs.acuity)) if on] \
            if vs is not None else []
        print(f"panel: {len(m.panel.questionnaires)} questionnaire(s), {len(questions)} "
              f"question(s); vision checks: {', '.join(checks) or 'none'} "
              "(see: cgvq-study panel STUDY)")
    ids = {str(s.id) for s in [*m.references, *m.conditions]}
    for w in grouped_warnings(result.warnings, ids):
        print(f"  warning: {w}")
    for e in result.errors:
        print(f"  error: {e}")
    if result.ok:
        print("OK: the study folder is ready")
        return 0
    print(f"{len(result.errors)} error(s): fix them before sending the study out")
    sys.stdout.flush()
    raise StudyError(f"{args.study} is not ready: {len(result.errors)} error(s) (listed on "
                     f"stdout), e.g. {result.errors[0]}")
