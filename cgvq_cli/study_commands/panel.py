"""``cgvq-study panel STUDY``: put the ready-made questionnaires (and the colour-vision check)
into a study's manifest, to edit there; or show what a manifest's panel asks."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "panel"
HELP = ("add the demographics questionnaire, the post-study survey and the vision checks to a "
        "study's manifest (cgvq-panel/1), or list what its panel asks")


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", type=Path, help="study folder (holds manifest.json)")
    parser.add_argument("--add-templates", action="store_true",
                        help="write the templates into the manifest (refused when it already "
                             "has a panel block)")
    parser.add_argument("--no-colour-check", action="store_true",
                        help="with --add-templates: no colour-vision check")
    parser.add_argument("--acuity", action="store_true",
                        help="with --add-templates: also the contrast/acuity check")
    parser.add_argument("--on-fail", choices=("end", "flag", "record"), default=None,
                        help="with --add-templates: what a failed vision check does (default "
                             "flag: the session goes on, the rater is flagged)")


def run(args: argparse.Namespace) -> int:
    from session_store.errors import StudyError
    from session_store.study_folder import MANIFEST_NAME, load_study
    from stimuli_manifests import parse_manifest, save_manifest
    from stimuli_manifests.panel import screening_distance_problem
    from stimuli_manifests.panel_templates import default_panel

    if not args.add_templates:
        given = [flag for flag, on in (("--no-colour-check", args.no_colour_check),
                                       ("--acuity", args.acuity),
                                       ("--on-fail", args.on_fail is not None)) if on]
        if given:
            raise StudyError(f"{' and '.join(given)} {'needs' if len(given) == 1 else 'need'} "
                             "--add-templates (it sets what the templates write); add it, or edit "
                             "the panel block in manifest.json")
    if args.on_fail is not None and args.no_colour_check and not args.acuity:
        raise StudyError("--on-fail needs a vision check to act on: --no-colour-check without "
                         "--acuity leaves none")
    on_fail = args.on_fail or "flag"
    study = load_study(args.study)
    manifest = study.manifest
    if args.add_templates:
        if manifest.panel is not None:
            raise StudyError(f"{args.study / MANIFEST_NAME} already has a panel block; edit it "
                             "there")
        if any((study.folder / "sessions").glob("*.sqlite")):
            raise StudyError("the study already holds session files; adding questionnaires "
                             "changes its manifest under them: use a new study folder")
        block = default_panel(colour_check=not args.no_colour_check)
        if args.acuity or args.no_colour_check or on_fail != "flag":
            block["vision_screening"] = {"colour": not args.no_colour_check,
                                         "acuity": bool(args.acuity), "on_fail": on_fail}
            if not args.acuity and args.no_colour_check:
                del block["vision_screening"]
        seat = manifest.protocol.viewing_distance_cm
        if seat is not None and "vision_screening" in block:  # screen where they will sit
            block["vision_screening"]["viewing_distance_cm"] = seat
        data = manifest.model_dump(mode="json", exclude_none=True)
        data["panel"] = block
        manifest = parse_manifest(data, source=str(args.study / MANIFEST_NAME))
        save_manifest(manifest, args.study / MANIFEST_NAME)
        print(f"added the panel templates to {args.study / MANIFEST_NAME}; edit the questions "
              "there, then run: cgvq-study check " + str(args.study))
    panel = manifest.panel
    if panel is None:
        print("the manifest has no panel block: participants are asked nothing besides the "
              "ratings (add one with --add-templates)")
        return 0
    for qn in panel.questionnaires:
        when = "before the first trial" if qn.when == "before" else "after the last trial"
        print(f"{qn.id} ({when}{', voluntary' if qn.voluntary else ''}): {qn.title}")
        for k, page in enumerate(panel_pages(qn), start=1):
            print(f"  page {k}: " + "; ".join(page))
    vs = panel.vision_screening
    if vs is not None:
        checks = [n for n, on in (("colour", vs.colour), ("acuity", vs.acuity)) if on]
        print(f"vision checks: {', '.join(checks) or 'none'} at {vs.viewing_distance_cm:g} cm; "
              f"a failed check: {vs.on_fail}")
        if vs.acuity:
            print(f"  acuity: {vs.optotype}, pass at logMAR {vs.acuity_logmar:g} and Weber "
                  f"contrast {vs.contrast_weber:g}")
        if (problem := screening_distance_problem(manifest)) is not None:
            print(f"  warning: {problem}")
    return 0


def panel_pages(questionnaire) -> list[list[str]]:
    """Each page's questions as 'id (type, required/optional)'."""
    return [[f"{q.id} ({q.type}, {'required' if q.required else 'optional'})"
             for q in page.questions] for page in questionnaire.pages]
