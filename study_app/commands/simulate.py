"""``cgvq-study simulate``: simulated participants with known truth, as session files."""

from __future__ import annotations

import argparse

NAME = "simulate"
HELP = "simulate a panel of raters (SUREAL generative model) into session files"


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--manifest", required=True, help="the study's manifest.json")
    parser.add_argument("--raters", type=int, required=True, help="number of raters")
    parser.add_argument("--outliers", type=int, default=0,
                        help="how many of them are outlier raters (default 0)")
    parser.add_argument("--outlier-kind", choices=("random", "inverted", "mixed"),
                        default="random", help="how outliers answer (default random)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the whole simulation")
    parser.add_argument("--repetitions", type=int, default=None,
                        help="repetitions per stimulus (default: the manifest's protocol)")
    parser.add_argument("--out", required=True,
                        help="folder for the session files and ground_truth.json "
                             "(e.g. STUDY/sessions)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace sessions simulated into --out before")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from ..errors import StudyError
    from ..simulate import SimulationOptions, simulate_panel

    if args.seed < 0:
        raise StudyError(f"--seed {args.seed}: use a non-negative integer")
    opts = SimulationOptions(raters=args.raters, outliers=args.outliers,
                             outlier_kind=args.outlier_kind, seed=args.seed,
                             repetitions=args.repetitions)
    truth = simulate_panel(args.manifest, args.out, opts, overwrite=args.overwrite,
                           progress=not args.no_progress)
    print(f"wrote {args.raters} session files and the ground truth {truth}")
    return 0
