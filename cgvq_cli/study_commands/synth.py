"""``cgvq-study synth``: make a synthetic CG stimulus set (videos + manifest)."""

from __future__ import annotations

import argparse
import re

from session_store.errors import StudyError

NAME = "synth"
EXTRA = "synth"  # the post-processing needs scipy
HELP = "render synthetic computer-graphics stimuli (six distortion families x 4 levels)"


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*(?:[xX]\s*(\d+))?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size; use e.g. 128 or 160x120")
    w = int(m.group(1))
    return w, int(m.group(2) or w)


def register(parser: argparse.ArgumentParser) -> None:
    from study_app.synth import DEFAULT_SCENES, METHODS

    parser.add_argument("--out", required=True, help="study folder to create")
    parser.add_argument("--size", type=_size, default=(128, 128),
                        help="frame size, N or WxH, multiples of 8 (default 128)")
    parser.add_argument("--seconds", type=float, default=1.0, help="clip length (default 1)")
    parser.add_argument("--fps", type=int, default=30, choices=(30, 60),
                        help="frame rate of all families except interpolation (always 60)")
    parser.add_argument("--scenes", default=",".join(DEFAULT_SCENES),
                        help="comma-separated scene names (default %(default)s)")
    parser.add_argument("--methods", default="all",
                        help=f"comma-separated families or 'all': {', '.join(METHODS)}")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing study in --out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from study_app.synth import SynthOptions, available_scenes, parse_methods, synthesize

    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip())
    if scenes == ("all",):
        scenes = tuple(available_scenes())
    opts = SynthOptions(width=args.size[0], height=args.size[1], seconds=args.seconds,
                        fps=args.fps, scenes=scenes, methods=tuple(parse_methods(args.methods)),
                        seed=args.seed)
    if args.seed < 0:
        raise StudyError(f"--seed {args.seed}: use a non-negative integer")
    path = synthesize(args.out, opts, overwrite=args.overwrite, progress=not args.no_progress)
    print(f"wrote {path}")
    return 0
